"""Plausibility checks: each wrong input stops ``relcal calibrate`` with the likely cause (exit 2,
nothing written, inputs untouched), and the right input passes (no false alarm)."""

import csv
import io
import json

import numpy as np
import pytest
from conftest import DATA
from helpers_dataset import synthetic_dataset
from scipy.spatial.transform import Rotation

from relcal import geometry as tf
from relcal.calibration import plausibility as pl
from relcal.cli import main
from relcal.errors import RelcalError
from relcal.robot.kinematics import fk
from relcal.robot.loading import get_robot
from relcal.robot.model import dump_model
from relcal.vision.boards import Board

POSITIONER = DATA / "rct_positioner" / "positioner_kinematic_measurements.yaml"


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    """A right dataset: 60 samples of a perturbed A465, poses given, 5 mm/1 deg outliers in 3."""
    return synthetic_dataset(tmp_path_factory.mktemp("syn") / "d", n=60, outliers=3, seed=4)


def rows_of(root):
    text = (root / "samples.csv").read_text()
    table = list(csv.reader(io.StringIO(text)))
    return table[0], table[1:]


def copy_with(synthetic, tmp_path, edit=None, spec=None):
    """A copy of the synthetic dataset with ``edit(header, rows)`` applied to its samples."""
    root = tmp_path / "d"
    root.mkdir(parents=True)
    header, rows = rows_of(synthetic.root)
    if edit is not None:
        edit(header, rows)
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerows([header, *rows])
    (root / "samples.csv").write_text(out.getvalue())
    (root / "dataset.yaml").write_text(spec or (synthetic.root / "dataset.yaml").read_text())
    return root


