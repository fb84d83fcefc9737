"""``relcal plan --mode eye_to_hand``: a fixed camera and the board on the flange.

Checked against truth computed here: every planned pose shows the whole pattern inside the fixed
camera's image with the margin (the corners projected with the pinhole model by hand), the plan
beats random feasible sets on its own criterion, and on planted truth (board-in-camera poses
simulated at the planned configurations with the planning noise) ``relcal.handeye`` in
eye-to-hand mode recovers the board on the flange with the spread the plan predicts and the
camera's pose in the base frame near the truth. The plan file names the mode and ``relcal
capture`` carries it into the dataset, or refuses the virtual cell, which cannot show it."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import yaml

import relcal
from relcal import geometry as tf
from relcal.calibration.handeye_job import deliver
from relcal.design.cell import FixedCameraCell
from relcal.design.criteria import DEFAULT_NOISE
from relcal.design.plan import plan
from relcal.robot.kinematics import fk
from relcal.vision.boards import Board

CAMERA = tf.from_xyz_rpy(np.array([1.0, 0.4, 0.5]), np.radians([-106.6, -21.0, 129.8]))
X_GUESS = tf.from_xyz_rpy(np.array([0.01, -0.02, 0.09]), np.radians([178.0, 4.0, 30.0]))
N_POSES = 12


@pytest.fixture
def run_cli(capsys):
    """``relcal ARGS`` in this process: its exit code and everything it printed."""
    from relcal.cli import main

    def run(*args: str) -> tuple[int, str]:
        try:
            code = main(list(args))
        except SystemExit as exc:  # argparse's own errors
            code = exc.code
        out = capsys.readouterr()
        return code, out.out + out.err

    return run


@pytest.fixture(scope="module")
def ur5e():
    return relcal.get_robot("ur5e")


@pytest.fixture(scope="module")
def handeye_plan(ur5e):
    cell = FixedCameraCell(camera_pose=CAMERA, handeye=X_GUESS)
    res = plan(ur5e, cell, n_poses=N_POSES, n_candidates=300, random_sets=10, n_validation=10,
               purpose="handeye", seed=2)  # fmt: skip
    return cell, res


def pattern_corners(board: Board) -> np.ndarray:
    """``(4, 3)`` outer corners of a chessboard's printed squares in the board frame, m: the
    inner corners run from 0 to (columns - 2) and (rows - 2) squares, one square more out."""
    s = board.spacing
    x0, y0, x1, y1 = -s, -s, (board.columns - 1) * s, (board.rows - 1) * s
    return np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]], float)


def test_every_planned_pose_shows_the_whole_board(ur5e, handeye_plan):
    cell, res = handeye_plan
    cam = cell.camera
    k = np.array([[cam.fx, 0, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1.0]])
    corners = np.c_[pattern_corners(cell.board), np.ones(4)]
    margin = 40.0
    for q in res.q:
        board_in_camera = np.linalg.inv(CAMERA) @ fk(ur5e, q) @ X_GUESS
        pts = (board_in_camera @ corners.T)[:3]  # (3, 4) camera frame
        assert (pts[2] > 0.2).all()  # in front of the camera
        uv = (k @ pts)[:2] / pts[2]
        assert (uv[0] >= margin).all() and (uv[0] <= cam.width - 1 - margin).all(), uv
        assert (uv[1] >= margin).all() and (uv[1] <= cam.height - 1 - margin).all(), uv
        # the printed face turned towards the camera (its z axis points into the print)
        centre = (
            board_in_camera[:3, :3] @ pattern_corners(cell.board).mean(0) + board_in_camera[:3, 3]
        )
        facing = -board_in_camera[:3, 2] @ (-centre / np.linalg.norm(centre))
        assert facing >= np.cos(np.radians(40.0)) - 1e-9
        assert 0.25 - 1e-9 <= np.linalg.norm(centre) <= 0.45 + 1e-9


def test_handeye_plan_beats_random_sets(handeye_plan):
    _, res = handeye_plan
    assert res.mode == "eye_to_hand" and res.purpose == "handeye"
    assert len(res.q) >= N_POSES
    assert res.plan.worst[1] < res.random_median_worst, (res.plan.worst, res.random_median_worst)
    assert res.motion.bad_pairs == 0


def test_planted_truth_recovered_with_the_predicted_spread(ur5e, handeye_plan):
    cell, res = handeye_plan
    x_true = X_GUESS @ tf.from_vector(np.r_[0.003, -0.002, 0.004, 0.01, -0.02, 0.015])
    camera_true = CAMERA @ tf.from_vector(np.r_[0.01, 0.02, -0.01, 0.01, 0.005, -0.01])
    sd = np.r_[np.full(3, DEFAULT_NOISE.position), np.full(3, DEFAULT_NOISE.orientation)]
    predicted = np.sqrt(np.diag(res.plan.uncertainty.crb))  # X exp(xi), xi in the board frame
    flange = fk(ur5e, res.q)
    zx, zc, zp = [], [], []
    plan_xyz, plan_rot = res.motion.camera_std  # the plan's prediction of the delivered pose
    for seed in range(20):
        eps = np.random.default_rng(seed).normal(size=(len(res.q), 6)) * sd
        measured = np.linalg.inv(camera_true) @ flange @ x_true @ tf.from_vector(eps)
        ds = relcal.Dataset.from_arrays(ur5e, res.q, measured, mode="eye_to_hand", handeye=X_GUESS)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            he = relcal.handeye(ds, seed=0)
        assert he.mode == "eye_to_hand"
        zx.append(tf.to_vector(np.linalg.inv(x_true) @ he.fit.handeye) / predicted)
        camera = deliver("eye_to_hand", he.fit, he.frames)[0]  # base -> camera, refined
        assert (camera.parent, camera.child) == (he.frames["base"], he.frames["camera"])
        rot = tf.log_rotation(camera.transform[:3, :3] @ camera_true[:3, :3].T)
        shift = camera.transform[:3, 3] - camera_true[:3, 3]
        zc.append(np.r_[shift / camera.xyz_std, rot / camera.rotation_std])
        zp.append(np.r_[shift / plan_xyz, rot / plan_rot])
    zx, zc, zp = np.array(zx), np.array(zc), np.array(zp)
    # the board on the flange: every estimate within 3 of the plan's predicted std (up to one
    # outlier in the 120 components), and their spread what the plan predicts
    assert (np.abs(zx) > 3.0).sum() <= 1 and np.abs(zx).max() < 4.0, zx
    rms = np.sqrt(np.mean(zx**2, axis=0))
    assert ((rms > 0.6) & (rms < 1.45)).all(), rms
    # the fixed camera in the base frame (what eye-to-hand delivers): its spread is what the plan
    # predicts, and the fit's own std (learned from these 12 samples) says so too
    rms = np.sqrt(np.mean(zp**2, axis=0))
    assert ((rms > 0.6) & (rms < 1.45)).all(), rms
    assert np.sqrt(np.mean(zc**2, axis=0)).max() < 1.45, zc


def test_calibration_plan_for_a_fixed_camera(ur5e):
    cell = FixedCameraCell(camera_pose=CAMERA)
    res = plan(ur5e, cell, n_poses=15, n_candidates=200, random_sets=5, n_validation=10, seed=1)
    assert res.mode == "eye_to_hand" and res.purpose == "calibrate"
    assert res.plan.worst[1] < res.random_median_worst
    assert any(n.startswith("a[") or n.startswith("d[") for n in res.plan.uncertainty.names)


def test_plan_file_and_capture_carry_the_mode(run_cli, tmp_path):
    out = tmp_path / "plan.csv"
    code, text = run_cli(
        "plan", "--robot", "ur5e", "--mode", "eye_to_hand", "--camera-pose",
        "1.0,0.4,0.5,-106.6,-21,129.8", "--for", "handeye", "--n-poses", "6",
        "--n-candidates", "120", "--random-sets", "0", "--out", str(out),
    )  # fmt: skip
    assert code == 0, text
    assert "eye-to-hand" in text and "fixed camera at 1,0.4,0.5" in text
    assert out.read_text().splitlines()[2] == "# relcal mode: eye_to_hand"
    from relcal.design.planfile import plan_mode, read_plan

    assert plan_mode(out) == "eye_to_hand"
    assert read_plan(out, relcal.get_robot("ur5e")).q.shape == (6, 6)
    code, text = run_cli(
        "capture", str(out), "--robot-driver", "sim", "--camera", "sim", "--out",
        str(tmp_path / "ds"),
    )  # fmt: skip
    assert code == 2 and "fixed camera" in text and "virtual cell" in text
    assert not (tmp_path / "ds").exists()


def test_dataset_writer_records_the_mode(tmp_path):
    from relcal.capture.record import DatasetWriter
    from relcal.design.cell import default_board, default_camera

    model = relcal.get_robot("ur5e")
    q = np.zeros((2, 6))
    with DatasetWriter(
        tmp_path / "ds", model, "ur5e", default_board(), default_camera(), ["p001", "p002"], q,
        mode="eye_to_hand",
    ):  # fmt: skip
        pass
    spec = yaml.safe_load((tmp_path / "ds" / "dataset.yaml").read_text())
    assert spec["mode"] == "eye_to_hand"


@pytest.mark.parametrize(
    "args, message",
    [
        (["--camera-pose", "1,0,0.5,0,0,0"], "--camera-pose"),
        (["--mode", "eye_to_hand", "--board-center", "0.4,0,0"], "--board-center"),
        (["--mode", "eye_to_hand", "--camera-pose", "1,0,0.5"], "--camera-pose"),
        # millimetres for metres: named as such (were 'each within +-360' and 'no feasible
        # configuration ... the board may be out of reach')
        (
            ["--mode", "eye_to_hand", "--camera-pose", "1000,400,500,-106.6,-21,129.8"],
            "1187 m away, more than 20 m (millimetres given? 1, 0.4, 0.5 in m)",
        ),
        (["--handeye", "40,0,60"], "72.11 m away, more than 2 m (millimetres given? 0.04, 0, 0.06"),
        (["--handeye", "0,0.04,0.06,0,400,0"], "angles in deg, within +-360"),
    ],
)
def test_bad_fixed_camera_options(run_cli, args, message):
    code, text = run_cli("plan", "--robot", "ur5e", "--n-candidates", "50", *args)
    assert code == 2 and message in text and "Traceback" not in text, text


@pytest.mark.parametrize(
    "value, message",
    [
        ("0,0_4,0", "an underscore inside a number"),  # float() read it as 0, 4, 0
        ("0,40,60", "more than 2 m (millimetres given?"),
        ("0,0.04", "expected 3 or 6 numbers"),
    ],
)
def test_capture_reads_its_handeye_as_plan_does(run_cli, value, message):
    """capture --handeye had its own float() reading: '0,0_4,0' was a camera 4 m off the
    flange and 40 mm given as 40 m went into dataset.yaml."""
    code, text = run_cli("capture", "plan.csv", "--out", "ds", "--handeye", value)
    assert code == 2 and "--handeye" in text and message in text and "Traceback" not in text, text


def test_a_camera_facing_away_from_the_arm_is_named(ur5e):
    """A camera 1 m out looking up: the board poses in front of it are beyond the arm's reach,
    and the refusal says where to look (the camera's pose, the board's mount)."""
    from relcal.design.cell import FixedCameraCell
    from relcal.design.feasibility import Constraints, candidates
    from relcal.errors import RelcalError

    cell = FixedCameraCell(camera_pose=tf.from_xyz_rpy(np.array([1.0, 0.0, 0.5]), np.zeros(3)))
    with pytest.raises(RelcalError, match="move --camera-pose"):
        candidates(ur5e, cell, Constraints(), 4, batch=50, max_rounds=1)
