"""One input gate for every kind of data and every entry point: joint limits, magnitudes, the
chain against the measurements (another arm, a wrong unit or order), complex values, a board
moved mid-session, and standard deviations no bootstrap supports. Each case is refused with the
likely cause (exit 2, nothing written) where the pose path refuses it, and each fix the message
suggests, followed, works."""

import csv
import io
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import DATA
from helpers_dataset import synthetic_dataset

from relcal import geometry as tf
from relcal.calibration import plausibility as pl
from relcal.calibration.verify import verify_session
from relcal.cli import main
from relcal.data.dataset import Dataset, load_dataset
from relcal.errors import ArgumentError, RelcalError
from relcal.robot.kinematics import fk
from relcal.robot.loading import get_robot

TIAGO = DATA / "tiago_pro"
POSITIONS = Path(__file__).resolve().parents[1] / "examples" / "tiago-pro-positions"


def positions(tmp_path: Path, name: str = "d", edit=None, spec_edit=None) -> Path:
    """A copy of the real TIAGo Pro positions (94 samples of the right arm) with its samples
    table edited as ``edit(header, rows)`` and its dataset.yaml as ``spec_edit(text)``."""
    root = tmp_path / name
    root.mkdir()
    rows = list(csv.reader(io.StringIO((TIAGO / "mocap_position_20260702.csv").read_text())))
    header, body = rows[0], rows[1:]
    if edit is not None:
        edit(header, body)
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerows([header, *body])
    (root / "samples.csv").write_text(out.getvalue())
    spec = (POSITIONS / "dataset.yaml").read_text()
    spec = spec.replace(
        "../../../shared/data/tiago_pro/tiago_pro.urdf", str(TIAGO / "tiago_pro.urdf")
    )
    spec = re.sub(r"(?m)^samples:.*$", "samples: samples.csv", spec)
    (root / "dataset.yaml").write_text(spec_edit(spec) if spec_edit else spec)
    return root


def refused(capsys, root: Path, *argv: str) -> str:
    out = root.parent / f"{root.name}-cal"
    code = main(["calibrate", str(root), "--out", str(out), "--quiet", *argv])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err and not out.exists()
    return err


def calibrates(capsys, root: Path, *argv: str) -> None:
    out = root.parent / f"{root.name}-cal"
    code = main(["calibrate", str(root), "--out", str(out), "--quiet", *argv])
    err = capsys.readouterr().err
    assert code in (0, 1), err  # 1: finished, a verdict short of deploy
    assert (out / "model.yaml").exists()


def drop_rows(ids):
    def edit(header, rows):
        rows[:] = [r for k, r in enumerate(rows, start=1) if str(k) not in ids]

    return edit


def test_right_arm_positions_with_the_left_arm_tip_are_refused(tmp_path, capsys):
    """The left arm of the TIAGo Pro turns the same joint values into a rigid motion of the right
    arm's points (the point misfit is identical): only the joint limits tell, and they are
    checked on points as on poses (before: a calibrated left-arm URDF with joint 2 at -241 deg,
    its limits [-30, 270])."""

    def left(header, rows):
        header[:] = [h.replace("arm_right", "arm_left") for h in header]

    def left_tip(spec):
        return spec.replace("gripper_right_pal_atc_base_link", "arm_left_tool_link")

    err = refused(capsys, positions(tmp_path, "left", left, left_tip))
    assert "arm_left_1_joint) = -241.073 deg is outside the model's limits [-30, 270]" in err
    assert "another robot or chain (root and tip links)" in err
    calibrates(capsys, positions(tmp_path, "right"))  # the right chain, as the data say


def test_one_reading_beyond_its_limit_in_position_data_is_named(tmp_path, capsys):
    def beyond(header, rows):
        rows[4][header.index("arm_right_2_joint")] = "3.0"  # limits -2.44 .. 1.13 rad

    err = refused(capsys, positions(tmp_path, "d", beyond))
    assert "sample 5: q3 (arm_right_2_joint) = 171.887 deg is outside" in err
    assert "a mistyped reading or a wrong row? fix or remove it" in err
    calibrates(
        capsys, positions(tmp_path, "fixed", lambda h, r: (beyond(h, r), drop_rows({"5"})(h, r)))
    )


