"""Candidates and constraints for a fixed camera and the board on the flange (eye-to-hand,
:class:`~relcal.design.cell.FixedCameraCell`).

The mirror of the eye-in-hand candidates of :mod:`relcal.design.feasibility`: there the camera
is drawn over a cap above the fixed board; here the board is drawn in front of the fixed camera
(:func:`sample_board_poses`): its centre on a ray through the image at a distance in range, its
printed face tilted from the line of sight by up to the viewing angle (uniform over the cap's
area, any azimuth), any roll about its normal; the flange that carries it there follows from the
flange-from-board ``X``, and inverse kinematics from random starts reaches it.

The constraints (:func:`check`, the names of :data:`~relcal.design.feasibility.CONSTRAINTS`) are
those of a camera on the flange with each sample's board pose ``F_k X`` and the one camera:
the whole pattern in the image with the margin, the distance from the camera to the pattern's
centre, the viewing angle (between the board's normal and its line of sight to the camera),
joint limits and singularities as they are. ``clearance`` is kept from the fixed camera instead
of from a board's plane: every link capsule (radius ``link_radius`` about the kinematic
skeleton) and the board's sphere stay that far beyond the camera's sphere (``camera_radius``).
Self-collision and the cell's boxes use the same capsules (or the URDF's collision geometry),
with a sphere of ``camera_radius`` about the pattern's centre for the board (its plate's full
extent is not checked); the line of sight runs from the camera's centre to a grid over the
pattern, past the links (the board itself and the bodies rigidly on the flange, its mount, left
out).
"""

from __future__ import annotations

import numpy as np

from relcal import geometry as tf
from relcal.design.cell import FixedCameraCell, pattern_middle
from relcal.design.collision import cell_collision, segment_distance, self_collision, skeleton
from relcal.design.sight import in_image, sight_lines, skeleton_sight_free, urdf_sight_free
from relcal.design.urdf_collision import urdf_geometry
from relcal.robot.ik import inverse_condition
from relcal.robot.kinematics import fk
from relcal.robot.model import RobotModel


def board_poses(model: RobotModel, cell: FixedCameraCell, q: np.ndarray) -> np.ndarray:
    """Board frames ``(N, 4, 4)`` in the base frame, ``F(q) X``, with the nominal model."""
    return fk(model, q) @ cell.handeye


