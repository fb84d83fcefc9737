"""The capture loop with fake devices: what it refuses before moving, how it waits for a still
arm, which frame it takes, what it records, how it retries and skips, and the dataset folder it
writes sample by sample (resume, refusals). No MuJoCo here: see test_capture_virtual.py."""

import json
import os
import re

import cv2
import numpy as np
import pytest

from relcal.capture.interfaces import Frame, JointReading, MoveFailed
from relcal.capture.loop import DEG, CaptureSettings, capture, judge_frame, sharpness
from relcal.capture.record import DatasetWriter
from relcal.capture.virtual import SIM_CAMERA, SimClock
from relcal.data.dataset import load_dataset
from relcal.errors import RelcalError
from relcal.outputset import tracking
from relcal.robot.loading import get_robot
from relcal.vision.boards import Board, board_points
from relcal.vision.render import look_at, render_board

BOARD = Board("chessboard", 7, 10, 0.02)
MODEL = get_robot("ur5e")


@pytest.fixture(scope="module")
def board_image():
    centre = board_points(BOARD).mean(axis=0)
    pose = look_at(centre + np.array([0.02, -0.03, -0.32]), centre)
    return render_board(BOARD, SIM_CAMERA, pose, 0.6, 1.5, 0.2, seed=1)


class FakeRobot:
    """Reaches each target ``settle`` s after the move returns, ringing until then."""

    joint_names = MODEL.joint_names

    def __init__(self, clock, settle=0.4, offset=0.0, fail_moves=0, noise=0.0005 * DEG):
        self.clock, self.settle, self.offset = clock, settle, offset
        self.fail_moves, self.noise = fail_moves, noise
        self.q = np.zeros(6)
        self.target = np.zeros(6)
        self.returned = 0.0
        self.moves, self.returns, self.stops = [], [], 0
        self.rng = np.random.default_rng(0)

    def true_q(self, t):
        left = self.returned + self.settle - t
        ring = 0.05 * np.sin(40 * t) * (left > 0)  # rad, until settled
        return self.target + self.offset + ring

    def read(self):
        t = self.clock.now()
        return JointReading(self.true_q(t) + self.rng.normal(0, self.noise, 6), t)

    def move(self, q, timeout):
        self.moves.append(np.array(q))
        if self.fail_moves:
            self.fail_moves -= 1
            raise MoveFailed("protective stop")
        self.target = np.array(q)
        self.clock.sleep(0.5)
        self.returned = self.clock.now()
        self.returns.append(self.returned)

    def stop(self):
        self.stops += 1

    def close(self):
        pass


class FakeCamera:
    """Frames at 20 Hz; ``stale`` buffered frames from before the call come first."""

    def __init__(self, clock, image, stale=0):
        self.clock, self.image, self.stale = clock, image, stale
        self.stamps = []

    def grab(self, timeout):
        now = self.clock.now()
        if self.stale:
            self.stale -= 1
            stamp = now - 1.0 - 0.05 * self.stale  # from before the move
        else:
            self.clock.sleep(0.05)
            stamp = self.clock.now() - 0.01
        self.stamps.append(stamp)
        return Frame(self.image, stamp, sequence=len(self.stamps))

    def intrinsics(self):
        return SIM_CAMERA

    def close(self):
        pass


class ListSink:
    def __init__(self):
        self.samples, self.skips = [], {}

    def record(self, sample):
        self.samples.append(sample)

    def skip(self, pose_id, index, reasons):
        self.skips[pose_id] = list(reasons)


def targets(k=3):
    q = np.zeros((k, 6))
    q[:, 0] = np.radians(np.arange(k) * 10.0)
    return [f"p{i + 1}" for i in range(k)], q


def run(robot, camera, clock, image_ok=True, **kw):
    ids, q = kw.pop("plan", targets())
    sink = ListSink()
    settings = kw.pop("settings", CaptureSettings(settle_window=0.3))
    summary = capture(
        ids, q, MODEL, robot, camera, clock, BOARD, sink, SIM_CAMERA, settings, progress=False, **kw
    )
    return summary, sink


