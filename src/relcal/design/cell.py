"""The cell: where the board is, the camera and how it is mounted on the flange, and the camera
paths over the board that the simulation and the identifiability report use.

Two kinds of cell: :class:`Cell`, a camera on the flange looking at a board fixed in the cell
(eye-in-hand), and :class:`FixedCameraCell`, a camera fixed in the cell looking at a board the
robot carries (eye-to-hand). Both state ``handeye``, the ``X`` of ``C_k = W F_k X`` on the
flange (the camera, or the board), and ``mode``, as datasets do.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import ClassVar

import numpy as np

from relcal import geometry as tf
from relcal.checks import check_array, check_instance, check_transform
from relcal.geometry import look_at
from relcal.robot.model import RobotModel
from relcal.vision.boards import Board, pattern_extent
from relcal.vision.camera import Camera

SPIRAL_DISTANCE = (0.25, 0.40)  # m, camera to board centre along the simulated spiral
SPIRAL_TILT_DEG = 35.0  # largest viewing angle from the board normal along the spiral


def default_camera() -> Camera:
    """2448 x 2048 px, 3.45 um pixels, 8 mm lens, no distortion."""
    f = 8e-3 / 3.45e-6
    return Camera(fx=f, fy=f, cx=1223.5, cy=1023.5, width=2448, height=2048)


def default_board() -> Board:
    """A chessboard of 7 x 10 squares of 20 mm."""
    return Board(type="chessboard", rows=7, columns=10, spacing=0.02)


def default_handeye() -> np.ndarray:
    """Flange-from-camera ``(4, 4)``: camera 40 mm beside and 60 mm in front of the flange."""
    return tf.from_vector(np.array([0.0, 0.04, 0.06, 0.0, 0.0, 0.0]))


def board_frame(board: Board, center: np.ndarray) -> np.ndarray:
    """Board frame in the base frame ``(4, 4)``: pattern centred on ``center`` (m), lying flat
    with its z axis down (printed face up), x along base x."""
    x0, y0, x1, y1 = pattern_extent(board)
    middle = np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
    rot = np.diag([1.0, -1.0, -1.0])
    return tf.homogeneous(rot, np.asarray(center, dtype=float) - rot @ middle)


@dataclass(frozen=True)
class Cell:
    """The board, where it is, the camera and how it is mounted on the flange.

    ``center`` is the pattern centre in the base frame (m); the board lies flat on the table,
    printed face up (:func:`board_frame`). ``handeye`` is the flange-from-camera ``X`` of the
    mount drawing: the guess that planning and identification start from, and the truth of a
    simulation (:mod:`relcal.sim.scenario`).

    Parameters
    ----------
    board : Board
        The calibration board (default: a chessboard of 7 x 10 squares of 20 mm).
    center : (3,) ndarray of float
        The pattern centre in the robot's base frame, m (default 0.45, 0, 0).
    camera : Camera
        The camera's intrinsics (default: 2448 x 2048 px, 3.45 um pixels, 8 mm lens, no
        distortion).
    handeye : (4, 4) ndarray of float
        Flange-from-camera transform ``X``, m (default: the camera 40 mm beside and 60 mm in
        front of the flange).
    """

    mode: ClassVar[str] = "eye_in_hand"

    board: Board = field(default_factory=default_board)
    center: np.ndarray = field(default_factory=lambda: np.array([0.45, 0.0, 0.0]))
    camera: Camera = field(default_factory=default_camera)
    handeye: np.ndarray = field(default_factory=default_handeye)

    def __post_init__(self) -> None:
        """Arguments checked where the API is entered: a wrong type or shape is an
        ArgumentError naming the field."""
        check_instance(self.board, Board, "Cell.board", "a Board (relcal.vision.boards.Board)")
        check_instance(self.camera, Camera, "Cell.camera", "a Camera (relcal.vision.camera)")
        center = check_array(
            self.center, "Cell.center", (3,), hint="the board centre x, y, z in the base frame, m"
        )
        object.__setattr__(self, "center", center)
        object.__setattr__(self, "handeye", check_transform(self.handeye, "Cell.handeye"))

    @property
    def board_pose(self) -> np.ndarray:
        """Board frame in the base frame ``(4, 4)``."""
        return board_frame(self.board, self.center)

    @property
    def corners(self) -> np.ndarray:
        """The pattern's outer corners ``(4, 3)`` in the board frame (m)."""
        return pattern_corners(self.board)

    @property
    def normal(self) -> np.ndarray:
        """Unit normal of the printed face, towards the camera (base frame)."""
        return -self.board_pose[:3, 2]


def pattern_corners(board: Board) -> np.ndarray:
    """The pattern's outer corners ``(4, 3)`` in the board frame, m."""
    x0, y0, x1, y1 = pattern_extent(board)
    return np.array([[x0, y0, 0.0], [x1, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0]])


def pattern_middle(board: Board) -> np.ndarray:
    """The pattern's centre ``(3,)`` in the board frame, m."""
    x0, y0, x1, y1 = pattern_extent(board)
    return np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])


BOARD_OFFSET = 0.08  # m: the default board's pattern centre in front of the flange


def board_on_flange(board: Board, offset: float = BOARD_OFFSET) -> np.ndarray:
    """Flange-from-board ``(4, 4)`` of a board carried by the robot: the pattern centred on the
    flange's z axis ``offset`` (m) in front of it, printed face out along the flange's z, the
    board's x along the flange's x."""
    rot = np.diag([1.0, -1.0, -1.0])  # board z (into the print) back towards the flange
    return tf.homogeneous(rot, np.array([0.0, 0.0, offset]) - rot @ pattern_middle(board))