def run(capsys, root, *patterns, code=2):
    before = {p.name: p.read_bytes() for p in root.iterdir() if p.is_file()}
    out = root / "calibration"
    got = main(["calibrate", str(root), "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert got == code, err
    assert "Traceback" not in err
    for pattern in patterns:
        assert pattern in err, err
    if code == 2:
        assert not out.exists()
    assert before == {p.name: p.read_bytes() for p in root.iterdir() if p.is_file()}
    return err


def poses_of(header, rows):
    col = {h: i for i, h in enumerate(header)}
    values = np.array(
        [[float(r[col[c]]) for c in ("x", "y", "z", "qx", "qy", "qz", "qw")] for r in rows]
    )
    return tf.homogeneous(Rotation.from_quat(values[:, 3:]).as_matrix(), values[:, :3]), col


def set_poses(header, rows, poses, quat_order=(0, 1, 2, 3)):
    col = {h: i for i, h in enumerate(header)}
    for r, pose in zip(rows, poses, strict=True):
        quat = Rotation.from_matrix(pose[:3, :3]).as_quat()[list(quat_order)]
        for c, v in zip(
            ("x", "y", "z", "qx", "qy", "qz", "qw"), (*pose[:3, 3], *quat), strict=True
        ):
            r[col[c]] = repr(float(v))


# --- right inputs: no false alarm ----------------------------------------------------------------


def test_right_synthetic_dataset_calibrates(capsys, synthetic, tmp_path):
    root = copy_with(synthetic, tmp_path)
    run(capsys, root, code=0)
    found = json.loads((root / "calibration" / "results.json").read_text())["settings"]
    found = found["plausibility"]
    assert found["rotation_misfit_deg"] < 5.0
    assert abs(found["translation_scale"] - 1.0) < 0.01  # poses in metres of this very arm


def test_right_positioner_calibrates(capsys, tmp_path):
    if not POSITIONER.exists():
        pytest.skip("real data not available")
    assert main(["import", "rct-positioner", str(POSITIONER), "--out", str(tmp_path / "p")]) == 0
    capsys.readouterr()
    run(capsys, tmp_path / "p", code=0)
    doc = json.loads((tmp_path / "p" / "calibration" / "results.json").read_text())
    found = doc["settings"]["plausibility"]
    assert found["rotation_misfit_deg"] < 0.5
    assert "translation_scale" not in found  # rotations about one point: scale not determined


# --- wrong inputs --------------------------------------------------------------------------------


def test_poses_in_millimetres(capsys, synthetic, tmp_path):
    def edit(header, rows):
        poses, _ = poses_of(header, rows)
        poses[:, :3, 3] *= 1000
        set_poses(header, rows, poses)

    run(capsys, copy_with(synthetic, tmp_path, edit), "samples.csv", "poses look like millimetres")


def test_quaternions_w_first(capsys, synthetic, tmp_path):
    def edit(header, rows):
        poses, _ = poses_of(header, rows)
        set_poses(header, rows, poses, quat_order=(3, 0, 1, 2))  # w, x, y, z in qx..qw

    run(capsys, copy_with(synthetic, tmp_path, edit), "quaternions look w-first", "x, y, z, w")


def test_inverted_poses(capsys, synthetic, tmp_path):
    def edit(header, rows):
        poses, _ = poses_of(header, rows)
        set_poses(header, rows, tf.invert(poses))

    err = run(capsys, copy_with(synthetic, tmp_path, edit), "poses look inverted")
    assert "board in camera given, camera in board expected for eye_in_hand" in err


def test_joint_beyond_its_limit(capsys, synthetic, tmp_path):
    def edit(header, rows):
        rows[5][header.index("q2")] = "150"

    err = run(capsys, copy_with(synthetic, tmp_path, edit), "q2 (shoulder) = 150 deg", "[-90, 90]")
    assert f"sample {synthetic.ids[0][:1]}005" in err


def test_absurd_joint_reading(capsys, synthetic, tmp_path):
    def edit(header, rows):
        rows[2][header.index("q1")] = "1e308"

    run(capsys, copy_with(synthetic, tmp_path, edit), "q1 (waist) = 1e+308 deg", "outside")


def test_absurd_position(capsys, synthetic, tmp_path):
    def edit(header, rows):
        rows[7][header.index("x")] = "1e308"

    run(capsys, copy_with(synthetic, tmp_path, edit), "sample s007: position", "not physical")


def test_handeye_guess_in_millimetres(capsys, synthetic, tmp_path):
    spec = "robot: a465\nhayati: auto\njoint_unit: deg\nhandeye: {xyz: [0, 40, 60]}\n"
    root = copy_with(synthetic, tmp_path, spec=spec)
    run(capsys, root, "dataset.yaml", "handeye: xyz", "looks like millimetres")


def test_translations_scaled_by_a_wrong_unit_or_board(capsys, synthetic, tmp_path):
    def edit(header, rows):
        poses, _ = poses_of(header, rows)
        poses[:, :3, 3] *= 1.25
        set_poses(header, rows, poses)

    run(capsys, copy_with(synthetic, tmp_path, edit), "measured translations are 1.2")


def test_corrections_larger_than_the_tolerance(capsys, synthetic, tmp_path):
    # the planted errors are 0.1..0.9 mm and 0.01..0.9 deg: a 0.05 mm tolerance is exceeded
    spec = (synthetic.root / "dataset.yaml").read_text() + "tolerances: {length_mm: 0.05}\n"
    err = run(capsys, copy_with(synthetic, tmp_path, spec=spec), "corrected by", "length_mm")
    assert "identified corrections too large" in err and "mm (tolerance 0.05 mm" in err


def test_a_wrong_link_length_in_the_model_is_named(capsys, synthetic, tmp_path):
    """The model says a2 = 0.283 m where the arm has 0.303 m: the 20 mm correction is refused."""
    robot = get_robot("a465")
    text = dump_model(robot.with_values(a=robot.a - np.array([0, 0.020, 0, 0, 0, 0])))
    spec = "robot: robot.yaml\nhayati: auto\njoint_unit: deg\nhandeye: {xyz: [0, 0.04, 0.06]}\n"
    root = copy_with(synthetic, tmp_path, spec=spec)
    (root / "robot.yaml").write_text(text)
    err = run(capsys, root, "a[2] corrected by +", "not a calibration")
    value = float(err.split("a[2] corrected by ")[1].split(" mm")[0])
    assert abs(value - 20) < 2  # the planted 20 mm plus the synthetic arm's own sub-mm error


# --- the pure checks ------------------------------------------------------------------------------


def test_joint_unit_alternatives_are_named(synthetic):
    """Radians read as degrees (small angles, so the load-time unit check does not fire)."""
    robot = get_robot("a465")
    rng = np.random.default_rng(3)
    q = rng.uniform(-0.05, 0.05, (30, 6)) * 20  # up to 1 rad: the true readings
    poses = fk(robot, q) @ tf.from_vector(np.array([0, 0.04, 0.06, 0.1, 0, 0]))
    ids = [f"s{k}" for k in range(30)]
    with pytest.raises(Exception, match="radians declared as degrees"):
        pl.check_inputs(robot, np.radians(q), poses, ids, "samples.csv", fk=lambda x: fk(robot, x))
    assert pl.check_inputs(
        robot, q, poses, ids, "samples.csv", fk=lambda x: fk(robot, x)
    ).determined


def test_readings_skipped_by_their_rotation_angles_surely_misfit():
    """The readings diagnose_readings leaves unevaluated (their rotation angles alone put the
    misfit above the tolerance, whatever R_X) are those whose misfit is above it: the bound is
    never above the misfit _evaluate finds over the pairs that turn, wrong samples left out or
    not."""
    robot = get_robot("a465")
    rng = np.random.default_rng(7)
    q = rng.uniform(-1.5, 1.5, (40, 6))
    x = tf.from_vector(np.array([0, 0.04, 0.06, 0.3, -0.2, 0.1]))
    noise = np.c_[rng.normal(0, 1e-4, (40, 3)), rng.normal(0, 2e-3, (40, 3))]
    poses = fk(robot, q) @ x @ tf.from_vector(noise)
    poses[[3, 17]] = poses[[17, 3]]  # two wrong rows: samples left out of the misfit
    pairs = pl.check_pairs(40)
    moving = pl.moving_pairs(q, pairs)
    assert 1 <= pl._misfit_rank(pairs) <= len(pairs) // 2
    measured = pl._motions(poses, pairs)
    skipped = 0
    for scale in (1.0, 0.5, 0.9, -1.0, 1.3, 3.0):
        for joint in range(6):
            read = q.copy()
            read[:, joint] *= scale
            flange = pl._motions(fk(robot, read), pairs)
            for tolerance in np.radians([1.0, 5.0, 10.0, 30.0]):
                turning = pl.turning_pairs(flange, measured, moving, tolerance)
                misfit = pl._evaluate("", flange, measured, pairs, tolerance, moving).fit.misfit
                rank = pl._misfit_rank(pairs[turning])
                floor = np.abs(flange.angles - measured.angles)[turning]
                assert np.partition(floor, rank - 1)[rank - 1] <= misfit + 1e-12
                surely = pl._surely_misfit(flange, measured, pairs, moving, tolerance)
                assert not surely or misfit > tolerance
                skipped += surely
    assert skipped > 0  # the bound does skip readings


def test_scale_message_names_the_board_square():
    board = Board(type="chessboard", rows=7, columns=10, spacing=0.025)
    text = pl.scale_message(1.25, board, poses_given=False)
    assert "square looks 1.25x the true size" in text and "0.025 m" in text and "0.02 m" in text
    assert "millimetres" in pl.scale_message(1000.0, board, poses_given=True)


def test_rotations_about_one_point_leave_the_scale_undetermined():
    rng = np.random.default_rng(0)
    rot = Rotation.random(20, random_state=rng).as_matrix()
    centre = np.array([0.3, -0.2, 0.5])
    flange = tf.homogeneous(rot, centre - np.einsum("pij,j->pi", rot, centre))
    x = tf.from_vector(np.array([0.1, 0.0, 0.05, 0.2, 0.1, 0.0]))
    measured = np.linalg.inv(x) @ flange @ x
    pairs = pl.check_pairs(20)
    a, b = pl.relative(flange, pairs), pl.relative(measured, pairs)
    misfit, rx = pl.rotation_misfit(a, b)
    assert misfit < 1e-9
    scaled = measured.copy()
    scaled[:, :3, 3] *= 3.0
    assert not pl.translation_scale(a, pl.relative(scaled, pairs), rx).determined


def test_wrong_robot_is_named_as_a_disagreement(capsys, synthetic, tmp_path):
    """A465 data calibrated as a UR5e: no reading fits, the message says by how much and what to
    check."""
    spec = "robot: ur5e\nhayati: auto\njoint_unit: deg\n"
    err = run(capsys, copy_with(synthetic, tmp_path, spec=spec), "disagree with the commanded")
    assert "no other reading of the columns" in err and "robot model" in err


def test_guess_rotated_far_from_the_data(capsys, synthetic, tmp_path):
    spec = "robot: a465\njoint_unit: deg\nhandeye: {xyz: [0, 0.04, 0.06], rpy: [90, 0, 0]}\n"
    run(capsys, copy_with(synthetic, tmp_path, spec=spec), "handeye: the guess's rotation is")


def test_wrong_mode_reads_as_inverted_camera_poses():
    """With images, inverted poses mean the mode is the wrong one."""
    robot = get_robot("a465")
    rng = np.random.default_rng(5)
    q = rng.uniform(-1.0, 1.0, (25, 6))
    x = tf.from_vector(np.array([0, 0.04, 0.06, 0.05, -0.03, 0.2]))
    w = tf.from_vector(np.array([0.5, 0.1, -0.2, 3.0, 0.1, 0.4]))
    camera_in_board = w @ fk(robot, q) @ x
    ids = [f"s{k}" for k in range(25)]
    kwargs = {"fk": lambda v: fk(robot, v), "poses_given": False}
    pl.check_inputs(robot, q, camera_in_board, ids, "dataset.yaml", **kwargs)
    with pytest.raises(Exception, match=r"inverted \(mode: eye_to_hand meant, not eye_in_hand\?\)"):
        pl.check_inputs(robot, q, tf.invert(camera_in_board), ids, "dataset.yaml", **kwargs)


TIAGO = DATA / "tiago_pro"


def test_right_tiago_mocap_poses_pass_and_inverted_ones_are_named():
    """TIAGo Pro right arm, 48 motion-capture poses of a marker on the gripper (FK of PAL's URDF
    by yourdfpy): the real robot's relative rotations differ from the URDF's by a median 3.9 deg
    (under the 10 deg tolerance), the scale is 1.008, and the inverted poses are named."""
    yourdfpy = pytest.importorskip("yourdfpy")
    if not TIAGO.exists():
        pytest.skip("real data not available")
    urdf = yourdfpy.URDF.load(
        str(TIAGO / "tiago_pro.urdf"), load_meshes=False, build_collision_scene_graph=False
    )
    joints = ["torso_lift_joint"] + [f"arm_right_{i}_joint" for i in range(1, 8)]
    rows = list(csv.DictReader(io.StringIO((TIAGO / "mocap_pose_20260805.csv").read_text())))
    flange, marker = [], []
    for r in rows:
        urdf.update_cfg({n: float(r[n]) for n in joints})
        flange.append(urdf.get_transform("gripper_right_pal_atc_base_link", "base_footprint"))
        rpy = [float(r[k]) for k in ("phiz1", "phiy1", "phix1")]
        rot = Rotation.from_euler("ZYX", rpy).as_matrix()  # R = Rz Ry Rx
        marker.append(tf.homogeneous(rot, np.array([float(r[k]) for k in ("x1", "y1", "z1")])))
    flange, marker = np.array(flange), np.array(marker)
    pairs = pl.check_pairs(len(rows))
    a, b = pl.relative(flange, pairs), pl.relative(marker, pairs)
    misfit, rx = pl.rotation_misfit(a, b)
    print(f"\nTIAGo: rotation misfit {np.degrees(misfit):.2f} deg")
    assert misfit < pl.Tolerances().rotation
    scale = pl.translation_scale(a, b, rx)
    assert scale.determined and abs(scale.ratio - 1) < pl.Tolerances().scale
    # the marker sits about 0.142 m along the gripper's z axis (data README)
    assert abs(scale.handeye_translation[2] - 0.142) < 0.02

    ids = [str(k) for k in range(len(rows))]
    pl.check_flange_inputs(flange, marker, ids, "mocap")  # passes
    either = r"^mocap: flange poses look inverted .*, or poses look inverted"
    with pytest.raises(RelcalError, match=either):
        pl.check_flange_inputs(flange, tf.invert(marker), ids, "mocap")


@pytest.mark.parametrize(
    ("case", "expected"),
    [("w_first", "quaternions look w-first"), ("inverted", "poses look inverted")],
)
def test_positioner_readings_named(capsys, tmp_path, case, expected):
    """The positioner turns about one point: w-first and inverted readings fit its rotations and
    translations alike, so both are named (as given: 27.9 deg misfit, read either way: 0.06)."""
    if not POSITIONER.exists():
        pytest.skip("real data not available")
    assert main(["import", "rct-positioner", str(POSITIONER), "--out", str(tmp_path / "p")]) == 0
    capsys.readouterr()
    source = type("Source", (), {"root": tmp_path / "p"})

    def edit(header, rows):
        poses, _ = poses_of(header, rows)
        if case == "w_first":
            set_poses(header, rows, poses, quat_order=(3, 0, 1, 2))
        else:
            set_poses(header, rows, tf.invert(poses))

    root = copy_with(source, tmp_path / "x", edit)
    (root / "positioner.yaml").write_text((tmp_path / "p" / "positioner.yaml").read_text())
    run(capsys, root, expected, "agree with the commanded ones to 0.06 deg")