def test_waits_for_the_still_window_and_records_its_mean(board_image):
    clock = SimClock()
    robot = FakeRobot(clock, settle=0.4)
    summary, sink = run(robot, FakeCamera(clock, board_image), clock)
    assert summary.recorded == ["p1", "p2", "p3"] and not summary.skipped
    for s, target, back in zip(sink.samples, targets()[1], robot.returns, strict=True):
        start, end = s.window
        # the window began once the ringing stopped (not when the move returned) and lasted
        # the settle window
        assert back + 0.4 - 0.011 <= start < back + 0.4 + 0.05 and end - start >= 0.3 - 1e-9
        assert s.frame.stamp >= start  # the frame was exposed once the arm was still
        assert np.abs(s.q - target).max() < 0.002 * DEG  # mean of noisy still readings
        assert s.n_points == BOARD.n_points and s.rms_px < 0.5


def test_frames_buffered_before_the_still_window_are_discarded(board_image):
    clock = SimClock()
    camera = FakeCamera(clock, board_image, stale=4)
    summary, sink = run(FakeRobot(clock), camera, clock, plan=targets(1))
    sample = sink.samples[0]
    assert sample.discarded_frames == 4
    assert sample.frame.stamp >= sample.window[0]
    assert all(t < sample.window[0] for t in camera.stamps[:4])


def test_arm_never_still_is_retried_then_skipped_with_the_reason(board_image):
    clock = SimClock()
    robot = FakeRobot(clock, settle=1e9)
    settings = CaptureSettings(settle_window=0.3, settle_timeout=2.0, retries=1)
    summary, sink = run(robot, FakeCamera(clock, board_image), clock, settings=settings)
    assert summary.recorded == [] and set(sink.skips) == {"p1", "p2", "p3"}
    assert all(len(r) == 2 and r[0].startswith("not still") for r in sink.skips.values())
    assert len(robot.moves) == 6


def test_limits_are_checked_before_moving(board_image):
    clock = SimClock()
    robot = FakeRobot(clock)
    ids, q = targets(2)
    q[1, 2] = np.radians(400.0)  # beyond the UR5e's +-360 deg
    summary, sink = run(robot, FakeCamera(clock, board_image), clock, plan=(ids, q))
    assert summary.recorded == ["p1"]
    assert sink.skips["p2"][0].startswith("outside joint limits: elbow")
    assert len(robot.moves) == 1
    settings = CaptureSettings(settle_window=0.3, lower=np.full(6, -0.1), upper=np.full(6, 0.1))
    clock = SimClock()
    robot = FakeRobot(clock)
    summary, sink = run(robot, FakeCamera(clock, board_image), clock, settings=settings)
    assert summary.recorded == ["p1"] and "user joint limits" in sink.skips["p2"][0]


def test_failed_move_is_retried_and_final_joint_error_is_checked(board_image):
    clock = SimClock()
    robot = FakeRobot(clock, fail_moves=1)
    summary, sink = run(robot, FakeCamera(clock, board_image), clock, plan=targets(1))
    assert summary.recorded == ["p1"] and summary.outcomes[0].attempts == 2
    assert summary.outcomes[0].reasons == ["move failed: protective stop"]
    clock = SimClock()
    offset = np.zeros(6)
    offset[2] = 0.5 * DEG  # the elbow settles half a degree off the target
    robot = FakeRobot(clock, offset=offset)
    summary, sink = run(robot, FakeCamera(clock, board_image), clock, plan=targets(1))
    assert re.match(r"joint error: elbow settled 0\.(4999|5000|5001) deg", sink.skips["p1"][0])


