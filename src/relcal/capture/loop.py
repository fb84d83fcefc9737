"""The capture loop: for every planned pose, move, wait until still, take a fresh frame, check it,
record joints and image as one sample.

Pure logic over the interfaces of :mod:`relcal.capture.interfaces` (a robot, a camera, a clock)
and a sink that stores samples (:class:`relcal.capture.record.DatasetWriter`, or anything with
``record`` and ``skip``), so that the tests drive it with fakes and the virtual cell, and a real
cell with drivers, through the same code.

For each pose, in the plan's order (see :func:`capture`):

1. **Before moving**: the target must be finite and inside the joint limits (the model's, or the
   user's tighter ones), and pass ``precheck`` (e.g. a collision check) where one is given. A pose
   that fails is skipped at once with the reason; the robot is never sent there.
2. **Move** with a timeout (:class:`MoveFailed`: retried, then skipped).
3. **Wait until still**: joints are read every ``poll`` seconds; the arm is still when, over the
   last ``settle_window`` seconds, every joint's readings span at most ``settle_threshold``
   (peak to peak: this is "|dq| below a threshold over a window" from positions, robust to
   encoder noise) and, with ``settle_velocity`` set and a driver that reports joint velocities
   (:attr:`JointReading.dq`: franky, ur_rtde), every reading's ``|dq|`` is at most
   ``settle_velocity`` (a vibration too small for the positions' threshold). Off by default:
   velocities are noisier than positions (franky-sim's chatter at 0.08 rad/s on an arm at rest,
   whose positions span 0.005 deg). Not still within ``settle_timeout``: the attempt fails.
   "The move returned" is never taken for "the arm is still": how fast the arm still moved when
   the move returned, and how long it then took to become still, are kept per sample.
4. **Final joint error**: the mean of the readings in the still window must be within
   ``joint_tolerance`` of the target on every joint (checked once still: a moving arm's error
   says nothing).
5. **A fresh frame**: frames stamped before the still window began (buffered by the driver or
   the device) are discarded, up to ``max_stale_frames``; then the joints are read once more and
   must still be within ``settle_threshold`` of the window's mean (the arm did not start moving
   while the frame was taken).
6. **Detect and gate** with relcal's own detection (:func:`relcal.vision.detect.detect`): enough
   points, sharpness (variance of the Laplacian over the board's region) and, given intrinsics,
   the reprojection RMS of the pose (:func:`relcal.vision.detect.estimate_pose`).
7. **Record** the joints as the mean over the still window with the frame, under the pose's id
   (with a driver that reads the controller's flange pose, ``flange=True``: the mean of the
   window's flange poses too, :func:`mean_flange`; a window without them fails the attempt);
   a failed attempt is retried ``retries`` times (moving again to the same target), then the pose
   is skipped with every attempt's reason. An image is only ever stored with the joints read
   around its own exposure, under its own pose id.

Joint values are in the model's units (rad, m); times in seconds on the loop's clock.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from relcal.capture.interfaces import Camera, Clock, Frame, JointReading, MoveFailed, Robot
from relcal.errors import RelcalError
from relcal.robot.model import RobotModel
from relcal.vision.boards import Board
from relcal.vision.camera import Camera as Intrinsics

DEG = np.pi / 180.0


@dataclass(frozen=True)
class CaptureSettings:
    """How the loop moves, waits and judges a frame.

    Attributes
    ----------
    retries : int
        Further attempts at a pose after the first one fails (0: one attempt).
    move_timeout : float
        s, given to :meth:`Robot.move`.
    settle_window : float
        s, how long the joints must stay still.
    settle_threshold : float
        rad (m for prismatic joints): largest peak-to-peak spread of a joint's readings over the
        window.
    settle_timeout : float
        s after the move returned within which the arm must become still.
    poll : float
        s between joint readings while waiting.
    settle_velocity : float or None
        rad/s (m/s): largest ``|dq|`` of any joint over the still window, for drivers that report
        velocities (``None``, the default: positions only).
    joint_tolerance : float
        rad (m): largest difference between the still mean and the target on any joint.
    frame_timeout : float
        s, given to :meth:`Camera.grab` for one frame.
    max_stale_frames : int
        Frames stamped before the still window that may be discarded before the attempt fails.
    min_points : int or None
        Fewest board points a frame must show (default: every point for boards the detector
        needs whole, half of them and at least 6 for ChArUco).
    max_rms : float
        px, largest reprojection RMS of the pose (with intrinsics).
    min_sharpness : float
        Smallest variance of the Laplacian (grey levels squared) over the board's region
        (:func:`sharpness`).
    lower, upper : ndarray or None
        Joint limits ``(n,)`` (rad, m) tighter than the model's, e.g. the cell's.
    """

    retries: int = 2
    move_timeout: float = 60.0
    settle_window: float = 0.5
    settle_threshold: float = 0.01 * DEG
    settle_timeout: float = 15.0
    poll: float = 0.01
    settle_velocity: float | None = None
    joint_tolerance: float = 0.1 * DEG
    frame_timeout: float = 2.0
    max_stale_frames: int = 60
    min_points: int | None = None
    max_rms: float = 0.5
    min_sharpness: float = 150.0
    lower: np.ndarray | None = None
    upper: np.ndarray | None = None

    def __post_init__(self) -> None:
        positive = ("move_timeout", "settle_window", "settle_threshold", "settle_timeout", "poll")
        for name in (*positive, "joint_tolerance", "frame_timeout", "max_rms"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise RelcalError(
                    f"capture setting {name}: expected a positive number, got {value}"
                )
        if self.settle_velocity is not None and not (
            np.isfinite(self.settle_velocity) and self.settle_velocity > 0
        ):
            raise RelcalError(
                f"capture setting settle_velocity: expected a positive number, got "
                f"{self.settle_velocity}"
            )
        if self.retries < 0 or self.max_stale_frames < 0:
            raise RelcalError("capture settings retries and max_stale_frames must be >= 0")
        if self.settle_window >= self.settle_timeout:
            raise RelcalError(
                f"capture settings: the settle window ({self.settle_window} s) must be shorter "
                f"than the settle timeout ({self.settle_timeout} s)"
            )


@dataclass(frozen=True)
class Sample:
    """One accepted capture: what the sink stores.

    ``q`` ``(n,)`` is the mean of the joint readings over the still window (rad, m); ``frame`` the
    accepted frame; ``window`` the still window ``(start, end)`` (s); ``returned_speed`` the
    largest joint speed (rad/s, m/s) right after the move returned (:func:`speed_of` the first two
    readings), ``settle_seconds`` the time from the move's return to the end of the still window
    (s).
    """

    pose_id: str
    index: int
    q: np.ndarray
    target: np.ndarray
    frame: Frame
    window: tuple[float, float]
    attempts: int
    n_points: int
    rms_px: float | None
    sharpness: float
    discarded_frames: int
    joint_std: np.ndarray  # (n,) standard deviation of the readings over the window
    returned_speed: float = float("nan")
    settle_seconds: float = float("nan")
    flange: np.ndarray | None = None  # (4, 4) the controller's mean flange pose over the window

    def record(self) -> dict:
        """The capture log entry (plain types; angles as stored, rad and m)."""
        return {
            "attempts": self.attempts,
            "frame_stamp": float(self.frame.stamp),
            "frame_sequence": self.frame.sequence,
            "still_window": [float(self.window[0]), float(self.window[1])],
            "points": self.n_points,
            "rms_px": None if self.rms_px is None else float(self.rms_px),
            "sharpness": float(self.sharpness),
            "discarded_frames": self.discarded_frames,
            "joint_std": [float(v) for v in self.joint_std],
            "returned_speed": _finite_or_none(self.returned_speed),
            "settle_seconds": _finite_or_none(self.settle_seconds),
            "target": [float(v) for v in self.target],
        }


def _finite_or_none(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None


class Sink(Protocol):
    """Where samples go (a dataset folder: :class:`relcal.capture.record.DatasetWriter`)."""

    def record(self, sample: Sample) -> None: ...

    def skip(self, pose_id: str, index: int, reasons: Sequence[str]) -> None: ...


@dataclass
class PoseOutcome:
    """What became of one pose: ``status`` ``recorded``, ``skipped``, or with ``--resume``
    ``done before`` (recorded by an earlier run) or ``skipped before``."""

    pose_id: str
    index: int
    status: str
    attempts: int = 0
    reasons: list[str] = field(default_factory=list)
    seconds: float = 0.0  # on the loop's clock

    @property
    def reason(self) -> str:
        return self.reasons[-1] if self.reasons else ""


@dataclass
class CaptureSummary:
    """The run: one outcome per planned pose, in plan order, and time spent."""

    outcomes: list[PoseOutcome]
    seconds: float  # on the loop's clock
    detect_seconds: float = 0.0  # CPU wall time spent detecting and gating (this process)
    interrupted: bool = False

    def ids(self, status: str) -> list[str]:
        return [o.pose_id for o in self.outcomes if o.status == status]

    @property
    def recorded(self) -> list[str]:
        return self.ids("recorded")

    @property
    def skipped(self) -> dict[str, str]:
        return {o.pose_id: o.reason for o in self.outcomes if o.status == "skipped"}

    def reason_counts(self) -> dict[str, int]:
        """Skips per kind of reason (the text before the first colon)."""
        out: dict[str, int] = {}
        for o in self.outcomes:
            if o.status == "skipped":
                key = o.reason.split(":")[0]
                out[key] = out.get(key, 0) + 1
        return out

    def document(self) -> dict:
        """The summary as plain types (``--json``)."""
        return {
            "planned": len(self.outcomes),
            "recorded": len(self.recorded),
            "recorded_before": len(self.ids("done before")),
            "skipped": len(self.skipped),
            "skipped_before": len(self.ids("skipped before")),
            "interrupted": self.interrupted,
            "seconds": self.seconds,
            "poses_per_minute": (
                60.0 * len(self.recorded) / self.seconds if self.seconds > 0 else None
            ),
            "skip_reasons": self.reason_counts(),
            "poses": [
                {
                    "id": o.pose_id,
                    "status": o.status,
                    "attempts": o.attempts,
                    "reasons": o.reasons,
                    "seconds": o.seconds,
                }
                for o in self.outcomes
            ],
        }


class _Failed(Exception):
    """One attempt failed; the message is the reason shown to the user."""


def limit_problem(
    model: RobotModel, q: np.ndarray, settings: CaptureSettings = CaptureSettings()
) -> str | None:  # noqa: B008
    """Why joint target ``q`` ``(n,)`` may not be sent to the robot, or None.

    Non-finite values, values outside the model's joint limits, or outside the user's limits in
    ``settings``; angles reported in degrees, prismatic joints in mm.
    """
    q = np.asarray(q, float)
    if q.shape != (model.n_joints,):
        return f"target has {q.size} joint values, the robot {model.n_joints}"
    if not np.all(np.isfinite(q)):
        return "target is not finite"
    for name, lo, hi in (
        ("joint limits", model.lower, model.upper),
        ("user joint limits", settings.lower, settings.upper),
    ):
        if lo is None or hi is None:
            continue
        slack = 1e-9  # rad, m: the round-off of a plan written in degrees with 12 digits
        bad = np.flatnonzero((q < lo - slack) | (q > hi + slack))
        if bad.size:
            i = int(bad[0])
            prism = bool(model.prismatic[i])
            f, unit = (1e3, "mm") if prism else (1 / DEG, "deg")
            return (
                f"outside {name}: {model.joint_names[i]} = {q[i] * f:.3f} {unit}, limits "
                f"{lo[i] * f:.3f} .. {hi[i] * f:.3f} {unit}"
            )
    return None


def sharpness(gray: np.ndarray, points: np.ndarray) -> float:
    """Variance of the Laplacian (grey levels squared) over the convex hull of ``points``
    ``(N, 2)`` (px) in an 8-bit grey image: the focus measure of Pech-Pacheco et al., restricted
    to the board so that a featureless background does not dilute it, and taken after a Gaussian
    of 1 px so that sensor noise does not count as detail (noise of 4 grey levels adds about 20;
    on the virtual cell's 640 x 512 images a sharp board gives 1800 to 3000, a blur of 1.5 px
    500 to 1000, of 2.5 px 200 to 350, of 4 px 60 to 120)."""
    import cv2

    smooth = cv2.GaussianBlur(gray, (0, 0), 1.0)
    lap = cv2.Laplacian(smooth, cv2.CV_64F, ksize=3)
    mask = np.zeros(gray.shape, np.uint8)
    hull = cv2.convexHull(np.asarray(points, np.float32).reshape(-1, 1, 2)).astype(np.int32)
    cv2.fillConvexPoly(mask, hull, 1)
    values = lap[mask > 0]
    return float(values.var()) if values.size > 8 else 0.0


@dataclass(frozen=True)
class _Judged:
    n_points: int
    rms: float | None
    sharp: float


def judge_frame(
    image: np.ndarray,
    board: Board,
    intrinsics: Intrinsics | None,
    settings: CaptureSettings = CaptureSettings(),  # noqa: B008
) -> _Judged | str:
    """Detect ``board`` in ``image`` and apply the gates of ``settings``; the reason (a string
    ``"kind: details"``) when the frame is not good enough."""
    from relcal.vision.detect import Rejected, detect, estimate_pose, to_gray

    gray = to_gray(image)
    if intrinsics is not None and intrinsics.width is not None and intrinsics.height is not None:
        if (gray.shape[1], gray.shape[0]) != (intrinsics.width, intrinsics.height):
            return (
                f"image size: {gray.shape[1]}x{gray.shape[0]} px, the intrinsics are for "
                f"{intrinsics.width}x{intrinsics.height} px"
            )
    wanted = settings.min_points
    if wanted is None:
        wanted = board.n_points if board.needs_whole_view else max(6, board.n_points // 2)
    found = detect(gray, board, min_points=6)
    if isinstance(found, Rejected):
        return f"board not found: {found.reason}"
    n = len(found.ids)
    if n < wanted:
        return f"too few points: {n} of the board's {board.n_points} (need {wanted})"
    sharp = sharpness(gray, found.image_points)
    if sharp < settings.min_sharpness:
        return (
            f"blurred: sharpness {sharp:.1f} below {settings.min_sharpness:g} (variance of the "
            "Laplacian over the board)"
        )
    rms = None
    if intrinsics is not None:
        pose = estimate_pose(found, intrinsics, max_rms=settings.max_rms)
        if isinstance(pose, Rejected):
            return f"reprojection: {pose.reason}"
        rms = pose.rms
    return _Judged(n, rms, sharp)


def speed_of(first: JointReading, second: JointReading | None = None) -> float:
    """The largest joint speed (rad/s, m/s) at ``first``: the difference to the next reading
    ``second`` over their stamps, else ``first``'s reported velocities (``nan`` without
    either). Positions first: reported velocities can be noisier than the motion measured."""
    if second is not None and second.stamp > first.stamp:
        step = np.asarray(second.q, float) - np.asarray(first.q, float)
        return float(np.abs(step).max() / (second.stamp - first.stamp))
    if first.dq is not None:
        return float(np.abs(np.asarray(first.dq, float)).max())
    return float("nan")


def still_spread(window: Sequence[JointReading]) -> tuple[np.ndarray, float | None]:
    """Per joint, the peak-to-peak spread ``(n,)`` of the positions over ``window`` (rad, m),
    and the largest ``|dq|`` (rad/s, m/s) of its readings when every one reports velocities
    (else ``None``)."""
    values = np.array([r.q for r in window])
    speed = None
    if all(r.dq is not None for r in window):
        speed = float(np.abs(np.array([r.dq for r in window])).max())
    return np.ptp(values, axis=0), speed


def wait_until_still(
    robot: Robot, clock: Clock, settings: CaptureSettings
) -> tuple[list[JointReading], float, float]:
    """Read the joints until they have been still for ``settle_window`` seconds: positions
    within ``settle_threshold`` peak to peak, and with ``settle_velocity`` set, reported
    velocities (where the driver gives them) within it.

    Returns
    -------
    readings : list of JointReading
        The readings of the still window, oldest first.
    start : float
        When the still window began (s): the stamp of its first reading.
    returned_speed : float
        The largest joint speed (rad/s, m/s) at the first reading (:func:`speed_of`).

    Raises
    ------
    _Failed
        Not still within ``settle_timeout`` (the reason gives the spread still seen).
    """
    begin = clock.now()
    history: list[JointReading] = []
    first: list[JointReading] = []
    spread, fastest = np.inf, None
    limit = settings.settle_velocity
    while True:
        reading = robot.read()
        dq = None if reading.dq is None else np.asarray(reading.dq, float)
        flange = getattr(reading, "flange", None)
        flange = None if flange is None else np.asarray(flange, float)
        reading = JointReading(np.asarray(reading.q, float), float(reading.stamp), dq, flange)
        history.append(reading)
        if len(first) < 2:
            first.append(reading)
        cut = reading.stamp - settings.settle_window
        # keep the readings of the window, and the last one before it (coverage)
        while len(history) > 2 and history[1].stamp <= cut:
            history.pop(0)
        if history[0].stamp <= cut + 1e-9:
            window = [r for r in history if r.stamp >= cut - 1e-9]
            if len(window) >= 3:
                spread_j, fastest = still_spread(window)
                spread = float(spread_j.max())
                if np.all(spread_j <= settings.settle_threshold) and (
                    limit is None or fastest is None or fastest <= limit
                ):
                    return window, window[0].stamp, speed_of(*first)
        if clock.now() - begin > settings.settle_timeout:
            shown = "no full window" if not np.isfinite(spread) else f"{spread / DEG:.4f} deg"
            speed = limits = ""
            if limit is not None and fastest is not None:
                speed = f", speed up to {fastest / DEG:.4f} deg/s"
                limits = f", {limit / DEG:.4f} deg/s"
            raise _Failed(
                f"not still: joints still moving after {settings.settle_timeout:g} s "
                f"(spread over the last {settings.settle_window:g} s: {shown}{speed}, threshold "
                f"{settings.settle_threshold / DEG:.4f} deg{limits})"
            )
        clock.sleep(settings.poll)


def mean_flange(window: Sequence[JointReading]) -> np.ndarray | None:
    """The mean ``(4, 4)`` of the flange poses of a still window (positions averaged, rotations
    by their chordal mean), or None when a reading lacks one."""
    from relcal.data.flange import mean_rotation

    poses = [r.flange for r in window]
    if not poses or any(p is None for p in poses):
        return None
    poses = np.array(poses, dtype=float)
    out = np.eye(4)
    out[:3, :3] = mean_rotation(poses[:, :3, :3])
    out[:3, 3] = poses[:, :3, 3].mean(axis=0)
    return out


def fresh_frame(
    camera: Camera, clock: Clock, start: float, settings: CaptureSettings
) -> tuple[Frame, int]:
    """The first frame stamped at or after ``start`` (s), and how many older ones were
    discarded (buffered frames taken before the arm was still)."""
    discarded = 0
    while True:
        frame = camera.grab(settings.frame_timeout)
        if frame.stamp >= start:
            return frame, discarded
        discarded += 1
        if discarded > settings.max_stale_frames:
            raise _Failed(
                f"stale frames: {discarded} frames stamped before the arm was still "
                f"(newest {start - frame.stamp:.3f} s too early); is the camera's clock the "
                "loop's?"
            )


def _joint_name(robot: Robot, i: int) -> str:
    names = tuple(getattr(robot, "joint_names", ()))
    return names[i] if i < len(names) and names[i] else f"joint {i + 1}"


def attempt(
    index: int,
    pose_id: str,
    target: np.ndarray,
    robot: Robot,
    camera: Camera,
    clock: Clock,
    board: Board,
    intrinsics: Intrinsics | None,
    settings: CaptureSettings,
    attempts: int,
    timing: dict,
    flange: bool = False,
) -> Sample:
    """One attempt at one pose (steps 2 to 6 of the module docstring, and with ``flange`` the
    mean flange pose of the still window); raises :class:`_Failed` with the reason."""
    try:
        robot.move(target, settings.move_timeout)
    except MoveFailed as exc:
        raise _Failed(f"move failed: {exc}") from None
    returned = clock.now()
    window, start, returned_speed = wait_until_still(robot, clock, settings)
    values = np.array([r.q for r in window])
    mean = values.mean(axis=0)
    error = np.abs(mean - target)
    worst = int(np.argmax(error))
    if error[worst] > settings.joint_tolerance:
        raise _Failed(
            f"joint error: {_joint_name(robot, worst)} settled {np.degrees(error[worst]):.4f} deg "
            f"from the target (tolerance {np.degrees(settings.joint_tolerance):.4f} deg)"
        )
    pose = mean_flange(window) if flange else None
    if flange and pose is None:
        raise _Failed(
            "no flange pose: the driver reported none in the still window (is the controller's "
            "tool pose published?)"
        )
    frame, discarded = fresh_frame(camera, clock, start, settings)
    after = np.asarray(robot.read().q, float)
    moved = np.abs(after - mean).max()
    if moved > settings.settle_threshold:
        raise _Failed(
            f"moved during the frame: joints {np.degrees(moved):.4f} deg from the still mean "
            "after the frame was taken"
        )
    begin = time.perf_counter()
    judged = judge_frame(frame.image, board, intrinsics, settings)
    timing["detect"] = timing.get("detect", 0.0) + time.perf_counter() - begin
    if isinstance(judged, str):
        raise _Failed(judged)
    return Sample(
        pose_id=pose_id,
        index=index,
        q=mean,
        target=np.asarray(target, float),
        frame=frame,
        window=(start, window[-1].stamp),
        attempts=attempts,
        n_points=judged.n_points,
        rms_px=judged.rms,
        sharpness=judged.sharp,
        discarded_frames=discarded,
        joint_std=values.std(axis=0),
        returned_speed=returned_speed,
        settle_seconds=window[-1].stamp - returned,
        flange=pose,
    )


def capture(
    ids: Sequence[str],
    targets: np.ndarray,
    model: RobotModel,
    robot: Robot,
    camera: Camera,
    clock: Clock,
    board: Board,
    sink: Sink,
    intrinsics: Intrinsics | None = None,
    settings: CaptureSettings = CaptureSettings(),  # noqa: B008
    done: frozenset[str] | set[str] = frozenset(),
    precheck: Callable[[np.ndarray], str | None] | None = None,
    progress: bool = True,
    skipped_before: frozenset[str] | set[str] = frozenset(),
    flange: bool = False,
) -> CaptureSummary:
    """Visit every planned pose and record a sample at each (see the module docstring).

    Parameters
    ----------
    ids : sequence of str
        Pose ids, unique; a sample is stored under its pose's id.
    targets : ndarray, shape (K, n)
        Joint targets (rad, m) in the robot's joint order.
    model : RobotModel
        For the joint limits (and names in messages).
    robot, camera, clock
        The devices (:mod:`relcal.capture.interfaces`).
    board : Board
    sink : Sink
        Stores each sample whole as it is taken, and each skip.
    intrinsics : Camera or None
        For the reprojection gate (without: no pose is estimated while capturing).
    settings : CaptureSettings
    done : set of str
        Ids recorded by an earlier run (``--resume``): not visited again.
    skipped_before : set of str
        Ids an earlier run skipped: not visited again either (``--resume`` without
        ``--retry-skipped``).
    precheck : callable or None
        ``precheck(q) -> reason or None``: a further check before moving (collisions).
    progress : bool
        A tqdm bar on stderr with the pose count, the skips and the last reason.
    flange : bool
        Record the controller's flange pose with each sample (the mean over the still window of
        :attr:`JointReading.flange`, which the driver must report: a driver whose class says
        ``reports_flange = True``).

    Returns
    -------
    CaptureSummary
        Also when interrupted (``KeyboardInterrupt`` is re-raised after the robot is stopped;
        the sink holds every sample taken until then).
    """
    from tqdm import tqdm

    targets = np.atleast_2d(np.asarray(targets, float))
    if len(ids) != len(targets):
        raise RelcalError(f"{len(ids)} pose ids for {len(targets)} joint targets")
    if len(set(ids)) != len(ids):
        raise RelcalError("pose ids must be unique")
    outcomes: list[PoseOutcome] = []
    timing: dict = {}
    begin = clock.now()
    bar = tqdm(total=len(ids), disable=not progress, unit="pose", desc="capture", leave=True)
    recorded = skipped = 0
    summary = CaptureSummary(outcomes, 0.0)
    try:
        for k, (pose_id, target) in enumerate(zip(ids, targets, strict=True)):
            if pose_id in done or pose_id in skipped_before:
                status = "done before" if pose_id in done else "skipped before"
                outcomes.append(PoseOutcome(pose_id, k, status))
                bar.update(1)
                continue
            started = clock.now()
            outcome = PoseOutcome(pose_id, k, "skipped")
            problem = limit_problem(model, target, settings)
            if problem is None and precheck is not None:
                problem = precheck(target)
            if problem is not None:
                outcome.reasons.append(problem)
            else:
                for n in range(1, settings.retries + 2):
                    outcome.attempts = n
                    try:
                        sample = attempt(
                            k, pose_id, target, robot, camera, clock, board, intrinsics,
                            settings, n, timing, flange,
                        )  # fmt: skip
                    except _Failed as exc:
                        outcome.reasons.append(str(exc))
                        continue
                    sink.record(sample)
                    outcome.status = "recorded"
                    break
            if outcome.status == "skipped":
                sink.skip(pose_id, k, outcome.reasons)
                skipped += 1
            else:
                recorded += 1
            outcome.seconds = clock.now() - started
            outcomes.append(outcome)
            bar.set_postfix_str(
                f"recorded {recorded}, skipped {skipped}"
                + (f" (last: {pose_id} {outcome.reason.split(':')[0]})" if outcome.reasons else ""),
                refresh=False,
            )
            bar.update(1)
    except BaseException as exc:
        summary.interrupted = True
        exc.capture_summary = summary  # type: ignore[attr-defined]  # for the command line
        try:
            robot.stop()
        finally:
            summary.seconds = clock.now() - begin
            summary.detect_seconds = timing.get("detect", 0.0)
            bar.close()
        raise
    bar.close()
    summary.seconds = clock.now() - begin
    summary.detect_seconds = timing.get("detect", 0.0)
    return summary
