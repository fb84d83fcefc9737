"""Compensation on the synthetic A465: calibrate from noise-free relative data, then reach 50
random target poses with the true robot using nominal and compensated joints."""

import json
from dataclasses import replace

import numpy as np
import pytest
from conftest import random_q
from helpers_dataset import synthetic_dataset
from helpers_sim import HANDEYE, make_problem

from relcal import geometry as tf
from relcal.calibration.compensate import aligned_errors, compensate
from relcal.calibration.identify import calibrated_handeye, identify
from relcal.calibration.measurement import split_params
from relcal.cli import main
from relcal.robot.export import calibrated_model
from relcal.robot.kinematics import fk
from relcal.robot.loading import get_robot
from relcal.robot.model import auto_hayati, dump_model, load_model


def test_compensation_brings_positioning_errors_down(a465, rng, tmp_path):
    nominal = auto_hayati(a465)
    problem, truth = make_problem(nominal, "invariant", "pose", rng, n_poses=40)
    result = identify(problem)
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


def test_calibrate_then_compensate_end_to_end(tmp_path, rng):
    """The user's path on the synthetic A465 dataset (pose noise 0.02 mm / 0.001 deg): calibrate
    writes the report, URDF, YAML and JSON; compensate, with the camera as the tool, brings the
    true arm's positioning errors at 50 random targets down at least 5x."""
    syn = synthetic_dataset(tmp_path / "d", n=40)
    out = tmp_path / "out"
    report = tmp_path / "report.html"
    assert main(["calibrate", str(syn.root), "--out", str(out), "--report", str(report)]) == 0
    assert {"model.yaml", "robot.urdf", "results.json", "parameters.csv"} <= {
        p.name for p in out.iterdir()
    }
    assert report.read_text().startswith("<!DOCTYPE html>")
    handeye = json.loads((out / "results.json").read_text())["handeye"]
    camera = tf.from_xyz_rpy(np.array(handeye["xyz_m"]), np.radians(handeye["rpy_deg"]))
    calibrated = replace(load_model(out / "model.yaml"), tool=camera)
    nominal = replace(auto_hayati(get_robot("a465")), tool=HANDEYE)
    (tmp_path / "cal.yaml").write_text(dump_model(calibrated))
    (tmp_path / "nominal.yaml").write_text(dump_model(nominal))

    q_program = random_q(nominal, 50, rng, scale=0.6)
    program = tmp_path / "program.csv"
    program.write_text(
        "id," + ",".join(f"q{i + 1}" for i in range(6)) + "\n"
        + "".join(f"t{k}," + ",".join(f"{v:.12g}" for v in np.degrees(q)) + "\n"
                  for k, q in enumerate(q_program))
    )  # fmt: skip
    joints = tmp_path / "joints.csv"
    args = ["compensate", "--model", str(tmp_path / "cal.yaml"), "--targets", str(program)]
    assert main([*args, "--nominal", str(tmp_path / "nominal.yaml"), "--out", str(joints)]) == 0
    rows = [line.split(",") for line in joints.read_text().splitlines()[1:]]
    q_comp = np.radians([[float(v) for v in row[1:7]] for row in rows])

    true_arm = replace(syn.true_model, tool=syn.true_handeye)
    wanted = fk(nominal, q_program)[:, :3, 3]
    before = aligned_errors(wanted, fk(true_arm, q_program)[:, :3, 3])
    after = aligned_errors(wanted, fk(true_arm, q_comp)[:, :3, 3])
    rms_before, rms_after = np.sqrt(np.mean(before**2)), np.sqrt(np.mean(after**2))
    print(f"positioning RMS in a user frame: {rms_before * 1e3:.3f} -> {rms_after * 1e3:.4f} mm")
    assert rms_before > 5 * rms_after


def test_compensate_warns_outside_the_joint_ranges_the_calibration_covered(tmp_path, capsys):
    """results.json beside the model records the training joint ranges: a target beyond them is
    named on standard error (its accuracy was never validated); targets inside are not."""
    syn = synthetic_dataset(tmp_path / "d", n=30)
    out = tmp_path / "out"
    assert main(["calibrate", str(syn.root), "--out", str(out), "--quiet"]) == 0
    ranges = json.loads((out / "results.json").read_text())["joint_ranges"]["joints"]
    lower = np.array([j["lower"] for j in ranges])
    upper = np.array([j["upper"] for j in ranges])
    model = load_model(out / "model.yaml")
    inside = (lower + upper) / 2
    beyond = inside.copy()
    beyond[0] = upper[0] + 0.5 * (model.upper[0] - upper[0])  # within the joint's limits
    assert beyond[0] < model.upper[0] and beyond[0] > upper[0] + np.radians(2)
    program = tmp_path / "program.csv"
    program.write_text(
        "id," + ",".join(f"q{i + 1}" for i in range(6)) + "\n"
        + "".join(f"{name}," + ",".join(f"{v:.12g}" for v in np.degrees(q)) + "\n"
                  for name, q in (("in", inside), ("far", beyond)))
    )  # fmt: skip
    argv = ["compensate", "--model", str(out / "model.yaml"), "--targets", str(program)]
    argv += ["--nominal", str(out / "model.yaml"), "--out", str(tmp_path / "j.csv")]
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert "target far:" in err and "outside the joint ranges the calibration covered" in err
    assert "target in:" not in err