def default_camera_pose() -> np.ndarray:
    """Base-from-camera ``(4, 4)`` of the default fixed camera: 1.1 m out along the base's x and
    0.6 m up, looking back at the point 0.4 m out and 0.3 m up (a tripod beside a table-top
    arm), image x along the base's -y."""
    return look_at(np.array([1.1, 0.0, 0.6]), np.array([0.4, 0.0, 0.3]), 0.0)


@dataclass(frozen=True)
class FixedCameraCell:
    """A fixed camera and the board the robot carries on its flange (eye-to-hand).

    The measured pose is the board in the camera frame, ``C_k = W F_k X`` with ``W`` the
    camera-from-base (the inverse of ``camera_pose``) and ``X`` = ``handeye`` the
    flange-from-board, as in a dataset with ``mode: eye_to_hand``
    (:mod:`relcal.calibration.handeye_closed`).

    Parameters
    ----------
    board : Board
        The calibration board on the flange (default: a chessboard of 7 x 10 squares of 20 mm).
    camera : Camera
        The fixed camera's intrinsics (default as :class:`Cell`'s).
    camera_pose : (4, 4) ndarray of float
        Base-from-camera: the camera's optical frame (z along the view, x along the image rows)
        in the robot's base frame, m (default :func:`default_camera_pose`).
    handeye : (4, 4) ndarray of float, optional
        Flange-from-board ``X``, m (default :func:`board_on_flange`: the pattern centred 80 mm
        in front of the flange, printed face out along its z axis).
    """

    mode: ClassVar[str] = "eye_to_hand"

    board: Board = field(default_factory=default_board)
    camera: Camera = field(default_factory=default_camera)
    camera_pose: np.ndarray = field(default_factory=default_camera_pose)
    handeye: np.ndarray | None = None

    def __post_init__(self) -> None:
        """Arguments checked where the API is entered (an ArgumentError naming the field)."""
        check_instance(
            self.board, Board, "FixedCameraCell.board", "a Board (relcal.vision.boards.Board)"
        )
        check_instance(
            self.camera, Camera, "FixedCameraCell.camera", "a Camera (relcal.vision.camera)"
        )
        pose = check_transform(self.camera_pose, "FixedCameraCell.camera_pose")
        object.__setattr__(self, "camera_pose", pose)
        x = board_on_flange(self.board) if self.handeye is None else self.handeye
        object.__setattr__(self, "handeye", check_transform(x, "FixedCameraCell.handeye"))

    @property
    def corners(self) -> np.ndarray:
        """The pattern's outer corners ``(4, 3)`` in the board frame (m)."""
        return pattern_corners(self.board)

    @property
    def board_center(self) -> np.ndarray:
        """Flange-from-pattern-centre ``(4, 4)``: ``handeye`` moved to the pattern's centre
        (where the collision checks put the board's sphere)."""
        return self.handeye @ tf.homogeneous(np.eye(3), pattern_middle(self.board))


AnyCell = Cell | FixedCameraCell


def camera_pose(cell: Cell, k: int, n_poses: int, rng: np.random.Generator) -> np.ndarray:
    """The k-th of ``n_poses`` camera poses ``(4, 4)`` in the base frame: a golden-angle spiral
    over a spherical cap above the board (up to :data:`SPIRAL_TILT_DEG` from its normal), with
    random distance (:data:`SPIRAL_DISTANCE`), aim point and roll."""
    tilt = np.radians(SPIRAL_TILT_DEG) * np.sqrt((k + 0.5) / n_poses)
    azimuth = k * np.pi * (3 - np.sqrt(5))
    direction = np.array(
        [np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), np.cos(tilt)]
    )
    eye = cell.center + rng.uniform(*SPIRAL_DISTANCE) * direction
    aim = cell.center + np.append(rng.uniform(-0.03, 0.03, 2), 0.0)
    return look_at(eye, aim, rng.uniform(-1.0, 1.0))


def joint_path(
    model: RobotModel, cell: Cell, n_poses: int, rng: np.random.Generator, tries: int = 10
) -> np.ndarray:
    """Joint configurations ``(K, n)`` reaching the spiral of camera poses with the nominal model,
    each the IK solution nearest the previous one. An unreachable pose is drawn again (new
    distance, aim and roll) up to ``tries`` times, then skipped."""
    from relcal.robot.ik import solve

    out: list[np.ndarray] = []
    for k in range(n_poses):
        for _ in range(tries):
            flange = camera_pose(cell, k, n_poses, rng) @ tf.invert(cell.handeye)
            sol = solve(model, flange, q_near=out[-1] if out else None)
            if sol.converged:
                out.append(sol.q)
                break
    return np.array(out)


def place_board(model: RobotModel, cell: Cell | None = None, probes: int = 8) -> Cell:
    """``cell`` (default :class:`Cell`) with the board where the camera path is reachable: as
    given if most of ``probes`` spiral poses are, else the best of a few placements scaled to the
    robot's size (distance along x and height relative to the base)."""
    cell = cell or Cell()

    def reachable(c: Cell) -> int:
        return len(joint_path(model, c, probes, np.random.default_rng(0), tries=1))

    if reachable(cell) >= 0.75 * probes:
        return cell
    reach = float(np.abs(model.a).sum() + np.abs(model.d).sum())
    candidates = [
        replace(cell, center=np.array([f * reach, 0.0, g * reach]))
        for f in (0.35, 0.5, 0.65)
        for g in (-0.4, -0.2, 0.0, 0.2)
    ]
    return max([cell, *candidates], key=reachable)
