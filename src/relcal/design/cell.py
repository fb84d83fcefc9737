"""The cell: where the board is, the camera and how it is mounted on the flange, and the camera
paths over the board that the simulation and the identifiability report use."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from relcal import geometry as tf
from relcal.geometry import look_at
from relcal.robot.model import RobotModel
from relcal.vision.boards import Board, pattern_extent
from relcal.vision.camera import Camera


def default_camera() -> Camera:
    """2448 x 2048 px, 3.45 um pixels, 8 mm lens, no distortion."""
    f = 8e-3 / 3.45e-6
    return Camera(fx=f, fy=f, cx=1223.5, cy=1023.5, width=2448, height=2048)


def board_frame(board: Board, center: np.ndarray) -> np.ndarray:
    """Board frame in the base frame ``(4, 4)``: pattern centred on ``center`` (m), lying flat
    with its z axis down (printed face up), x along base x."""
    x0, y0, x1, y1 = pattern_extent(board)
    middle = np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
    rot = np.diag([1.0, -1.0, -1.0])
    return tf.homogeneous(rot, np.asarray(center, dtype=float) - rot @ middle)


@dataclass(frozen=True)
class Cell:
    """The board, where it is, the camera and how it is mounted on the flange."""

    board: Board
    board_pose: np.ndarray  # (4, 4) board frame in the base frame
    camera: Camera
    handeye: np.ndarray  # (4, 4) flange-from-camera guess X

    @property
    def corners(self) -> np.ndarray:
        """The pattern's outer corners ``(4, 3)`` in the board frame (m)."""
        x0, y0, x1, y1 = pattern_extent(self.board)
        return np.array([[x0, y0, 0.0], [x1, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0]])

    @property
    def center(self) -> np.ndarray:
        """Pattern centre in the base frame (m)."""
        return (self.board_pose @ np.r_[self.corners.mean(axis=0), 1.0])[:3]

    @property
    def normal(self) -> np.ndarray:
        """Unit normal of the printed face, towards the camera (base frame)."""
        return -self.board_pose[:3, 2]


def default_cell(
    board: Board | None = None,
    center: tuple[float, float, float] = (0.45, 0.0, 0.0),
    camera: Camera | None = None,
    handeye: np.ndarray | None = None,
) -> Cell:
    """The simulation's cell: board on the table at ``center``, camera 40 mm beside and 60 mm in
    front of the flange (as :class:`relcal.sim.simulate.Setup`)."""
    board = board or Board(type="chessboard", rows=7, columns=10, spacing=0.02)
    handeye = (
        handeye if handeye is not None else tf.from_vector(np.array([0, 0.04, 0.06, 0, 0, 0.0]))
    )
    return Cell(board, board_frame(board, np.array(center)), camera or default_camera(), handeye)


@dataclass(frozen=True)
class Setup:
    """Where the board is and how the camera sits on the flange."""

    board_center: np.ndarray = field(default_factory=lambda: np.array([0.45, 0.0, 0.0]))
    handeye: np.ndarray = field(
        default_factory=lambda: tf.from_vector(np.array([0.0, 0.04, 0.06, 0.0, 0.0, 0.0]))
    )
    distance: tuple[float, float] = (0.25, 0.40)  # m, camera to board centre
    max_tilt_deg: float = 35.0  # viewing angle from the board normal


def camera_pose(setup: Setup, k: int, n_poses: int, rng: np.random.Generator) -> np.ndarray:
    """The k-th of ``n_poses`` camera poses ``(4, 4)`` in the base frame: a golden-angle spiral
    over a spherical cap above the board, with random distance, aim point and roll."""
    tilt = np.radians(setup.max_tilt_deg) * np.sqrt((k + 0.5) / n_poses)
    azimuth = k * np.pi * (3 - np.sqrt(5))
    direction = np.array(
        [np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), np.cos(tilt)]
    )
    eye = setup.board_center + rng.uniform(*setup.distance) * direction
    aim = setup.board_center + np.append(rng.uniform(-0.03, 0.03, 2), 0.0)
    return look_at(eye, aim, rng.uniform(-1.0, 1.0))


def joint_path(
    model: RobotModel, setup: Setup, n_poses: int, rng: np.random.Generator, tries: int = 10
) -> np.ndarray:
    """Joint configurations ``(K, n)`` reaching the spiral of camera poses with the nominal model,
    each the IK solution nearest the previous one. An unreachable pose is drawn again (new
    distance, aim and roll) up to ``tries`` times, then skipped."""
    from relcal.robot.ik import solve

    out: list[np.ndarray] = []
    for k in range(n_poses):
        for _ in range(tries):
            flange = camera_pose(setup, k, n_poses, rng) @ tf.invert(setup.handeye)
            sol = solve(model, flange, q_near=out[-1] if out else None)
            if sol.converged:
                out.append(sol.q)
                break
    return np.array(out)


def place_board(model: RobotModel, probes: int = 8) -> Setup:
    """A board placement in front of ``model`` where the camera path is reachable: the default
    if most of ``probes`` spiral poses are, else the best of a few placements scaled to the
    robot's size (distance along x and height relative to the base)."""

    def reachable(setup: Setup) -> int:
        return len(joint_path(model, setup, probes, np.random.default_rng(0), tries=1))

    default = Setup()
    if reachable(default) >= 0.75 * probes:
        return default
    reach = float(np.abs(model.a).sum() + np.abs(model.d).sum())
    candidates = [
        Setup(board_center=np.array([f * reach, 0.0, g * reach]))
        for f in (0.35, 0.5, 0.65)
        for g in (-0.4, -0.2, 0.0, 0.2)
    ]
    return max([default, *candidates], key=reachable)
