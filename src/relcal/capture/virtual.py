"""The virtual cell: a robot with planted errors, a controller that takes time to settle, a flange
camera with real intrinsics and lens distortion, and the printed board, rendered with MuJoCo.

What it is for: rehearsing a capture (``relcal capture --robot-driver sim --camera sim``),
testing the capture loop end to end without hardware, and measuring what a calibration recovers
from images when the truth is known.

The truth
    A nominal :class:`~relcal.robot.model.RobotModel` (what the user names with ``--robot``) with
    planted errors: random geometric errors (0.1..0.9 mm, 0.01..0.9 deg, as
    :func:`relcal.sim.scenario.random_errors` draws them) on the layout ``relcal calibrate`` uses
    (Hayati joints where axes are parallel), or errors from a file, and optionally the
    non-geometric terms relcal models (joint scale, compliance, first harmonic). The camera's pose
    at an exposure is ``B^-1 F_true(q_true(t)) X_true``: relcal's own forward kinematics of the
    true model (non-geometric terms included, through
    :func:`~relcal.robot.kinematics.effective_joints`) at the arm's *actual* joint values at that
    instant, with the true hand-eye ``X_true`` about 1 mm / 0.5 deg off the mount drawing.

The arm
    Each joint follows a minimum-jerk reference to the target through a second-order response
    (natural frequency ``omega``, damping ``zeta``: it lags while moving and overshoots after),
    integrated exactly over 2 ms steps. :meth:`SimRobot.move` returns when the *reference* ends,
    before the arm is still. Readings carry Gaussian encoder noise and the time they were taken.

The camera
    Frames are exposed at ``fps`` on the cell's clock and delivered ``latency`` later, through a
    buffer as drivers have them: the newest frame (default), or the oldest ``stale`` frames of a
    buffer that stops filling when full (OpenCV's ``VideoCapture`` on V4L2, the classic cause of
    stale images), with a share of frames dropped if asked. Each frame carries its exposure stamp
    and a sequence number, as a real driver's would.

The image
    MuJoCo renders the scene on the CPU (EGL or OSMesa): the board as a texture of the sheet
    ``relcal board`` prints, at its true size, lying on a table; the robot's links as capsules at
    the true joint frames; an occluder where a fault hides the board. MuJoCo's pinhole camera has
    square pixels and a centred principal point, so the scene is rendered with a wide enough
    field of view and remapped through the real camera's intrinsics and lens distortion (every
    output pixel takes the MuJoCo pixel its undistorted ray hits). Through MuJoCo's texture
    sampling (Mesa's rasteriser on the CPU, rendered at twice the resolution) the detected
    corners lie about twice as far from their true projections as with relcal's analytic
    renderer (:func:`relcal.vision.render.render_levels`, exact area coverage): median 0.08 px
    against 0.04 px per frame in ``bench/capture.py``, up to 0.2 px on close views. So by
    default the board's own pixels come from the analytic renderer wherever MuJoCo's
    segmentation says the board is visible, and everything else (links, occluders, table, what
    hides what) from MuJoCo: the analytic renderer knows nothing of a scene, MuJoCo draws one.
    ``board_pixels="mujoco"`` takes MuJoCo's texture for the board too. Then relcal's blur,
    lighting gradient and sensor noise (:func:`relcal.vision.render.finish_image`).

What the devices report
    :class:`SimRobot` and :class:`SimCamera` (registered as ``sim`` in
    :mod:`relcal.capture.devices`: :class:`VirtualRobot`, :class:`VirtualCamera`) implement the
    interfaces of
    :mod:`relcal.capture.interfaces` and report only what real ones would: noisy joint readings
    with stamps, frames with stamps and sequence numbers, and the controller's flange pose with
    each reading, computed as a controller computes it, from the joints it read: by default
    with the arm's true kinematics (a controller that carries its arm's factory calibration),
    with ``flange_model="nominal"`` with the nominal model (a controller without one: the
    planted errors then enter the logged flange poses). The truth (planted errors, true joints
    at every delivered frame's exposure) stays in the cell, for :meth:`VirtualCell.truth`, which
    the capture loop never reads.

Time is simulated (:class:`SimClock`): sleeping advances it at once, so a capture of 30 poses
takes the seconds of rendering and detection, not of robot motion.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from relcal import geometry as tf
from relcal.capture.interfaces import CaptureError, Frame, JointReading, MoveFailed
from relcal.errors import RelcalError
from relcal.robot.kinematics import Layout, apply_errors, fk, forward_frames, make_layout
from relcal.robot.model import RobotModel, auto_hayati, with_nongeometric
from relcal.vision.boards import Board, board_extent, pattern_extent, reflectance
from relcal.vision.camera import Camera as Intrinsics

DEG = np.pi / 180.0
MM = 1e-3

#: The virtual cell's camera: the field of view of ``relcal plan``'s default camera (2448 x 2048
#: px, 8 mm lens) at 640 x 512 px, with the barrel distortion of a short lens.
SIM_CAMERA = Intrinsics(
    fx=606.3,
    fy=606.1,
    cx=321.2,
    cy=254.6,
    distortion=(-0.11, 0.09, 0.0004, -0.0003, -0.02),
    width=640,
    height=512,
)
STEP = 0.002  # s, integration step of the arm


class SimClock:
    """Simulated seconds: :meth:`sleep` advances time at once."""

    def __init__(self, start: float = 0.0) -> None:
        self.t = float(start)

    def now(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.t += max(float(seconds), 0.0)


@dataclass(frozen=True)
class Faults:
    """Faults to inject, for tests and rehearsals.

    Attributes
    ----------
    hidden : tuple of int
        Plan rows (0-based) at which something hides the board on every attempt.
    hidden_once : tuple of int
        Plan rows at which the board is hidden on the first visit only (someone walks through).
    stale : int
        Buffer depth of a camera that keeps the *oldest* frames and drops new ones when full
        (0: a camera that delivers the newest frame).
    slow_settle : bool
        The arm settles slowly (natural frequency 0.8 Hz, damping 0.2: seconds of ringing).
    drop : float
        Share of frames the camera loses (0..1).
    """

    hidden: tuple[int, ...] = ()
    hidden_once: tuple[int, ...] = ()
    stale: int = 0
    slow_settle: bool = False
    drop: float = 0.0

    @classmethod
    def parse(cls, text: str, ids: list[str] | None = None) -> Faults:
        """From ``hide:p003+p010;hide_once:p005;stale:8;slow;drop:0.3``: faults separated by
        ``;``, a value after ``:``, pose ids (of the plan ``ids``, or 0-based rows) joined by
        ``+`` (no ``=`` or ``,``, so that the text passes as one ``--robot-option faults=...``)."""
        out: dict[str, Any] = {}
        for part in filter(None, (p.strip() for p in text.split(";"))):
            key, _, value = part.partition(":")
            key = key.strip().lower().replace("_", "-")
            try:
                if key in ("hide", "hide-once"):
                    rows = []
                    for name in filter(None, (v.strip() for v in value.split("+"))):
                        if ids is not None and name in ids:
                            rows.append(ids.index(name))
                        elif name.isdigit():
                            rows.append(int(name))
                        else:
                            raise ValueError(f"'{name}' is not a pose id of the plan")
                    out["hidden" if key == "hide" else "hidden_once"] = tuple(rows)
                elif key == "stale":
                    out["stale"] = int(value or 8)
                elif key == "slow":
                    out["slow_settle"] = True
                elif key == "drop":
                    out["drop"] = float(value)
                    if not 0 <= out["drop"] < 1:
                        raise ValueError("expected a share from 0 up to 1")
                else:
                    raise ValueError("unknown fault (hide, hide_once, stale, slow, drop)")
            except ValueError as exc:
                raise RelcalError(f"--robot-option faults: '{part}': {exc}") from None
        return cls(**out)


@dataclass(frozen=True)
class Truth:
    """What the virtual robot really is (never shown to the capture loop)."""

    model: RobotModel  # the nominal model with the layout's options (Hayati, non-geometric)
    layout: Layout
    errors: np.ndarray  # (P,) planted errors on ``layout`` (m, rad, 1, ...)
    handeye: np.ndarray  # (4, 4) true flange-from-camera
    handeye_guess: np.ndarray  # (4, 4) the mount drawing
    board: Board
    board_pose: np.ndarray  # (4, 4) board frame in the base frame
    camera: Intrinsics  # true intrinsics

    @property
    def true_model(self) -> RobotModel:
        return apply_errors(self.model, self.layout, self.errors)


@dataclass(frozen=True)
class ArmDynamics:
    """Joint response: minimum-jerk reference at up to ``speed`` (rad/s, m/s) followed through
    a second-order response of natural frequency ``omega`` (rad/s) and damping ``zeta``."""

    omega: float = 2 * np.pi * 2.0
    zeta: float = 0.35
    speed: float = 1.0
    min_duration: float = 0.3  # s

    def transition(self, dt: float) -> np.ndarray:
        """The exact 2 x 2 state transition of (error, velocity) over ``dt`` s."""
        from scipy.linalg import expm

        a = np.array([[0.0, 1.0], [-(self.omega**2), -2.0 * self.zeta * self.omega]])
        return expm(a * dt)


SLOW = ArmDynamics(omega=2 * np.pi * 0.8, zeta=0.2)


class _Arm:
    """The arm's true joint state over time (integrated lazily up to the clock)."""

    def __init__(self, q0: np.ndarray, dynamics: ArmDynamics, history: float = 300.0) -> None:
        self.dyn = dynamics
        self.phi = dynamics.transition(STEP)
        self.t = 0.0
        self.q = np.array(q0, float)
        self.v = np.zeros_like(self.q)
        self.start = self.goal = self.q.copy()
        self.t0, self.duration = 0.0, 0.0
        size = int(history / STEP) + 2
        self._times = np.full(size, -np.inf)
        self._states = np.zeros((size, len(self.q)))
        self._head = 0
        self._store()

    def _store(self) -> None:
        k = self._head % len(self._times)
        self._times[k] = self.t
        self._states[k] = self.q
        self._head += 1

    def reference(self, t: float) -> np.ndarray:
        if self.duration <= 0 or t >= self.t0 + self.duration:
            return self.goal
        s = max(t - self.t0, 0.0) / self.duration
        blend = 10 * s**3 - 15 * s**4 + 6 * s**5
        return self.start + (self.goal - self.start) * blend

    def advance(self, t: float) -> None:
        phi = self.phi
        while self.t + STEP <= t + 1e-12:
            r = self.reference(self.t + 0.5 * STEP)
            e = self.q - r
            self.q = r + phi[0, 0] * e + phi[0, 1] * self.v
            self.v = phi[1, 0] * e + phi[1, 1] * self.v
            self.t += STEP
            self._store()

    def command(self, goal: np.ndarray, now: float) -> float:
        """Start a move to ``goal`` at ``now``; the reference's duration (s)."""
        self.advance(now)
        self.start = self.reference(now).copy()
        self.goal = np.array(goal, float)
        peak = np.abs(self.goal - self.start).max()
        self.t0 = now
        self.duration = max(1.875 * peak / self.dyn.speed, self.dyn.min_duration)
        return self.duration

    def halt(self, now: float) -> None:
        self.advance(now)
        self.goal = self.q.copy()
        self.duration = 0.0

    def at(self, t: float) -> np.ndarray:
        """True joints at time ``t`` (s, past or present), interpolated between steps."""
        self.advance(t)
        n = min(self._head, len(self._times))
        order = (np.arange(self._head - n, self._head)) % len(self._times)
        times = self._times[order]
        if t < times[0] - 1e-9:
            raise CaptureError(f"virtual cell: no arm state kept for t = {t:.3f} s")
        k = int(np.searchsorted(times, t))
        if k >= n:
            return self._states[order[-1]].copy()
        if k == 0:
            return self._states[order[0]].copy()
        t0, t1 = times[k - 1], times[k]
        w = (t - t0) / (t1 - t0) if t1 > t0 else 1.0
        return (1 - w) * self._states[order[k - 1]] + w * self._states[order[k]]


