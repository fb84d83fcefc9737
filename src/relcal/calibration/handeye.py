"""A starting guess of the hand-eye transform from data: ``C_k = W F_k X`` solved for ``X``.

Relative motions satisfy ``A X = X B`` with ``A = F_i^-1 F_j`` and ``B = C_i^-1 C_j``. As in Park
and Martin, the rotation vectors obey ``a = R_X b``, which an SVD (Kabsch) solves; the translation
then follows from ``(R_A - I) t_X = R_X t_B - t_A`` by linear least squares.

Only motions that carry information count (:func:`handeye_rotation`): the rotation vectors of the
pairs that turn, and the directions of the translations of the pairs that move without turning
(``t_A = R_X t_B`` there). A recording whose orientations differ about one axis only (two cubes of
an ISO 9283 test, each at one tool orientation) leaves ``R_X`` free about that axis unless such
translations fix it; one at a single orientation is fixed by its translations alone. The guess
is then refined by a robust least-squares fit of ``A X = X B`` over the pairs (rotation and
translation), so that it is the best hand-eye transform of the nominal kinematics: the
identification refines ``X`` with the geometry, and a correction of it beyond the tolerances
means a wrong input, not a rough start.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from relcal import geometry as tf
from relcal.calibration.measurement import AUTO_ALL_PAIRS, capped_pairs
from relcal.errors import RelcalError

PURE_TRANSLATION = np.radians(1.0)  # rad: pairs that turn less are translations for R_X
LEVER = 1.0  # m/rad: rotation vectors beside translations in the fits of X
DETERMINED = np.radians(1.0)  # rad: R_X less sure than this about some axis is not known
SIGMA = 0.01  # m (rad times LEVER): the misfit of right data per vector, for DETERMINED
STILL = 1e-3  # m: a pair that neither turns nor moves this far is a configuration repeated
HOLD = 0.1  # m: how far t_X may move from its guess at the cost of one pair's residual scale
REFINE_PAIRS = 3000  # pairs of the refinement of the guess (random ones of a larger set)


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


def handeye_rotation(
    commanded: np.ndarray,
    measured: np.ndarray,
    turning: np.ndarray,
    still: np.ndarray,
    rotvecs: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, bool]:
    """``R_X`` ``(3, 3)`` of ``A X = X B`` from the relative motions ``commanded`` (``A``) and
    ``measured`` (``B``) ``(P, 4, 4)``: the rotation vectors of the pairs ``turning`` (``(P,)``
    bool; those turning less than :data:`~relcal.calibration.plausibility.SURE_AXIS`, 150 deg,
    when two or more do) beside the directions of the translations of the pairs ``still`` (they
    move without turning: ``t_A = s R_X t_B`` whatever ``t_X``; each ``t_B`` taken at the length
    of its ``t_A``, so that the scale does not matter), rotation vectors times :data:`LEVER`.
    Returns ``R_X`` and whether the motions determine it: its standard deviation about the least
    determined axis (:func:`rotation_std`) below :data:`DETERMINED` (pairs that all turn about
    one axis, with no translation across it, leave ``R_X`` free about that axis). ``rotvecs``:
    the rotation
    vectors of ``commanded`` and ``measured`` when already computed."""
    ra, rb = (
        rotvecs
        if rotvecs is not None
        else (rotation_vectors(commanded), rotation_vectors(measured))
    )
    sure = turning & (np.linalg.norm(ra, axis=1) < np.radians(150.0))
    if sure.sum() < 2:
        sure = turning
    ta, tb = commanded[still, :3, 3], measured[still, :3, 3]
    la, lb = np.linalg.norm(ta, axis=1), np.linalg.norm(tb, axis=1)
    keep = (la > 0) & (lb > 0)
    a = np.concatenate([ra[sure] * LEVER, ta[keep]])
    b = np.concatenate([rb[sure] * LEVER, tb[keep] * (la[keep] / lb[keep])[:, None]])
    if len(a) < 2:
        return np.eye(3), False
    rot = tf.kabsch(a, b)
    return rot, bool(rotation_std(a, b, rot) < DETERMINED)


def rotation_std(a: np.ndarray, b: np.ndarray, rot: np.ndarray, sigma: float = SIGMA) -> float:
    """Standard deviation (rad) of the Kabsch fit ``a_k = R b_k`` (``(K, 3)`` each, ``R`` the
    fit) about its least determined axis, for vectors of noise ``sigma`` per component: the
    variance over the curvature of the cost in that direction (``sum |c|^2 I - c c^T``, ``c =
    R b``); infinite when the vectors are all parallel (nothing fixes a rotation about them).
    A fixed ``sigma`` (not the residuals') makes it a property of the motions: wrong data do not
    pass for motions that cannot tell."""
    c = b @ rot.T
    curvature = np.eye(3) * np.sum(c * c) - c.T @ c
    low, high = np.linalg.eigvalsh(curvature)[[0, -1]]
    if not low > 1e-9 * high:
        return float("inf")
    return float(sigma / np.sqrt(low))


def informative_pairs(commanded: np.ndarray, measured: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which pairs turn (either motion by more than :data:`PURE_TRANSLATION`) and which move
    without turning (both turn less, and the commanded one moves more than :data:`STILL`): a
    configuration recorded again is neither (repeatability data, no motion)."""
    angle_a = np.linalg.norm(rotation_vectors(commanded), axis=1)
    angle_b = np.linalg.norm(rotation_vectors(measured), axis=1)
    turning = (angle_a > PURE_TRANSLATION) | (angle_b > PURE_TRANSLATION)
    moves = np.linalg.norm(commanded[:, :3, 3], axis=1) > STILL
    return turning, ~turning & moves


def refine_handeye(commanded: np.ndarray, measured: np.ndarray, guess: np.ndarray) -> np.ndarray:
    """``X`` ``(4, 4)`` by a robust least-squares fit of ``A X = X B`` over the pairs (``(P, 4,
    4)`` each; :data:`REFINE_PAIRS` random ones of more): per pair the translation of
    ``A X - X B`` (m) and the rotation vector of ``R_A R_X R_B^T R_X^T`` times :data:`LEVER`,
    soft-L1 loss bending at 3 robust standard deviations of the residuals at ``guess``, so that
    a few wrong samples do not pull it. ``t_X`` is held at ``guess`` by three rows (quadratic:
    a shift of :data:`HOLD` costs as much as one pair at the residual scale), so that directions
    the motions do not determine (``t_X`` along the one axis every pair turns about, or every
    direction when no pair turns) stay there while those they determine move freely."""
    from scipy.optimize import least_squares

    from relcal.calibration.noise import robust_scale

    if len(commanded) > REFINE_PAIRS:
        pick = np.sort(np.random.default_rng(0).choice(len(commanded), REFINE_PAIRS, False))
        commanded, measured = commanded[pick], measured[pick]
    ra, ta = commanded[:, :3, :3], commanded[:, :3, 3]
    rb, tb = measured[:, :3, :3], measured[:, :3, 3]

    def residual(x: np.ndarray) -> np.ndarray:
        rx = Rotation.from_rotvec(x[3:]).as_matrix()
        trans = ra @ x[:3] + ta - tb @ rx.T - x[:3]
        rot = tf.log_rotation(ra @ rx @ np.swapaxes(rb, 1, 2) @ rx.T) * LEVER
        return np.concatenate([trans, rot], axis=1).ravel()

    x0 = np.concatenate([guess[:3, 3], Rotation.from_matrix(guess[:3, :3]).as_rotvec()])
    scale = max(3.0 * robust_scale(residual(x0)), 1e-6)

    def held(x: np.ndarray) -> np.ndarray:
        r = residual(x) / scale  # soft-L1, applied here so that the rows holding t_X are not
        soft = np.sign(r) * np.sqrt(2.0 * (np.sqrt(1.0 + r * r) - 1.0))
        return np.concatenate([soft, (x[:3] - x0[:3]) / HOLD])

    fit = least_squares(held, x0, x_scale="jac")
    return tf.homogeneous(Rotation.from_rotvec(fit.x[3:]).as_matrix(), fit.x[:3])


def solve_handeye(flange: np.ndarray, measured: np.ndarray) -> np.ndarray:
    """``X`` ``(4, 4)`` from flange poses ``F_k`` and measured poses ``C_k`` ``(N, 4, 4)``: all
    pairs, or :data:`GUESS_PAIRS` random ones of a larger set (linear in the samples).

    When the rotations of the pairs that turn determine ``R_X`` (:func:`handeye_rotation` on
    them alone), Park and Martin's closed form on every pair (the rotation vectors aligned,
    then ``t_X`` by least squares). Otherwise (every
    pair turning about one axis, or none: the cubes of an ISO 9283 test at one or two tool
    orientations) from the motions that carry information: ``R_X`` from the rotations and the
    translations of the pairs that move without turning (:func:`handeye_rotation`), ``t_X`` by
    least squares where rotations fix it and zero where none does
    (:func:`handeye_translation`), then :func:`refine_handeye`."""
    pairs = capped_pairs(len(flange), GUESS_PAIRS)
    a, b = tf.relative(flange, pairs), tf.relative(measured, pairs)
    turning, still = informative_pairs(a, b)
    rotations_tell = handeye_rotation(a, b, turning, np.zeros(len(pairs), dtype=bool))[1]
    if len(pairs) >= 2 and rotations_tell:
        rot = align_rotations(a, b)
        lhs = (a[:, :3, :3] - np.eye(3)).reshape(-1, 3)
        rhs = (np.einsum("ij,pj->pi", rot, b[:, :3, 3]) - a[:, :3, 3]).reshape(-1)
        return tf.homogeneous(rot, np.linalg.lstsq(lhs, rhs, rcond=None)[0])
    rot, known = handeye_rotation(a, b, turning, still)
    if len(pairs) < 2 or not known:
        raise RelcalError(
            "cannot guess the hand-eye transform: the poses must rotate about at least two "
            "different axes, or move in two directions without turning (or give handeye: in "
            "dataset.yaml)"
        )
    trans = handeye_translation(a[turning | still], b[turning | still], rot)
    return refine_handeye(a, b, tf.homogeneous(rot, trans))


def handeye_translation(commanded: np.ndarray, measured: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """``t_X`` ``(3,)`` of ``(R_A - I) t_X = R_X t_B - t_A`` by least squares over the pairs,
    with ``R_X`` = ``rot``; directions in which the pairs turn less than
    :data:`PURE_TRANSLATION` (root mean square) are left at zero: no rotation fixes them (a
    recording at one tool orientation), and a fit would only follow the noise."""
    lhs = (commanded[:, :3, :3] - np.eye(3)).reshape(-1, 3)
    rhs = (np.einsum("ij,pj->pi", rot, measured[:, :3, 3]) - commanded[:, :3, 3]).reshape(-1)
    u, sv, vt = np.linalg.svd(lhs, full_matrices=False)
    turn = sv / np.sqrt(max(len(commanded), 1))  # rms of |(R_A - I) v| over the pairs
    keep = turn > 2 * np.sin(PURE_TRANSLATION / 2)
    return vt[keep].T @ ((u[:, keep].T @ rhs) / sv[keep])


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