def test_frames_are_gated_on_board_sharpness_and_reprojection(board_image):
    settings = CaptureSettings()
    blank = np.full_like(board_image, 90)
    assert judge_frame(blank, BOARD, SIM_CAMERA, settings).startswith("board not found")
    blurred = cv2.GaussianBlur(board_image, (0, 0), 4.5)
    judged = judge_frame(blurred, BOARD, SIM_CAMERA, settings)
    assert isinstance(judged, str) and judged.startswith("blurred"), judged
    good = judge_frame(board_image, BOARD, SIM_CAMERA, settings)
    assert good.n_points == 54 and good.sharp > 10 * settings.min_sharpness
    wrong = SIM_CAMERA.with_size(640, 512)
    wrong = type(wrong)(wrong.fx * 1.3, wrong.fy, wrong.cx, wrong.cy, wrong.distortion, 640, 512)
    assert judge_frame(board_image, BOARD, wrong, settings).startswith("reprojection")
    # the sharpness is measured on the board, not diluted by the background around it
    pts = np.array([[200.0, 150.0], [440.0, 150.0], [440.0, 360.0], [200.0, 360.0]])
    assert sharpness(blank, pts) == 0.0


def test_interrupt_stops_the_robot_and_keeps_whole_samples(board_image):
    clock = SimClock()
    robot = FakeRobot(clock)

    class Interrupting(FakeCamera):
        def grab(self, timeout):
            if len(self.stamps) == 2:
                raise KeyboardInterrupt
            return super().grab(timeout)

    sink = ListSink()
    ids, q = targets(4)
    with pytest.raises(KeyboardInterrupt) as info:
        capture(ids, q, MODEL, robot, Interrupting(clock, board_image), clock, BOARD, sink,
                SIM_CAMERA, CaptureSettings(settle_window=0.3), progress=False)  # fmt: skip
    assert robot.stops == 1 and [s.pose_id for s in sink.samples] == ["p1", "p2"]
    assert info.value.capture_summary.interrupted


def _writer(root, ids, q, resume=False):
    return DatasetWriter(root, MODEL, "ur5e", BOARD, SIM_CAMERA, ids, q, resume=resume)


def test_dataset_is_valid_after_each_sample_and_resumes(tmp_path, board_image):
    root = tmp_path / "ds"
    ids, q = targets(3)
    clock = SimClock()
    writer = _writer(root, ids, q)
    settings = CaptureSettings(settle_window=0.3)
    camera = FakeCamera(clock, board_image)
    capture(ids[:1], q[:1], MODEL, FakeRobot(clock), camera, clock, BOARD, writer, SIM_CAMERA,
            settings, progress=False)  # fmt: skip
    with tracking():  # as the command line runs each command: reads noted for that run only
        data = load_dataset(root)
    assert data.ids == ("p1",) and data.images[0].name == "p1.png"
    assert data.images[0].is_file() and not list(root.rglob("*.tmp"))
    with pytest.raises(RelcalError, match="add --resume"):
        _writer(root, ids, q)
    moved = q.copy()
    moved[0, 1] += 0.1
    with pytest.raises(RelcalError, match="other joint targets"):
        _writer(root, ids, moved, resume=True)
    writer = _writer(root, ids, q, resume=True)
    assert writer.done == {"p1"}
    robot = FakeRobot(clock)
    summary = capture(ids, q, MODEL, robot, FakeCamera(clock, board_image), clock, BOARD, writer,
                      SIM_CAMERA, CaptureSettings(settle_window=0.3), done=writer.done,
                      progress=False)  # fmt: skip
    assert summary.ids("done before") == ["p1"] and summary.recorded == ["p2", "p3"]
    assert len(robot.moves) == 2  # p1 was not visited again
    with tracking():
        data = load_dataset(root)
    assert data.ids == ("p1", "p2", "p3")
    np.testing.assert_allclose(data.q, q, atol=0.002 * DEG)
    log = json.loads((root / "capture.json").read_text())
    assert log["runs"] == 2 and set(log["samples"]) == {"p1", "p2", "p3"}


def test_resume_refuses_a_folder_it_did_not_write(tmp_path):
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep me")
    ids, q = targets(2)
    with pytest.raises(RelcalError, match="not a capture folder"):
        _writer(tmp_path / "mine", ids, q, resume=True)
    assert (tmp_path / "mine" / "notes.txt").read_text() == "keep me"


