"""Input files a user really writes: YAML's ``off``, blank lines, a byte-order mark, semicolons,
empty or directory image paths, robot files with unit mistakes. Each wrong one answered with the
file, the line and the likely cause (exit 2, no traceback); each right one read."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_bad_input import run_bad, write_dataset

from relcal.data.dataset import load_dataset
from relcal.errors import RelcalError
from relcal.io import read_table
from relcal.robot.loading import get_robot
from relcal.robot.model import load_model


def test_hayati_off_as_yaml_reads_it(tmp_path):
    root = write_dataset(tmp_path / "d")
    (root / "dataset.yaml").write_text("robot: a465\nhayati: off\n")
    assert not load_dataset(root).model.hayati.any()
    (root / "dataset.yaml").write_text("robot: a465\nhayati: auto\n")
    assert load_dataset(root).model.hayati.any()


def test_line_numbers_count_blank_lines(capsys, tmp_path):
    root = write_dataset(tmp_path / "d")
    lines = (root / "samples.csv").read_text().splitlines()
    cells = lines[5].split(",")
    cells[3] = "abc"
    lines[5] = ",".join(cells)
    lines[2:2] = ["", "  ", ""]  # three blank lines before it: the bad row is line 9
    (root / "samples.csv").write_text("\n".join(lines) + "\n")
    run_bad(capsys, ["calibrate", root], "samples.csv line 9: q3: expected a number, got 'abc'")


def test_byte_order_mark_and_semicolons_are_read(tmp_path):
    root = write_dataset(tmp_path / "d")
    reference = load_dataset(root)
    text = (root / "samples.csv").read_text()
    (root / "samples.csv").write_bytes(b"\xef\xbb\xbf" + text.replace(",", ";").encode())
    got = load_dataset(root)
    assert got.ids == reference.ids
    np.testing.assert_array_equal(got.q, reference.q)
    np.testing.assert_array_equal(got.poses, reference.poses)


def test_decimal_commas_are_named(capsys, tmp_path):
    root = write_dataset(tmp_path / "d")
    lines = (root / "samples.csv").read_text().splitlines()
    lines = [lines[0].replace(",", ";")] + [
        ln.replace(",", ";").replace(".", ",") for ln in lines[1:]
    ]
    (root / "samples.csv").write_text("\n".join(lines) + "\n")
    run_bad(
        capsys, ["calibrate", root], "samples.csv line 2: q1: expected a number", "decimal comma"
    )


def test_table_rows_keep_their_line_numbers(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text('\n\nid,a\n\n1,"x, y"\n\n2,z\n')
    header, rows = read_table(path, "row")
    assert header == ["id", "a"]
    assert [r.line for r in rows] == [5, 7]
    # a field spanning lines is a quote left open (it swallowed the rows up to the next quote,
    # silently: a target or sample fewer): refused with the lines it spans
    path.write_text('\n\nid,a\n\n1,"x\ny"\n2,z\n')
    with pytest.raises(RelcalError, match=r"line 5: a quoted field runs on to line 6 \('x y'\)"):
        read_table(path, "row")


@pytest.mark.parametrize(
    ("text", "patterns"),
    [
        ("[1, 2]", ["dataset.yaml line 1: (top level): expected a mapping", "list"]),
        ("robot: a465\nhandeye: [0, 0.1]\n", ["dataset.yaml line 2: handeye: expected a mapping"]),
    ],
)
def test_no_internal_class_names(capsys, tmp_path, text, patterns):
    root = write_dataset(tmp_path / "d", spec=text)
    err = run_bad(capsys, ["calibrate", root], *patterns)
    assert "_DatasetSpec" not in err and "_Frame" not in err and "instance of" not in err


def image_dataset(root, cell):
    root.mkdir()
    (root / "img").mkdir()
    (root / "dataset.yaml").write_text(
        "robot: a465\nboard: {type: chessboard, rows: 7, columns: 10, square: 0.02}\n"
        "camera: calibrate\n"
    )
    (root / "samples.csv").write_text(f"id,q1,q2,q3,q4,q5,q6,image\na,1,2,3,4,5,6,{cell}\n")
    return root


def test_empty_image_path(capsys, tmp_path):
    root = image_dataset(tmp_path / "d", "")
    run_bad(capsys, ["calibrate", root], "samples.csv line 2: image: empty; expected an image path")


def test_directory_as_image(capsys, tmp_path):
    root = image_dataset(tmp_path / "d", "img")
    run_bad(capsys, ["calibrate", root], "samples.csv line 2: image:", "is a directory")


# --- robot model files ----------------------------------------------------------------------------


def robot_file(tmp_path, joints, head="name: x\nconvention: dh\n"):
    path = tmp_path / "arm.yaml"
    path.write_text(head + "joints:\n" + "".join(f"  - {j}\n" for j in joints))
    return path


@pytest.mark.parametrize(
    ("head", "joints", "patterns"),
    [
        (
            None,
            ["{d: 330, alpha: 90}", "{a: 303}"],
            ["line 4: joints[0].d: 330 m looks like millimetres"],
        ),
        (None, ["{a: 1e300}"], ["line 4: joints[0].a: 1e+300 m is not a physical"]),
        (
            None,
            ['{d: 0.3, alpha: "90"}'],
            ["line 4: joints[0].alpha: expected a number, got the text '90'"],
        ),
        (
            None,
            ["{name: waist}", "{name: waist}"],
            ["joint names must be unique: waist named twice"],
        ),
        (
            "name: x\nconvention: dh\nangle_unit: rad\n",
            ["{alpha: 90}", "{alpha: 0}"],
            ["joints[0].alpha: 90 looks like degrees, but angle_unit: rad"],
        ),
        (
            "name: x\nconvention: dh\nangle_unit: rad\n",
            ["{limits: [-170, 170]}"],
            ["joints[0].limits", "looks like degrees"],
        ),
        (
            "name: x\nconvention: dh\nbase: {xyz: [0, 0, 800]}\n",
            ["{a: 0.3}"],
            ["base.xyz: 800 m looks like millimetres"],
        ),
    ],
)
def test_robot_file_mistakes(capsys, tmp_path, head, joints, patterns):
    path = robot_file(tmp_path, joints, head or "name: x\nconvention: dh\n")
    run_bad(capsys, ["simulate", "--robot", path, "--poses", "10"], *patterns)


def test_right_robot_files_load(tmp_path):
    path = robot_file(
        tmp_path,
        ["{d: 0.3, a: 1.5e-2, alpha: 1.5707963}", "{a: 4.9, limits: [-3.1, 3.1]}"],
        "name: x\nconvention: dh\nangle_unit: rad\n",
    )
    model = load_model(path)
    assert model.a[0] == pytest.approx(0.015) and model.a[1] == 4.9
    for name in ("a465", "puma560", "ur5e", "irb120", "franka_fr3"):
        get_robot(name)


def test_puma560_matches_its_cited_source():
    """Robotics Toolbox for Python, roboticstoolbox/models/DH/Puma560.py: d1 = 26.45 in and the
    joint limits of the same file."""
    puma = get_robot("puma560")
    assert puma.d[0] == pytest.approx(26.45 * 0.0254, abs=1e-9)
    np.testing.assert_allclose(np.degrees(puma.upper), [160, 110, 135, 266, 100, 266])
    np.testing.assert_allclose(np.degrees(puma.lower), [-160, -110, -135, -266, -100, -266])
    np.testing.assert_allclose(puma.a, [0, 0.4318, 0.0203, 0, 0, 0])
    np.testing.assert_allclose(puma.d[1:], [0, 0.15005, 0.4318, 0, 0])


def test_board_with_one_row_too_many_is_not_posed():
    """A 7 x 10 chessboard seen close and nearly square-on (pose of a `relcal simulate --images`
    frame): declared as 8 x 10, OpenCV's finder takes the pattern's edge for a row of corners and
    the pose fits at 0.03 px. The squares around the grid give it away."""
    from dataclasses import replace

    from relcal.sim.synth import DEFAULT_CAMERA
    from relcal.vision.boards import Board
    from relcal.vision.detect import Detection, Rejected, detect
    from relcal.vision.render import render_board

    board = Board("chessboard", 7, 10, 0.02)
    rot = Rotation.from_euler("xyz", [0.933, -1.147, -134.229], degrees=True).as_matrix()
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rot, [0.0966, 0.0504, -0.2745]
    image = render_board(board, DEFAULT_CAMERA, pose, 0.8, 2.0, 0.3, 0)
    assert isinstance(detect(image, board), Detection)
    wrong = detect(image, replace(board, rows=8))
    assert isinstance(wrong, Rejected)
    assert "does not match the printed pattern" in wrong.reason
    assert "fewer rows or columns than declared" in wrong.reason


def test_importer_messages_name_no_internal_class(capsys, tmp_path):
    path = tmp_path / "measurements.yaml"
    path.write_text("sample_1:\n  pose: 3\n  target_joints: [0.1, 0.2]\n")
    err = run_bad(
        capsys,
        ["import", "rct-positioner", path, "--out", tmp_path / "out"],
        "measurements.yaml line 2: sample_1.pose: expected a mapping of fields",
    )
    assert "_Observation" not in err and "_Pose" not in err and not (tmp_path / "out").exists()
