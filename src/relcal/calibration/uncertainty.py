"""Uncertainty of identified parameters: covariance, correlation and predicted accuracy.

The identification is linearised at the parameters (nominal by default): residuals
``r ~ A (p_true - p) + e`` with ``A`` the identification Jacobian restricted to the estimated
subset and ``e`` the residual noise. The noise comes from the poses: each measured camera pose
``C_k`` carries a small error ``eps_k`` (6-vector, translation m and rotation rad, in the frame the
formulation's residuals live in), and each joint reading an error ``eta_k`` that moves the modelled
pose by ``J_q eta_k``. Relative measurements mix the errors of two poses, so consecutive pairs are
correlated and all-pairs sets are redundant: ``e = B eps`` with ``B`` (:func:`noise_blocks`) mapping
the ``6 N`` per-pose errors to the ``M`` residual rows, ``Cov(e) = B S B^T`` with ``S`` the
block-diagonal per-pose covariance (:func:`pose_covariances`).

Two covariances of the estimate follow:

- least squares (what :func:`identify.identify` computes, with the problem's row weights):
  ``K B S B^T K^T`` with ``K = (A^T A)^-1 A^T`` (the "sandwich");
- weighted by the full noise covariance (Gauss-Markov, maximum likelihood for Gaussian noise):
  ``(A^T Cov(e)^+ A)^-1``, the Cramer-Rao bound of the linearised problem. It does not depend on
  the pairing strategy or on the order of the poses (any connected pairing carries the same
  information); the least-squares covariance does.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph

from relcal import geometry as tf
from relcal.calibration.identifiability import Identifiability, scaled
from relcal.calibration.measurement import (
    PairStrategy,
    Problem,
    make_pairs,
    residuals,
    split_params,
    unweighted,
)
from relcal.calibration.noise import Noise, robust_scale, row_factors
from relcal.deferred import Deferred, resolved_state
from relcal.errors import RelcalError
from relcal.robot.ik import joint_layout
from relcal.robot.kinematics import fk, pose_jacobian

Estimator = Literal["least_squares", "weighted"]
_RANK_TOL = 1e-10  # relative tolerance on the singular values of the noise factor


# --- the noise -----------------------------------------------------------------------------------


def body_covariance(poses: np.ndarray, vector_covariance: np.ndarray) -> np.ndarray:
    """Covariances ``(N, 6, 6)`` of body-frame pose errors (``C exp(eps)``) from covariances of
    ``transforms.to_vector(C)`` (translation m, rotation vector rad), as the image pipeline gives
    them (:class:`relcal.vision.detect.PoseResult`)."""
    g = tf.vector_tangent(tf.to_vector(poses))  # eps = (R^T dt, J_r(phi) dphi)
    return g @ vector_covariance @ np.swapaxes(g, -1, -2)


def _joint_variances(noise: Noise, n_joints: int) -> np.ndarray:
    joints = np.broadcast_to(np.asarray(noise.joints, dtype=float), (n_joints,))
    return joints**2


def pose_covariances(
    problem: Problem,
    noise: Noise,
    covariances: np.ndarray | None = None,
    params: np.ndarray | None = None,
) -> np.ndarray:
    """Per-pose error covariances ``(N, 6, 6)`` in the frame of the formulation's residuals.

    Frame-invariant: the camera's own (body) frame, ``C_k exp(eps_k)``. Published and absolute:
    the base frame at the tool point, ``(R eps_t, R eps_w)``. The camera pose error is isotropic
    with ``noise.position`` (m) and ``noise.orientation`` (rad) per axis, or the given
    ``covariances`` ``(N, 6, 6)`` of ``to_vector(C_k)``; joint noise ``noise.joints`` (rad, or m for
    prismatic joints; scalar or per joint) adds ``G Sigma_q G^T`` with ``G`` the joint Jacobian in
    the same frame.
    """
    n = len(problem.q)
    params = np.zeros(problem.full_layout.size) if params is None else params
    model, handeye = split_params(problem, params)
    if covariances is not None:
        covariances = np.asarray(covariances, dtype=float)
        if covariances.shape != (n, 6, 6):
            raise RelcalError(
                f"pose covariances must have shape ({n}, 6, 6), got {covariances.shape}"
            )
        camera = body_covariance(problem.poses, covariances)
    else:
        camera = np.broadcast_to(noise.pose_covariance(), (n, 6, 6)).copy()
    if problem.formulation not in ("invariant", "board"):
        rot = fk(model, problem.q)[:, :3, :3]
        d = np.zeros((n, 6, 6))
        d[:, :3, :3] = rot
        d[:, 3:, 3:] = rot
        camera = d @ camera @ np.swapaxes(d, -1, -2)
    var_q = _joint_variances(noise, model.n_joints)
    if np.any(var_q > 0):
        g = joint_map(problem, params)
        camera = camera + (g * var_q) @ np.swapaxes(g, -1, -2)
    return camera


def joint_map(problem: Problem, params: np.ndarray | None = None) -> np.ndarray:
    """Per-pose joint Jacobians ``(N, 6, n)`` in the frame of :func:`pose_covariances`: how a
    joint reading error moves the modelled pose (camera body frame for the frame-invariant
    formulation, base frame at the tool point otherwise)."""
    params = np.zeros(problem.full_layout.size) if params is None else params
    model, handeye = split_params(problem, params)
    tip, jq = pose_jacobian(model, problem.q, joint_layout(model))
    if problem.formulation not in ("invariant", "board"):
        return jq
    body = tf.rotate_twist(np.swapaxes(tip[:, :3, :3], -1, -2), jq)  # flange body twists
    return tf.adjoint(tf.invert(handeye)) @ body


def noise_blocks(
    problem: Problem, params: np.ndarray | None = None, measured: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """The residual noise per measurement: which poses ``(m, s)`` each of the ``m`` measurements
    involves (``s`` = 2 for pairs, 1 for absolute poses) and the blocks ``(m, s, r, 6)`` mapping
    those poses' errors to its ``r`` residual rows (with the problem's row weights).

    Frame-invariant pair (i, j): ``eps_j - Ad(M_ij^-1) eps_i`` with ``M_ij`` the relative camera
    motion, modelled at ``params`` or, with ``measured``, the measured ``C_i^-1 C_j`` (closer to
    the truth than the nominal model); published: ``eps_j - eps_i``; absolute: ``eps_k``.
    Position-only measurements keep the first 3 rows of each.
    """
    n = len(problem.q)
    params = np.zeros(problem.full_layout.size) if params is None else params
    if problem.formulation in ("absolute", "board"):  # each pose its own measurement
        poses = np.arange(n)[:, None]
        blocks = np.broadcast_to(np.eye(6), (n, 1, 6, 6))
    else:
        pairs = problem.pair_indices()
        poses = pairs[:, ::-1]  # (j, i): pose j enters with +I, pose i with the left block
        i, j = pairs.T
        if problem.formulation == "invariant" and measured:
            left = -tf.adjoint(tf.invert(tf.relative(problem.poses, pairs)))
        elif problem.formulation == "invariant":
            model, handeye = split_params(problem, params)
            tip = fk(model, problem.q)
            x_inv = tf.invert(handeye)
            model_rel = x_inv @ tf.invert(tip[i]) @ tip[j] @ handeye
            left = -tf.adjoint(tf.invert(model_rel))
        else:
            left = np.broadcast_to(-np.eye(6), (len(poses), 6, 6))
        blocks = np.stack([np.broadcast_to(np.eye(6), left.shape), left], axis=1)
    if problem.weights is not None:
        blocks = blocks * np.asarray(problem.weights, dtype=float)[None, None, :, None]
    if problem.pair_weights is not None:
        blocks = problem.pair_weights[:, None] @ blocks
    return poses, blocks[:, :, : problem.rows_per_measurement]


def noise_map(
    problem: Problem, params: np.ndarray | None = None, measured: bool = False
) -> np.ndarray:
    """``B`` ``(M, 6 N)``: residual rows per unit per-pose error, dense (small problems), from
    :func:`noise_blocks`."""
    poses, blocks = noise_blocks(problem, params, measured)
    m, slots, r, _ = blocks.shape
    dense = np.zeros((m, r, len(problem.q), 6))
    for k in range(slots):
        dense[np.arange(m), :, poses[:, k], :] += blocks[:, k]
    return dense.reshape(m * r, -1)


def _root(cov: np.ndarray) -> np.ndarray:
    """Symmetric square roots ``(N, 6, 6)`` of positive semi-definite covariances."""
    w, v = np.linalg.eigh(cov)
    return (v * np.sqrt(np.clip(w, 0.0, None))[:, None, :]) @ np.swapaxes(v, -1, -2)


def noise_factor(
    problem: Problem,
    noise: Noise,
    covariances: np.ndarray | None = None,
    params: np.ndarray | None = None,
    measured: bool = False,
) -> np.ndarray:
    """``Z`` ``(M, 6 N)`` with ``Z Z^T`` the covariance of the residual noise (``B S^(1/2)``),
    dense; ``measured`` as in :func:`noise_map`."""
    root = _root(pose_covariances(problem, noise, covariances, params))
    n = len(problem.q)
    blockdiag = np.zeros((n, 6, n, 6))
    blockdiag[np.arange(n), :, np.arange(n), :] = root
    return noise_map(problem, params, measured) @ blockdiag.reshape(6 * n, 6 * n)


def projected_noise_factor(
    problem: Problem,
    a: np.ndarray,
    noise: Noise,
    covariances: np.ndarray | None = None,
    params: np.ndarray | None = None,
) -> np.ndarray:
    """``A^T Z`` ``(k, 6 N)`` for a Jacobian ``A`` ``(M, k)``, without forming ``Z``: each
    measurement adds its rows' share to the poses it involves, in ``O(M k)`` time and memory (an
    all-pairs set of N poses has ``M ~ 3 N^2`` rows, and ``Z`` would hold ``M x 6 N`` numbers)."""
    poses, blocks = noise_blocks(problem, params)
    m, slots, r, _ = blocks.shape
    rows = a.reshape(m, r, -1)

    def share(block: np.ndarray) -> np.ndarray:  # rows^T block per measurement (m, k, 6)
        factors = row_factors(block) if r == 6 else None
        if factors is not None:  # one diagonal block (the plain weighting's first slot)
            return np.multiply(np.swapaxes(rows, 1, 2), factors, order="C")
        return np.swapaxes(rows, 1, 2) @ block  # (a batched product: einsum is 20x slower)

    shares = np.concatenate([share(blocks[:, k]) for k in range(slots)])
    # each pose's sum of its measurements' shares, slot by slot and measurement by measurement
    # (the order of a sequential sum): one sparse product instead of unbuffered additions
    incidence = scipy.sparse.csr_matrix(
        (np.ones(m * slots), (poses.T.ravel(), np.arange(m * slots))), (len(problem.q), m * slots)
    )
    out = (incidence @ shares.reshape(m * slots, -1)).reshape(-1, a.shape[1], 6)
    root = _root(pose_covariances(problem, noise, covariances, params))
    return np.concatenate(out @ root, axis=1)


def residual_covariance(
    problem: Problem,
    noise: Noise,
    covariances: np.ndarray | None = None,
    params: np.ndarray | None = None,
) -> np.ndarray:
    """Covariance ``(M, M)`` of the residual noise (small problems; it is dense)."""
    z = noise_factor(problem, noise, covariances, params)
    return z @ z.T


def whitener(z: np.ndarray) -> np.ndarray:
    """``W`` ``(r, M)`` with ``W Cov W^T = I_r`` and ``W^T W = Cov^+`` for ``Cov = Z Z^T``."""
    u, s, _ = np.linalg.svd(z, full_matrices=False)
    keep = s > _RANK_TOL * (s[0] if len(s) else 0.0)
    if not keep.any():
        raise RelcalError("the noise model is zero: give position/orientation or joint noise")
    return u[:, keep].T / s[keep, None]


# --- the noise level from a fit's residuals ------------------------------------------------------


def fitted_row_variances(
    problem: Problem, params: np.ndarray, a: np.ndarray, subset: np.ndarray
) -> np.ndarray:
    """What a least-squares fit leaves of unit pose noise in each unweighted residual row.

    With the residual noise ``e = B eps`` (:func:`noise_blocks`) and the fit's correction
    ``A G eps``, ``G = (A^T A)^-1 A^T B`` (``A`` and ``B`` with the problem's row weights, as the
    fit weighed them), the unweighted rows keep ``e_plain - A_plain G eps``. Its variance is
    ``|Z_row|^2 - 2 A_row G Z_row^T + A_row G G^T A_row^T`` (``Z = B_plain`` restricted to the
    translation or the rotation components of the pose errors): the rows' share of their noise,
    the pairs' sharing of poses (a pose counted twice) and the degrees of freedom the fit took
    (``m - k`` for independent rows) in one number per row.

    Parameters
    ----------
    problem : Problem
        The problem fitted (a formulation of :func:`noise_blocks`: relative, board or absolute).
    params : (P,) ndarray of float
        The estimate (the linearisation point).
    a : (M, P) ndarray of float
        The Jacobian of the fit's (weighted) residual rows at ``params``.
    subset : (k,) ndarray of int
        The estimated columns.

    Returns
    -------
    (m, r, 2) ndarray of float
        Per measurement and residual row (``r`` = 3 or 6, translation rows first) the expected
        square of the unweighted residual per unit variance of each pose error component in
        translation (``[..., 0]``, m^2 per m^2) and in rotation (``[..., 1]``, per rad^2).
    """
    subset = np.asarray(subset, dtype=int)
    rows = problem.rows_per_measurement
    a_fit = a[:, subset]
    # G = (A^T A)^-1 A^T B, per pose (N, k, 6): unit noise in both components, the identity root
    g = _inverse_scaled(a_fit.T @ a_fit) @ projected_noise_factor(
        problem, a_fit, Noise(1.0, 1.0), params=params
    )
    g = np.ascontiguousarray(np.swapaxes(g.reshape(len(subset), -1, 6), 0, 1))
    plain = unweighted(problem)
    a_plain = a_fit if plain is problem else residuals(plain, params)[1][:, subset]
    a_plain = a_plain.reshape(-1, rows, len(subset))
    poses, blocks = noise_blocks(plain, params)
    # A_row G_n per slot (the pose the slot involves): (m, r, 6) each
    fitted = [a_plain @ g[poses[:, s]] for s in range(blocks.shape[1])]
    out = np.empty((len(a_plain), rows, 2))
    for c, cols in enumerate((slice(0, 3), slice(3, 6))):
        own = sum(np.sum(blocks[:, s, :, cols] ** 2, axis=-1) for s in range(blocks.shape[1]))
        cross = sum(
            np.sum(fitted[s][..., cols] * blocks[:, s, :, cols], axis=-1)
            for s in range(blocks.shape[1])
        )
        gc = np.swapaxes(g[:, :, cols], 0, 1).reshape(len(subset), -1)
        share = np.sum((a_plain @ (gc @ gc.T)) * a_plain, axis=-1)  # A_row G G^T A_row^T
        out[..., c] = own - 2.0 * cross + share
    return out


def residual_noise(
    problem: Problem, params: np.ndarray, a: np.ndarray, subset: np.ndarray
) -> Noise:
    """The pose noise levels that explain the residuals a least-squares fit left, robustly.

    Each unweighted residual row, divided by the standard deviation the fit leaves it
    (:func:`fitted_row_variances` at the levels sought), is a unit normal where the noise
    model holds; the levels are those at which 1.4826 MAD of the translation rows, and of the
    rotation rows, so divided is one (outliers move a median little). A plain 1.4826 MAD of the
    rows instead measures the residuals, which are smaller than the noise: the fit takes ``k``
    of the ``m`` rows' degrees of freedom, and more than ``k`` where pairs share poses; with 30
    poses in consecutive pairs the standard deviations came out 8 % (full pose) to 25 %
    (positions) too small. The translation rows of frame-invariant pairs also carry the
    rotation noise over the lever of the relative motion, which is counted.

    Position-only measurements have no rotation rows: nothing separates the rotation noise, and
    the translation rows' whole scatter is taken as the position level (orientation 0).

    Parameters
    ----------
    problem, params, a, subset
        As for :func:`fitted_row_variances`.

    Returns
    -------
    Noise
        ``position`` (m) and ``orientation`` (rad), each at least 1e-12 (noise-free residuals).
    """
    rows = problem.rows_per_measurement
    r = residuals(unweighted(problem), params, jacobian=False).reshape(-1, rows)
    d = fitted_row_variances(problem, params, a, subset)
    floor = 1e-24
    groups = [(r[:, :3].ravel(), d[:, :3].reshape(-1, 2))]
    if rows == 6:
        groups.append((r[:, 3:].ravel(), d[:, 3:].reshape(-1, 2)))
    # rows the fit absorbs entirely (no variance left) carry nothing about the level
    live = [dd.sum(axis=1) > 1e-12 * dd.sum(axis=1).max(initial=0.0) for _, dd in groups]
    groups = [(x[keep], dd[keep]) for (x, dd), keep in zip(groups, live, strict=True)]
    if rows == 3:  # one level: the translation rows' scatter under position noise alone
        x, dd = groups[0]
        level = robust_scale(x / np.sqrt(dd[:, 0])) if len(x) else 0.0
        return Noise(position=max(level, 1e-12), orientation=0.0)
    mean = np.array([dd.mean(axis=0) for _, dd in groups])  # (group, component)
    start = np.array([robust_scale(x) ** 2 for x, _ in groups])
    var = np.clip(np.linalg.lstsq(mean, start, rcond=None)[0], floor, None)
    for _ in range(50):
        # each group's rows in units of the standard deviation the levels give them; their
        # robust scale says how far the group's mean variance is off
        spread = [dd @ var for _, dd in groups]
        scale = np.array(
            [robust_scale(x / np.sqrt(v)) for (x, _), v in zip(groups, spread, strict=True)]
        )
        new = np.linalg.lstsq(mean, scale**2 * [v.mean() for v in spread], rcond=None)[0]
        new = np.clip(new, floor, None)
        done = np.all(np.abs(scale - 1.0) < 1e-9) or np.array_equal(new, var)
        var = new
        if done:
            break
    return Noise(position=float(np.sqrt(var[0])), orientation=float(np.sqrt(var[1])))


# --- per-pose information (planning) -------------------------------------------------------------


def pose_rows(
    problem: Problem,
    noise: Noise,
    covariances: np.ndarray | None = None,
    params: np.ndarray | None = None,
) -> tuple[np.ndarray, int]:
    """Whitened per-pose Jacobians ``(N, r, P + h)`` and the nuisance size ``h``.

    Each pose's own error (``r`` = 6 rows, 3 for position-only published data) as a function of
    the parameters (``problem.full_layout``, ``P`` columns) and of what relative measurements
    cancel (``h`` nuisance columns last): the board pose ``W`` (6, frame-invariant), a constant
    offset of every row (published: the differences cancel it), nothing (absolute, and the board
    formulation, whose layout has ``W``'s columns ``board.*`` already). Eliminating
    the nuisance from the summed information ``sum_k R_k^T R_k`` gives the same information as
    any connected set of pairs weighted by its full covariance (the Cramer-Rao bound does not
    depend on the pairing), and the sum is additive over poses, which pose selection needs.
    """
    if problem.formulation in ("invariant", "board") and problem.measure == "position":
        raise RelcalError(
            f"per-pose information needs full-pose measurements for the {problem.formulation} "
            "formulation (relative positions, and positions in the measured camera's frame, do "
            "not split into these per-pose terms); use --measure pose"
        )
    n = len(problem.q)
    params = np.zeros(problem.full_layout.size) if params is None else params
    model, handeye = split_params(problem, params)
    tip, jac = pose_jacobian(model, problem.q, problem.layout)
    if problem.formulation in ("invariant", "board"):
        body = tf.rotate_twist(np.swapaxes(tip[:, :3, :3], -1, -2), jac)
        geo = tf.adjoint(tf.invert(handeye)) @ body
        he = np.broadcast_to(np.eye(6), (n, 6, 6))
        board = tf.adjoint(tf.invert(tip @ handeye))  # W -> W exp(w)
        if problem.formulation == "board" and np.any(params[-6:]):  # per unit of the 6-vector
            board = board @ tf.vector_tangent(params[-6:])
        if problem.formulation == "board" and np.any(params[-12:-6]):
            he = np.broadcast_to(tf.vector_tangent(params[-12:-6]), (n, 6, 6))
        rows = np.concatenate([geo, he, board], axis=-1)
        h = 6 if problem.formulation == "invariant" else 0
    elif problem.formulation == "published":  # differences cancel any constant offset
        offset = np.zeros((n, 6, problem.rows_per_measurement))
        offset[:, : problem.rows_per_measurement] = np.eye(problem.rows_per_measurement)
        rows, h = np.concatenate([jac, offset], axis=-1), problem.rows_per_measurement
    else:
        rows, h = jac, 0
    cov = pose_covariances(problem, noise, covariances, params)
    r = problem.rows_per_measurement
    rows, cov = rows[:, :r], cov[:, :r, :r]
    w, v = np.linalg.eigh(cov)
    if np.any(w <= 1e-30 * np.abs(w).max(initial=0.0)) or not np.all(w > 0):
        raise RelcalError(
            "the pose noise covariance is singular: give positive position and orientation noise"
        )
    inv_root = (v / np.sqrt(w)[:, None, :]) @ np.swapaxes(v, -1, -2)
    return inv_root @ rows, h


def eliminate(information: np.ndarray, h: int) -> np.ndarray:
    """Schur complement ``(..., P, P)`` of the last ``h`` (nuisance) rows and columns of
    information matrices ``(..., P + h, P + h)``."""
    if h == 0:
        return information
    a = information[..., :-h, :-h]
    b = information[..., :-h, -h:]
    c = information[..., -h:, -h:]
    return a - b @ np.linalg.solve(c, np.swapaxes(b, -1, -2))


# --- parameter covariance ------------------------------------------------------------------------


def _inverse_scaled(info: np.ndarray) -> np.ndarray:
    """Inverse of a symmetric information matrix, computed on unit-diagonal scaling; directions
    without information get an enormous (not infinite) variance."""
    d = np.sqrt(np.clip(np.diag(info), 1e-300, None))
    unit = info / np.outer(d, d)
    w, v = np.linalg.eigh(unit)
    w = np.clip(w, np.finfo(float).eps * max(w.max(initial=0.0), 1e-300), None)
    return (v / w) @ v.T / np.outer(d, d)


@dataclass(frozen=True)
class Uncertainty:
    """Covariance of the estimated parameters.

    ``crb`` and ``least_squares`` are ``(k, k)`` over ``subset`` (indices into ``names``), SI
    units (m, rad): the Cramer-Rao bound (the noise-weighted estimator) and the covariance of the
    problem's least-squares estimate (its pairs and row weights). ``estimator`` says which one
    :attr:`covariance` is. Parameters outside the subset are not estimated (held at nominal).
    ``crb`` may be given as a function of no arguments that computes it: it is then computed on
    first use (:func:`parameter_covariance` does so; the covariance of a least-squares fit needs
    only ``least_squares``).
    """

    names: tuple[str, ...]
    is_angle: np.ndarray  # (P,)
    subset: np.ndarray  # (k,)
    crb: np.ndarray = Deferred()  # (k, k); or a function of no arguments computing it
    least_squares: np.ndarray | None  # (k, k), None when not computed (pose planning)
    estimator: Estimator
    identifiable: np.ndarray  # (P,) individually identifiable (no share in the null space)
    units: tuple[str, ...] = ()  # SI unit per parameter (Layout.units); () means m or rad

    __getstate__ = resolved_state

    @property
    def covariance(self) -> np.ndarray:
        """``(k, k)`` covariance of the chosen estimator."""
        if self.estimator == "weighted" or self.least_squares is None:
            return self.crb
        return self.least_squares

    def _full(self, cov: np.ndarray) -> np.ndarray:
        out = np.full(len(self.names), np.nan)
        out[self.subset] = np.sqrt(np.diag(cov))
        return out

    @property
    def std(self) -> np.ndarray:
        """Standard deviations ``(P,)`` (m or rad) of the chosen estimator; NaN if not estimated."""
        return self._full(self.covariance)

    @property
    def crb_std(self) -> np.ndarray:
        """Cramer-Rao standard deviations ``(P,)``; NaN for parameters not estimated."""
        return self._full(self.crb)

    @property
    def least_squares_std(self) -> np.ndarray:
        """Least-squares standard deviations ``(P,)``; NaN for parameters not estimated (or all
        NaN when not computed)."""
        if self.least_squares is None:
            return np.full(len(self.names), np.nan)
        return self._full(self.least_squares)

    @property
    def correlation(self) -> np.ndarray:
        """Correlation matrix ``(k, k)`` of the estimated subset (chosen estimator)."""
        s = np.sqrt(np.diag(self.covariance))
        return self.covariance / np.outer(s, s)

    def strongest_correlations(self, count: int = 8) -> list[tuple[str, str, float]]:
        """The ``count`` most correlated pairs ``(name_a, name_b, rho)``, largest ``|rho|`` 1st."""
        corr = self.correlation
        i, j = np.triu_indices(len(corr), k=1)
        order = np.argsort(-np.abs(corr[i, j]), kind="stable")[:count]
        names = [self.names[k] for k in self.subset]
        return [(names[i[o]], names[j[o]], float(corr[i[o], j[o]])) for o in order]


def spanning_chain(problem: Problem) -> Problem:
    """``problem`` on consecutive pairs, when that carries the same information: its pairs connect
    every pose and each pair's measurement is a function of the chain's (full relative poses, or
    differences of base-frame errors). The Cramer-Rao bound then needs ``6 (N - 1)`` rows, however
    many pairs the problem has. Otherwise (absolute poses, relative positions in the camera frame,
    pairs that leave poses apart) ``problem`` itself."""
    n = len(problem.q)
    if problem.formulation in ("absolute", "board") or (
        problem.formulation == "invariant" and problem.measure == "position"
    ):
        return problem
    pairs = problem.pair_indices()
    graph = scipy.sparse.coo_matrix((np.ones(len(pairs)), tuple(pairs.T)), shape=(n, n))
    if scipy.sparse.csgraph.connected_components(graph, directed=False)[0] != 1:
        return problem
    return replace(problem, pairs=make_pairs(n, "consecutive"), pair_weights=None)


PER_POSE = ("absolute", "board")  # formulations whose every measurement is one pose's own


def pose_whiteners(
    problem: Problem,
    noise: Noise,
    covariances: np.ndarray | None = None,
    params: np.ndarray | None = None,
) -> np.ndarray:
    """Whitening blocks ``(N, r, r)`` of a formulation whose measurements are one pose each
    (:data:`PER_POSE`: board, absolute): block ``k`` times pose ``k``'s ``r`` residual rows (after
    the problem's row weights) has the identity covariance, ``W_k^T W_k = Cov_k^+``; the whole
    whitening is block diagonal, ``O(N)`` numbers where :func:`whitener` of
    :func:`noise_factor` would hold ``(r N)^2`` and take an SVD of that size.

    Directions whose variance is below ``_RANK_TOL^2`` of the largest (over all poses; e.g.
    orientation rows without orientation noise) get a zero row, as :func:`whitener` leaves them
    out.

    Raises
    ------
    RelcalError
        The problem is not of a per-pose formulation, or the noise model is zero.
    """
    if problem.formulation not in PER_POSE:
        raise RelcalError(
            f"per-pose whitening: the {problem.formulation} formulation's measurements share "
            "poses (use whitener(noise_factor(...)))"
        )
    params = np.zeros(problem.full_layout.size) if params is None else params
    _, blocks = noise_blocks(problem, params)
    root = _root(pose_covariances(problem, noise, covariances, params))
    factor = blocks[:, 0] @ root  # (N, r, 6): each pose's residual noise is factor @ unit noise
    cov = factor @ np.swapaxes(factor, -1, -2)
    w, v = np.linalg.eigh(cov)
    top = max(float(w.max(initial=0.0)), 1e-300)
    keep = w > _RANK_TOL**2 * top
    if not keep.any():
        raise RelcalError("the noise model is zero: give position/orientation or joint noise")
    inv = np.where(keep, 1.0 / np.sqrt(np.where(keep, w, 1.0)), 0.0)
    return inv[:, :, None] * np.swapaxes(v, -1, -2)


def pose_whitener(
    problem: Problem,
    noise: Noise,
    covariances: np.ndarray | None = None,
    params: np.ndarray | None = None,
) -> scipy.sparse.csr_matrix:
    """The block-diagonal whitening ``(M, M)`` of :func:`pose_whiteners` as a sparse matrix
    (``r^2 N`` stored numbers), for the solvers' ``whiten`` (``whiten @ r``, ``whiten @ A``: time
    and memory linear in the poses)."""
    blocks = pose_whiteners(problem, noise, covariances, params)
    n, r, _ = blocks.shape
    columns = np.arange(n)[:, None, None] * r + np.arange(r)  # each row's block of columns
    indices = np.broadcast_to(columns, blocks.shape).reshape(-1)
    indptr = np.arange(0, n * r * r + 1, r)
    return scipy.sparse.csr_matrix((blocks.reshape(-1), indices, indptr), shape=(n * r, n * r))


def _per_pose_whitened(
    problem: Problem,
    a: np.ndarray,
    noise: Noise,
    covariances: np.ndarray | None,
    params: np.ndarray,
) -> np.ndarray:
    """``A`` ``(r N, k)`` of a per-pose formulation (board) whitened pose by pose
    (:func:`pose_whiteners`), in ``O(N k)``; the dense whitener of :func:`noise_factor` would
    hold ``(r N)^2`` numbers. Poses whose covariance is singular (no noise at all) are left out
    of the information."""
    blocks = pose_whiteners(problem, noise, covariances, params)
    rows = a.reshape(len(blocks), blocks.shape[1], -1)
    return (blocks @ rows).reshape(-1, a.shape[1])


def parameter_covariance(
    problem: Problem,
    noise: Noise,
    identifiability: Identifiability | None = None,
    covariances: np.ndarray | None = None,
    params: np.ndarray | None = None,
    estimator: Estimator = "least_squares",
    subset: np.ndarray | None = None,
) -> Uncertainty:
    """Covariance of the parameters estimated on the identifiable subset.

    Parameters
    ----------
    problem : the identification problem (its poses only matter for ``covariances``).
    noise : standard deviations of the measured pose (m, rad) and of the joint readings (rad).
    identifiability : the analysis giving the subset (default :func:`analyse_problem`).
    covariances : ``(N, 6, 6)`` per-pose covariances of ``to_vector(C_k)`` (replace the isotropic
        pose noise; joint noise still adds).
    params : linearisation point, ``problem.full_layout`` (default nominal, zeros).
    estimator : ``least_squares`` (relcal's ``identify``) or ``weighted`` (the Cramer-Rao bound).
    subset : parameter indices to estimate (default ``identifiability.subset``).
    """
    from relcal.calibration.identifiability import analyse_problem

    params = np.zeros(problem.full_layout.size) if params is None else np.asarray(params, float)
    ident = identifiability or analyse_problem(problem)
    subset = np.sort(np.asarray(ident.subset if subset is None else subset, dtype=int))
    if estimator not in ("least_squares", "weighted"):
        raise ValueError(f"unknown estimator '{estimator}': use least_squares or weighted")
    silent = not np.any(noise.joints) and not np.any(
        noise.pose_covariance() if covariances is None else covariances
    )
    if silent:  # what the bound's whitening would find, said before it is deferred
        raise RelcalError("the noise model is zero: give position/orientation or joint noise")
    _, a = residuals(problem, params, model_jacobian=True)
    a = a[:, subset]

    def bound() -> np.ndarray:  # the Cramer-Rao bound, computed when first asked for
        if problem.formulation == "board":  # independent poses: a block-diagonal whitening
            wa = _per_pose_whitened(problem, a, noise, covariances, params)
        else:
            chain = spanning_chain(problem)
            same = chain is problem
            a_chain = a if same else residuals(chain, params, model_jacobian=True)[1][:, subset]
            wa = whitener(noise_factor(chain, noise, covariances, params)) @ a_chain
        crb = _inverse_scaled(wa.T @ wa)
        return 0.5 * (crb + crb.T)

    kz = _inverse_scaled(a.T @ a) @ projected_noise_factor(problem, a, noise, covariances, params)
    ls = kz @ kz.T
    identifiable = np.zeros(problem.full_layout.size, dtype=bool)
    identifiable[: len(ident.identifiable)] = ident.identifiable  # shorter: hand-eye known
    return Uncertainty(
        names=problem.full_layout.names,
        is_angle=problem.full_layout.is_angle(),
        units=problem.full_layout.units(),
        subset=subset,
        crb=bound,
        least_squares=0.5 * (ls + ls.T),
        estimator=estimator,
        identifiable=identifiable,
    )


# --- predicted accuracy --------------------------------------------------------------------------


@dataclass(frozen=True)
class Accuracy:
    """Predicted relative-pose errors after calibration, from the parameter covariance alone.

    Per validation pair: the RMS (expected root-mean-square over repeated calibrations) of the
    position error (m) and of the rotation error (rad) of the predicted relative pose.
    """

    pairs: np.ndarray  # (P, 2) indices into the validation poses
    position: np.ndarray  # (P,) m
    orientation: np.ndarray  # (P,) rad


def predicted_accuracy(
    problem: Problem,
    uncertainty: Uncertainty,
    q_validation: np.ndarray,
    pairing: PairStrategy = "all",
    params: np.ndarray | None = None,
) -> Accuracy:
    """Propagate the parameter covariance to relative poses between validation configurations
    ``(V, n)``: ``Cov(pair) = A_pair Cov(p) A_pair^T`` with the problem's formulation (unweighted,
    full pose). The board formulation's too are relative poses (frame-invariant pairs, which the
    board transform does not move), as a calibration validates it."""
    q_validation = np.atleast_2d(np.asarray(q_validation, dtype=float))
    n = len(q_validation)
    pairs = make_pairs(n, pairing)
    relative = "invariant" if problem.formulation == "board" else problem.formulation
    shell = replace(
        problem,
        q=q_validation,
        poses=np.broadcast_to(np.eye(4), (n, 4, 4)),
        formulation=relative,
        pairs=pairs,
        measure="pose",
        weights=None,
        pair_weights=None,
    )
    params = np.zeros(problem.full_layout.size) if params is None else params
    _, a = residuals(shell, params[: shell.full_layout.size], model_jacobian=True)
    if shell.full_layout.size < len(params):  # the board's columns: no effect on relative poses
        a = np.pad(a, ((0, 0), (0, len(params) - shell.full_layout.size)))
    a = a[:, uncertainty.subset].reshape(-1, 6, len(uncertainty.subset))
    cov = a @ uncertainty.covariance @ np.swapaxes(a, -1, -2)  # (P, 6, 6)
    diag = np.clip(np.diagonal(cov, axis1=-2, axis2=-1), 0.0, None)
    if problem.formulation == "absolute":
        pairs = np.stack([np.arange(n), np.arange(n)], axis=1)
    return Accuracy(
        pairs=pairs,
        position=np.sqrt(diag[:, :3].sum(axis=1)),
        orientation=np.sqrt(diag[:, 3:].sum(axis=1)),
    )


# --- clustered samples (coincidence placements) --------------------------------------------------

INDEPENDENT = "independent samples"
DESIGN_EFFECT = "placement design effect"


@dataclass(frozen=True)
class ClusteredCovariance:
    """Covariance of a least-squares estimate whose residuals are correlated within clusters
    (the samples of one placement of a coincidence plate share its systematic errors).

    ``covariance`` and ``independent`` are ``(P, P)`` (SI units, NaN outside the estimated
    subset): the clustered one and ``s^2 (A^T A)^-1`` of independent samples. ``inflation`` is
    their ratio (``>= 1``), ``estimated`` the design effect before it was floored at 1, ``dof``
    the degrees of freedom of that estimate (Satterthwaite; ``inf`` when nothing is estimated),
    ``clusters`` the number of clusters and ``method`` which covariance it is
    (:data:`DESIGN_EFFECT`, or :data:`INDEPENDENT` with fewer than two clusters).
    """

    covariance: np.ndarray
    independent: np.ndarray
    method: str
    inflation: float
    estimated: float
    dof: float
    clusters: int

    def settings(self) -> dict:
        """What ``results.json`` and the registry record say about it (``settings.covariance``)."""
        return {
            "method": self.method,
            "clusters": self.clusters,
            "inflation": float(self.inflation),
            "design_effect": float(self.estimated) if np.isfinite(self.estimated) else None,
            "dof": float(self.dof) if np.isfinite(self.dof) else None,
        }


def design_effect(
    jac: np.ndarray, r: np.ndarray, clusters: np.ndarray
) -> tuple[float, float, float]:
    """The placement design effect of a least-squares fit: how much the clusters' scores vary
    beyond what independent residuals of the same size would give.

    Parameters
    ----------
    jac : (M, k) ndarray
        Jacobian of the (weighted) residual rows on the estimated parameters (any units: the
        columns are scaled to unit norm inside).
    r : (M,) ndarray
        The residuals at the estimate (the fit's normal equations hold: ``jac^T r ~ 0``).
    clusters : (M,) ndarray of int
        The cluster of each row (e.g. the placement of its sample).

    Returns
    -------
    effect : float
        ``Q / E0[Q]`` with ``Q = sum_c g_c^T H^-1 g_c`` (``g_c = A_c^T r_c`` the cluster's score,
        ``H = A^T A``) and ``E0[Q] = s^2 sum_c tr(H^-1 (H_c - H_c H^-1 H_c))`` its exact mean for
        independent rows of variance ``s^2 = |r|^2 / (M - k)`` (``H_c = A_c^T A_c``): 1 on
        average for independent samples, the average variance ratio of the estimate over the
        parameter directions when rows are correlated within clusters.
    dof : float
        Satterthwaite degrees of freedom of ``Q`` for independent Gaussian rows
        (``E0[Q]^2 / (Var0[Q] / 2)``).
    s2 : float
        The residual variance ``s^2``.

    Raises
    ------
    RelcalError
        When ``jac``, ``r`` and ``clusters`` do not have one row each.
    """
    jac = np.asarray(jac, dtype=float)
    r = np.asarray(r, dtype=float)
    m, k = jac.shape
    if len(r) != m or len(clusters) != m:
        raise RelcalError(f"{m} Jacobian rows, {len(r)} residuals, {len(clusters)} clusters")
    norms = np.linalg.norm(jac, axis=0)
    unit = jac / np.where(norms > 0, norms, 1.0)
    h_inv = np.linalg.pinv(unit.T @ unit, hermitian=True)
    s2 = float(r @ r) / max(m - k, 1)
    labels = np.unique(clusters)
    parts = [
        (unit[clusters == c].T @ unit[clusters == c], unit[clusters == c].T @ r[clusters == c])
        for c in labels
    ]
    q = sum(float(g @ h_inv @ g) for _, g in parts)
    hh = [h_inv @ hc for hc, _ in parts]  # H^-1 H_c
    mean = sum(float(np.trace(x) - np.trace(x @ x)) for x in hh)
    # Var0[Q] = 2 s^4 tr((B Sigma)^2), Sigma_cd = delta_cd H_c - H_c H^-1 H_d, B = diag(H^-1):
    # (B Sigma)_cd = delta_cd X_c - X_c X_d with X_c = H^-1 H_c, so that
    # tr((B Sigma)^2) = sum_cd tr(T_cd T_dc) = sum_c [tr(X_c^2) - 2 tr(X_c^3)] + tr(S^2) with
    # S = sum_c X_c^2 (the c != d terms are tr(X_c^2 X_d^2), cyclic): linear in the clusters
    # (:func:`_square_pairwise` is the double sum itself, for the tests).
    squares = [x @ x for x in hh]
    total = sum(squares, np.zeros_like(h_inv))
    square = sum(
        float(np.trace(x2) - 2.0 * np.sum(x2 * x.T)) for x, x2 in zip(hh, squares, strict=True)
    )
    square += float(np.sum(total * total.T))
    if mean <= 0 or s2 <= 0:
        return 1.0, float("inf"), s2
    dof = mean**2 / square if square > 0 else float("inf")
    return q / (s2 * mean), dof, s2


def _square_pairwise(hh: list[np.ndarray]) -> float:
    """``sum_cd tr(T_cd T_dc)`` with ``T_cd = delta_cd X_c - X_c X_d`` summed pair by pair
    (quadratic in the clusters): the reference :func:`design_effect`'s linear form is tested
    against."""
    square = 0.0
    for c, xc in enumerate(hh):
        for d, xd in enumerate(hh):
            t_cd = (xc if c == d else 0.0) - xc @ xd
            t_dc = (xd if c == d else 0.0) - xd @ xc
            square += float(np.trace(t_cd @ t_dc))
    return square


def least_squares_covariance(jac: np.ndarray, r: np.ndarray, subset: np.ndarray) -> np.ndarray:
    """``s^2 (A^T A)^-1`` of the columns ``subset`` of ``jac`` ``(M, P)``, with ``s^2 = |r|^2 /
    (M - k)``, embedded in a ``(P, P)`` matrix that is NaN outside the subset."""
    n = jac.shape[1]
    cov = np.full((n, n), np.nan)
    if len(subset) == 0:
        return cov
    unit, norms = scaled(jac[:, subset])
    s2 = float(r @ r) / max(len(r) - len(subset), 1)
    inv = np.linalg.pinv(unit.T @ unit, hermitian=True)
    cov[np.ix_(subset, subset)] = s2 * inv / np.outer(norms, norms)
    return cov


def clustered_covariance(
    jac: np.ndarray, r: np.ndarray, subset: np.ndarray, clusters: np.ndarray
) -> ClusteredCovariance:
    """Covariance of a least-squares estimate from rows correlated within ``clusters``.

    The independent-samples covariance ``s^2 (A^T A)^-1`` (:func:`least_squares_covariance`
    form) scaled by the clusters' design effect (:func:`design_effect`), floored at 1 (fewer
    than two clusters: nothing to estimate it from, the independent covariance is kept).

    A per-direction estimate (the cluster-robust sandwich ``H^-1 (sum_c g_c g_c^T) H^-1``, or
    the jackknife over clusters) has rank at most ``G - 1`` with ``G`` clusters: with the 3 to 9
    placements of a coincidence calibration and its 20 to 30 shared parameters it leaves most
    directions without any variance, so one factor for every direction, estimated from all
    clusters' scores at once, is what such data support.

    Parameters
    ----------
    jac : (M, P) ndarray
        Jacobian of the weighted residual rows (relcal's sign), SI units per parameter.
    r : (M,) ndarray
        Weighted residuals at the estimate.
    subset : (k,) ndarray of int
        The estimated parameters (columns of ``jac``).
    clusters : (M,) ndarray of int
        The cluster of each row.

    Returns
    -------
    ClusteredCovariance
    """
    subset = np.asarray(subset, dtype=int)
    clusters = np.asarray(clusters)
    independent = least_squares_covariance(jac, r, subset)
    count = len(np.unique(clusters))
    if count < 2 or len(subset) == 0:
        return ClusteredCovariance(
            independent, independent, INDEPENDENT, 1.0, float("nan"), float("inf"), count
        )
    effect, dof, _ = design_effect(jac[:, subset], r, clusters)
    inflation = max(effect, 1.0)
    return ClusteredCovariance(
        independent * inflation, independent, DESIGN_EFFECT, inflation, effect, dof, count
    )
