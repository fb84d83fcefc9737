"""Rigid transforms as 4x4 homogeneous matrices, batched over leading axes.

A pose error or small motion is a 6-vector ``(tx, ty, tz, rx, ry, rz)``: translation in metres,
then a rotation vector in radians. Rotation-vector conversions are closed-form (Rodrigues' formula
and its inverse, robust near 0 and pi): SciPy's ``Rotation`` costs tens of microseconds per call,
which the small batches of an identification pay many times.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from scipy.spatial.transform import Rotation

MM, DEG = 1e-3, np.pi / 180  # one millimetre and one degree in SI units


def rot_x(angle: np.ndarray | float) -> np.ndarray:
    """Rotation matrices about x, shape ``(..., 3, 3)`` for angles of shape ``(...)`` (rad)."""
    c, s = np.cos(angle), np.sin(angle)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([o, z, z, z, c, -s, z, s, c], axis=-1).reshape(*np.shape(c), 3, 3)


def rot_y(angle: np.ndarray | float) -> np.ndarray:
    """Rotation matrices about y, shape ``(..., 3, 3)``."""
    c, s = np.cos(angle), np.sin(angle)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([c, z, s, z, o, z, -s, z, c], axis=-1).reshape(*np.shape(c), 3, 3)


def rot_z(angle: np.ndarray | float) -> np.ndarray:
    """Rotation matrices about z, shape ``(..., 3, 3)``."""
    c, s = np.cos(angle), np.sin(angle)
    o, z = np.ones_like(c), np.zeros_like(c)
    return np.stack([c, -s, z, s, c, z, z, z, o], axis=-1).reshape(*np.shape(c), 3, 3)


def homogeneous(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """Stack ``(..., 3, 3)`` rotations and ``(..., 3)`` translations into ``(..., 4, 4)``."""
    shape = np.broadcast_shapes(rotation.shape[:-2], translation.shape[:-1])
    out = np.zeros((*shape, 4, 4))
    out[..., :3, :3] = rotation
    out[..., :3, 3] = translation
    out[..., 3, 3] = 1.0
    return out


def invert(transform: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms ``(..., 4, 4)`` without a general matrix inverse."""
    out = np.zeros(np.shape(transform))
    out[..., :3, :3] = np.swapaxes(transform[..., :3, :3], -1, -2)
    out[..., :3, 3] = -np.einsum("...ji,...j->...i", transform[..., :3, :3], transform[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def from_vector(vec: np.ndarray) -> np.ndarray:
    """Transforms ``(..., 4, 4)`` from 6-vectors ``(..., 6)`` (translation m, rotvec rad)."""
    vec = np.asarray(vec, dtype=float)
    return homogeneous(exp_rotation(vec[..., 3:]), vec[..., :3])


def to_vector(transform: np.ndarray) -> np.ndarray:
    """6-vectors ``(..., 6)`` (translation m, rotation vector rad) of transforms ``(..., 4, 4)``."""
    transform = np.asarray(transform, dtype=float)
    return np.concatenate([transform[..., :3, 3], log_rotation(transform[..., :3, :3])], axis=-1)


def exp_rotation(rotvec: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` of rotation vectors ``(..., 3)`` (Rodrigues' formula)."""
    w = np.asarray(rotvec, dtype=float)
    if w.shape == (3,):  # one vector (a hand-eye or frame update): plain floats cost far less
        return _exp_rotation_one(*w.tolist())
    angle2 = np.einsum("...i,...i->...", w, w)
    angle = np.sqrt(angle2)
    small = angle < 1e-4  # Taylor series there: exact to round-off, no 0/0
    safe = np.where(small, 1.0, angle)
    # R = cos(t) I + a [w] + b w w^T with a = sin(t)/t, b = (1 - cos t)/t^2 = 2 sin^2(t/2)/t^2.
    a = np.where(small, 1 - angle2 / 6, np.sin(safe) / safe)
    b = np.where(small, 0.5 - angle2 / 24, 2 * (np.sin(safe / 2) / safe) ** 2)
    return (
        np.cos(angle)[..., None, None] * np.eye(3)
        + a[..., None, None] * skew(w)
        + b[..., None, None] * (w[..., :, None] * w[..., None, :])
    )


def _exp_rotation_one(x: float, y: float, z: float) -> np.ndarray:
    """:func:`exp_rotation` of one vector, the same formula on Python floats."""
    angle2 = x * x + y * y + z * z
    angle = math.sqrt(angle2)
    if angle < 1e-4:
        a, b = 1 - angle2 / 6, 0.5 - angle2 / 24
    else:
        a, b = math.sin(angle) / angle, 2 * (math.sin(angle / 2) / angle) ** 2
    c = math.cos(angle)
    return np.array(
        [
            [c + b * x * x, b * x * y - a * z, b * x * z + a * y],
            [b * x * y + a * z, c + b * y * y, b * y * z - a * x],
            [b * x * z - a * y, b * y * z + a * x, c + b * z * z],
        ]
    )


def right_jacobian(rotvec: np.ndarray) -> np.ndarray:
    """Right Jacobian ``(..., 3, 3)`` of SO(3) at rotation vectors ``(..., 3)`` (rad):
    ``exp(w + dw) ~ exp(w) exp([J_r(w) dw])``."""
    # J_r = I - (1 - cos t)/t^2 [w] + (t - sin t)/t^3 [w]^2
    return _so3_series(
        rotvec,
        lambda t2: (t2 / 24 - 0.5, 1 / 6 - t2 / 120),
        lambda t: ((np.cos(t) - 1) / t**2, (t - np.sin(t)) / t**3),
    )


def right_jacobian_inverse(rotvec: np.ndarray) -> np.ndarray:
    """Inverse of the right Jacobian ``(..., 3, 3)`` of SO(3) at rotation vectors ``(..., 3)``
    (rad): ``log(exp(w) exp(dw)) ~ w + J_r^-1(w) dw``. The left one is ``J_r^-1(-w)``:
    ``log(exp(dw) exp(w)) ~ w + J_r^-1(-w) dw``. Valid below pi."""
    # J_r^-1 = I + [w]/2 + (1/t^2 - (1 + cos t) / (2 t sin t)) [w]^2
    return _so3_series(
        rotvec,
        lambda t2: (0.5, 1 / 12 + t2 / 720),
        lambda t: (0.5, 1 / t**2 - (1 + np.cos(t)) / (2 * t * np.sin(t))),
    )


def _so3_series(w: np.ndarray, series: Callable, exact: Callable) -> np.ndarray:
    """``I + a [w] + b [w]^2`` ``(..., 3, 3)`` at rotation vectors ``w`` ``(..., 3)``, with the
    coefficients ``(a, b)`` from ``exact(angle)`` or, below 1e-4 rad (exact to round-off there,
    no 0/0), from ``series(angle^2)``. One vector (a hand-eye update) is done on Python floats; a
    batch evaluates only the branches its angles need (near an optimum, all are small)."""
    w = np.asarray(w, dtype=float)
    if w.shape == (3,):
        x, y, z = w.tolist()
        t2 = x * x + y * y + z * z
        a, b = series(t2) if t2 < 1e-8 else exact(math.sqrt(t2))
        d = 1.0 - b * t2
        return np.array(
            [
                [d + b * x * x, b * x * y - a * z, b * x * z + a * y],
                [b * x * y + a * z, d + b * y * y, b * y * z - a * x],
                [b * x * z - a * y, b * y * z + a * x, d + b * z * z],
            ]
        )
    t2 = np.einsum("...i,...i->...", w, w)
    small = t2 < 1e-8
    if small.all():
        a, b = series(t2)
    else:
        t = np.sqrt(np.where(small, 1.0, t2))
        a, b = exact(t)
        if small.any():
            a_s, b_s = series(t2)
            a, b = np.where(small, a_s, a), np.where(small, b_s, b)
    a, b = np.asarray(a), np.asarray(b)  # a may be a constant
    # [w]^2 = w w^T - t^2 I
    out = b[..., None, None] * (w[..., :, None] * w[..., None, :])
    diagonal = np.einsum("...ii->...i", out)
    diagonal += (1.0 - b * t2)[..., None]
    out += skew(a[..., None] * w)
    return out


def vector_tangent(vec: np.ndarray) -> np.ndarray:
    """``(..., 6, 6)`` ``diag(R(w)^T, J_r(w))`` of 6-vectors ``(t, w)`` ``(..., 6)``: the body
    motion of :func:`from_vector` per unit change of its vector,
    ``from_vector(v + dv) ~ from_vector(v) exp([T dv])``, exactly at any ``v``."""
    vec = np.asarray(vec, dtype=float)
    out = np.zeros((*vec.shape[:-1], 6, 6))
    out[..., :3, :3] = np.swapaxes(exp_rotation(vec[..., 3:]), -1, -2)
    out[..., 3:, 3:] = right_jacobian(vec[..., 3:])
    return out


def log_rotation(rotation: np.ndarray) -> np.ndarray:
    """Rotation vectors ``(..., 3)`` (angle in [0, pi]) of rotation matrices ``(..., 3, 3)``.

    The angle is ``atan2(sin, cos)`` from the skew part and the trace. Up to 90 degrees the axis
    comes from the skew part ``R - R^T = 2 sin(t) [n]``; beyond, where that part vanishes towards
    pi, from the symmetric part (:func:`_axis_near_pi`).
    """
    r = np.asarray(rotation, dtype=float)
    skew_part = np.empty(r.shape[:-1])  # 2 sin(t) n
    np.subtract(r[..., 2, 1], r[..., 1, 2], out=skew_part[..., 0])
    np.subtract(r[..., 0, 2], r[..., 2, 0], out=skew_part[..., 1])
    np.subtract(r[..., 1, 0], r[..., 0, 1], out=skew_part[..., 2])
    sin_t = 0.5 * np.sqrt(np.einsum("...i,...i->...", skew_part, skew_part))
    cos_t = 0.5 * (r[..., 0, 0] + r[..., 1, 1] + r[..., 2, 2] - 1)
    angle = np.arctan2(sin_t, cos_t)
    # t / (2 sin t), with its series 1/2 + t^2/12 where sin t is tiny (only used for t < pi/2).
    tiny = sin_t < 1e-6
    factor = np.where(tiny, 0.5 + angle**2 / 12, angle / (2 * np.where(tiny, 1.0, sin_t)))
    out = factor[..., None] * skew_part
    far = cos_t < 0
    if np.any(far):
        out[far] = angle[far, None] * _axis_near_pi(r[far], skew_part[far], cos_t[far])
    return out


def _axis_near_pi(r: np.ndarray, skew_part: np.ndarray, cos_t: np.ndarray) -> np.ndarray:
    """Unit axes ``(K, 3)`` of rotations ``(K, 3, 3)`` turning more than 90 degrees.

    ``(R + R^T) / 2 - cos(t) I = (1 - cos t) n n^T``: its column with the largest diagonal entry is
    ``n`` up to a positive scale, accurate up to pi; the sign follows the skew part ``2 sin(t) n``.
    """
    sym = 0.5 * (r + np.swapaxes(r, -1, -2)) - cos_t[:, None, None] * np.eye(3)
    rows = np.arange(len(r))
    k = np.argmax(np.diagonal(sym, axis1=-2, axis2=-1), axis=-1)
    column = sym[rows, :, k]  # (1 - cos t) n_k n
    axis = column / np.linalg.norm(column, axis=-1, keepdims=True)
    return np.where(skew_part[rows, k, None] < 0, -axis, axis)


def pose_error(target: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Base-frame errors ``(..., 6)`` from ``pose`` to ``target`` (both ``(..., 4, 4)``): the
    position difference ``t_target - t_pose`` (m), then the rotation vector (rad) of
    ``R_target R_pose^T``; the rows of :func:`relcal.robot.kinematics.pose_jacobian`."""
    target, pose = np.asarray(target, dtype=float), np.asarray(pose, dtype=float)
    rot = target[..., :3, :3] @ np.swapaxes(pose[..., :3, :3], -1, -2)
    out = np.empty((*rot.shape[:-2], 6))
    out[..., :3] = target[..., :3, 3] - pose[..., :3, 3]
    out[..., 3:] = log_rotation(rot)
    return out


def from_xyz_rpy(xyz: np.ndarray, rpy: np.ndarray) -> np.ndarray:
    """Transform from translation (m) and fixed-axis roll, pitch, yaw (rad), as in URDF."""
    rot = Rotation.from_euler("xyz", rpy).as_matrix()
    return homogeneous(rot, np.asarray(xyz, dtype=float))


def to_xyz_rpy(transform: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Translation (m) and fixed-axis roll, pitch, yaw (rad) of one ``(4, 4)`` transform.

    ``R = Rz(yaw) Ry(pitch) Rx(roll)``. Roll and pitch come from the last row; yaw from what is
    left of ``R`` once they are taken out, so the three angles rebuild ``R`` to round-off even
    near pitch = +-90 degrees (where independent formulas lose digits: URDFs often write
    pitch = 1.570796325).
    """
    r = np.asarray(transform, dtype=float)[:3, :3]
    pitch = math.atan2(-r[2, 0], math.hypot(r[2, 1], r[2, 2]))
    roll = math.atan2(r[2, 1], r[2, 2])
    rest = r @ rot_x(roll).T @ rot_y(pitch).T  # Rz(yaw)
    yaw = math.atan2(rest[1, 0], rest[0, 0])
    return np.asarray(transform, dtype=float)[:3, 3].copy(), np.array([roll, pitch, yaw])


def relative(poses: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """Relative motions ``T_i^-1 T_j`` ``(P, 4, 4)`` of poses ``(N, 4, 4)`` for index pairs
    ``(P, 2)``: a relative measurement ``M_ij = C_i^-1 C_j``, or the commanded ``F_i^-1 F_j``."""
    return invert(poses[pairs[:, 0]]) @ poses[pairs[:, 1]]


def kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation ``R`` ``(3, 3)`` minimising ``sum_k |a_k - R b_k|^2`` over vectors ``(K, 3)``
    (an SVD of ``a^T b``, reflections excluded): point sets (centred) or rotation vectors."""
    u, _, vt = np.linalg.svd(a.T @ b)
    return u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt


def rotate_twist(rotation: np.ndarray, twist: np.ndarray) -> np.ndarray:
    """Apply ``blockdiag(R, R)`` to twists: ``rotation (..., 3, 3)``, ``twist (..., 6, P)``."""
    out = np.empty_like(twist)
    out[..., :3, :] = rotation @ twist[..., :3, :]
    out[..., 3:, :] = rotation @ twist[..., 3:, :]
    return out


def adjoint(transform: np.ndarray) -> np.ndarray:
    """Adjoint ``(..., 6, 6)`` mapping twists ``(v, w)`` in a frame to the frame's parent."""
    rot, t = transform[..., :3, :3], transform[..., :3, 3]
    out = np.zeros((*transform.shape[:-2], 6, 6))
    out[..., :3, :3] = rot
    out[..., 3:, 3:] = rot
    out[..., :3, 3:] = skew(t) @ rot
    return out


def skew(vec: np.ndarray) -> np.ndarray:
    """Cross-product matrices ``(..., 3, 3)`` of vectors ``(..., 3)``."""
    vec = np.asarray(vec, dtype=float)
    x, y, z = vec[..., 0], vec[..., 1], vec[..., 2]
    out = np.zeros((*vec.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -z, y, -x
    out[..., 1, 0], out[..., 2, 0], out[..., 2, 1] = z, -y, x
    return out


def look_at(eye: np.ndarray, target: np.ndarray, roll: float) -> np.ndarray:
    """Camera pose (z axis toward ``target``, rolled by ``roll`` rad about it), ``(4, 4)``."""
    z = target - eye
    z /= np.linalg.norm(z)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    rot = np.stack([x, y, z], axis=1) @ rot_z(roll)
    return homogeneous(rot, eye)