def test_the_gate_is_what_the_calibration_produces(a465, rng):
    """A calibration that changed only the waist's zero offset by 0.3 deg: every correction is
    exactly -0.3 deg on the waist and nothing elsewhere (independent truth), so the gate allows
    twice that plus the floor on the waist and the floor alone on the others; the predicted miss
    is what 0.3 deg turns into at the arm's reach. A correction of the same size on another
    joint, or a branch flip, is implausible."""
    from relcal.calibration.compensate import (
        GATE_FLOOR_RAD,
        GATE_MARGIN,
        GATE_SINGULAR,
        _inverse_condition,
        correction_gate,
        implausible,
    )

    offset = np.radians(0.3)
    cal = a465.with_values(theta_off=a465.theta_off + np.r_[offset, 0, 0, 0, 0, 0])
    gate = correction_gate(cal, a465)
    np.testing.assert_allclose(gate.joint[0], GATE_MARGIN * offset + GATE_FLOOR_RAD, rtol=1e-6)
    np.testing.assert_allclose(gate.joint[1:], GATE_FLOOR_RAD, atol=1e-9)
    reach = np.linalg.norm(fk(a465, random_q(a465, 500, rng))[:, :2, 3], axis=1).max()
    assert gate.position_mm < GATE_MARGIN * offset * reach * 1e3 + 0.5 + 1e-6
    assert gate.rotation_deg == pytest.approx(GATE_MARGIN * 0.3 + 0.05, rel=1e-6)

    q_nom = random_q(a465, 20, rng, scale=0.5)
    comp = compensate(cal, fk(a465, q_nom), q_nominal=q_nom)
    np.testing.assert_allclose(comp.q - q_nom, np.tile([-offset, 0, 0, 0, 0, 0], (20, 1)),
                               atol=1e-8)  # fmt: skip
    assert not implausible(comp, gate, cal).any()
    flipped = replace(comp, q=comp.q + np.r_[0, 0, 0, np.radians(2), 0, 0])
    cond = np.minimum(_inverse_condition(cal, flipped.q), _inverse_condition(cal, q_nom))
    regular = cond >= GATE_SINGULAR  # near a singularity joint corrections are warned, not gated
    assert regular.sum() >= 10 and implausible(flipped, gate, cal)[regular].all()


@pytest.mark.parametrize(
    "table, message",
    [
        (
            "id,q1,q2,q3,q4,q5,q6\na,1,2,3,4,5,6\na,2,3,4,5,6,7\n",
            "line 3: id 'a' duplicates line 2",
        ),
        ("id,q1,q2,q3,q4,q5,q6\n ,1,2,3,4,5,6\n", "line 2: id: empty; give every target an id"),
        (
            "id,x,y,z,x,rx,ry,rz\na,0.5,0,0.4,0.1,3,0,0\n",
            "line 1: header: column(s) x appear twice",
        ),
        ("id,q1,q2,q3,q4,q5,q6,q1\na,1,2,3,4,5,6,9\n", "line 1: header: column(s) q1 appear twice"),
        # decimal commas: a targets file has no dataset.yaml to declare them in
        (
            "id;q1;q2;q3;q4;q5;q6\na;1,5;2;3;4;5;6\n",
            "line 2: q1: expected a number, got '1,5' (a "
            "decimal comma? this table takes decimal points only: export it with points)",
        ),
        # a quote left open: target a swallowed into b's id (one target compensated, exit 0)
        (
            'id,q1,q2,q3,q4,q5,q6\n"a,1,2,3,4,5,6\nb",2,3,4,5,6,7\n',
            "line 2: a quoted field runs on to line 3 ('a,1,2,3,4,5,6 b'): a quote left open?",
        ),
        # a rotation vector in degrees (a controller writes radians, at most pi)
        ("id,x,y,z,rx,ry,rz\na,0.5,0,0.4,3,0,0\nb,0.5,0,0.4,180,0,0\n", "line 3: rx, ry, rz is"),
    ],
)
def test_targets_with_ambiguous_rows_or_columns_are_refused(table, message, tmp_path, a465, capsys):
    """Two targets under one id (the output cannot tell them apart), an empty id, a column
    named twice (one of them was read, the other ignored) and a rotation vector of 180 rad were
    compensated, exit 0."""
    model_path = tmp_path / "cal.yaml"
    model_path.write_text(dump_model(a465))
    targets = tmp_path / "targets.csv"
    targets.write_text(table)
    argv = ["compensate", "--model", str(model_path), "--nominal", str(model_path)]
    assert main([*argv, "--targets", str(targets), "--out", str(tmp_path / "j.csv")]) == 2
    err = capsys.readouterr().err
    assert f"{targets} {message}" in err and "Traceback" not in err
    assert not (tmp_path / "j.csv").exists()


def test_ids_with_commas_and_quotes_are_quoted_in_the_output(tmp_path, a465):
    """An id read from a quoted cell (``"a,b"``) was written unquoted: the output row had one
    field more than its header. Written quoted, the output reads back with the same ids."""
    import csv

    model_path = tmp_path / "cal.yaml"
    model_path.write_text(dump_model(a465))
    targets = tmp_path / "targets.csv"
    targets.write_text('id,q1,q2,q3,q4,q5,q6\n"a,b",1,2,3,4,5,6\n"x""y",2,3,4,5,6,7\n')
    out = tmp_path / "j.csv"
    argv = ["compensate", "--model", str(model_path), "--nominal", str(model_path)]
    assert main([*argv, "--targets", str(targets), "--out", str(out), "--quiet"]) == 0
    rows = list(csv.reader(out.read_text().splitlines()))
    assert [r[0] for r in rows[1:]] == ["a,b", 'x"y']
    assert {len(r) for r in rows} == {len(rows[0])}