def test_a_point_beyond_any_cell_is_named(tmp_path, capsys):
    def far(header, rows):
        rows[6][header.index("x1")] = "1e9"

    err = refused(capsys, positions(tmp_path, "d", far))
    assert "sample 7: position x, y, z = [1.0000e+09" in err and "not physical" in err
    calibrates(
        capsys, positions(tmp_path, "fixed", lambda h, r: (far(h, r), drop_rows({"7"})(h, r)))
    )


def test_radian_joints_declared_degrees_in_position_data_are_named(tmp_path, capsys):
    """The points against the commanded flange positions tell the unit (610 mm as given, 24 mm
    read as radians), whatever the model selection (before: passed with --selection
    conservative)."""

    def degrees(spec):
        return spec.replace("joint_unit: rad", "joint_unit: deg")

    err = refused(
        capsys, positions(tmp_path, "d", spec_edit=degrees), "--selection", "conservative"
    )
    assert "joint angles look like radians declared as degrees (fix: joint_unit: rad" in err
    calibrates(capsys, positions(tmp_path, "fixed"), "--selection", "conservative")


def test_the_point_checks_pass_the_right_data_and_measure_their_misfit():
    dataset = load_dataset(POSITIONS)
    from relcal.data.imaging import measure

    found = pl.check_point_dataset(dataset, measure(dataset))
    assert 15 < found["point_misfit_mm"] < 40  # the arm's own errors (baseline RMS about 28 mm)


def test_complex_joint_values_are_refused_where_arrays_enter():
    model = get_robot("ur10")
    q = np.zeros((6, 6), dtype=complex)
    q[3, 2] = 0.2 + 0.1j
    poses = np.broadcast_to(np.eye(4), (6, 4, 4))
    for call in (lambda v: Dataset.from_arrays(model, v, poses), lambda v: fk(model, v)):
        with pytest.raises(ArgumentError, match=r"q\[3, 2\] = \(0.2\+0.1j\): complex"):
            call(q)
        call(q.real)  # the fix: the real values, where that is meant
    fk(model, q.real + 0j)  # complex with no imaginary part: the same numbers


@pytest.fixture(scope="module")
def right(tmp_path_factory):
    """60 samples of a perturbed A465, poses given."""
    return synthetic_dataset(tmp_path_factory.mktemp("right") / "d", n=60, seed=4)


def copy_poses(src: Path, dst: Path, rows=None, moved=None) -> Path:
    """The synthetic dataset, keeping ``rows`` (positions), the board moved by the 6-vector
    ``moved`` (m, rad) for the last 10 samples."""
    dst.mkdir(parents=True)
    shutil.copy(src / "dataset.yaml", dst / "dataset.yaml")
    table = list(csv.reader(io.StringIO((src / "samples.csv").read_text())))
    header, body = table[0], table[1:]
    if moved is not None:
        col = [header.index(c) for c in ("x", "y", "z", "qx", "qy", "qz", "qw")]
        values = np.array([[float(r[c]) for c in col] for r in body])
        from scipy.spatial.transform import Rotation

        poses = tf.homogeneous(Rotation.from_quat(values[:, 3:]).as_matrix(), values[:, :3])
        poses[-10:] = tf.from_vector(np.asarray(moved)) @ poses[-10:]
        quat = Rotation.from_matrix(poses[:, :3, :3]).as_quat()
        for r, p, qq in zip(body, poses, quat, strict=True):
            for c, v in zip(col, [*p[:3, 3], *qq], strict=True):
                r[c] = repr(float(v))
    if rows is not None:
        body = [body[k] for k in rows]
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerows([header, *body])
    (dst / "samples.csv").write_text(out.getvalue())
    return dst


