"""End to end in the virtual cell (MuJoCo): relcal plan -> relcal capture -> calibrate, checked
against the truth the cell planted; and a capture with faults (board hidden, stale frames, dropped
frames, a slowly settling arm, Ctrl-C half-way, --resume) whose dataset is whole and pairs every
image with the joints read around its own exposure."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from relcal import geometry as tf
from relcal.calibration.pipeline import calibrate
from relcal.cli import main
from relcal.data.dataset import load_dataset
from relcal.data.imaging import measure
from relcal.design.planfile import read_plan
from relcal.outputset import tracking
from relcal.robot.kinematics import fk
from relcal.robot.loading import get_robot

ROOT = Path(__file__).resolve().parents[1]


def relcal(*args: str) -> None:
    assert main([str(a) for a in args]) == 0, args


def truth_of(robot: str, seed: int):
    """The cell's truth, rebuilt from the seed as the sim driver builds it (and checked against
    the truth file the run wrote)."""
    from relcal.capture.virtual import make_cell

    return make_cell(get_robot(robot), seed=seed).truth


def noise_floor(truth, dataset, measured, pairs) -> np.ndarray:
    """Held-out errors ``(P, 6)`` of the true model, hand-eye and board placement on the
    measured poses (each pose in the board frame for pairs ``(k, k)``; relative poses for
    others): what the image and joint noise alone leave."""
    camera = tf.invert(truth.board_pose) @ fk(truth.true_model, dataset.q) @ truth.handeye
    out = []
    for i, j in pairs:
        if i == j:
            out.append(tf.to_vector(tf.invert(camera[i]) @ measured.poses[i]))
            continue
        model = tf.invert(camera[i]) @ camera[j]
        meas = tf.invert(measured.poses[i]) @ measured.poses[j]
        out.append(tf.to_vector(tf.invert(model) @ meas))
    return np.array(out)


def rms_mm(errors: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(errors[:, :3] ** 2, axis=1)))) * 1e3


@pytest.mark.parametrize("robot,seed", [("ur5e", 1), ("franka_fr3", 2)])
def test_plan_capture_calibrate_recovers_the_planted_errors(tmp_path, capsys, robot, seed):
    """The user's loop as the README prints it: ``relcal plan --robot ROBOT --n-poses 30``
    (every joint moving at most 120 deg between consecutive poses), ``relcal capture PLAN`` with
    no --robot (the plan's header names it; a --robot that contradicts it is refused), then
    ``relcal calibrate``: the planted errors within 3 std, the held-out error at the noise
    floor and far below the baseline's."""
    plan, out, truth_file = tmp_path / "plan.csv", tmp_path / "ds", tmp_path / "truth.json"
    relcal("plan", "--robot", robot, "--poses", 30, "--candidates", 400, "--random-sets", 0,
           "--out", plan, "--json", tmp_path / "plan.json", "--quiet")  # fmt: skip
    assert plan.read_text().splitlines()[1] == f"# relcal robot: {robot}"
    travel = json.loads((tmp_path / "plan.json").read_text())["travel"]
    assert travel["max_move"] == pytest.approx(np.radians(120))
    if robot == "ur5e":  # (the FR3's plan may keep a move over the bound, warned)
        q = read_plan(plan, get_robot(robot)).q
        assert len(q) >= 30 and np.degrees(np.abs(np.diff(q, axis=0))).max() <= 120.0 + 1e-9
        assert travel["moves_beyond_max_move"] == []
        other = ["capture", str(plan), "--robot", "a465", "--robot-driver", "sim"]
        assert main([*other, "--camera", "sim", "--out", str(tmp_path / "other")]) == 2
        err = capsys.readouterr().err
        assert "was made for 'Universal Robots UR5e'" in err and "leave --robot out" in err
        assert not (tmp_path / "other").exists()
    relcal("capture", plan, "--robot-driver", "sim", "--camera", "sim",
           "--out", out, "--handeye", "0,0.04,0.06", "--robot-option", f"seed={seed}",
           "--robot-option", f"truth={truth_file}", "--json", tmp_path / "c.json",
           "--quiet")  # fmt: skip
    assert f"robot: {robot}" in (out / "dataset.yaml").read_text()
    summary = json.loads((tmp_path / "c.json").read_text())
    assert summary["recorded"] >= 25, summary["skip_reasons"]
    truth = truth_of(robot, seed)
    written = json.loads(truth_file.read_text())
    factors, _ = truth.layout.display()
    np.testing.assert_allclose([written["errors"][n] for n in truth.layout.names],
                               truth.errors * factors)  # fmt: skip
    with tracking():
        dataset = load_dataset(out)
        measured = measure(dataset, progress=False)
        cal = calibrate(dataset, measured, holdout=0.25, seed=0)
    assert measured.ok.all()
    # every identified geometric parameter within 3 predicted standard deviations of the truth
    names = list(cal.problem.full_layout.names)
    where = {n: k for k, n in enumerate(names)}
    z = {}
    for name, true in zip(truth.layout.names, truth.errors, strict=True):
        k = where.get(name)
        if k is not None and cal.result.identifiable[k]:
            z[name] = (cal.result.params[k] - true) / cal.std[k]
    assert len(z) >= 15 and all(np.isfinite(list(z.values())))
    assert max(abs(v) for v in z.values()) < 3.0, z
    # the held-out error reaches the noise floor (the true model's error on the same pairs)
    val = cal.validation
    floor = rms_mm(noise_floor(truth, dataset, measured, val.pairs))
    after, before = rms_mm(val.calibrated), rms_mm(val.before)
    assert floor > 0.02 and after < 1.3 * floor, (after, floor)
    assert before > 20 * after


def usable_poses(robot: str, seed: int, plan: Path) -> list[int]:
    """Rows of the plan whose ideal image (no faults, no noise) passes the frame gates (the
    planner's line-of-sight check uses capsules about the skeleton, not the rendered links, so
    a rare pose may still show a link over a corner, which the loop rightly skips)."""
    from relcal.capture.loop import judge_frame
    from relcal.capture.virtual import make_cell

    model = get_robot(robot)
    cell = make_cell(model, seed=seed)
    out = []
    for k, q in enumerate(read_plan(plan, model).q):
        levels, _ = cell.renderer.render(q)
        image = (np.clip(levels, 0, 1) * 255).astype(np.uint8)
        if not isinstance(judge_frame(image, cell.truth.board, cell.truth.camera), str):
            out.append(k)
    cell.close()
    return out


def _recorded(out: Path) -> int:
    try:
        return max(len((out / "samples.csv").read_text().splitlines()) - 1, 0)
    except FileNotFoundError:
        return 0


def test_faults_interrupt_and_resume_leave_a_whole_correctly_paired_dataset(tmp_path):
    robot, seed = "ur5e", 4
    plan, out = tmp_path / "plan.csv", tmp_path / "ds"
    relcal("plan", "--robot", robot, "--poses", 12, "--candidates", 300, "--random-sets", 0,
           "--out", plan, "--quiet")  # fmt: skip
    ids = read_plan(plan, get_robot(robot)).ids
    good = [ids[k] for k in usable_poses(robot, seed, plan)]
    assert len(good) >= 8  # (a pose can show a link in front of the board: see usable_poses)
    hidden, hidden_once = good[1], good[3]
    faults = f"hide:{hidden};hide_once:{hidden_once};stale:4;slow;drop:0.3"
    command = [
        sys.executable, "-c", "import sys; from relcal.cli import main; sys.exit(main())",
        "capture", str(plan), "--robot", robot,
        "--robot-driver", "sim", "--camera", "sim", "--out", str(out),
        "--robot-option", f"seed={seed}", "--robot-option", f"faults={faults}",
    ]  # fmt: skip
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    first = subprocess.Popen(
        [*command, "--robot-option", f"truth={tmp_path / 'truth1.json'}", "--quiet"],
        env=env,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 240
    while _recorded(out) < 4 and first.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    first.send_signal(signal.SIGINT)
    _, err = first.communicate(timeout=120)
    assert first.returncode == 130, err
    assert "--resume" in err
    with tracking():
        partial = load_dataset(out)  # a valid dataset as it stands
    assert 4 <= len(partial.ids) < len(ids) - 1
    assert all(p.is_file() for p in partial.images)
    done = subprocess.run(
        [*command, "--robot-option", f"truth={tmp_path / 'truth2.json'}", "--resume", "--quiet"],
        env=env,
        capture_output=True,
        text=True,
        timeout=240,
    )
    assert done.returncode == 0, done.stderr
    log = json.loads((out / "capture.json").read_text())
    with tracking():
        dataset = load_dataset(out)
        measured = measure(dataset, progress=False)
    # whole: every planned pose but the skipped ones, once, in plan order, each image there; the
    # always-hidden pose skipped after 3 attempts (others may be: a link in front of the board)
    skipped = log["skipped"]
    assert list(dataset.ids) == [i for i in ids if i not in skipped] and len(dataset.ids) >= 9
    assert len(skipped[hidden]) == 3
    assert all(r.startswith("board not found") for r in skipped[hidden])
    assert log["samples"][hidden_once]["attempts"] == 2  # hidden on the first visit only
    assert set(skipped) <= {hidden} | (set(ids) - set(good))
    assert measured.ok.all()
    images = sorted(p.name for p in (out / "images").iterdir())
    assert images == sorted(f"{i}.png" for i in dataset.ids)
    # correctly paired: each sample's joints are the true joints at its image's exposure
    truths = {1: json.loads((tmp_path / "truth1.json").read_text()),
              2: json.loads((tmp_path / "truth2.json").read_text())}  # fmt: skip
    runs = {log["samples"][i]["run"] for i in dataset.ids}
    assert runs == {1, 2}
    model = get_robot(robot)
    discarded = 0
    for k, pid in enumerate(dataset.ids):
        entry = log["samples"][pid]
        frames = {f["sequence"]: f for f in truths[entry["run"]]["frames"]}
        frame = frames[entry["frame_sequence"]]
        assert frame["stamp"] == entry["frame_stamp"] and not frame["hidden"]
        # (within the settle threshold, 0.01 deg: a slowly settling arm still creeps inside it;
        # a frame from another pose or from during the move would be degrees off)
        assert np.abs(np.degrees(dataset.q[k] - frame["q_true"])).max() < 0.01, pid
        # and the image is the one rendered at that exposure: its pose is the true camera pose
        true_pose = np.array(frame["camera_in_board"])
        error = tf.to_vector(tf.invert(true_pose) @ measured.poses[k])
        assert np.abs(error[:3]).max() < 0.5e-3 and np.abs(error[3:]).max() < np.radians(0.05)
        discarded += entry["discarded_frames"]
    assert discarded >= len(dataset.ids)  # the stale buffer was there, and was discarded
    # the arm was far from still when its moves returned (slow settling), yet the joints match
    errors = [m["error_deg"] for t in truths.values() for m in t["moves"]]
    assert np.median(errors) > 0.1
    del model


def test_the_camera_follows_the_true_model_with_its_nongeometric_terms():
    """The virtual camera's pose is relcal's forward kinematics of the true model, joint scale
    and harmonics included, at the true joints of the exposure; the robot reports only noisy
    joints (and the flange pose its controller computes from them) and the camera only stamped
    images."""
    from relcal.capture.virtual import make_cell
    from relcal.robot.kinematics import effective_joints

    model = get_robot("ur5e")
    cell = make_cell(model, seed=5, nongeometric=("scale", "harmonic"))
    truth = cell.truth
    assert {"scale[2]", "harmonic_c[3]"} <= set(truth.layout.names)
    assert truth.true_model.has_nongeometric_values()
    q = np.radians([10.0, -100.0, 90.0, -80.0, -90.0, 20.0])
    cell.robot.move(q, 60.0)
    cell.clock.sleep(5.0)
    reading = cell.robot.read()
    frame = cell.camera.grab(1.0)
    assert frame.stamp <= cell.clock.now() and frame.image.dtype == np.uint8
    assert set(vars(reading)) == {"q", "stamp", "dq", "flange"} and reading.dq is None
    # the controller's flange pose: its kinematics (the true ones) at the joints it read
    np.testing.assert_allclose(reading.flange, fk(truth.true_model, reading.q), atol=1e-15)
    assert set(vars(frame)) >= {"image", "stamp"}
    record = cell.frames[-1]
    q_true = np.array(record["q_true"])
    assert np.abs(np.degrees(reading.q - q_true)).max() < 0.01  # encoder noise only
    expected = tf.invert(truth.board_pose) @ fk(truth.true_model, q_true) @ truth.handeye
    np.testing.assert_allclose(record["camera_in_board"], expected, atol=1e-12)
    geometric_only = replace_values(truth.true_model)
    other = tf.invert(truth.board_pose) @ fk(geometric_only, q_true) @ truth.handeye
    assert np.abs(other[:3, 3] - expected[:3, 3]).max() > 1e-5  # the terms move the camera
    assert not np.allclose(effective_joints(truth.true_model, q_true[None]), q_true)


def replace_values(model):
    """``model`` without its non-geometric values."""
    from dataclasses import replace

    zeros = np.zeros(model.n_joints)
    return replace(model, scale=zeros, compliance=zeros, harmonic_c=zeros, harmonic_s=zeros)


def test_the_virtual_camera_follows_another_robot_driver():
    """``--camera sim`` with a driver other than ``sim``: each frame is rendered from the joints
    the driver reports at the grab, stamped with that reading's stamp; the board's pose in the
    image is the planted truth's (FK of the true model at those joints, true hand-eye)."""
    from relcal.capture import devices
    from relcal.capture.interfaces import JointReading
    from relcal.errors import RelcalError
    from relcal.vision.detect import detect, estimate_pose

    model = get_robot("ur5e")
    q = np.radians([195.581, -82.863, 122.037, -126.937, -121.334, -85.147])  # sees the board

    class Driver:
        joint_names = model.joint_names

        def __init__(self):
            self.reads = 0

        def read(self):
            self.reads += 1
            return JointReading(q + 1e-4 * self.reads, 40.0 + self.reads)

    driver = Driver()
    camera = devices.open_camera("sim", {"seed": "4"}, robot=driver, model=model, board=None)
    try:
        frames = [camera.grab(1.0) for _ in range(2)]
        assert [f.stamp for f in frames] == [41.0, 42.0] and [f.sequence for f in frames] == [0, 1]
        truth = camera.cell.truth
        assert camera.intrinsics() == truth.camera and truth.errors.any()
        same = truth_of("ur5e", 4)  # what the sim robot plants with that seed
        np.testing.assert_array_equal(truth.errors, same.errors)
        np.testing.assert_array_equal(truth.handeye, same.handeye)
        for k, frame in enumerate(frames):
            q_read = q + 1e-4 * (k + 1)
            expected = tf.invert(truth.board_pose) @ fk(truth.true_model, q_read) @ truth.handeye
            found = detect(frame.image, truth.board)
            pose = estimate_pose(found, truth.camera)
            assert np.abs(pose.T_board_camera[:3, 3] - expected[:3, 3]).max() < 5e-4  # m
            np.testing.assert_allclose(camera.cell.frames[k]["q_true"], q_read)
    finally:
        camera.close()
    with pytest.raises(RelcalError, match="needs a robot driver to follow"):
        devices.open_camera("sim", {}, model=model)
