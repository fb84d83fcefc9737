"""A starting guess of the hand-eye transform from data: ``C_k = W F_k X`` solved for ``X``.

Relative motions satisfy ``A X = X B`` with ``A = F_i^-1 F_j`` and ``B = C_i^-1 C_j``. As in Park
and Martin, the rotation vectors obey ``a = R_X b``, which an SVD (Kabsch) solves; the translation
then follows from ``(R_A - I) t_X = R_X t_B - t_A`` by linear least squares. The identification
refines ``X`` with the geometry, so this only needs to be close.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from relcal import geometry as tf
from relcal.calibration.measurement import AUTO_ALL_PAIRS, capped_pairs
from relcal.errors import RelcalError


def rotation_vectors(transforms: np.ndarray) -> np.ndarray:
    """Rotation vectors ``(P, 3)`` of the rotations of transforms ``(P, 4, 4)``."""
    return Rotation.from_matrix(transforms[:, :3, :3]).as_rotvec()


def align_rotations(
    commanded: np.ndarray, measured: np.ndarray, max_angle: float | None = None
) -> np.ndarray:
    """The rotation ``R_X`` ``(3, 3)`` that best maps the rotation vectors of measured relative
    motions onto those of the commanded ones (``a = R_X b`` of ``A X = X B``, Park and Martin;
    :func:`geometry.kabsch`). With ``max_angle`` (rad) only pairs turning less (where the axis
    is sure) count, when at least two do."""
    a, b = rotation_vectors(commanded), rotation_vectors(measured)
    if max_angle is not None:
        keep = np.linalg.norm(a, axis=1) < max_angle
        if keep.sum() >= 2:
            a, b = a[keep], b[keep]
    return tf.kabsch(a, b)


GUESS_PAIRS = AUTO_ALL_PAIRS * (AUTO_ALL_PAIRS - 1) // 2  # pairs of the guess: all of 300 samples


def solve_handeye(flange: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """``X`` ``(4, 4)`` from flange poses ``F_k`` and measured poses ``C_k`` ``(N, 4, 4)``: all
    pairs, or :data:`GUESS_PAIRS` random ones of a larger set (linear in the samples)."""
    pairs = capped_pairs(len(flange), GUESS_PAIRS)
    a, b = tf.relative(flange, pairs), tf.relative(measured, pairs)
    if len(pairs) < 2 or np.linalg.matrix_rank(rotation_vectors(a), tol=1e-3) < 2:
        raise RelcalError(
            "cannot guess the hand-eye transform: the poses must rotate about at least two "
            "different axes (or give handeye: in dataset.yaml)"
        )
    rot = align_rotations(a, b)
    lhs = (a[:, :3, :3] - np.eye(3)).reshape(-1, 3)
    rhs = (np.einsum("ij,pj->pi", rot, b[:, :3, 3]) - a[:, :3, 3]).reshape(-1)
    trans = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    return tf.homogeneous(rot, trans)


def solve_instrument(
    flange: np.ndarray, points: np.ndarray, marker: np.ndarray | None = None, iterations: int = 20
) -> tuple[np.ndarray, np.ndarray]:
    """Starting guesses of the instrument-from-base transform ``T`` ``(4, 4)`` and the marker
    position ``m`` ``(3,)`` (flange frame) from flange poses ``F_k`` ``(N, 4, 4)`` and measured
    points ``p_k = T F_k m`` ``(N, 3)``.

    Alternates a point-set registration (Kabsch) of the modelled points ``F_k m`` onto ``p_k``
    with the linear least-squares solve of ``p_k - R_T t_k = R_T R_k m + t_T`` for ``m`` and
    ``t_T``; starts from ``marker`` (default the flange origin).
    """
    points = np.asarray(points, dtype=float)
    m = np.zeros(3) if marker is None else np.asarray(marker, dtype=float)
    rot_f, t_f = flange[:, :3, :3], flange[:, :3, 3]
    if len(points) < 3 or np.linalg.matrix_rank(t_f - t_f.mean(axis=0), tol=1e-4) < 3:
        raise RelcalError(
            "cannot guess the instrument-to-base transform: the measured points must span "
            "three dimensions (move the robot over a volume, not a plane or a line)"
        )
    n = len(points)
    for _ in range(iterations):
        model = rot_f @ m + t_f
        rot = tf.kabsch(points - points.mean(axis=0), model - model.mean(axis=0))
        lhs = np.concatenate([rot @ rot_f, np.broadcast_to(np.eye(3), (n, 3, 3))], axis=2)
        rhs = points - t_f @ rot.T
        sol = np.linalg.lstsq(lhs.reshape(-1, 6), rhs.reshape(-1), rcond=None)[0]
        m = sol[:3]
    return tf.homogeneous(rot, sol[3:]), m
