"""Collisions a planned pose must avoid, with the robot approximated by capsules.

relcal's robot models are kinematic (DH, modified DH, or a URDF's joint chain): they carry no
link geometry, so each link is a capsule of radius ``link_radius`` around its kinematic skeleton,
the polyline a DH table draws: link ``i`` runs from joint frame ``i - 1`` along the joint axis by
``d_i`` and then along the common normal by ``a_i`` to frame ``i`` (modified DH: along ``x`` by
``a_{i-1}``, then along ``z`` by ``d_i``). The camera is a sphere of ``camera_radius`` about its
optical centre (its mount, between it and the flange, is not checked). Checked:

- **self-collision**: every pair of capsules of links whose skeleton between them is longer than
  their two radii (neighbours meet at their joint by construction, and so do the links on either
  side of a spherical wrist or of a short elbow offset: those pairs touch in every pose, and a
  real arm keeps them apart by its joint limits);
- **cell collision**: every capsule against the boxes of ``obstacles`` (axis-aligned in the base
  frame; the distance is taken at points along each capsule's axis spaced at most half its
  radius, so an intersection deeper than about an eighth of the radius is never missed).

The board's own plane is the ``clearance`` constraint of :mod:`relcal.design.feasibility`. What
is not checked: the links' true shapes (offsets of the real housings from the skeleton, motor
bulges), the camera's cable, and anything not given as an obstacle.
"""

from __future__ import annotations

import numpy as np

from relcal.robot.kinematics import forward_frames
from relcal.robot.model import RobotModel

MIN_LENGTH = 1e-6  # m: shorter skeleton segments are left out (they are points on a joint)


def skeleton(model: RobotModel, q: np.ndarray, handeye: np.ndarray) -> tuple[np.ndarray, list]:
    """Segments ``(N, S, 2, 3)`` of the kinematic skeleton (m, base frame) of configurations
    ``q`` ``(N, n)`` and, per segment, the link it belongs to (1..n, n + 1 for the camera).

    ``handeye`` is the flange-from-camera transform ``(4, 4)``; the flange is frame ``n`` with the
    model's tool transform. The camera's segment has zero length (a sphere)."""
    frames = forward_frames(model, np.atleast_2d(q))  # (N, n + 1, 4, 4)
    origins = frames[:, :, :3, 3]
    segments, links = [], []
    for i in range(1, model.n_joints + 1):
        if model.convention == "dh":  # O_{i-1} -> O_i - a_i x_i -> O_i
            corner = origins[:, i] - model.a[i - 1] * frames[:, i, :3, 0]
        else:  # O_{i-1} -> O_{i-1} + a_{i-1} x_{i-1} -> O_i
            corner = origins[:, i - 1] + model.a[i - 1] * frames[:, i - 1, :3, 0]
        for a, b in ((origins[:, i - 1], corner), (corner, origins[:, i])):
            segments.append(np.stack([a, b], axis=1))
            links.append(i)
    flange = frames[:, -1] @ model.tool
    camera = flange @ handeye
    segments.append(np.stack([origins[:, -1], flange[:, :3, 3]], axis=1))
    links.append(model.n_joints)
    segments.append(np.stack([camera[:, :3, 3], camera[:, :3, 3]], axis=1))  # a sphere
    links.append(model.n_joints + 1)
    seg = np.stack(segments, axis=1)  # (N, S, 2, 3)
    length = np.linalg.norm(seg[..., 1, :] - seg[..., 0, :], axis=-1).max(axis=0)
    keep = (length > MIN_LENGTH) | (np.array(links) == model.n_joints + 1)
    return seg[:, keep], [link for link, k in zip(links, keep, strict=True) if k]


