"""Compensation on the synthetic A465: calibrate from noise-free relative data, then reach 50
random target poses with the true robot using nominal and compensated joints."""

from dataclasses import replace

import numpy as np
from conftest import random_q
from helpers_sim import make_problem

from relcal.cli import main
from relcal.compensate import aligned_errors, compensate
from relcal.export import calibrated_model
from relcal.identify import calibrated_handeye, identify
from relcal.kinematics import fk
from relcal.measurement import split_params
from relcal.model import auto_hayati, dump_model


def test_compensation_brings_positioning_errors_down(a465, rng, tmp_path):
    nominal = auto_hayati(a465)
    problem, truth = make_problem(nominal, "invariant", "pose", rng, n_poses=40)
    result = identify(problem, "lm")
    true_model, true_x = split_params(problem, truth)
    # The camera is the tool: relative calibration determines F X, not F alone.
    true_robot = replace(true_model, tool=true_x)
    cal = calibrated_model(nominal, problem.layout, result.params)
    cal = replace(cal, tool=calibrated_handeye(problem, result))
    nominal_cam = replace(nominal, tool=problem.handeye)

    targets = fk(nominal_cam, random_q(nominal, 50, rng, scale=0.6))
    comp = compensate(cal, targets, nominal=nominal_cam)
    assert comp.converged.all()
    before = aligned_errors(targets[:, :3, 3], fk(true_robot, comp.q_nominal)[:, :3, 3])
    after = aligned_errors(targets[:, :3, 3], fk(true_robot, comp.q)[:, :3, 3])
    assert np.sqrt(np.mean(before**2)) > 5 * np.sqrt(np.mean(after**2))
    assert np.all(comp.predicted_position_mm > 0)
    assert np.all((comp.q >= cal.lower - 1e-9) & (comp.q <= cal.upper + 1e-9))

    # The command line: joint program in, corrected joints out.
    model_path = tmp_path / "cal.yaml"
    model_path.write_text(dump_model(cal))
    nominal_path = tmp_path / "nominal.yaml"
    nominal_path.write_text(dump_model(nominal_cam))
    program = tmp_path / "program.csv"
    rows = ["id," + ",".join(f"q{i + 1}" for i in range(6))]
    rows += [
        f"t{k}," + ",".join(f"{v:.12g}" for v in np.degrees(q))
        for k, q in enumerate(comp.q_nominal[:5])
    ]
    program.write_text("\n".join(rows) + "\n")
    out = tmp_path / "joints.csv"
    args = ["compensate", "--model", str(model_path), "--targets", str(program)]
    assert main([*args, "--nominal", str(nominal_path), "--out", str(out)]) == 0
    lines = out.read_text().splitlines()
    assert lines[0].startswith("id,q1,") and "predicted_position_mm" in lines[0] and len(lines) == 6
    written = np.array([[float(v) for v in line.split(",")[1:7]] for line in lines[1:]])
    np.testing.assert_allclose(np.radians(written), comp.q[:5], atol=1e-7)


def test_compensate_needs_nominal_for_a_joint_program(tmp_path, a465, capsys):
    model_path = tmp_path / "cal.yaml"
    model_path.write_text(dump_model(a465))
    program = tmp_path / "program.csv"
    program.write_text("id,q1,q2,q3,q4,q5,q6\na,1,2,3,4,5,6\n")
    assert main(["compensate", "--model", str(model_path), "--targets", str(program)]) == 2
    assert "a joint program needs --nominal" in capsys.readouterr().err
