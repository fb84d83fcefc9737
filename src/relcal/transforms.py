"""Rigid transforms as 4x4 homogeneous matrices, batched over leading axes.

A pose error or small motion is a 6-vector ``(tx, ty, tz, rx, ry, rz)``: translation in metres,
then a rotation vector in radians. Rotation-vector conversions use SciPy's ``Rotation``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


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
    rt = np.swapaxes(transform[..., :3, :3], -1, -2)
    return homogeneous(rt, -np.einsum("...ij,...j->...i", rt, transform[..., :3, 3]))


def from_vector(vec: np.ndarray) -> np.ndarray:
    """Transforms ``(..., 4, 4)`` from 6-vectors ``(..., 6)`` (translation m, rotvec rad)."""
    vec = np.asarray(vec, dtype=float)
    flat = vec.reshape(-1, 6)
    rot = Rotation.from_rotvec(flat[:, 3:]).as_matrix()
    return homogeneous(rot, flat[:, :3]).reshape(*vec.shape[:-1], 4, 4)


def to_vector(transform: np.ndarray) -> np.ndarray:
    """6-vectors ``(..., 6)`` (translation m, rotation vector rad) of transforms ``(..., 4, 4)``."""
    transform = np.asarray(transform, dtype=float)
    flat = transform.reshape(-1, 4, 4)
    rv = Rotation.from_matrix(flat[:, :3, :3]).as_rotvec()
    return np.concatenate([flat[:, :3, 3], rv], axis=1).reshape(*transform.shape[:-2], 6)


def from_xyz_rpy(xyz: np.ndarray, rpy: np.ndarray) -> np.ndarray:
    """Transform from translation (m) and fixed-axis roll, pitch, yaw (rad), as in URDF."""
    rot = Rotation.from_euler("xyz", rpy).as_matrix()
    return homogeneous(rot, np.asarray(xyz, dtype=float))


def to_xyz_rpy(transform: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Translation (m) and fixed-axis roll, pitch, yaw (rad) of one ``(4, 4)`` transform."""
    return transform[:3, 3].copy(), Rotation.from_matrix(transform[:3, :3]).as_euler("xyz")


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
    x, y, z = vec[..., 0], vec[..., 1], vec[..., 2]
    o = np.zeros_like(x)
    return np.stack([o, -z, y, z, o, -x, -y, x, o], axis=-1).reshape(*vec.shape[:-1], 3, 3)