def _mujoco():
    """Import MuJoCo for offscreen rendering on the CPU (``MUJOCO_GL``, default ``egl``)."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    try:
        import mujoco
    except ImportError:
        raise RelcalError(
            "the virtual cell needs MuJoCo, which is optional: pip install 'relcal[virtual]'"
        ) from None
    return mujoco


def _quat(rotation: np.ndarray) -> np.ndarray:
    """MuJoCo quaternion (w, x, y, z) of a rotation matrix."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(rotation).as_quat()
    return np.array([w, x, y, z])


class SceneRenderer:
    """The cell drawn by MuJoCo and seen through a real camera (see the module docstring).

    Parameters
    ----------
    truth : Truth
    link_radius : float
        m, radius of the capsules drawn for the links.
    board_pixels : {"analytic", "mujoco"}
        Where the board's own pixels come from.
    supersample : int
        Rays per pixel along each axis of the analytic board pixels.
    """

    def __init__(
        self,
        truth: Truth,
        link_radius: float = 0.035,
        board_pixels: str = "analytic",
        supersample: int = 2,
    ) -> None:
        if board_pixels not in ("analytic", "mujoco"):
            raise RelcalError(f"board_pixels: expected analytic or mujoco, got '{board_pixels}'")
        mujoco = _mujoco()
        self.mj = mujoco
        self.truth = truth
        self.board_pixels = board_pixels
        self.supersample = int(supersample)
        cam = truth.camera
        width, height = cam.size
        s = 2 if board_pixels == "mujoco" else 1
        u, v = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
        rays = cam.undistort(np.stack([u, v], -1).reshape(-1, 2)).reshape(height, width, 2)
        f = s * max(cam.fx, cam.fy)
        self.render_size = (
            int(np.ceil(2 * f * np.abs(rays[..., 0]).max())) + 4,
            int(np.ceil(2 * f * np.abs(rays[..., 1]).max())) + 4,
        )
        rw, rh = self.render_size
        self.map_x = (f * rays[..., 0] + rw / 2 - 0.5).astype(np.float32)
        self.map_y = (f * rays[..., 1] + rh / 2 - 0.5).astype(np.float32)
        self.fovy = float(np.degrees(2 * np.arctan(rh / 2 / f)))
        self._segments = self._link_segments()
        self.model = self._build(link_radius)
        self.data = mujoco.MjData(self.model)
        try:
            self.renderer = mujoco.Renderer(self.model, rh, rw)
            # What hides the board is found at half the resolution (a quarter of the readback)
            self.masker = mujoco.Renderer(self.model, (rh + 1) // 2, (rw + 1) // 2)
            self.masker.enable_segmentation_rendering()
        except Exception as exc:  # no OpenGL context
            gl = os.environ.get("MUJOCO_GL")
            raise RelcalError(
                f"MuJoCo could not render offscreen (MUJOCO_GL={gl}): {exc}; install Debian's "
                "libegl1, libegl-mesa0 and libgl1-mesa-dri (make mujoco-gl), or set "
                "MUJOCO_GL=osmesa with libosmesa6"
            ) from None
        self._board_geom = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_GEOM, "board")

    # -------------------------------------------------------------- the scene

    def _link_segments(self) -> list[tuple[int, int, float]]:
        """(frame a, frame b, length) of the links drawn: consecutive joint frames, then the
        last frame to the tool; distances are constant for a serial chain."""
        model = self.truth.true_model
        q = np.zeros((1, model.n_joints))
        frames = forward_frames(model, q)[0]
        points = [*frames[:, :3, 3], fk(model, q)[0][:3, 3]]
        out = []
        for k in range(len(points) - 1):
            length = float(np.linalg.norm(points[k + 1] - points[k]))
            if length > 0.02:
                out.append((k, k + 1, length))
        return out

    def _build(self, link_radius: float):
        import cv2

        mujoco = self.mj
        truth = self.truth
        board = truth.board_pose
        cam = truth.camera
        # Texture dense enough for the nearest view (0.15 m) at the render's focal length.
        ppm = float(np.clip(2.0 * max(cam.fx, cam.fy) / 0.15, 2000.0, 12000.0))
        x0, y0, x1, y1 = board_extent(truth.board)
        levels, (tx0, ty0) = reflectance(truth.board, ppm)
        th, tw = levels.shape
        tx1, ty1 = tx0 + tw / ppm, ty0 + th / ppm
        from relcal.vision.render import INK_LEVEL, PAPER_LEVEL

        grey = np.round(255 * (INK_LEVEL + (PAPER_LEVEL - INK_LEVEL) * levels)).astype(np.uint8)
        ok, png = cv2.imencode(".png", np.repeat(grey[:, :, None], 3, axis=2))
        if not ok:
            raise RelcalError("virtual cell: could not encode the board texture")
        vertex = np.array([[tx0, ty0, 0], [tx1, ty0, 0], [tx1, ty1, 0], [tx0, ty1, 0]])
        vs = " ".join(f"{a:.9g}" for a in vertex.ravel())
        pos = " ".join(f"{a:.9g}" for a in board[:3, 3])
        quat = " ".join(f"{a:.9g}" for a in _quat(board[:3, :3]))
        # The table under the board: 2 mm behind the sheet (the board's z points into it).
        table = board @ tf.homogeneous(
            np.eye(3), np.array([0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.003])
        )
        tpos = " ".join(f"{a:.9g}" for a in table[:3, 3])
        links = "".join(
            f'<body name="link{k}" mocap="true"><geom type="capsule" size="{link_radius:.4f} '
            f'{0.5 * length:.6f}" rgba="0.55 0.6 0.65 1" contype="0" conaffinity="0"/></body>'
            for k, (_, _, length) in enumerate(self._segments)
        )
        xml = f"""<mujoco model="relcal virtual cell">
  <statistic extent="1" center="0 0 0"/>
  <visual>
    <global offwidth="{self.render_size[0]}" offheight="{self.render_size[1]}"/>
    <quality offsamples="4"/>
    <map znear="0.01" zfar="20"/>
    <headlight ambient="0.45 0.45 0.45" diffuse="0.5 0.5 0.5" specular="0 0 0"/>
  </visual>
  <asset>
    <texture name="board" type="2d" file="board.png"/>
    <material name="board" texture="board" specular="0" shininess="0" emission="0.35"/>
    <mesh name="sheet" vertex="{vs}" face="0 1 2 0 2 3 0 2 1 0 3 2"
          texcoord="0 0 1 0 1 1 0 1" inertia="shell"/>
  </asset>
  <worldbody>
    <light pos="0 0 3" dir="0 0 -1" diffuse="0.3 0.3 0.3"/>
    <geom name="board" type="mesh" mesh="sheet" material="board" pos="{pos}" quat="{quat}"
          contype="0" conaffinity="0"/>
    <geom name="table" type="box" size="0.6 0.6 0.001" pos="{tpos}" quat="{quat}"
          rgba="0.3 0.32 0.3 1" contype="0" conaffinity="0"/>
    {links}
    <body name="occluder" mocap="true" pos="0 0 -50">
      <geom type="box" size="0.09 0.07 0.004" rgba="0.7 0.45 0.3 1" contype="0" conaffinity="0"/>
    </body>
    <camera name="flange_camera" pos="0 0 0" fovy="{self.fovy:.9f}"/>
  </worldbody>
</mujoco>"""
        return mujoco.MjModel.from_xml_string(xml, assets={"board.png": png.tobytes()})

    # -------------------------------------------------------------- drawing

    def render(self, q_true: np.ndarray, hidden: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Ideal grey levels ``(H, W)`` (0..1, float32) of the camera at true joints ``q_true``
        ``(n,)``, and the true camera pose ``T_board_camera`` ``(4, 4)``."""
        import cv2

        from relcal.vision.render import BACKGROUND_LEVEL, render_levels

        mujoco = self.mj
        truth = self.truth
        model = truth.true_model
        q = np.asarray(q_true, float)[None, :]
        frames = forward_frames(model, q)[0]
        flange = fk(model, q)[0]
        points = [*frames[:, :3, 3], flange[:3, 3]]
        for k, (a, b, _) in enumerate(self._segments):
            p, r = points[a], points[b]
            axis = (r - p) / np.linalg.norm(r - p)
            x = np.cross(axis, [1.0, 0.0, 0.0])
            if np.linalg.norm(x) < 1e-6:
                x = np.cross(axis, [0.0, 1.0, 0.0])
            x /= np.linalg.norm(x)
            rot = np.stack([x, np.cross(axis, x), axis], axis=1)
            self.data.mocap_pos[k] = 0.5 * (p + r)
            self.data.mocap_quat[k] = _quat(rot)
        camera = flange @ truth.handeye  # base-from-camera (OpenCV axes)
        t_board_camera = tf.invert(truth.board_pose) @ camera
        occluder = len(self._segments)
        if hidden:
            # a panel 8 cm in front of the board's centre, facing the camera
            px0, py0, px1, py1 = pattern_extent(truth.board)
            centre = truth.board_pose @ np.array([(px0 + px1) / 2, (py0 + py1) / 2, 0.0, 1.0])
            towards = camera[:3, 3] - centre[:3]
            towards /= np.linalg.norm(towards)
            self.data.mocap_pos[occluder] = centre[:3] + 0.08 * towards
            self.data.mocap_quat[occluder] = _quat(camera[:3, :3])
        else:
            self.data.mocap_pos[occluder] = [0.0, 0.0, -50.0]
        self.model.cam_pos[0] = camera[:3, 3]
        self.model.cam_quat[0] = _quat(camera[:3, :3] @ np.diag([1.0, -1.0, -1.0]))
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)
        self.renderer.update_scene(self.data, camera=0)
        rgb = self.renderer.render()
        grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0
        scene = cv2.remap(grey, self.map_x, self.map_y, cv2.INTER_LINEAR, borderValue=0.0)
        if self.board_pixels == "mujoco":
            return scene, t_board_camera
        self.masker.update_scene(self.data, camera=0)
        seg = self.masker.render()[..., 0]
        mask = (seg == self._board_geom).astype(np.uint8)
        half_x, half_y = 0.5 * (self.map_x + 0.5) - 0.5, 0.5 * (self.map_y + 0.5) - 0.5
        mask = cv2.remap(mask, half_x, half_y, cv2.INTER_NEAREST, borderValue=0)
        board = render_levels(
            truth.board,
            truth.camera,
            t_board_camera,
            supersample=self.supersample,
            background=BACKGROUND_LEVEL,
        )
        return np.where(mask > 0, board, scene).astype(np.float32), t_board_camera

    def close(self) -> None:
        self.renderer.close()
        self.masker.close()


@dataclass
class VirtualCell:
    """A simulated robot, camera and board sharing one clock (see the module docstring).

    Build it with :func:`make_cell`; take the devices with :attr:`robot` and :attr:`camera`.
    """

    truth: Truth
    clock: SimClock
    joint_noise: float = 0.001 * DEG  # rad (m for prismatic joints), per reading
    dynamics: ArmDynamics = field(default_factory=ArmDynamics)
    fps: float = 15.0
    latency: float = 0.03  # s from exposure to delivery
    faults: Faults = field(default_factory=Faults)
    targets: np.ndarray | None = None  # (K, n) plan rows, for the faults that name rows
    blur_sigma: float = 0.6  # px
    noise_sigma: float = 1.5  # grey levels
    lighting_gradient: float = 0.2
    board_pixels: str = "analytic"
    seed: int = 0
    flange_model: str = "true"  # the controller's kinematics: "true" or "nominal"
    frames: list[dict] = field(default_factory=list)  # truth of every delivered frame
    moves: list[dict] = field(default_factory=list)  # truth of every move: still when it returned?
    render_seconds: float = 0.0  # wall time spent rendering

    def __post_init__(self) -> None:
        model = self.truth.model
        dyn = SLOW if self.faults.slow_settle else self.dynamics
        self.dynamics = dyn
        home = np.clip(np.zeros(model.n_joints), model.lower, model.upper)
        self.arm = _Arm(home, dyn)
        self.rng = np.random.default_rng(self.seed + 1)
        self._visits: dict[int, int] = {}
        self._occlusion: list[tuple[float, bool]] = [(-np.inf, False)]  # (from t, hidden)
        self._renderer: SceneRenderer | None = None
        if self.flange_model not in ("true", "nominal"):
            raise RelcalError(
                f"virtual cell: flange_model '{self.flange_model}': expected true or nominal"
            )
        self.controller_model = (
            self.truth.true_model if self.flange_model == "true" else self.truth.model
        )
        self.robot = SimRobot(self)
        self.camera = SimCamera(self)

    @property
    def renderer(self) -> SceneRenderer:
        """The MuJoCo scene, built at the first frame."""
        if self._renderer is None:
            self._renderer = SceneRenderer(self.truth, board_pixels=self.board_pixels)
        return self._renderer

    def row_of(self, target: np.ndarray) -> int | None:
        """The plan row whose target this is (for faults that name rows)."""
        if self.targets is None:
            return None
        hit = np.flatnonzero(np.all(np.abs(self.targets - target) < 1e-9, axis=1))
        return int(hit[0]) if hit.size else None

    def moved_to(self, target: np.ndarray, now: float) -> None:
        """Note a move to ``target`` starting at ``now`` (s): whether a fault hides the board
        from then on."""
        row = self.row_of(target)
        hidden = False
        if row is not None:
            self._visits[row] = self._visits.get(row, 0) + 1
            hidden = row in self.faults.hidden or (
                row in self.faults.hidden_once and self._visits[row] == 1
            )
        self._occlusion.append((now, hidden))

    def hidden_at(self, t: float) -> bool:
        """Whether the board is hidden at time ``t`` (s)."""
        return next(h for start, h in reversed(self._occlusion) if start <= t)

    def frame_at(self, sequence: int) -> Frame:
        """Render frame ``sequence`` (exposed at ``sequence / fps``) and note its truth."""
        stamp = sequence / self.fps
        return self.frame_of(self.arm.at(stamp), stamp, sequence, self.hidden_at(stamp))

    def frame_of(self, q_true: np.ndarray, stamp: float, sequence: int, hidden=False) -> Frame:
        """Render the camera at true joints ``q_true`` ``(n,)`` (rad, m) as frame ``sequence``
        exposed at ``stamp`` (s), and note its truth."""
        import time

        begin = time.perf_counter()
        levels, t_board_camera = self.renderer.render(q_true, hidden)
        from relcal.vision.render import finish_image

        image = finish_image(
            levels,
            self.blur_sigma,
            self.noise_sigma,
            self.lighting_gradient,
            seed=self.seed * 1_000_003 + sequence,
        )
        self.render_seconds += time.perf_counter() - begin
        self.frames.append(
            {
                "sequence": int(sequence),
                "stamp": float(stamp),
                "q_true": [float(v) for v in q_true],
                "hidden": hidden,
                "camera_in_board": [[float(v) for v in row] for row in t_board_camera],
            }
        )
        return Frame(image=image, stamp=float(stamp), sequence=int(sequence))

    def truth_document(self) -> dict:
        """The planted truth and the true joints of every delivered frame (plain types; lengths
        in mm, angles in deg, as ``relcal simulate --errors`` files take them)."""
        t = self.truth
        factors, units = t.layout.display()
        xyz, rpy = tf.to_xyz_rpy(t.handeye)
        gxyz, grpy = tf.to_xyz_rpy(t.handeye_guess)
        return {
            "robot": t.model.name,
            "seed": self.seed,
            "length_unit": "mm",
            "angle_unit": "deg",
            "errors": {
                n: float(v * f) for n, v, f in zip(t.layout.names, t.errors, factors, strict=True)
            },
            "error_units": dict(zip(t.layout.names, units, strict=True)),
            "handeye": {
                "xyz_mm": [float(v / MM) for v in xyz],
                "rpy_deg": [float(np.degrees(v)) for v in rpy],
            },
            "handeye_guess": {
                "xyz_mm": [float(v / MM) for v in gxyz],
                "rpy_deg": [float(np.degrees(v)) for v in grpy],
            },
            "board_in_base": [[float(v) for v in row] for row in t.board_pose],
            "camera": t.camera.to_dict(),
            "joint_noise_deg": float(np.degrees(self.joint_noise)),
            "dynamics": {"omega_rad_s": self.dynamics.omega, "zeta": self.dynamics.zeta},
            "fps": self.fps,
            "flange_model": self.flange_model,
            "faults": {
                "hidden": list(self.faults.hidden),
                "hidden_once": list(self.faults.hidden_once),
                "stale": self.faults.stale,
                "slow_settle": self.faults.slow_settle,
                "drop": self.faults.drop,
            },
            "moves_note": "per move: plan row, when it returned (s), largest joint error then",
            "moves": self.moves,
            "frames_note": "true joints (rad, m) at the exposure of each frame delivered",
            "frames": self.frames,
        }

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


class SimRobot:
    """The virtual arm, as a driver sees it (:class:`relcal.capture.interfaces.Robot`): noisy
    joint readings and the controller's flange pose computed from them
    (:attr:`VirtualCell.controller_model`)."""

    reports_flange = True

    def __init__(self, cell: VirtualCell) -> None:
        self.cell = cell
        self.joint_names = tuple(cell.truth.model.joint_names)

    def read(self) -> JointReading:
        cell = self.cell
        now = cell.clock.now()
        q = cell.arm.at(now) + cell.rng.normal(0.0, cell.joint_noise, len(self.joint_names))
        return JointReading(q, now, flange=fk(cell.controller_model, q))

    def move(self, q: np.ndarray, timeout: float) -> None:
        cell = self.cell
        model = cell.truth.model
        q = np.asarray(q, float)
        if q.shape != (model.n_joints,) or not np.all(np.isfinite(q)):
            raise MoveFailed(f"target must be {model.n_joints} finite joint values")
        if np.any(q < model.lower - 1e-9) or np.any(q > model.upper + 1e-9):
            raise MoveFailed("target outside the controller's joint limits")
        cell.moved_to(q, cell.clock.now())
        duration = cell.arm.command(q, cell.clock.now())
        if duration > timeout:
            cell.clock.sleep(timeout)
            cell.arm.halt(cell.clock.now())
            raise MoveFailed(
                f"the move needs {duration:.1f} s, more than the {timeout:g} s timeout"
            )
        cell.clock.sleep(duration)  # returns when the reference ends: the arm still rings
        now = cell.clock.now()
        cell.moves.append(
            {
                "row": cell.row_of(q),
                "returned": now,
                "error_deg": float(np.degrees(np.abs(cell.arm.at(now) - q).max())),
            }
        )

    def stop(self) -> None:
        self.cell.arm.halt(self.cell.clock.now())

    def close(self) -> None:
        pass


class SimCamera:
    """The virtual flange camera (:class:`relcal.capture.interfaces.Camera`)."""

    def __init__(self, cell: VirtualCell) -> None:
        self.cell = cell
        self.last = -1  # sequence of the newest frame the device has produced and handed on
        self.buffer: list[int] = []  # frames held by a stale buffer, oldest first

    def _dropped(self, sequence: int) -> bool:
        drop = self.cell.faults.drop
        if drop <= 0:
            return False
        rng = np.random.default_rng([self.cell.seed, 7, sequence])
        return bool(rng.random() < drop)

    def grab(self, timeout: float) -> Frame:
        cell = self.cell
        fps, latency = cell.fps, cell.latency
        deadline = cell.clock.now() + timeout
        depth = cell.faults.stale
        while True:
            now = cell.clock.now()
            newest = int(np.floor((now - latency) * fps + 1e-9))  # delivered by now
            new = [k for k in range(self.last + 1, newest + 1) if not self._dropped(k)]
            self.last = max(self.last, newest)
            if depth > 0:  # a full buffer keeps its oldest frames; newer ones are lost
                self.buffer += new[: max(depth - len(self.buffer), 0)]
                if self.buffer:
                    return cell.frame_at(self.buffer.pop(0))
            elif new:  # the newest frame overwrote the older ones
                return cell.frame_at(new[-1])
            if now >= deadline:
                raise CaptureError(f"virtual camera: no frame within {timeout:g} s")
            next_delivery = (newest + 1) / fps + latency
            cell.clock.sleep(min(max(next_delivery - now, 1e-4), deadline - now + 1e-4))

    def intrinsics(self) -> Intrinsics | None:
        return self.cell.truth.camera

    def close(self) -> None:
        self.cell.close()


def plant_errors(layout: Layout, rng: np.random.Generator, scale: float = 1.0) -> np.ndarray:
    """Random planted errors on ``layout`` (as :func:`relcal.sim.scenario.random_errors`)."""
    from relcal.sim.scenario import random_errors

    return scale * random_errors(layout, rng)


def make_cell(
    model: RobotModel,
    board: Board | None = None,
    *,
    seed: int = 0,
    board_center: np.ndarray | None = None,
    handeye: np.ndarray | None = None,
    camera: Intrinsics = SIM_CAMERA,
    nongeometric: tuple[str, ...] = (),
    errors: np.ndarray | None = None,
    faults: Faults = Faults(),  # noqa: B008 (frozen)
    targets: np.ndarray | None = None,
    clock: SimClock | None = None,
    **options: Any,
) -> VirtualCell:
    """A virtual cell for ``model`` with planted errors drawn from ``seed``.

    Parameters
    ----------
    model : RobotModel
        The nominal robot (the dataset names it).
    board : Board or None
        Default: ``relcal plan``'s default, a 7 x 10 chessboard of 20 mm squares.
    seed : int
        Draws the errors, the true hand-eye, the encoder noise and the image noise.
    board_center : ndarray (3,) or None
        Pattern centre in the base frame (m), board flat and face up; default ``relcal
        plan``'s (0.45, 0, 0).
    handeye : ndarray (4, 4) or None
        The mount drawing (flange-from-camera); default ``relcal plan``'s (0, 0.04, 0.06) m.
        The true one is about 1 mm / 0.5 deg off it.
    camera : Camera
        True intrinsics and distortion (:data:`SIM_CAMERA`).
    nongeometric : tuple of str
        Non-geometric terms to plant too (``scale``, ``compliance``, ``harmonic``).
    errors : ndarray or None
        Planted errors on the layout of ``auto_hayati(model)`` with ``nongeometric`` (m, rad, 1,
        rad/(N m)); random when None.
    faults : Faults
    targets : ndarray (K, n) or None
        The plan's joint targets (rad, m), for faults that name plan rows.
    clock : SimClock or None
    **options
        Further :class:`VirtualCell` fields (``joint_noise``, ``fps``, ``dynamics``, ...).
    """
    from relcal.design.cell import Cell
    from relcal.sim.scenario import HANDEYE_ERROR

    rng = np.random.default_rng(seed)
    base = Cell()
    board = board or base.board
    centre = base.center if board_center is None else np.asarray(board_center, float)
    guess = base.handeye if handeye is None else np.asarray(handeye, float)
    nominal = auto_hayati(model)
    if nongeometric:
        nominal = with_nongeometric(nominal, tuple(nongeometric))
    layout = make_layout(nominal)
    if errors is None:
        errors = plant_errors(layout, rng)
    errors = np.asarray(errors, float)
    if errors.shape != (layout.size,):
        raise RelcalError(
            f"virtual cell: {errors.size} planted errors for the {layout.size} parameters of "
            f"{model.name}"
        )
    pos, ori = HANDEYE_ERROR
    true_handeye = guess @ tf.from_vector(np.r_[rng.normal(0, pos, 3), rng.normal(0, ori, 3)])
    from relcal.design.cell import board_frame

    truth = Truth(
        model=nominal,
        layout=layout,
        errors=errors,
        handeye=true_handeye,
        handeye_guess=guess,
        board=board,
        board_pose=board_frame(board, centre),
        camera=camera,
    )
    return VirtualCell(
        truth=truth,
        clock=clock or SimClock(),
        faults=faults,
        targets=None if targets is None else np.asarray(targets, float),
        seed=seed,
        **options,
    )


__all__ = [
    "SIM_CAMERA",
    "ArmDynamics",
    "Faults",
    "FollowingCamera",
    "SceneRenderer",
    "SimCamera",
    "SimClock",
    "SimRobot",
    "Truth",
    "VirtualCamera",
    "VirtualCell",
    "VirtualRobot",
    "make_cell",
]


# ------------------------------------------------------------------ the drivers of the registry


def _cell_options(
    board_center: str | None, handeye: str | None, flag: str
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The board centre ``(3,)`` (m) and the hand-eye guess ``(4, 4)`` of the driver options
    ``board_center`` (``x,y,z``) and ``handeye`` (``x,y,z[,roll,pitch,yaw]``, m and deg), each
    None when not given; ``flag`` names the option in errors."""
    centre = None if board_center is None else _floats(board_center, (3,), f"{flag} board_center")
    if handeye is None:
        return centre, None
    he = np.r_[_floats(handeye, (3, 6), f"{flag} handeye"), 0.0, 0.0, 0.0][:6]
    return centre, tf.from_xyz_rpy(he[:3], np.radians(he[3:]))


def _floats(text: str, counts: tuple[int, ...], what: str) -> np.ndarray:
    try:
        values = np.array([float(v) for v in text.split(",")])
    except ValueError:
        values = np.array([])
    if len(values) not in counts or not np.all(np.isfinite(values)):
        raise RelcalError(f"{what} '{text}': expected {' or '.join(map(str, counts))} numbers")
    return values


class VirtualRobot(SimRobot):
    """``--robot-driver sim``: the arm of a virtual cell built for the robot model, the board and
    the plan of the run (see the module docstring); use it with ``--camera sim``. The loop runs on
    the cell's simulated clock (:attr:`clock`).

    Options (``--robot-option KEY=VALUE``): ``seed`` (planted errors, true hand-eye, noise;
    default 0); ``truth`` (a JSON file written when the robot is closed: planted errors, true
    hand-eye, the true joints of every frame; the loop never reads it); ``faults``
    (``hide:p003+p010;hide_once:p005;stale:4;slow;drop:0.3``, see :meth:`Faults.parse`);
    ``board_center`` (X,Y,Z m, default 0.45,0,0 as ``relcal plan``); ``handeye`` (the mount
    drawing X,Y,Z[,ROLL,PITCH,YAW] in m and deg, default 0,0.04,0.06 as ``relcal plan``);
    ``nongeometric`` (terms to plant too: scale,compliance,harmonic); ``errors`` (planted errors
    from a YAML file in ``relcal simulate --errors`` format instead of random ones);
    ``joint_noise`` (deg per reading, default 0.001); ``board_pixels`` (analytic or mujoco);
    ``flange_model`` (the kinematics the controller computes its flange pose with: ``true``, the
    arm's own, as a factory-calibrated controller, default; or ``nominal``).
    """

    simulated = True

    def __init__(
        self,
        joint_names=(),
        clock=None,
        model=None,
        board=None,
        plan_ids=(),
        plan_targets=None,
        seed: int = 0,
        truth: str | None = None,
        faults: str = "",
        board_center: str | None = None,
        handeye: str | None = None,
        nongeometric: str = "",
        errors: str | None = None,
        joint_noise: float = 0.001,
        board_pixels: str = "analytic",
        flange_model: str = "true",
    ) -> None:
        if model is None:
            raise RelcalError("--robot-driver sim: the virtual cell needs the robot model")
        flag = "--robot-option"
        centre, guess = _cell_options(board_center, handeye, flag)
        terms = tuple(t for t in nongeometric.replace(" ", "").split(",") if t)
        if joint_noise < 0:
            raise RelcalError(f"{flag} joint_noise: expected a standard deviation >= 0 deg")
        if board_pixels not in ("analytic", "mujoco"):
            raise RelcalError(f"{flag} board_pixels: expected analytic or mujoco")
        if flange_model not in ("true", "nominal"):
            raise RelcalError(f"{flag} flange_model: expected true or nominal")
        planted = None
        if errors is not None:
            from relcal.sim.scenario import load_errors

            nominal = auto_hayati(model)
            if terms:
                nominal = with_nongeometric(nominal, terms)
            planted = load_errors(errors, make_layout(nominal))
        if truth:
            from relcal.outputset import File, check_file

            check_file(File(truth, b"", f"{flag} truth"))
        cell = make_cell(
            model,
            board,
            seed=int(seed),
            board_center=centre,
            handeye=guess,
            nongeometric=terms,
            errors=planted,
            faults=Faults.parse(faults, list(plan_ids)),
            targets=plan_targets,
            joint_noise=float(joint_noise) * DEG,
            board_pixels=board_pixels,
            flange_model=flange_model,
        )
        super().__init__(cell)
        self.clock = cell.clock
        self.truth_path = truth

    def close(self) -> None:
        """Write the truth file (``truth`` option), once."""
        if self.truth_path:
            from relcal.io import json_text, write_text

            write_text(self.truth_path, json_text(self.cell.truth_document()), "truth")
            self.truth_path = None


class VirtualCamera(SimCamera):
    """``--camera sim``: the virtual flange camera.

    With ``--robot-driver sim`` it is the camera of the virtual cell that driver built (on its
    simulated clock; no options). With any other driver (a real arm, or a simulator such as
    franky-sim) it *follows the driver*: each :meth:`grab` reads the joints the driver reports
    and renders the board the camera on that arm's flange would see, the arm taken as the robot
    model with planted errors (as the virtual cell plants them), stamped with the reading's own
    stamp on the loop's clock. A capture of a real or simulated controller's motion (its
    settling, its timing) with images whose truth is known: ``relcal calibrate`` should recover
    the planted errors. Its options then (``--camera-option``): ``seed``, ``truth``,
    ``board_center``, ``handeye``, ``errors`` as the ``sim`` robot's.
    """

    simulated = True

    def __init__(
        self,
        robot=None,
        clock=None,
        model=None,
        board=None,
        seed: int | None = None,
        truth: str | None = None,
        board_center: str | None = None,
        handeye: str | None = None,
        errors: str | None = None,
    ) -> None:
        given = [
            n
            for n, v in (
                ("seed", seed),
                ("truth", truth),
                ("board_center", board_center),
                ("handeye", handeye),
                ("errors", errors),
            )
            if v is not None
        ]
        if isinstance(robot, VirtualRobot):
            if given:
                raise RelcalError(
                    f"--camera sim: option {given[0]} belongs to --robot-option when the robot "
                    "is the virtual cell's (--robot-driver sim)"
                )
            super().__init__(robot.cell)
            self.follows = None
            return
        if robot is None or model is None:
            raise RelcalError("--camera sim: the virtual camera needs a robot driver to follow")
        self.follows = robot
        self._follower = FollowingCamera(
            robot,
            model,
            board,
            clock=clock,
            seed=0 if seed is None else int(seed),
            truth=truth,
            board_center=board_center,
            handeye=handeye,
            errors=errors,
        )
        super().__init__(self._follower.cell)

    def grab(self, timeout: float) -> Frame:
        if self.follows is None:
            return super().grab(timeout)
        return self._follower.grab(timeout)

    def close(self) -> None:
        if self.follows is None:
            super().close()
        else:
            self._follower.close()


class FollowingCamera:
    """A virtual flange camera on a robot driven by another driver (see :class:`VirtualCamera`).

    Parameters
    ----------
    robot : Robot
        The driver whose reported joints place the camera.
    model : RobotModel
        The nominal robot model; the truth is it with errors planted from ``seed`` (or
        ``errors``, a ``relcal simulate --errors`` YAML).
    board : Board or None
    clock : Clock or None
        The loop's clock (frames are stamped with the reading's stamp, already on it).
    seed, truth, board_center, handeye, errors
        As the options of :class:`VirtualRobot`; ``truth`` is written on :meth:`close`.
    """

    def __init__(
        self,
        robot,
        model: RobotModel,
        board: Board | None = None,
        *,
        clock=None,
        seed: int = 0,
        truth: str | None = None,
        board_center: str | None = None,
        handeye: str | None = None,
        errors: str | None = None,
    ) -> None:
        flag = "--camera-option"
        centre, guess = _cell_options(board_center, handeye, flag)
        planted = None
        if errors is not None:
            from relcal.sim.scenario import load_errors

            planted = load_errors(errors, make_layout(auto_hayati(model)))
        if truth:
            from relcal.outputset import File, check_file

            check_file(File(truth, b"", f"{flag} truth"))
        self.robot = robot
        self.cell = make_cell(
            model, board, seed=int(seed), board_center=centre, handeye=guess, errors=planted
        )
        self.truth_path = truth
        self.sequence = 0

    def grab(self, timeout: float) -> Frame:
        """A frame of the board seen from the joints the robot reports now, stamped with that
        reading's stamp (loop clock)."""
        reading = self.robot.read()
        q = np.asarray(reading.q, float)
        if q.shape != (self.cell.truth.model.n_joints,) or not np.all(np.isfinite(q)):
            raise CaptureError(f"--camera sim: the robot reported joints {q}")
        frame = self.cell.frame_of(q, float(reading.stamp), self.sequence)
        self.sequence += 1
        return frame

    def intrinsics(self) -> Intrinsics | None:
        return self.cell.truth.camera

    def close(self) -> None:
        """Write the truth file (``truth`` option), once, and free the renderer."""
        try:
            if self.truth_path:
                from relcal.io import json_text, write_text

                write_text(self.truth_path, json_text(self.truth_document()), "truth")
                self.truth_path = None
        finally:
            self.cell.close()

    def truth_document(self) -> dict:
        """The planted truth and the joints of every frame (as
        :meth:`VirtualCell.truth_document`, without the virtual arm's dynamics, moves and
        faults, which a followed driver does not have)."""
        doc = self.cell.truth_document()
        for key in (
            "dynamics",
            "fps",
            "faults",
            "moves_note",
            "moves",
            "joint_noise_deg",
            "flange_model",
        ):
            doc.pop(key, None)
        doc["followed_driver"] = type(self.robot).__name__
        doc["frames_note"] = "joints (rad, m) the driver reported for each frame, taken as true"
        return doc