def _frame_with_z(z: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """Rotations ``(N, 3, 3)`` whose z axis is the unit ``z`` ``(N, 3)``, turned by ``roll``
    ``(N,)`` (rad) about it."""
    helper = np.where(np.abs(z[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(z, x)
    c, s = np.cos(roll)[:, None], np.sin(roll)[:, None]
    return np.stack([c * x + s * y, -s * x + c * y, z], axis=2)


def sample_board_poses(
    cell: FixedCameraCell, constraints, count: int, rng: np.random.Generator
) -> np.ndarray:
    """Board frames ``(count, 4, 4)`` in the base frame in front of the fixed camera.

    The pattern's centre at a distance uniform in ``constraints.distance`` (m) on the ray
    through a pixel uniform over the image less the margin and the pattern's half-size at that
    distance; its normal (towards the camera) tilted from the line of sight uniformly over the
    cap's area up to ``constraints.max_view_angle_deg``, any azimuth; any roll about it."""
    cam = cell.camera
    dist = rng.uniform(*constraints.distance, count)
    half = 0.5 * np.ptp(cell.corners[:, :2], axis=0).max()  # px it may take at least
    reach = cam.fx * half / dist + constraints.margin_px
    lo_u, hi_u = reach, cam.width - 1 - reach
    lo_v, hi_v = reach, cam.height - 1 - reach
    u = np.where(lo_u < hi_u, lo_u + rng.uniform(0, 1, count) * (hi_u - lo_u), cam.cx)
    v = np.where(lo_v < hi_v, lo_v + rng.uniform(0, 1, count) * (hi_v - lo_v), cam.cy)
    ray = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones(count)], axis=1)
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    centre = dist[:, None] * ray  # camera frame
    max_tilt = np.radians(constraints.max_view_angle_deg)
    cos_t = rng.uniform(np.cos(max_tilt), 1.0, count)
    sin_t = np.sqrt(1 - cos_t**2)
    az = rng.uniform(0, 2 * np.pi, count)
    sight = _frame_with_z(-ray, np.zeros(count))  # z from the board towards the camera
    local = np.stack([sin_t * np.cos(az), sin_t * np.sin(az), cos_t], axis=1)
    normal = np.einsum("nij,nj->ni", sight, local)  # towards the camera
    rot = _frame_with_z(-normal, rng.uniform(-np.pi, np.pi, count))  # board z: into the print
    origin = centre - rot @ pattern_middle(cell.board)
    return cell.camera_pose @ tf.homogeneous(rot, origin)


def image_points(cell: FixedCameraCell, boards: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels ``(N, 4, 2)`` of the pattern's corners on the boards ``(N, 4, 4)`` (base frame)
    and their depths ``(N, 4)`` (m)."""
    corners = np.c_[cell.corners, np.ones(4)]
    in_camera = tf.invert(cell.camera_pose) @ boards
    pts = np.einsum("nij,kj->nki", in_camera, corners)[..., :3]
    z = pts[..., 2]
    safe = np.where(z > 1e-9, z, 1e-9)
    cam = cell.camera
    u = cam.fx * pts[..., 0] / safe + cam.cx
    v = cam.fy * pts[..., 1] / safe + cam.cy
    return np.stack([u, v], axis=-1), z


def camera_clearance(
    model: RobotModel, cell: FixedCameraCell, q: np.ndarray, constraints
) -> np.ndarray:
    """Mask ``(N,)``: every link capsule and the board's sphere stay ``clearance`` beyond the
    camera's sphere (m)."""
    seg, links = skeleton(model, q, cell.board_center)
    radius = np.where(
        np.array(links) == model.n_joints + 1, constraints.camera_radius, constraints.link_radius
    )
    eye = np.broadcast_to(cell.camera_pose[:3, 3], seg[..., 0, :].shape)
    dist = segment_distance(seg[..., 0, :], seg[..., 1, :], eye, eye)  # (N, S)
    return (dist >= radius + constraints.camera_radius + constraints.clearance).all(axis=1)


def check(
    model: RobotModel, cell: FixedCameraCell, q: np.ndarray, constraints
) -> dict[str, np.ndarray]:
    """Per constraint of :data:`~relcal.design.feasibility.CONSTRAINTS`, a mask ``(N,)`` of the
    configurations ``q`` ``(N, n)`` (rad, m) that satisfy it (see the module docstring)."""
    boards = board_poses(model, cell, q)
    pix, depth = image_points(cell, boards)
    inside = in_image(cell.camera, pix, depth, constraints.margin_px)
    centres = boards[:, :3, :3] @ pattern_middle(cell.board) + boards[:, :3, 3]
    sight = cell.camera_pose[:3, 3] - centres
    distance = np.linalg.norm(sight, axis=1)
    normal = -boards[:, :3, 2]  # the printed face's normal
    cosine = np.einsum("ni,ni->n", sight, normal) / distance
    angle = np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))
    lo, hi = constraints.distance
    masks = {
        "joint limits": np.all((q >= model.lower) & (q <= model.upper), axis=1),
        "board in view": inside,
        "distance": (distance >= lo) & (distance <= hi),
        "viewing angle": angle <= constraints.max_view_angle_deg,
        "singularity": inverse_condition(model, q, constraints.length_scale)
        >= constraints.min_inverse_condition,
        "clearance": camera_clearance(model, cell, q, constraints),
    }
    rest = np.logical_and.reduce(list(masks.values()))
    masks.update(collisions(model, cell, q, constraints, rest))
    masks["line of sight"] = line_of_sight(model, cell, q, constraints, rest)
    return masks


def collisions(
    model: RobotModel, cell: FixedCameraCell, q: np.ndarray, constraints, rest: np.ndarray
) -> dict[str, np.ndarray]:
    """``self-collision`` and ``cell collision`` masks ``(N,)``: the URDF's collision geometry
    where the chain has some (checked where ``rest`` holds), else capsules about the skeleton,
    the board a sphere of ``camera_radius`` about the pattern's centre."""

    radii = (constraints.link_radius, constraints.camera_radius)
    obstacles = np.array(constraints.obstacles, dtype=float).reshape(-1, 6)
    centre = cell.board_center
    geometry = urdf_geometry(model) if max(radii) > 0 or len(obstacles) else None
    if geometry is not None:
        free, clear = np.ones(len(q), dtype=bool), np.ones(len(q), dtype=bool)
        idx = np.flatnonzero(rest)
        if max(radii) > 0:
            free[idx] = geometry.self_collision_free(q[idx])
        board = (fk(model, q[idx]) @ centre)[:, :3, 3]
        clear[idx] = geometry.cell_free(q[idx], board, obstacles, constraints.camera_radius)
        return {"self-collision": free, "cell collision": clear}
    if max(radii) > 0:
        free = self_collision(model, q, centre, *radii)
    else:
        free = np.ones(len(q), dtype=bool)
    return {
        "self-collision": free,
        "cell collision": cell_collision(model, q, centre, obstacles, *radii),
    }


def line_of_sight(
    model: RobotModel, cell: FixedCameraCell, q: np.ndarray, constraints, rest: np.ndarray
) -> np.ndarray:
    """Mask ``(N,)``: the fixed camera sees the whole pattern of each board ``F(q) X`` past the
    robot's links (checked where ``rest`` holds, elsewhere True; True with ``sight_grid`` 0)."""
    ok = np.ones(len(q), dtype=bool)
    idx = np.flatnonzero(rest)
    if constraints.sight_grid <= 0 or not len(idx):
        return ok
    cameras = np.broadcast_to(cell.camera_pose, (len(idx), 4, 4))
    boards = board_poses(model, cell, q[idx])
    lines = sight_lines(cameras, boards, cell.corners, max(constraints.sight_grid, 2))
    geometry = urdf_geometry(model)
    if geometry is not None:
        ok[idx] = urdf_sight_free(geometry, q[idx], lines)
    elif constraints.link_radius > 0:
        ok[idx] = skeleton_sight_free(
            model, q[idx], cell.board_center, lines, constraints.link_radius
        )
    return ok