def segment_distance(p0, p1, q0, q1) -> np.ndarray:
    """Distance between segments ``p0 p1`` and ``q0 q1`` (arrays ``(..., 3)``), exactly: the
    closest points clamped to both segments (Ericson, *Real-Time Collision Detection*, 5.1.9)."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a = np.einsum("...i,...i->...", d1, d1)
    e = np.einsum("...i,...i->...", d2, d2)
    f = np.einsum("...i,...i->...", d2, r)
    c = np.einsum("...i,...i->...", d1, r)
    b = np.einsum("...i,...i->...", d1, d2)
    eps = 1e-18
    denom = a * e - b * b
    s = np.where(denom > eps, np.clip((b * f - c * e) / np.where(denom > eps, denom, 1), 0, 1), 0)
    t = (b * s + f) / np.where(e > eps, e, 1)
    s = np.where(t < 0, np.clip(-c / np.where(a > eps, a, 1), 0, 1), s)
    s = np.where(t > 1, np.clip((b - c) / np.where(a > eps, a, 1), 0, 1), s)
    # the second segment a point: the first's nearest point to it (the general formula's
    # denominator vanishes and would leave s at 0)
    s = np.where(e > eps, s, np.clip(-c / np.where(a > eps, a, 1), 0, 1))
    t = np.clip(t, 0, 1)
    s = np.where(a > eps, s, 0)
    t = np.where(e > eps, t, 0)
    closest = (p0 + d1 * s[..., None]) - (q0 + d2 * t[..., None])
    return np.linalg.norm(closest, axis=-1)


def self_collision(
    model: RobotModel,
    q: np.ndarray,
    handeye: np.ndarray,
    link_radius: float,
    camera_radius: float,
) -> np.ndarray:
    """Mask ``(N,)`` of configurations ``q`` ``(N, n)`` free of self-collision: no two capsules
    at least two links apart closer than the sum of their radii."""
    seg, links = skeleton(model, q, handeye)
    links = np.array(links)
    radius = np.where(links == model.n_joints + 1, camera_radius, link_radius)
    # Pairs far enough apart along the chain: the links strictly between them are longer than
    # the two radii (else the capsules touch in every pose: neighbours at their joint, the links
    # on either side of a spherical wrist or of a short elbow offset).
    length = np.linalg.norm(seg[..., 1, :] - seg[..., 0, :], axis=-1).min(axis=0)  # (S,)
    i, j = np.triu_indices(len(links), k=1)
    ahead = np.r_[0.0, np.cumsum(length)]  # chain length before each segment
    first = {link: np.flatnonzero(links == link)[0] for link in set(links.tolist())}
    last = {link: np.flatnonzero(links == link)[-1] for link in set(links.tolist())}
    between = np.array(
        [ahead[first[links[b]]] - ahead[last[links[a]] + 1] for a, b in zip(i, j, strict=True)]
    ).reshape(-1)
    far = (links[j] - links[i] >= 2) & (between >= radius[i] + radius[j])
    i, j = i[far], j[far]
    dist = segment_distance(seg[:, i, 0], seg[:, i, 1], seg[:, j, 0], seg[:, j, 1])
    return (dist >= radius[i] + radius[j]).all(axis=1)


def box_distance(points: np.ndarray, box: np.ndarray) -> np.ndarray:
    """Distance ``(...)`` of points ``(..., 3)`` from the box ``[xmin, ymin, zmin, xmax, ymax,
    zmax]`` (m; 0 inside)."""
    lo, hi = box[:3], box[3:]
    gap = np.maximum(np.maximum(lo - points, 0.0), points - hi)
    return np.linalg.norm(gap, axis=-1)


def cell_collision(
    model: RobotModel,
    q: np.ndarray,
    handeye: np.ndarray,
    obstacles: np.ndarray,
    link_radius: float,
    camera_radius: float,
) -> np.ndarray:
    """Mask ``(N,)`` of configurations ``q`` ``(N, n)`` whose capsules stay out of every box of
    ``obstacles`` ``(B, 6)`` (``[xmin, ymin, zmin, xmax, ymax, zmax]``, m, base frame)."""
    q = np.atleast_2d(q)
    obstacles = np.asarray(obstacles, dtype=float).reshape(-1, 6)
    if not len(obstacles):
        return np.ones(len(q), dtype=bool)
    seg, links = skeleton(model, q, handeye)
    radius = np.where(np.array(links) == model.n_joints + 1, camera_radius, link_radius)
    length = np.linalg.norm(seg[..., 1, :] - seg[..., 0, :], axis=-1).max(axis=0)  # (S,)
    ok = np.ones(len(q), dtype=bool)
    for s in range(seg.shape[1]):
        steps = max(2, int(np.ceil(length[s] / (0.5 * max(radius[s], 1e-3)))) + 1)
        t = np.linspace(0.0, 1.0, steps)[None, :, None]
        points = seg[:, s, None, 0] + t * (seg[:, s, None, 1] - seg[:, s, None, 0])
        for box in obstacles:
            ok &= (box_distance(points, box) >= radius[s]).all(axis=1)
    return ok
