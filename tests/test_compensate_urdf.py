"""``relcal compensate CALIBRATION`` on a URDF robot whose calibrated chain is not the URDF's
default one: example-robot-data's UR5 (default chain world -> wrist_3_link, calibrated
base_link -> tool0) with planted errors, calibrated from synthetic relative poses; the robot, chain
and nominal model come from the calibration, and the true arm reaches the compensated targets to
the calibration's own held-out accuracy. A wrong chain or another robot is refused."""

import json

import numpy as np
import pytest
from conftest import random_q
from helpers_sim import BOARD, HANDEYE, true_errors
from scipy.spatial.transform import Rotation
from urdf_helpers import ROBOTS

from relcal import geometry as tf
from relcal.calibration.compensate import aligned_errors
from relcal.cli import main
from relcal.data.dataset import write_samples
from relcal.robot.kinematics import apply_errors, fk, make_layout
from relcal.robot.loading import get_robot

UR5 = ROBOTS / "ur_description/urdf/ur5_robot.urdf"
CHAIN = ("base_link", "tool0")


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """A UR5 (chain base_link -> tool0) with planted errors of 0.1..0.9 mm and 0.01..0.9 deg,
    40 relative poses with 0.02 mm / 0.001 deg noise, calibrated by the command line."""
    if not UR5.is_file():
        pytest.skip(f"{UR5} is not available (pip install example-robot-data)")
    root = tmp_path_factory.mktemp("ur5")
    rng = np.random.default_rng(7)
    model = get_robot(UR5, *CHAIN)
    layout = make_layout(model)
    truth = true_errors(layout, rng)
    true_model = apply_errors(model, layout, truth)
    true_x = HANDEYE @ tf.from_vector(np.r_[rng.normal(0, 1e-3, 3), rng.normal(0, 5e-3, 3)])
    q = random_q(model, 40, rng, scale=0.5)
    poses = BOARD @ fk(true_model, q) @ true_x
    poses = poses @ tf.from_vector(
        np.c_[rng.normal(0, 2e-5, (40, 3)), rng.normal(0, 2e-5, (40, 3))]
    )
    data = root / "data"
    data.mkdir()
    (data / "dataset.yaml").write_text(
        f"robot: {{urdf: {UR5}, root: {CHAIN[0]}, tip: {CHAIN[1]}}}\n"
        "joint_unit: deg\nhandeye: {xyz: [0, 0.04, 0.06]}\n"
    )
    ids = [f"s{k:03d}" for k in range(40)]
    (data / "samples.csv").write_text(
        write_samples(data / "samples.csv", ids, np.degrees(q), poses=poses)
    )
    cal = root / "cal"
    assert main(["calibrate", str(data), "--out", str(cal), "--quiet"]) == 0
    return cal, model, true_model, true_x, rng


def pose_targets(path, targets):
    rows = ["id,x,y,z,qx,qy,qz,qw"]
    for k, t in enumerate(targets):
        quat = Rotation.from_matrix(t[:3, :3]).as_quat()
        rows.append(f"t{k:02d}," + ",".join(f"{v:.12g}" for v in (*t[:3, 3], *quat)))
    path.write_text("\n".join(rows) + "\n")


def read_joints(path, n):
    lines = path.read_text().splitlines()
    return np.radians([[float(v) for v in line.split(",")[1 : n + 1]] for line in lines[1:]])