def test_capture_opens_devices_by_name_and_refuses_bad_ones_in_one_line(capsys, tmp_path):
    from relcal.capture import devices
    from relcal.cli import main

    with pytest.raises(RelcalError, match="--camera sim: the virtual camera needs a robot"):
        devices.open_camera("sim", {})
    (tmp_path / "plan.csv").write_text("id,q1,q2,q3,q4,q5,q6\np1,1,2,3,4,5,6\n")
    base = ["capture", str(tmp_path / "plan.csv"), "--robot", "ur5e", "--out", str(tmp_path / "ds")]
    for extra, message in [
        (["--robot-driver", "nope", "--camera", "sim"], "--robot-driver 'nope': expected one of"),
        (["--robot-driver", "sim", "--camera", "sim", "--robot-option", "colour=red"],
         "--robot-driver sim: unknown option 'colour'"),
        (["--robot-driver", "sim", "--camera", "opencv"], "a real camera cannot see it"),
        (["--robot-driver", "sim", "--camera", "sim", "--camera-option", "seed=2"],
         "option seed belongs to --robot-option"),
        (["--robot-driver", "sim", "--camera", "sim", "--robot-option", "faults=hide:p9"],
         "'hide:p9': 'p9' is not a pose id of the plan"),
    ]:  # fmt: skip
        code = main([*base, *extra])
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1 and message in err, err
        assert not (tmp_path / "ds").exists()
    (tmp_path / "bad.csv").write_text("id,q1,q2,q3,q4,q5,q6\np/1,1,2,3,4,5,6\n")
    code = main([*base[:1], str(tmp_path / "bad.csv"), *base[2:], "--robot-driver", "sim",
                 "--camera", "sim"])  # fmt: skip
    assert code == 2 and "pose id 'p/1'" in capsys.readouterr().err


def test_an_interrupt_held_back_during_a_write_keeps_the_sample(tmp_path, board_image):
    """SIGINT during the renames is delivered after them: the sample is on disk, and the
    writer's memory (what --resume and the final log rely on) says so too."""
    import signal

    ids, q = targets(2)
    writer = _writer(tmp_path / "ds", ids, q)
    clock = SimClock()
    original = DatasetWriter.record

    def record_then_signal(self, sample):
        real = os.replace
        calls = []

        def replace(*args, **kwargs):  # the first rename of the sample's files
            if not calls:
                calls.append(1)
                signal.raise_signal(signal.SIGINT)  # arrives mid-write, held back
            return real(*args, **kwargs)

        os.replace = replace
        try:
            original(self, sample)
        finally:
            os.replace = real

    writer.record = record_then_signal.__get__(writer)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)  # as in a shell
    try:
        with pytest.raises(KeyboardInterrupt):
            capture(ids, q, MODEL, FakeRobot(clock), FakeCamera(clock, board_image), clock,
                    BOARD, writer, SIM_CAMERA, CaptureSettings(settle_window=0.3),
                    progress=False)  # fmt: skip
    finally:
        signal.signal(signal.SIGINT, previous)
    assert writer.done == {"p1"}
    writer.finish({"interrupted": True})
    resumed = _writer(tmp_path / "ds", ids, q, resume=True)
    assert resumed.done == {"p1"}


def test_a_urdf_robot_is_kept_as_its_urdf_in_the_dataset(tmp_path, board_image):
    from urdf_helpers import UR5E_KINEMATICS, ur_description_urdf

    from relcal.robot.urdf import load_urdf

    path = tmp_path / "ur5e.urdf"
    path.write_text(ur_description_urdf(UR5E_KINEMATICS))
    model = load_urdf(path, "base_link", "tool0")
    ids, q = targets(1)
    clock = SimClock()
    writer = DatasetWriter(tmp_path / "ds", model, str(path), BOARD, SIM_CAMERA, ids, q)
    robot = FakeRobot(clock)
    robot.joint_names = model.joint_names
    capture(ids, q, model, robot, FakeCamera(clock, board_image), clock, BOARD, writer,
            SIM_CAMERA, CaptureSettings(settle_window=0.3), progress=False)  # fmt: skip
    assert (tmp_path / "ds" / "robot.urdf").read_bytes() == path.read_bytes()
    with tracking():
        data = load_dataset(tmp_path / "ds")
    assert data.model.urdf is not None and data.model.joint_names == model.joint_names
    np.testing.assert_allclose(data.q, q, atol=0.002 * DEG)