@pytest.mark.parametrize("moved", [[0.03, 0, 0, 0, 0, 0], [0, 0, 0, 0, 0.05, 0]])
def test_a_board_moved_mid_session_is_found_and_its_samples_named(right, tmp_path, capsys, moved):
    root = copy_poses(right.root, tmp_path / "d", moved=moved)
    err = refused(capsys, root)
    named = re.search(r"samples (.*?) \(10 of 60\) see the board", err)
    assert named, err
    assert named[1] == ", ".join(f"s{k:03d}" for k in range(50, 58)) + " and 2 more"
    assert "fix: remove those samples" in err
    # the same session with its rows reversed: the same samples (the split ignores the order)
    rows = list(range(60))[::-1]
    err = refused(capsys, copy_poses(right.root, tmp_path / "r", rows=rows, moved=moved))
    named = re.search(r"samples (.*?) and 2 more \(10 of 60\) see the board", err)
    assert named and set(named[1].split(", ")) <= {f"s{k:03d}" for k in range(50, 60)}, err
    calibrates(capsys, copy_poses(right.root, tmp_path / "fixed", rows=range(50), moved=moved))


def test_no_moved_board_in_the_real_pose_sets():
    """No false alarm: the real TIAGo Pro poses (errors of 30 mm), the positioner and the IPA
    UR10 (1,495 poses, grid of positions at a few orientations)."""
    from relcal.calibration.handeye import solve_handeye
    from relcal.data.imaging import measure

    example = Path(__file__).resolve().parents[1] / "examples"
    for folder in (example / "tiago-pro-poses", example / "ipa-ur10"):
        dataset = load_dataset(folder)
        poses = measure(dataset).poses
        flange = fk(dataset.model, dataset.q)
        handeye = solve_handeye(flange, poses)
        found = pl.moved_frame(
            dataset.model, dataset.q, poses, handeye, lambda v, d=dataset: fk(d.model, v)
        )
        assert found is None, (folder, found)


def test_standard_deviations_orders_of_magnitude_below_the_bootstrap_are_refused(right, tmp_path):
    """Few samples: a fit that leaves almost no residual once printed hand-eye standard
    deviations of 1e-7 mm where the bootstrap said 10 mm. The gate compares them whatever the
    number of samples: orders of magnitude apart is refused (a rough bootstrap of few samples is
    a factor of a few off, not 100), a factor of 3 from few samples is not."""
    from types import SimpleNamespace

    from relcal.calibration.pipeline import calibrate

    dataset = load_dataset(copy_poses(right.root, tmp_path / "d", rows=range(25)))
    cal = calibrate(dataset, nongeometric="none")
    q = dataset.q[cal.train[:5]]  # as if from five training samples
    params = cal.result.params
    shrunk = SimpleNamespace(params=params, std=cal.result.std * 1e-7)
    with pytest.raises(RelcalError, match=r"x below the bootstrap's.*collect more samples"):
        pl.check_calibration(
            dataset, cal.problem, shrunk, None, cal.bootstrap_std, q=q, links=False
        )
    rough = SimpleNamespace(params=params, std=cal.bootstrap_std / 3)
    pl.check_calibration(dataset, cal.problem, rough, None, cal.bootstrap_std, q=q, links=False)
    # the fix, followed: the calibration of 25 samples passed the gate with its own numbers
    assert pl.median_std_ratio(cal.result.std, cal.bootstrap_std) < pl.STD_FEW


def test_verify_runs_the_same_gate_on_the_session(tmp_path, capsys):
    """verify refuses a session that calibrate would refuse: here one joint reading beyond its
    limit; the session fixed, it runs."""
    cal = tmp_path / "cal"
    first = positions(tmp_path, "train", lambda h, r: r.__delitem__(slice(47, None)))
    assert main(["calibrate", str(first), "--out", str(cal), "--quiet"]) in (0, 1)
    capsys.readouterr()

    def beyond(header, rows):  # the other 47 samples: a session the calibration never saw
        del rows[:47]
        rows[4][header.index("arm_right_2_joint")] = "3.0"

    session = positions(tmp_path, "session", beyond)
    code = main(["verify", str(cal), str(session), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err, err
    assert "sample 5: q3 (arm_right_2_joint) = 171.887 deg is outside" in err
    with pytest.raises(RelcalError, match="is outside the model's limits"):
        verify_session(cal, load_dataset(session))
    fixed = positions(tmp_path, "fixed", lambda h, r: (beyond(h, r), drop_rows({"5"})(h, r)))
    verify_session(cal, load_dataset(fixed))  # runs (its verdict is another matter)
