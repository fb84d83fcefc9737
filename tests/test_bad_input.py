"""The bad-input catalogue: each case through the command line, answered with a clear message
naming the file and the field or line, exit status 2, and no traceback."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from relcal import geometry as tf
from relcal.cli import main
from relcal.robot.kinematics import fk
from relcal.robot.model import get_robot

A465 = get_robot("a465")


def write_dataset(
    root, n=12, unit="deg", q=None, poses=None, header=None, extra_rows=(), spec=None
):
    """A valid eye-in-hand dataset with poses given directly, then edited by the case."""
    rng = np.random.default_rng(0)
    q = rng.uniform(-1.0, 1.0, (n, 6)) if q is None else q
    poses = (
        fk(A465, q) @ tf.from_vector(np.array([0, 0.04, 0.06, 0, 0, 0])) if poses is None else poses
    )
    root.mkdir(exist_ok=True)
    (root / "dataset.yaml").write_text(
        spec or f"robot: a465\njoint_unit: {unit}\nhandeye: {{xyz: [0, 0.04, 0.06]}}\n"
    )
    cols = header or "id,q1,q2,q3,q4,q5,q6,x,y,z,qx,qy,qz,qw"
    rows = [cols]
    shown = np.degrees(q) if unit == "deg" else q
    for k in range(n):
        quat = Rotation.from_matrix(poses[k, :3, :3]).as_quat()
        cells = [f"s{k}", *map(str, shown[k]), *map(str, poses[k, :3, 3]), *map(str, quat)]
        rows.append(",".join(cells))
    rows += list(extra_rows)
    (root / "samples.csv").write_text("\n".join(rows) + "\n")
    return root


def run_bad(capsys, argv, *patterns):
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err
    for pattern in patterns:
        assert pattern in err, err
    return err


def edit(path, old, new):
    path.write_text(path.read_text().replace(old, new, 1))


def test_01_missing_robot_file(capsys, tmp_path):
    run_bad(capsys, ["simulate", "--robot", tmp_path / "arm.yaml"], "arm.yaml: file not found")


def test_02_malformed_robot_yaml(capsys, tmp_path):
    path = tmp_path / "arm.yaml"
    path.write_text("name: x\nconvention: dh\njoints: [\n")
    run_bad(capsys, ["simulate", "--robot", path], "arm.yaml line", "malformed YAML")


def test_03_unknown_robot_name(capsys):
    run_bad(capsys, ["simulate", "--robot", "kuka_kr16"], "unknown robot 'kuka_kr16'", "a465")


def test_04_robot_field_of_wrong_type(capsys, tmp_path):
    path = tmp_path / "arm.yaml"
    path.write_text("name: x\nconvention: dh\njoints:\n  - {d: 0.3, alpha: ninety}\n")
    run_bad(capsys, ["simulate", "--robot", path], "arm.yaml line 4: joints[0].alpha")


def test_05_robot_with_no_joints(capsys, tmp_path):
    path = tmp_path / "arm.yaml"
    path.write_text("name: x\nconvention: dh\njoints: []\n")
    run_bad(capsys, ["simulate", "--robot", path], "joints: List should have at least 1 item")


def test_06_dataset_folder_missing(capsys, tmp_path):
    run_bad(capsys, ["calibrate", tmp_path / "nope"], "nope: not a dataset folder")


def test_07_dataset_yaml_unknown_field(capsys, tmp_path):
    root = write_dataset(tmp_path / "d", spec="robot: a465\njoint_units: deg\n")
    run_bad(capsys, ["calibrate", root], "dataset.yaml line 2: joint_units: Extra inputs")


def test_08_dataset_yaml_bad_mode(capsys, tmp_path):
    root = write_dataset(tmp_path / "d", spec="robot: a465\nmode: eye_on_hand\n")
    run_bad(capsys, ["calibrate", root], "dataset.yaml line 2: mode: Input should be")


def test_09_samples_file_missing(capsys, tmp_path):
    root = write_dataset(tmp_path / "d")
    (root / "samples.csv").unlink()
    run_bad(capsys, ["calibrate", root], "samples.csv: file not found")


def test_10_wrong_joint_count(capsys, tmp_path):
    root = write_dataset(tmp_path / "d")
    edit(root / "samples.csv", "q6,", "q6,q7,")
    run_bad(capsys, ["calibrate", root], "samples.csv line 1", "unexpected q7 (wrong joint count?)")


def test_11_row_with_missing_field(capsys, tmp_path):
    root = write_dataset(tmp_path / "d", extra_rows=["s99,1,2,3"])
    run_bad(capsys, ["calibrate", root], "samples.csv line 14: 4 fields, expected 14")


def test_12_nan_joint_angle(capsys, tmp_path):
    root = write_dataset(tmp_path / "d")
    lines = (root / "samples.csv").read_text().splitlines()
    cells = lines[3].split(",")
    cells[2] = "nan"
    lines[3] = ",".join(cells)
    (root / "samples.csv").write_text("\n".join(lines) + "\n")
    run_bad(capsys, ["calibrate", root], "samples.csv line 4: q2: expected a finite number")


def test_13_infinite_position(capsys, tmp_path):
    root = write_dataset(tmp_path / "d")
    lines = (root / "samples.csv").read_text().splitlines()
    cells = lines[2].split(",")
    cells[7] = "inf"
    lines[2] = ",".join(cells)
    (root / "samples.csv").write_text("\n".join(lines) + "\n")
    run_bad(capsys, ["calibrate", root], "samples.csv line 3: x: expected a finite number")


def test_14_not_a_number(capsys, tmp_path):
    root = write_dataset(tmp_path / "d", extra_rows=["s99,1,2,3,4,5,six,0,0,0,0,0,0,1"])
    run_bad(capsys, ["calibrate", root], "samples.csv line 14: q6: expected a number, got 'six'")


def test_15_degrees_declared_as_radians(capsys, tmp_path):
    root = write_dataset(tmp_path / "d", unit="deg")
    edit(root / "dataset.yaml", "joint_unit: deg", "joint_unit: rad")
    run_bad(capsys, ["calibrate", root], "looks like degrees", "joint_unit: rad")


def test_16_radians_declared_as_degrees(capsys, tmp_path):
    root = write_dataset(tmp_path / "d", unit="rad")
    edit(root / "dataset.yaml", "joint_unit: rad", "joint_unit: deg")
    run_bad(capsys, ["calibrate", root], "looks like radians", "joint_unit: deg")


def test_17_duplicate_sample_ids(capsys, tmp_path):
    root = write_dataset(tmp_path / "d")
    edit(root / "samples.csv", "s3,", "s2,")
    run_bad(capsys, ["calibrate", root], "samples.csv line 5: id 's2' duplicates line 4")


def test_18_non_unit_quaternion(capsys, tmp_path):
    root = write_dataset(tmp_path / "d", extra_rows=["s99,1,2,3,4,5,6,0,0,0,0.5,0,0,0.5"])
    run_bad(capsys, ["calibrate", root], "samples.csv line 14: qx, qy, qz, qw: expected a unit")


def test_19_missing_image(capsys, tmp_path):
    root = write_dataset(tmp_path / "d", header="id,q1,q2,q3,q4,q5,q6,image")
    lines = ["id,q1,q2,q3,q4,q5,q6,image", "a,1,2,3,4,5,6,img/a.png"]
    (root / "samples.csv").write_text("\n".join(lines) + "\n")
    run_bad(capsys, ["calibrate", root], "samples.csv line 2: image: file not found")


def test_20_too_few_poses(capsys, tmp_path):
    root = write_dataset(tmp_path / "d", n=3)
    run_bad(capsys, ["calibrate", root], "only 3 usable samples")


def test_21_poses_that_do_not_vary_a_joint(capsys, tmp_path):
    q = np.random.default_rng(1).uniform(-1, 1, (20, 6))
    q[:, 3] = 0.2  # joint 4 never moves
    q[:, 5] = 0.1
    root = write_dataset(tmp_path / "d", q=q)
    run_bad(capsys, ["calibrate", root], "the poses identify only", "vary the joints more")


def test_22_header_without_pose_or_image(capsys, tmp_path):
    root = write_dataset(tmp_path / "d")
    (root / "samples.csv").write_text("id,q1,q2,q3,q4,q5,q6\na,1,2,3,4,5,6\n")
    run_bad(capsys, ["calibrate", root], "expected an 'image' column, or a pose", "exactly one")


def test_23_empty_samples_file(capsys, tmp_path):
    root = write_dataset(tmp_path / "d")
    (root / "samples.csv").write_text("\n")
    run_bad(capsys, ["calibrate", root], "samples.csv: empty; expected a header line")


def test_24_errors_file_with_unknown_parameter(capsys, tmp_path):
    path = tmp_path / "errors.yaml"
    path.write_text("errors:\n  theta[1]: 0.1\n")
    run_bad(capsys, ["simulate", "--errors", path], "errors.yaml: errors: unknown parameter")


def test_25_errors_file_with_bad_unit(capsys, tmp_path):
    path = tmp_path / "errors.yaml"
    path.write_text("length_unit: inch\nerrors: {}\n")
    run_bad(capsys, ["simulate", "--errors", path], "errors.yaml line 1: length_unit")


def test_26_bad_noise(capsys):
    run_bad(capsys, ["simulate", "--noise", "0.1,-2"], "--noise '0.1,-2': expected")


def test_27_compensate_targets_with_bad_quaternion(capsys, tmp_path):
    model = tmp_path / "cal.yaml"
    from relcal.robot.model import dump_model

    model.write_text(dump_model(A465))
    targets = tmp_path / "t.csv"
    targets.write_text("id,x,y,z,qx,qy,qz,qw\na,0.3,0,0.3,0,0,0,2\n")
    run_bad(capsys, ["compensate", "--model", model, "--targets", targets], "t.csv line 2: qx")


def test_28_dataset_names_a_missing_robot_file(capsys, tmp_path):
    root = write_dataset(tmp_path / "d", spec="robot: arm.yaml\n")
    run_bad(capsys, ["calibrate", root], "arm.yaml: file not found")


@pytest.mark.parametrize("argv", [["simulate", "--poses", "2"]])
def test_29_too_few_simulated_poses(capsys, argv):
    run_bad(capsys, argv, "simulated poses")


def test_30_negative_board_size(capsys, tmp_path):
    argv = ["board", "--type", "chessboard", "--rows", "7", "--columns", "10", "--square", "-0.02"]
    run_bad(capsys, [*argv, "--out", tmp_path / "b.pdf"], "square: Input should be greater than 0")
    assert not (tmp_path / "b.pdf").exists()


def test_31_board_yaml_with_a_negative_spacing(capsys, tmp_path):
    spec = tmp_path / "board.yaml"
    spec.write_text("type: circles\nrows: 10\ncolumns: 10\nspacing: -0.0254\n")
    run_bad(
        capsys, ["board", "--spec", spec, "--out", tmp_path / "b.pdf"], "board.yaml line 4: spacing"
    )


def test_32_unknown_held_out_sample_id(capsys, tmp_path):
    root = write_dataset(tmp_path / "d", n=12)
    run_bad(capsys, ["calibrate", root, "--holdout-ids", "s1,nope"], "held-out sample id(s) nope")