class VibratingRobot(FakeRobot):
    """Rings until ``settle`` s after the move returned, then vibrates for ``buzz`` s more at
    10 Hz with 0.004 deg amplitude: 0.008 deg peak to peak, under the 0.01 deg position
    threshold, but 0.25 deg/s, over the velocity limit; reports velocities when ``dq``."""

    def __init__(self, clock, dq=True, buzz=1.0):
        super().__init__(clock, settle=0.4, noise=0.0)
        self.report_dq, self.buzz = dq, buzz

    def parts(self, t):
        since = t - self.returned - self.settle
        amp = 0.004 * DEG * ((since >= 0) & (since < self.buzz))
        w = 2 * np.pi * 10.0
        return amp * np.sin(w * t), amp * w * np.cos(w * t)

    def true_q(self, t):
        return super().true_q(t) + self.parts(t)[0]

    def read(self):
        t = self.clock.now()
        left = self.returned + self.settle - t
        ring_dq = 0.05 * 40 * np.cos(40 * t) * (left > 0)
        dq = np.full(6, ring_dq + self.parts(t)[1])
        return JointReading(self.true_q(t), t, dq if self.report_dq else None)


def test_reported_velocities_hold_the_window_until_the_arm_stops_moving(board_image):
    from relcal.capture.loop import speed_of

    starts = {}
    settings = CaptureSettings(settle_window=0.3, settle_velocity=0.02 * DEG)
    for dq in (False, True):
        clock = SimClock()
        robot = VibratingRobot(clock, dq=dq)
        camera = FakeCamera(clock, board_image)
        summary, sink = run(robot, camera, clock, plan=targets(1), settings=settings)
        assert summary.recorded == ["p1"]
        sample = sink.samples[0]
        starts[dq] = sample.window[0] - robot.returns[0]
        # the arm rang when the move returned (at t = 0.5 s: 0.05 rad x 40 rad/s x cos 20 =
        # 0.82 rad/s), from the first two positions 10 ms apart
        assert 0.4 < sample.returned_speed < 0.9, sample.returned_speed
        assert sample.settle_seconds == pytest.approx(starts[dq] + 0.3, abs=0.02)
        assert sample.record()["settle_seconds"] == pytest.approx(sample.settle_seconds)
    # positions alone accept the vibration (under the threshold) once the ringing ends, at
    # 0.4 s; the velocities wait until it ends too, at 1.4 s
    assert 0.39 <= starts[False] < 0.45, starts
    assert 1.39 <= starts[True] < 1.45, starts
    assert np.isnan(speed_of(JointReading(np.zeros(2), 1.0)))
    two = (JointReading(np.zeros(2), 1.0), JointReading(np.array([0.0, -0.03]), 1.01))
    assert speed_of(*two) == pytest.approx(3.0)
    assert speed_of(JointReading(np.zeros(2), 1.0, np.array([0.5, -2.0]))) == 2.0


def test_settle_velocity_is_checked():
    with pytest.raises(RelcalError, match="settle_velocity"):
        CaptureSettings(settle_velocity=-1.0)


def test_an_interrupt_while_a_failed_write_cleans_up_leaves_no_temporary(tmp_path, monkeypatch):
    """A sample's write fails (a full disk) and SIGINT arrives while its temporaries are being
    removed: the removal ends first, nothing is left beside the dataset's files."""
    import signal
    from pathlib import Path

    import relcal.capture.record as record

    def full(tmp, data):
        raise OSError(28, "No space left on device")

    real_unlink = Path.unlink

    def unlink(self, *args, **kwargs):
        signal.raise_signal(signal.SIGINT)
        return real_unlink(self, *args, **kwargs)

    monkeypatch.setattr(record, "_fill", full)
    monkeypatch.setattr(Path, "unlink", unlink)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)  # as in a shell
    try:
        with pytest.raises(KeyboardInterrupt):
            record._commit([(tmp_path / "a.csv", b"x"), (tmp_path / "b.csv", b"y")])
    finally:
        signal.signal(signal.SIGINT, previous)
        monkeypatch.undo()
    assert list(tmp_path.iterdir()) == []
