"""Line of sight: does the robot's own body hide part of the board from the flange camera?

A pose with the whole pattern inside the image (``board in view`` of
:mod:`relcal.design.feasibility`) may still show a link in front of it: the forearm between the
camera and the board when the wrist is folded back, the upper arm when the camera looks back
past the elbow. The loop then skips the pose ("board not found" or too few points) on every
attempt, after moving there. The check here tests *sight lines*: segments from the camera's
optical centre to a grid of points over the pattern (``grid`` x ``grid``, its corners included),
shortened by ``near`` at the camera (the camera's own housing and mount, which never hide its
view) and by ``far`` at the board (the links' clearance above it is its own constraint). A pose
is blocked when any sight line passes through the robot:

- with capsules about the kinematic skeleton (:func:`relcal.design.collision.skeleton`, radius
  ``link_radius``) when the model has no collision geometry (DH models, URDFs without
  ``<collision>``): exact segment-to-segment distances, vectorised over poses;
- with the URDF's own collision geometry through python-fcl where the chain has some
  (:class:`relcal.design.urdf_collision.UrdfCollision`): each sight line a capsule of radius
  ``ray_radius`` checked against every body of the file (those off the chain, such as a mobile
  manipulator's torso and head, at their joints' zero), except those rigidly attached to the flange
  (a gripper, the camera's mount: they move with the camera, so no pose changes what they hide;
  :func:`camera_bodies`).

A grid of 5 x 5 lines misses an obstacle thinner than the gap between neighbouring lines where
they pass it (about a quarter of the pattern's size at the board, less near the camera); links
are thicker than that near the camera, where they hide most.
"""

from __future__ import annotations

import numpy as np

from relcal import geometry as tf
from relcal.design.collision import segment_distance, skeleton
from relcal.robot.model import RobotModel


def sight_lines(
    cameras: np.ndarray,
    board_pose: np.ndarray,
    corners: np.ndarray,
    grid: int = 5,
    near: float = 0.03,
    far: float = 0.01,
) -> np.ndarray:
    """Segments ``(N, grid * grid, 2, 3)`` (m, base frame) from each camera centre towards a
    ``grid`` x ``grid`` lattice of points over the pattern, shortened by ``near`` at the camera
    and ``far`` at the board.

    Parameters
    ----------
    cameras : ndarray, shape (N, 4, 4)
        Camera poses in the base frame.
    board_pose : ndarray, shape (4, 4) or (N, 4, 4)
        Board frame in the base frame (one per camera pose: a board on the flange).
    corners : ndarray, shape (4, 3)
        The pattern's corners in the board frame (m), in order around it.
    grid : int
        Points per side of the lattice (>= 2).
    near, far : float
        m cut off each sight line at the camera and at the board.
    """
    if grid < 2:
        raise ValueError("sight_lines: grid must be at least 2")
    s = np.linspace(0.0, 1.0, grid)
    u, v = np.meshgrid(s, s, indexing="ij")
    u, v = u.ravel()[:, None], v.ravel()[:, None]
    c = np.asarray(corners, float)
    local = (1 - u) * (1 - v) * c[0] + u * (1 - v) * c[1] + u * v * c[2] + (1 - u) * v * c[3]
    board_pose = np.asarray(board_pose, float)
    if board_pose.ndim == 3:  # (N, R, 3)
        targets = local @ np.swapaxes(board_pose[:, :3, :3], 1, 2) + board_pose[:, None, :3, 3]
    else:
        targets = (local @ board_pose[:3, :3].T + board_pose[:3, 3])[None]  # (1, R, 3)
    eyes = np.asarray(cameras, float)[:, None, :3, 3]  # (N, 1, 3)
    direction = targets - eyes  # (N, R, 3)
    length = np.linalg.norm(direction, axis=-1, keepdims=True)
    unit = direction / np.maximum(length, 1e-12)
    start = eyes + near * unit
    end = eyes + np.maximum(length - far, near) * unit
    return np.stack([start, end], axis=2)


def skeleton_sight_free(
    model: RobotModel,
    q: np.ndarray,
    handeye: np.ndarray,
    lines: np.ndarray,
    link_radius: float,
) -> np.ndarray:
    """Mask ``(N,)``: no sight line of ``lines`` ``(N, R, 2, 3)`` passes within ``link_radius``
    (m) of the kinematic skeleton of configurations ``q`` ``(N, n)`` (the camera's own sphere
    left out)."""
    seg, links = skeleton(model, q, handeye)
    body = seg[:, np.array(links) != model.n_joints + 1]  # (N, S, 2, 3)
    lines = np.asarray(lines, float)
    dist = segment_distance(
        lines[:, :, None, 0], lines[:, :, None, 1], body[:, None, :, 0], body[:, None, :, 1]
    )  # (N, R, S)
    return (dist >= link_radius).all(axis=(1, 2))