def test_compensate_a_urdf_robot_from_its_calibration_alone(calibrated, tmp_path, capsys):
    cal, nominal, true_model, true_x, rng = calibrated
    results = json.loads((cal / "results.json").read_text())
    assert results["nominal_robot"]["chain"]["root"] == "base_link"
    assert results["nominal_robot"]["chain"]["tip"] == "tool0"
    held = {f["file"]: f for f in results["artifacts"]["files"]}["model.yaml"]["held_out"]
    validated_mm = held["position_rms_mm"]

    # targets: tool0 poses the nominal model reaches inside the calibrated joint ranges, the
    # elbow bent (a stretched arm reaches a target only on the branch the nominal one has)
    q_nominal = random_q(nominal, 90, rng, scale=0.4)
    q_nominal = q_nominal[np.abs(q_nominal[:, 2]) > np.radians(40)][:30]
    targets = fk(nominal, q_nominal)
    poses = tmp_path / "poses.csv"
    pose_targets(poses, targets)
    out, doc = tmp_path / "joints.csv", tmp_path / "joints.json"
    argv = ["compensate", str(cal), "--targets", str(poses), "--out", str(out), "--json", str(doc)]
    assert main(argv) == 0, capsys.readouterr().err
    q_comp = read_joints(out, 6)
    report = json.loads(doc.read_text())
    assert report["chain"]["root"] == "base_link" and report["summary"]["n_not_converged"] == 0

    # what the true arm does: the camera (the frame the calibration validated: relative
    # calibration determines F X, not F alone) before and after, in a taught user frame
    wanted = (targets @ np.asarray(report_handeye(results)))[:, :3, 3]
    before = aligned_errors(wanted, (fk(true_model, q_nominal) @ true_x)[:, :3, 3])
    after = aligned_errors(wanted, (fk(true_model, q_comp) @ true_x)[:, :3, 3])
    rms_before = np.sqrt(np.mean(before**2)) * 1e3
    rms_after = np.sqrt(np.mean(after**2)) * 1e3
    with capsys.disabled():
        print(f"camera RMS {rms_before:.3f} -> {rms_after:.4f} mm (validated {validated_mm} mm)")
    assert rms_before > 20 * rms_after
    assert rms_after < validated_mm  # within the validated accuracy
    # the flange itself: what the hand-eye absorbed stays, a constant offset in the tool frame
    flange = aligned_errors(targets[:, :3, 3], fk(true_model, q_comp)[:, :3, 3])
    assert np.sqrt(np.mean(flange**2)) * 1e3 < 0.2 * rms_before

    # the same through a joint program and through relcal's plan file (its own header)
    plan = tmp_path / "plan.csv"
    header = ",".join(["id", *nominal.joint_names])
    rows = [f"p{k:02d}," + ",".join(f"{v:.12g}" for v in np.degrees(q)) for k, q in
            enumerate(q_nominal)]  # fmt: skip
    plan.write_text(
        f"# relcal plan: robot {nominal.name}, joint unit deg\n{header}\n" + "\n".join(rows) + "\n"
    )
    out2 = tmp_path / "joints2.csv"
    assert main(["compensate", str(cal), "--targets", str(plan), "--out", str(out2)]) == 0
    q_plan = read_joints(out2, 6)  # the program's own branch: corrections of its joints
    assert capsys.readouterr().err.count("compensated") == 2
    after = aligned_errors(wanted, (fk(true_model, q_plan) @ true_x)[:, :3, 3])
    assert np.sqrt(np.mean(after**2)) * 1e3 < validated_mm


def report_handeye(results):
    he = results["handeye"]
    return tf.from_xyz_rpy(np.array(he["xyz_m"]), np.radians(he["rpy_deg"]))


def test_compensate_refuses_another_chain_or_robot(calibrated, tmp_path, capsys):
    cal, nominal, _, _, rng = calibrated
    poses = tmp_path / "poses.csv"
    pose_targets(poses, fk(nominal, random_q(nominal, 5, rng, scale=0.4)))
    out = tmp_path / "joints.csv"
    base = ["compensate", str(cal), "--targets", str(poses), "--out", str(out)]

    # the URDF's default chain (world -> wrist_3_link): the joints match, the chain does not
    assert main([*base, "--nominal", str(UR5), "--root", "world", "--tip", "wrist_3_link"]) == 2
    err = capsys.readouterr().err
    assert "chain world -> wrist_3_link, the calibration's is base_link -> tool0" in err
    assert not out.exists()
    # a URDF --nominal without --root/--tip takes the calibration's chain; the former spelling
    argv = ["compensate", "--model", str(cal / "model.yaml"), "--targets", str(poses)]
    assert main([*argv, "--nominal", str(UR5), "--out", str(out)]) == 0
    assert "former spelling" in capsys.readouterr().err
    # another robot
    out.unlink()
    assert main([*base, "--nominal", "ur5e"]) == 2
    assert "joints shoulder_pan, shoulder_lift" in capsys.readouterr().err and not out.exists()
    # a joint file with a seventh column is refused, never truncated
    seven = tmp_path / "seven.csv"
    seven.write_text("id,q1,q2,q3,q4,q5,q6,q7\na,0,-40,60,0,30,0,10\n")
    assert main(["compensate", str(cal), "--targets", str(seven), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "7 joint columns" in err and "has 6 joints" in err and not out.exists()


def test_the_gate_refuses_corrections_the_calibration_cannot_produce(calibrated, tmp_path, capsys):
    """A joint program written for the URDF's default chain, compensated with a nominal
    model of that chain given as a plain model file (so the chain check cannot see it): the
    predicted misses are hundreds of mm, far beyond what the calibration produces; refused."""
    from relcal.robot.model import dump_model

    cal, _, _, _, rng = calibrated
    other = get_robot(UR5)  # world -> wrist_3_link: the same joints, another tip frame
    model_file = tmp_path / "controller.yaml"
    model_file.write_text(dump_model(other))
    program = tmp_path / "program.csv"
    q = random_q(other, 5, rng, scale=0.4)
    program.write_text(
        "id," + ",".join(other.joint_names) + "\n"
        + "".join(f"a{k}," + ",".join(f"{v:.10g}" for v in np.degrees(row)) + "\n"
                  for k, row in enumerate(q))
    )  # fmt: skip
    out = tmp_path / "joints.csv"
    argv = ["compensate", str(cal), "--targets", str(program), "--nominal", str(model_file)]
    assert main([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    # refused before any target is solved: the nominal's flange lands hundreds of mm from the
    # calibration's (relcal.calibration.compensate.check_nominal); were it close enough to pass
    # that, the corrections' gate would refuse (test_compensate.py)
    assert f"--nominal {model_file}" in err and "leave --nominal out" in err, err
    assert not out.exists()