def urdf_sight_free(geometry, q: np.ndarray, lines: np.ndarray, ray_radius: float = 1e-3):
    """Mask ``(N,)``: no sight line of ``lines`` ``(N, R, 2, 3)``, as a capsule of
    ``ray_radius`` (m), touches a collision body of ``geometry`` (except :func:`camera_bodies`)
    (:class:`~relcal.design.urdf_collision.UrdfCollision`) at configurations ``q`` ``(N, n)``."""
    fcl = geometry.fcl
    q = np.atleast_2d(q)
    lines = np.asarray(lines, float)
    ok = np.ones(len(q), dtype=bool)
    if not len(q):
        return ok
    poses = geometry.poses(q)  # (N, B, 4, 4)
    rigid = camera_bodies(geometry)
    checked = [k for k in range(len(geometry.bodies)) if k not in rigid]  # static ones too
    radius = np.array([geometry.bodies[k].radius for k in checked])
    objects = [fcl.CollisionObject(geometry.bodies[k].geometry, fcl.Transform()) for k in checked]
    request = fcl.CollisionRequest()
    for n in range(len(q)):
        a, b = lines[n, :, 0], lines[n, :, 1]
        centres = poses[n, checked, :3, 3]  # (M, 3)
        # bounding spheres first: the distance from each body's centre to each line
        gap = segment_distance(a[:, None], b[:, None], centres[None], centres[None])  # (R, M)
        near = gap <= radius[None] + ray_radius
        if not near.any():
            continue
        for m in np.flatnonzero(near.any(axis=0)):
            k = checked[m]
            objects[m].setTransform(fcl.Transform(poses[n, k, :3, :3], poses[n, k, :3, 3]))
        for r, m in zip(*np.nonzero(near), strict=True):
            axis = b[r] - a[r]
            length = float(np.linalg.norm(axis))
            rot = _z_to(axis / max(length, 1e-12))
            ray = fcl.CollisionObject(
                fcl.Capsule(ray_radius, length), fcl.Transform(rot, 0.5 * (a[r] + b[r]))
            )
            if fcl.collide(ray, objects[m], request, fcl.CollisionResult()) > 0:
                ok[n] = False
                break
    return ok


def camera_bodies(geometry, probes: int = 3, seed: int = 0) -> set[int]:
    """Indices of the bodies of ``geometry`` rigidly attached to the flange (the tip link and
    links fixed to it: a gripper, the camera's mount): they move with the camera, so no pose
    changes what they hide, and they are left out of the line of sight. Found as the bodies whose
    pose relative to the flange is the same in ``probes`` random configurations."""
    from relcal.robot.kinematics import fk

    model = geometry.model
    rng = np.random.default_rng(seed)
    lo = np.where(np.isfinite(model.lower), model.lower, -np.pi)
    hi = np.where(np.isfinite(model.upper), model.upper, np.pi)
    q = rng.uniform(lo, hi, (probes, model.n_joints))
    flange = fk(model, q)  # (P, 4, 4)
    relative = tf.invert(flange)[:, None] @ geometry.poses(q)  # (P, B, 4, 4)
    same = np.abs(relative - relative[:1]).max(axis=(0, 2, 3)) < 1e-9
    return {int(k) for k in np.flatnonzero(same)}


def _z_to(axis: np.ndarray) -> np.ndarray:
    """A rotation ``(3, 3)`` taking the z axis to the unit vector ``axis``."""
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(z, axis)
    s, c = np.linalg.norm(v), float(z @ axis)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    return tf.exp_rotation(v / s * np.arctan2(s, c))


def in_image(camera, pix: np.ndarray, depth: np.ndarray, margin: float) -> np.ndarray:
    """Mask ``(N,)``: every point of each row of ``pix`` ``(N, K, 2)`` (px) lies in front of the
    camera (``depth`` ``(N, K)`` > 0) and at least ``margin`` px inside its image."""
    return (
        (depth > 0).all(axis=1)
        & (pix[..., 0] >= margin).all(axis=1)
        & (pix[..., 0] <= camera.width - 1 - margin).all(axis=1)
        & (pix[..., 1] >= margin).all(axis=1)
        & (pix[..., 1] <= camera.height - 1 - margin).all(axis=1)
    )
