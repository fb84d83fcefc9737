"""Identification: the published iterated SVD least squares, and Levenberg-Marquardt.

Both take a :class:`measurement.Problem` and return a :class:`Result` with the parameter
estimate (errors relative to the nominal model, SI units), convergence, cost, rank and the
identifiability analysis at the nominal model.
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
import scipy.linalg
import scipy.optimize

from relcal import geometry as tf
from relcal.calibration.blas import one_blas_thread
from relcal.calibration.identifiability import (
    DEFAULT_RCOND,
    Identifiability,
    analyse_problem,
    scaled,
)
from relcal.calibration.measurement import (
    Problem,
    check_measured,
    derived,
    pair_errors,
    residuals,
    row_clusters,
)
from relcal.calibration.noise import Noise
from relcal.calibration.uncertainty import (
    PER_POSE,
    ClusteredCovariance,
    clustered_covariance,
    least_squares_covariance,
    noise_factor,
    parameter_covariance,
    pose_whitener,
    residual_noise,
    whitener,
)
from relcal.errors import ArgumentError, RelcalError
from relcal.robot.kinematics import Layout, errors_applied

Method = Literal["published", "lm"]
Loss = Literal["linear", "huber", "soft_l1", "cauchy", "arctan"]


@dataclass(frozen=True)
class SolverOptions:
    """How :func:`identify` solves.

    ``method``: ``"lm"`` (Levenberg-Marquardt) or ``"published"`` (iterated truncated-SVD
    least squares, Lu & Hayes), both on the identifiable subset, the rest held at nominal.
    ``loss`` and ``f_scale`` (the residual, in weighted units, where a robust loss bends) apply
    to both, the same cost (``"published"`` reweights its iterations, :func:`identify_published`);
    ``rcond`` (singular values below ``rcond * s_max`` zeroed) and ``tol`` (relative step size
    that stops the iteration) to ``"published"``.

    Parameters
    ----------
    method : {"lm", "published"}
        The solver.
    loss : {"linear", "huber", "soft_l1", "cauchy", "arctan"}
        Loss of the weighted residuals (SciPy's names), for either method.
    f_scale : float
        Where a robust loss bends, in weighted residual units (> 0).
    max_iterations : int
        Most iterations (``"published"``) or residual evaluations (``"lm"``, SciPy's
        ``max_nfev``), > 0.
    rcond : float
        ``"published"``: relative singular value threshold, 0 < rcond < 1.
    tol : float
        ``"published"``: relative step size that stops the iteration (> 0).

    Raises
    ------
    ArgumentError
        An unknown method or loss, or a number out of its range.
    """

    method: Method = "lm"
    loss: Loss = "linear"
    f_scale: float = 1.0
    max_iterations: int = 200
    rcond: float = 1e-8
    tol: float = 1e-12

    def __post_init__(self) -> None:
        from relcal.checks import check_choice, check_number

        check_choice(self.method, "SolverOptions.method", ("published", "lm"))
        check_choice(self.loss, "SolverOptions.loss", Loss.__args__)
        check_number(self.f_scale, "SolverOptions.f_scale", 0, low_open=True)
        check_number(self.max_iterations, "SolverOptions.max_iterations", 1, integer=True)
        check_number(self.rcond, "SolverOptions.rcond", 0, 1, low_open=True, high_open=True)
        check_number(self.tol, "SolverOptions.tol", 0, low_open=True)


@dataclass(frozen=True)
class Result:
    """Outcome of one identification (the shape of robot_cal_tools' results).

    ``params`` ``(P,)`` follows ``problem.full_layout`` (errors from nominal, m and rad).
    ``covariance`` ``(P, P)`` of the estimated subset, NaN for parameters held at nominal: for
    relative measurements (pairs share poses, so their residuals correlate) the least-squares
    covariance of :func:`uncertainty.parameter_covariance` with the pose noise estimated from
    the residuals (:func:`uncertainty.residual_noise`; absolute poses too); for tracker points
    ``s^2 (A^T A)^-1``; for the
    noise-weighted estimator its Cramer-Rao form. Computed on first use. Costs are
    ``0.5 |r|^2`` per residual row, weighted as solved.

    Parameters
    ----------
    params : (P,) ndarray of float
        The estimated errors from nominal (m, rad, ...), following ``problem.full_layout``.
    names : tuple of str
        ``P`` parameter names.
    stopped : bool
        The solver's own stopping rule was met (see :attr:`converged`).
    iterations : int
        Iterations (or Jacobian evaluations) used.
    initial_residual_norm, residual_norm : float
        Norm of the weighted residual vector at the start and at the estimate.
    n_residuals : int
        Number of residual rows.
    rank : int
        Number of parameters estimated (the identifiable subset).
    seconds : float
        Wall time of the solve, s.
    method : str
        The solver used (``lm``, ``published``, ...).
    identifiability : Identifiability
        The analysis at the nominal model that chose the subset.
    problem : Problem
        The problem solved.
    whiten : ndarray of float or None
        The whitening applied to the residuals, when the noise-weighted estimator was used.
    noise : Noise or None
        The pose noise for the covariance; None: estimated from the residuals.
    loss : str
        The loss of the fit.
    f_scale : float
        Where the robust loss bends, weighted residual units.
    prior : (P,) ndarray of float or None
        Maximum a posteriori fits: the factors of the prior rows ``prior[k] * params[k]``
        appended to the weighted residual (weighted-residual units per unit of parameter; 0: no
        row). None: a plain least-squares fit.
    prior_std : (P,) ndarray of float or None
        The priors' standard deviations (m, rad; inf: no prior), or None.
    """

    params: np.ndarray
    names: tuple[str, ...]
    stopped: bool  # the solver's own stopping rule was met (see :attr:`converged`)
    iterations: int
    initial_residual_norm: float
    residual_norm: float
    n_residuals: int
    rank: int
    seconds: float
    method: str
    identifiability: Identifiability
    problem: Problem = field(repr=False, compare=False)
    whiten: np.ndarray | None = field(default=None, repr=False, compare=False)
    noise: Noise | None = field(default=None, compare=False)  # pose noise; default: from r
    loss: str = "linear"
    f_scale: float = 1.0
    # Maximum a posteriori fits: the prior rows ``prior[k] * params[k]`` appended to the
    # weighted residual (``(P,)``, weighted-residual units per unit of parameter; 0: no row),
    # and the priors' standard deviations ``(P,)`` in SI units (inf: none). None: plain fit.
    prior: np.ndarray | None = field(default=None, repr=False, compare=False)
    prior_std: np.ndarray | None = field(default=None, repr=False, compare=False)

    @functools.cached_property
    def gradient_check(self) -> GradientCheck:
        """The stationarity of the stated cost at :attr:`params`, from finite differences of
        the real residual (not the solver's Jacobian): :func:`gradient_check`."""
        return gradient_check(
            self.problem,
            self.params,
            self.identifiability.subset,
            self.loss,
            self.f_scale,
            self.whiten,
            prior=self.prior,
        )

    @property
    def converged(self) -> bool:
        """At the optimum of the stated cost: the solver stopped by its rule *and* the
        finite-difference gradient of the cost vanishes there (:attr:`gradient_check`)."""
        return bool(self.stopped and self.gradient_check.passed)

    def __repr__(self) -> str:
        from relcal._repr import short

        return short(
            "Result",
            "",
            "converged" if self.converged else "NOT converged",
            f"{self.method}, {self.iterations} iterations",
            f"rank {self.rank} of {len(self.params)} parameters",
            f"cost per observation {self.initial_cost_per_observation:.3g} -> "
            f"{self.final_cost_per_observation:.3g}",
        )

    @functools.cached_property
    def identifiable(self) -> np.ndarray:
        """``(P,)`` bool: determined by the data given the estimated subset (the others held at
        nominal): no share in the null space at the nominal model, and an estimate that does
        not move when the parameters held at nominal take other values (a curved symmetry can
        draw a parameter outside the nominal null space into a combination; this finds it)."""
        return self.identifiability.identifiable & ~held_dependence(
            self.problem, self.params, self.identifiability, self.whiten, self.method, self.prior
        )

    @functools.cached_property
    def clustered(self) -> ClusteredCovariance | None:
        """The covariance of rows correlated within clusters (coincidence: the placements) and
        how it was computed (:func:`relcal.calibration.uncertainty.clustered_covariance`); None
        for independent rows. Computed once: :attr:`data_covariance` and the record's settings
        share it."""
        clusters = None if self.whiten is not None else row_clusters(self.problem)
        if clusters is None:
            return None
        r, a = residuals(self.problem, self.params)
        return clustered_covariance(a, r, self.identifiability.subset, clusters)

    @functools.cached_property
    def data_covariance(self) -> np.ndarray:
        """Covariance ``(P, P)`` of the estimate from the data alone, as if the fit had no
        priors (m, rad; NaN for parameters held at nominal): :attr:`covariance` without the
        prior rows. Computed once: :attr:`covariance` and the weak-direction check share it."""
        if self.clustered is not None:
            return self.clustered.covariance
        return result_covariance(
            self.problem, self.params, self.identifiability, self.whiten, self.noise
        )

    @functools.cached_property
    def covariance(self) -> np.ndarray:
        """Covariance ``(P, P)`` of the estimate (m, rad; NaN for parameters held at nominal):
        the data's (:attr:`data_covariance`), combined with the priors when the fit had them
        (maximum a posteriori)."""
        if self.prior_std is None:
            return self.data_covariance
        return posterior_covariance(
            self.data_covariance, self.prior_std, self.identifiability.subset
        )

    @property
    def unidentifiable(self) -> list[str]:
        """The unidentifiable combinations, each described in words with its reason."""
        return [c.describe() for c in self.identifiability.combinations]

    @property
    def initial_cost_per_observation(self) -> float:
        """``0.5 |r|^2 / n_residuals`` at the start (weighted residual units squared)."""
        return 0.5 * self.initial_residual_norm**2 / self.n_residuals

    @property
    def final_cost_per_observation(self) -> float:
        """``0.5 |r|^2 / n_residuals`` at the estimate (weighted residual units squared)."""
        return 0.5 * self.residual_norm**2 / self.n_residuals

    @property
    def std(self) -> np.ndarray:
        """Standard deviations ``(P,)`` (NaN where not estimated)."""
        return np.sqrt(np.diagonal(self.covariance))

    @property
    def correlation(self) -> np.ndarray:
        """Correlation matrix ``(P, P)`` of the estimate (NaN where not estimated)."""
        std = self.std
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.covariance / np.outer(std, std)

    def labelled_covariance(self) -> dict[str, dict[str, float]]:
        """The covariance by parameter name, over the estimated parameters.

        Returns
        -------
        dict of str to dict of str to float
            ``{name: {name: covariance}}`` in SI units (m^2, m rad, rad^2).
        """
        est = np.flatnonzero(np.isfinite(self.std))
        return {
            self.names[i]: {self.names[j]: float(self.covariance[i, j]) for j in est} for i in est
        }

    def strongest_correlations(self, count: int = 10) -> list[tuple[str, str, float]]:
        """The strongest correlations between two estimated parameters.

        Parameters
        ----------
        count : int
            How many pairs to return.

        Returns
        -------
        list of (str, str, float)
            Up to ``count`` pairs ``(name_a, name_b, rho)``, largest ``|rho|`` first.
        """
        rho = self.correlation
        i, j = np.triu_indices(len(rho), k=1)
        keep = np.isfinite(rho[i, j])
        i, j = i[keep], j[keep]
        order = np.argsort(-np.abs(rho[i, j]))[:count]
        return [(self.names[i[k]], self.names[j[k]], float(rho[i[k], j[k]])) for k in order]


GRADIENT_TOL = 1e-6  # share of the cost a Gauss-Newton step could still remove
FD_STEP = 1e-7  # finite-difference step, SI units (m, rad, ...)
NULL_COLUMN = 1e-6  # a finite-difference column below this share of the largest: a symmetry
ROUND_OFF = 1e-10  # RMS error (m, rad; unweighted) below which a fit is exact to round-off


@dataclass(frozen=True)
class GradientCheck:
    """Stationarity of the stated cost, measured by finite differences.

    ``decrement``: the share of the cost ``|r|^2`` (robust losses: their reweighted residual) that
    one Gauss-Newton step on the finite-difference Jacobian could still remove,
    ``|P r|^2 / |r|^2`` with ``P`` the projection on the Jacobian's columns; it vanishes exactly
    where the gradient does. ``max_cosine``: the largest ``|cos|`` between the residual and one
    column (MINPACK's gradient test). ``passed``: ``decrement <= tolerance``, or a residual at
    round-off level (an exact fit). ``evaluations``: residual evaluations the check took.
    """

    passed: bool
    decrement: float
    max_cosine: float
    tolerance: float
    evaluations: int


def gradient_check(
    problem: Problem,
    params: np.ndarray,
    columns: np.ndarray,
    loss: str = "linear",
    f_scale: float = 1.0,
    whiten: np.ndarray | None = None,
    tolerance: float = GRADIENT_TOL,
    prior: np.ndarray | None = None,
) -> GradientCheck:
    """Whether ``params`` ``(P,)`` is a stationary point of the stated cost over ``columns``.

    The cost is ``0.5 sum rho((w r)^2)`` of the problem's weighted residual ``r`` (whitened by
    ``whiten`` ``(R, M)`` if given; ``rho`` the ``loss`` bending at ``f_scale``, SciPy's
    definitions). Each column of the Jacobian is a forward difference of the residual itself
    (step :data:`FD_STEP` in SI units), never the solver's analytic Jacobian, so a wrong
    Jacobian cannot certify its own fixed point. Forward differences suffice: their relative
    error (about ``FD_STEP``) moves the measured decrement by far less than its tolerance.
    ``prior`` ``(P,)``: the prior rows ``prior[k] * x[k]`` of a maximum a posteriori fit, appended
    for the ``columns`` where it is positive (:func:`prior_rows`); they bend with the loss too.
    """
    params = np.asarray(params, dtype=float)
    columns = np.asarray(columns, dtype=int)
    rows = prior_rows(prior, columns)

    def real(x: np.ndarray) -> np.ndarray:
        r = residuals(problem, x, jacobian=False)
        r = r if whiten is None else whiten @ r
        return r if rows is None else np.r_[r, rows[1] * x[rows[0]]]

    r = real(params)
    jac = np.empty((len(r), len(columns)))
    for k, c in enumerate(columns):
        step = np.zeros_like(params)
        step[c] = FD_STEP
        jac[:, k] = (real(params + step) - r) / FD_STEP
    if loss != "linear":  # the reweighted residual whose Gauss-Newton gradient is the cost's
        z = (r / f_scale) ** 2
        weight = np.sqrt(_loss_derivative(loss, z))
        r, jac = weight * r, weight[:, None] * jac
    norm2 = float(r @ r)
    errors = pair_errors(problem, params)  # unweighted, m and rad: weights scale round-off too
    exact = bool(np.sqrt(np.nanmean(errors**2)) <= ROUND_OFF)
    decrement, cosine = 0.0, 0.0
    col = np.linalg.norm(jac, axis=0)
    # Columns at round-off level are exact symmetries (the cost does not depend on them); scaled
    # to unit norm their noise would look like a gradient.
    live = col > NULL_COLUMN * max(float(col.max(initial=0.0)), 1e-300)
    if norm2 > 0 and live.any():
        unit = jac[:, live] / col[live]
        u, sv, _ = np.linalg.svd(unit, full_matrices=False)
        u = u[:, sv > DEFAULT_RCOND * sv[0]]  # the rank tolerance of the identifiability test
        decrement = float(np.sum((u.T @ r) ** 2) / norm2)
        cosine = float(np.max(np.abs(unit.T @ r)) / np.sqrt(norm2))
    passed = bool(np.isfinite(norm2) and (exact or decrement <= tolerance))
    return GradientCheck(passed, decrement, cosine, tolerance, 1 + len(columns))


def _loss_derivative(loss: str, z: np.ndarray) -> np.ndarray:
    """``rho'(z)`` of SciPy's robust losses at ``z = (r / f_scale)^2``."""
    if loss == "huber":
        return np.where(z <= 1, 1.0, 1 / np.sqrt(np.maximum(z, 1e-300)))
    if loss == "soft_l1":
        return 1 / np.sqrt(1 + z)
    if loss == "cauchy":
        return 1 / (1 + z)
    if loss == "arctan":
        return 1 / (1 + z**2)
    return np.ones_like(z)


def _cost_root(r: np.ndarray, loss: str, f_scale: float) -> float:
    """The root of ``sum f_scale^2 rho((r / f_scale)^2)`` of SciPy's losses (twice the cost that
    :func:`scipy.optimize.least_squares` minimises): ``|r|`` for the linear one."""
    if loss == "linear":
        return float(np.linalg.norm(r))
    z = (r / f_scale) ** 2
    if loss == "huber":
        rho = np.where(z <= 1, z, 2 * np.sqrt(z) - 1)
    elif loss == "soft_l1":
        rho = 2 * (np.sqrt(1 + z) - 1)
    elif loss == "cauchy":
        rho = np.log1p(z)
    else:  # arctan
        rho = np.arctan(z)
    return float(f_scale * np.sqrt(np.sum(rho)))


def prior_rows(
    prior: np.ndarray | None, columns: np.ndarray
) -> tuple[np.ndarray, np.ndarray] | None:
    """The parameters (among ``columns``) that have a prior row, and the rows' weights; None
    when there are none (a plain fit)."""
    if prior is None:
        return None
    columns = np.asarray(columns, dtype=int)
    keep = columns[np.asarray(prior, float)[columns] > 0]
    if not len(keep):
        return None
    return keep, np.asarray(prior, float)[keep]


def _prior_jacobian(rows: tuple[np.ndarray, np.ndarray] | None, subset: np.ndarray):
    """Where the parameters of the prior ``rows`` (:func:`prior_rows`) sit in ``subset``, and the
    rows' Jacobian ``(R, len(subset))`` over it (``rows[1]`` on those positions); ``(None, None)``
    without prior rows."""
    if rows is None:
        return None, None
    at = np.searchsorted(subset, rows[0])
    jac = np.zeros((len(at), len(subset)))
    jac[np.arange(len(at)), at] = rows[1]
    return at, jac


def posterior_covariance(data: np.ndarray, std: np.ndarray, subset: np.ndarray) -> np.ndarray:
    """The covariance ``(P, P)`` of a maximum a posteriori estimate: the data's covariance
    ``data`` (NaN outside ``subset``; it may be singular along weak directions) combined with
    independent priors of standard deviations ``std`` ``(P,)`` (inf: none),
    ``(C^+ + diag(1 / std^2))^-1`` on ``subset`` (Jacobi-scaled)."""
    subset = np.asarray(subset, dtype=int)
    out = np.full_like(data, np.nan)
    if not len(subset):
        return out
    c = data[np.ix_(subset, subset)]
    if not np.all(np.isfinite(c)):
        return data
    d = np.sqrt(np.clip(np.diag(c), 1e-300, None))
    info = np.linalg.pinv(c / np.outer(d, d), hermitian=True) / np.outer(d, d)
    info = info + np.diag(1.0 / np.asarray(std, float)[subset] ** 2)
    e = np.sqrt(np.clip(np.diag(info), 1e-300, None))
    out[np.ix_(subset, subset)] = np.linalg.pinv(info / np.outer(e, e), hermitian=True) / np.outer(
        e, e
    )
    return out


DEPENDENCE_TOL = 1e-4  # mm or deg of change per mm or deg of a parameter held at nominal
COINCIDENCE_DEPENDENCE = 0.1  # ... and, for coincidences, standard deviations of change


def held_dependence(
    problem: Problem,
    params: np.ndarray,
    ident: Identifiability,
    whiten: np.ndarray | None = None,
    method: str = "lm",
    prior: np.ndarray | None = None,
) -> np.ndarray:
    """``(P,)`` bool: estimated parameters that move (by more than ``DEPENDENCE_TOL`` per unit)
    when the parameters held at nominal move along the unidentifiable directions by one unit
    (1 mm or 1 deg of each combination's lead), the estimate refitted from there.

    Along an exact, straight symmetry only the combination's own parameters move; where the
    symmetry is curved, others follow at second order and are not determined individually.
    """
    out = np.zeros(len(params), dtype=bool)
    if not ident.combinations:
        return out
    subset = np.asarray(ident.subset)
    published = method.startswith("published")  # "published (huber loss)" too
    held = np.setdiff1d(np.arange(len(params)), subset)
    angle = problem.full_layout.is_angle()
    unit = np.where(angle, np.radians(1.0), 1e-3)
    step = np.zeros(len(params))
    for v in ident.null_space.T:
        lead = held[np.argmax(np.abs(v[held] / unit[held]))] if len(held) else np.argmax(np.abs(v))
        step += v / abs(v[lead]) * unit[lead]

    def solve(initial: np.ndarray, fixed: np.ndarray) -> Result:
        """The plain least squares of the subset from ``initial``, the others at ``fixed``, by
        the solver that gave the estimate."""
        if published:
            return identify_published(problem, identifiability=ident, initial=initial, fixed=fixed)
        return identify_lm(problem, 50, ident, whiten=whiten, initial=initial, fixed=fixed)

    if prior is not None:
        # What the *data* determine: the plain least squares from the estimate, against the
        # same moved along the symmetries (the priors pull both alike; a prior's pull on a
        # combination's member would read as a dependence of the others).
        params = solve(params, params).params
    moved = params.copy()
    moved[held] += step[held]
    refit = solve(params + step, moved)
    involved = np.linalg.norm(ident.null_space, axis=1) > 1e-6
    moves = np.abs(refit.params - params) / unit > DEPENDENCE_TOL
    if problem.formulation == "coincidence":
        # The base's motion turns the free group points (a curved symmetry, which the refit
        # follows only to its stopping precision), and a tool point judged on the last joint's
        # axis sits a fraction of a millimetre off it at the estimate: a held parameter moving
        # by 1 mm or 1 deg then moves others by a few thousandths of a millimetre. Below a
        # tenth of their standard deviation that is lost in the noise, not a dependence.
        cov = result_covariance(problem, params, ident, whiten, independent=True)
        std = np.sqrt(np.abs(np.diagonal(cov)))
        with np.errstate(invalid="ignore", divide="ignore"):
            moves &= ~(np.abs(refit.params - params) <= COINCIDENCE_DEPENDENCE * std)
    return moves & ~involved


def result_covariance(
    problem: Problem,
    params: np.ndarray,
    ident: Identifiability,
    whiten: np.ndarray | None = None,
    noise: Noise | None = None,
    independent: bool = False,
) -> np.ndarray:
    """The covariance ``(P, P)`` of :attr:`Result.covariance` (NaN outside the subset); the pose
    ``noise`` is estimated from the residuals when not given
    (:func:`relcal.calibration.uncertainty.residual_noise`: robust, isotropic, with what the fit
    took out of each row counted; the position level alone for position-only measurements,
    which have no orientation rows). Coincidence
    samples are clustered by placement (:func:`relcal.calibration.measurement.row_clusters`,
    :func:`relcal.calibration.uncertainty.clustered_covariance`) unless ``independent``."""
    r, a = residuals(problem, params)
    if whiten is not None:
        return least_squares_covariance(whiten @ a, whiten @ r, ident.subset)
    clusters = None if independent else row_clusters(problem)
    if clusters is not None:  # rows correlated within clusters (coincidence: placements)
        return clustered_covariance(a, r, ident.subset, clusters).covariance
    if problem.formulation in ("tracker", "coincidence"):  # independent points, in one unit
        return least_squares_covariance(a, r, ident.subset)
    # Poses (absolute ones too: one s^2 of rows in m and in rad would mix the two units)
    if noise is None:  # the levels the residuals show, with what the fit took out counted
        noise = residual_noise(problem, params, a, ident.subset)
    unc = parameter_covariance(problem, noise, ident, params=params)
    cov = np.full((len(params), len(params)), np.nan)
    cov[np.ix_(unc.subset, unc.subset)] = unc.least_squares
    return cov


def _check(problem: Problem) -> None:
    needed = problem.full_layout.size
    if problem.n_residuals() < needed:
        raise RelcalError(
            f"too few measurements: {problem.n_residuals()} residual rows for {needed} parameters;"
            " add poses"
        )


def _truncated_svd_solve(
    matrix: np.ndarray, rhs: np.ndarray, rcond: float
) -> tuple[np.ndarray, np.ndarray]:
    """``pinv(matrix) rhs`` with singular values below ``rcond * s_max`` zeroed, and the mask of
    kept singular values.

    The SVD is taken of the triangular factor of ``[matrix | rhs]`` (a QR without forming Q): it
    has the singular values of ``matrix``, its last column is ``Q^T rhs``, and for tall matrices
    it costs about half of the SVD of ``matrix`` itself.
    """
    n = matrix.shape[1]
    tri = np.linalg.qr(np.column_stack([matrix, rhs]), mode="r")
    u, s, vt = np.linalg.svd(tri[:n, :n])
    keep = s > rcond * s[0]
    return vt[keep].T @ ((u[:, keep].T @ tri[:n, n]) / s[keep]), keep


@one_blas_thread
def identify_published(
    problem: Problem,
    rcond: float = 1e-8,
    tol: float = 1e-12,
    max_iter: int = 50,
    identifiability: Identifiability | None = None,
    initial: np.ndarray | None = None,
    fixed: np.ndarray | None = None,
    prior: np.ndarray | None = None,
    prior_std: np.ndarray | None = None,
    loss: str = "linear",
    f_scale: float = 1.0,
) -> Result:
    """Iterated linear least squares with an SVD pseudo-inverse (Lu & Hayes), on the
    identifiable subset; with a robust loss, iteratively reweighted.

    The parameters of ``identifiability.subset`` (the QR-pivoted identifiable subset of
    :func:`relcal.analyse_problem`, the columns :func:`identify_lm` estimates) start from
    ``initial`` and are estimated; the others stay where ``fixed`` holds them (nominal by
    default), as :func:`identify_lm` holds them. Estimating every column instead leaves the
    solution free along the unidentifiable directions, where the pseudo-inverse's minimum-norm
    rule splits a correction the data give to one member (a hand-eye rotation, say) among all of
    them (the last joint's offset takes about half): the predictions are the same, the
    parameters not, and such a split can exceed any plausible correction.

    Each step solves ``A dp = r`` on the subset's columns scaled to unit norm, singular values
    below ``rcond * s_max`` zeroed (weak directions left where they are), halving the step
    until the cost does not rise. The iteration stops when the step is negligible (``|dp|``,
    scaled, below ``tol`` times the scaled parameter norm, or an absolute 1e-15), when no step
    along the Gauss-Newton direction lowers the cost, or when a full step lowers the cost by
    less than a millionth; :attr:`Result.converged` also asks the finite-difference gradient
    check.

    A robust ``loss`` (SciPy's, bending at ``f_scale`` weighted residual units) minimises the
    cost :func:`identify_lm` minimises with it, ``sum f_scale^2 rho((r / f_scale)^2)`` over the
    data and prior rows, by iteratively reweighted least squares: each step solves the normal
    equations of the rows weighted by ``sqrt(rho'((r / f_scale)^2))`` at the current residual
    (the same truncated SVD), and the halving asks the robust cost to fall. At its fixed point
    the gradient of the robust cost vanishes (what :func:`gradient_check` tests).

    Parameters
    ----------
    problem : Problem
        The identification problem.
    rcond : float
        Relative singular value threshold of the pseudo-inverse, ``0 < rcond < 1``.
    tol : float
        Relative step size that stops the iteration (> 0).
    max_iter : int
        Most iterations (> 0).
    identifiability : Identifiability, optional
        The analysis at the nominal model whose ``subset`` is estimated (computed if not given).
    initial : (P,) ndarray of float, optional
        Start of the estimated parameters (m, rad; only ``subset`` entries are read; default
        nominal, zeros).
    fixed : (P,) ndarray of float, optional
        Values (m, rad) at which the parameters outside ``subset`` are held (default zeros).
    prior : (P,) ndarray of float, optional
        A maximum a posteriori fit: the rows ``prior[k] * params[k]`` (weighted residual units;
        0: none) appended to the residual for the estimated parameters, as for
        :func:`identify_lm`.
    prior_std : (P,) ndarray of float, optional
        The priors' standard deviations (m, rad; inf: none), for the covariance.
    loss : {"linear", "huber", "soft_l1", "cauchy", "arctan"}
        Loss of the weighted residuals (SciPy's names).
    f_scale : float
        Where a robust loss bends, in weighted residual units (> 0).

    Returns
    -------
    Result
        The estimate ``(P,)`` over ``problem.full_layout``; ``rank`` counts the singular values
        kept at the last step (at most ``len(subset)``).
    """
    if loss not in Loss.__args__ or not (isinstance(f_scale, int | float) and f_scale > 0):
        raise ArgumentError(
            f"identify_published: unknown loss '{loss}' or f_scale {f_scale!r} not positive: use "
            f"one of {', '.join(Loss.__args__)} and f_scale > 0"
        )
    _check(problem)
    start = time.perf_counter()
    size = problem.full_layout.size
    ident, nominal = identifiability, None  # nominal: the residual and Jacobian there
    if ident is None:
        nominal = residuals(problem, np.zeros(size))
        ident = analyse_problem(problem, jac=nominal[1])
    subset = np.asarray(ident.subset, dtype=int)
    held = np.zeros(size) if fixed is None else np.asarray(fixed, dtype=float).copy()
    held[subset] = 0.0
    rows = prior_rows(prior, subset)
    at, prior_jac = _prior_jacobian(rows, subset)

    def stated(x: np.ndarray, jacobian: bool = True):
        """The stated cost's residual (data rows, then prior rows) and its Jacobian over the
        subset, ``r(x + dx) ~ r(x) - A dx``."""
        out = residuals(problem, x, jacobian=jacobian)
        r, a = (out[0], out[1][:, subset]) if jacobian else (out, None)
        if rows is not None:
            r = np.r_[r, -rows[1] * x[rows[0]]]
            a = np.vstack([a, prior_jac]) if jacobian else None
        return r, a

    params = held.copy()
    if initial is not None:
        params[subset] = np.asarray(initial, dtype=float)[subset]
    if nominal is not None and rows is None and not params.any():  # the analysis's evaluation
        r, a = nominal[0], nominal[1][:, subset]
    else:
        r, a = stated(params)
    n_rows = len(r) - (0 if rows is None else len(at))
    # The costs count from nominal (the held parameters where they are held).
    initial_norm = float(np.linalg.norm(r if initial is None else stated(held, False)[0]))
    keep = np.ones(len(subset), dtype=bool)
    # A full step that lowers the cost's root by less than this share stops the iteration;
    # reweighting converges linearly, so its steps are short well before the minimum.
    stall = 1e-6 if loss == "linear" else IRLS_TOL
    stopped, it = not len(subset), 0  # nothing to estimate: nothing to iterate
    while not stopped and it < max_iter:
        it += 1
        if loss == "linear":
            unit, norms = scaled(a)
            step, keep = _truncated_svd_solve(unit, r, rcond)
        else:  # the reweighted rows: a step of iteratively reweighted least squares
            weight = np.sqrt(_loss_derivative(loss, (r / f_scale) ** 2))
            weighted = weight * r
            unit, norms = scaled(weight[:, None] * a)
            step, keep = _truncated_svd_solve(unit, weighted, rcond)
            # The share of the reweighted cost the step promises to remove: it vanishes where
            # the robust cost's gradient does (the gradient check's decrement, analytic here).
            if np.sum((unit @ step) ** 2) <= IRLS_TOL * max(float(weighted @ weighted), 1e-300):
                stopped = True
                break
        step = step / norms
        previous = (params, r, a)
        level = _cost_root(r, loss, f_scale)  # the cost's root before the step
        # Where the linearisation does not hold over the whole step (with noise, typically a
        # weakly determined direction such as nearly parallel axes), a shorter step along the
        # same (descent) direction does: halved until the cost decreases.
        for halvings in range(40):  # noqa: B007 (read after the loop)
            params = previous[0].copy()
            params[subset] += step
            r = stated(params, jacobian=False)[0]
            if _cost_root(r, loss, f_scale) <= level:
                break
            step = step / 2
        else:  # no step along it lowers the cost: at the minimum to round-off
            params, r, a = previous
            stopped = True
            break
        r, a = stated(params)
        moved = np.linalg.norm(step * norms)
        # Negligible correction, or a cost that no longer decreases (at round-off level a
        # curved exact symmetry can keep a tiny singular value above rcond and move forever).
        stalled = _cost_root(r, loss, f_scale) >= level * (1 - stall) and it > 1
        stalled = stalled and halvings == 0  # a shortened step says nothing about the minimum
        if moved <= tol * max(np.linalg.norm(params[subset] * norms), 1e-3) or stalled:
            stopped = True
            break
    return Result(
        params=params,
        names=problem.full_layout.names,
        stopped=stopped,
        iterations=it,
        initial_residual_norm=initial_norm,
        residual_norm=float(np.linalg.norm(r)),
        n_residuals=n_rows,
        rank=int(np.sum(keep)),
        seconds=time.perf_counter() - start,
        method="published" if loss == "linear" else f"published ({loss} loss)",
        identifiability=ident,
        problem=problem,
        loss=loss,
        f_scale=f_scale,
        prior=prior,
        prior_std=prior_std if prior is not None else None,
    )


IRLS_TOL = 1e-10  # reweighted: a step promising less than this share of the cost stops

_DAMPING = 1e-6  # Marquardt's starting damping, relative to unit-norm columns
STEP_TOL = 0.01  # a step below this share of the standard deviations is not taken
COST_TOL = 1e-7  # ... nor one that promises more than this share of the cost


def levenberg_marquardt(
    evaluate, x0: np.ndarray, max_nfev: int = 200, rtol: float = 1e-10
) -> tuple[np.ndarray, bool, int]:
    """Minimise ``|r(x)|^2`` where ``evaluate(x) -> (r, A)`` with ``r(x + dx) ~ r(x) - A dx``.

    Marquardt's damping on columns scaled to unit norm (the scale never shrinks, as in MINPACK);
    a step is kept when it lowers the cost, and the iteration stops when the relative decrease
    or the scaled step falls below ``rtol``, or when a rejected step changes the cost by no more
    than round-off (the minimum is reached to the precision of the residual). The problems here
    are small and nearly linear at the start, so a few factorisations of a ``k x k`` normal
    matrix replace SciPy's per-call set-up.
    Returns the solution, whether it converged, and the evaluations used.
    """
    x = np.asarray(x0, dtype=float).copy()
    r, a = evaluate(x)
    cost, nfev, damping = float(r @ r), 1, _DAMPING
    gram, gradient = a.T @ a, a.T @ r
    scale = np.sqrt(np.diag(gram))
    scale = np.where(scale > 0, scale, 1.0)
    while nfev < max_nfev:
        # The normal equations of the unit-norm columns A / scale.
        normal = gram / np.outer(scale, scale)
        unit_gradient = gradient / scale
        step = _damped_solve(normal, damping, unit_gradient)
        if step is None:
            if damping > 1e10:  # no damping makes it positive definite: not finite
                return x, False, nfev
            damping *= 10.0
            continue
        # The decrease the linear model promises; nearly undamped, it bounds what any step
        # can still gain. Below the tolerance, or below moving the estimate by STEP_TOL of its
        # standard deviations (|A dx|^2 / s^2 with s^2 = cost / (m - k) the noise level the
        # residuals imply), the iteration ends unevaluated.
        promised = 2.0 * (unit_gradient @ step) - step @ normal @ step
        negligible = min(STEP_TOL**2 * cost / max(len(r) - len(x), 1), COST_TOL * cost)
        if damping <= _DAMPING and promised <= max(rtol * cost, negligible):
            return x, True, nfev
        trial = x + step / scale
        r_new, a_new = evaluate(trial)
        nfev += 1
        cost_new = float(r_new @ r_new)
        if cost_new <= cost:
            small_step = np.linalg.norm(step) <= rtol * (np.linalg.norm(x * scale) + rtol)
            small_gain = cost - cost_new <= rtol * cost
            x, r, a, cost = trial, r_new, a_new, cost_new
            gram, gradient = a.T @ a, a.T @ r
            scale = np.maximum(scale, np.sqrt(np.diag(gram)))
            damping = max(damping / 10.0, 1e-15)
            if small_step or small_gain or cost == 0.0:
                return x, _stationary(r, a, scale), nfev
        elif cost_new - cost <= 1e4 * rtol * cost or damping > 1e10:
            return x, _stationary(r, a, scale), nfev  # no step lowers the cost
        else:
            damping *= 10.0
    return x, False, nfev


def _damped_solve(normal: np.ndarray, damping: float, gradient: np.ndarray) -> np.ndarray | None:
    """``(N + damping I)^-1 g`` by Cholesky (LAPACK's ``dposv`` directly: the wrappers cost more
    than the solve at these sizes); None where the matrix is not numerically positive definite."""
    damped = normal.copy()
    damped.flat[:: len(damped) + 1] += damping
    _, step, info = scipy.linalg.lapack.dposv(damped, gradient)
    return None if info else step


def _stationary(r: np.ndarray, a: np.ndarray, scale: np.ndarray) -> bool:
    """Whether an undamped Gauss-Newton step at ``(r, A)`` would remove at most
    :data:`COST_TOL` of the cost: a small step or gain after heavy damping says nothing about
    the gradient, this does."""
    cost = float(r @ r)
    if cost == 0.0:
        return True
    unit = a / scale
    step = np.linalg.lstsq(unit, r, rcond=None)[0]
    return float(np.sum((unit @ step) ** 2)) <= COST_TOL * cost


def _reduced(
    problem: Problem, subset: np.ndarray, fixed: np.ndarray | None
) -> tuple[Problem, np.ndarray, np.ndarray] | None:
    """The frame-invariant ``problem`` with only the estimated link parameters in its layout (the
    held ones baked into the model), so that each evaluation computes ``k`` Jacobian columns, not
    all of them; with the positions of its parameters in the full layout and its subset. None
    where that does not apply."""
    n_geo = problem.layout.size
    free = np.asarray(subset, dtype=int)
    geo_free = np.sort(free[free < n_geo])
    if problem.formulation not in ("invariant", "board") or "origin" in problem.layout.kinds:
        return None
    if len(geo_free) == n_geo:
        return None
    held = np.zeros(problem.full_layout.size) if fixed is None else np.asarray(fixed, float).copy()
    held[free] = 0.0
    if np.any(held[n_geo:]):
        return None
    layout = problem.layout
    model = errors_applied(problem.model, layout, held[:n_geo]) if held.any() else problem.model
    sub = Layout(
        tuple(layout.names[i] for i in geo_free),
        tuple(layout.kinds[i] for i in geo_free),
        tuple(layout.index[i] for i in geo_free),
        layout.prismatic,
    )
    frames = problem.full_layout.size - n_geo  # hand-eye (and board) 6-vectors
    columns = np.concatenate([geo_free, np.arange(n_geo, n_geo + frames)])
    sub_subset = np.concatenate(
        [np.arange(len(geo_free)), len(geo_free) + free[free >= n_geo] - n_geo]
    )
    return derived(problem, model=model, layout=sub), columns, sub_subset


@one_blas_thread
def identify_lm(
    problem: Problem,
    max_nfev: int = 200,
    identifiability: Identifiability | None = None,
    loss: str = "linear",
    f_scale: float = 1.0,
    whiten: np.ndarray | None = None,
    initial: np.ndarray | None = None,
    fixed: np.ndarray | None = None,
    prior: np.ndarray | None = None,
    prior_std: np.ndarray | None = None,
) -> Result:
    """Levenberg-Marquardt (trust region) on the identifiable subset with column scaling.

    Parameters outside the QR-pivoted identifiable subset stay at their nominal values; the
    others start from ``initial`` ``(P,)`` (default nominal, zeros). ``fixed`` ``(P,)``: other
    values to hold the parameters outside the subset at. ``whiten`` ``(r, M)`` multiplies the
    residual rows first (a full noise covariance's inverse root: :func:`identify_weighted`).
    A subset of the link parameters is solved on a problem that carries only them.
    ``prior`` ``(P,)``: a maximum a posteriori fit, the rows ``prior[k] * params[k]`` (weighted
    residual units; 0: none) appended to the residual for the estimated parameters
    (:func:`relcal.calibration.priors.row_weights`); ``prior_std`` ``(P,)`` the priors' standard
    deviations (SI units), for the covariance. Without them the cost is the plain least squares.
    """
    _check(problem)
    nominal = None  # residual and Jacobian at the nominal model, when computed here
    if identifiability is None:
        nominal = residuals(problem, np.zeros(problem.full_layout.size))
        identifiability = analyse_problem(problem, jac=nominal[1])
    subset = identifiability.subset
    held = None if fixed is None else np.asarray(fixed, dtype=float).copy()
    if held is not None:
        held[subset] = 0.0
        if not held.any():
            held = None
    reduced = _reduced(problem, subset, held)
    if reduced is None:
        start = nominal if held is None else None
        res = _lm(
            problem,
            identifiability,
            subset,
            max_nfev,
            loss,
            f_scale,
            whiten,
            initial,
            held,
            start,
            prior,
        )
        return replace(res, prior_std=prior_std if prior is not None else None)
    # The sub-problem holds every link parameter it has (no further reduction).
    sub_problem, columns, sub_subset = reduced
    sub_initial = None if initial is None else np.asarray(initial, dtype=float)[columns]
    start = None if nominal is None or held is not None else (nominal[0], nominal[1][:, columns])
    sub_prior = None if prior is None else np.asarray(prior, float)[columns]
    res = _lm(
        sub_problem,
        identifiability,
        sub_subset,
        max_nfev,
        loss,
        f_scale,
        whiten,
        sub_initial,
        None,
        start,
        sub_prior,
    )
    params = np.zeros(problem.full_layout.size) if held is None else held
    params[columns] = res.params
    return replace(
        res,
        params=params,
        names=problem.full_layout.names,
        identifiability=identifiability,
        problem=problem,
        prior=prior,
        prior_std=prior_std if prior is not None else None,
    )


def _lm(
    problem: Problem,
    ident: Identifiability,
    subset: np.ndarray,
    max_nfev: int,
    loss: str,
    f_scale: float,
    whiten: np.ndarray | None,
    initial: np.ndarray | None,
    held: np.ndarray | None,
    start: tuple[np.ndarray, np.ndarray] | None,
    prior: np.ndarray | None = None,
) -> Result:
    """:func:`identify_lm` on ``subset`` of ``problem``'s parameters (``ident``'s, or its
    columns in a reduced problem), the others at ``held`` (zeros);
    ``start``: the residual and Jacobian there, if the caller has them; ``prior``: the prior
    rows' weights ``(P,)`` (see :func:`identify_lm`)."""
    began = time.perf_counter()
    rows = prior_rows(prior, subset)
    at, prior_jac = _prior_jacobian(rows, subset)  # positions in x, and the rows' Jacobian
    full = np.zeros(problem.full_layout.size) if held is None else held
    r0, a0 = start if start is not None else residuals(problem, full)
    # The latest evaluation, residual and full Jacobian together: the solver asks for the
    # Jacobian at the point it has just evaluated (the start, then each accepted step), and
    # both cost little more than the residual alone.
    x0 = np.zeros(len(subset)) if initial is None else np.asarray(initial, float)[subset]
    last = {"x": np.zeros(len(subset)).tobytes(), "r": r0, "jac": a0}

    def expand(x: np.ndarray) -> np.ndarray:
        out = full.copy()
        out[subset] = x
        return out

    def evaluate(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if last["x"] != x.tobytes():
            r, a = residuals(problem, expand(x))
            last.update(x=x.tobytes(), r=r, jac=a)
        return last["r"], last["jac"]

    every = len(subset) == len(full)  # the reduced problems estimate all their columns

    def stated(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The stated cost's residual and Jacobian, ``r(x + dx) ~ r(x) - A dx``."""
        r, a = evaluate(x)
        a = a if every else a[:, subset]
        if whiten is not None:
            r, a = whiten @ r, whiten @ a
        if rows is not None:
            r, a = np.concatenate([r, -rows[1] * x[at]]), np.vstack([a, prior_jac])
        return r, a

    def fun(x: np.ndarray) -> np.ndarray:
        return -stated(x)[0]

    def jac(x: np.ndarray) -> np.ndarray:
        return stated(x)[1]

    nfev = 0
    if loss == "linear":
        x0, converged, nfev = levenberg_marquardt(stated, x0, max_nfev)
    if loss != "linear" or not converged:
        # Robust losses, and the rare linear fit whose own iteration stalled off the optimum:
        # SciPy's trust-region reflective solver takes over.
        sol = scipy.optimize.least_squares(
            fun,
            x0,
            jac=jac,
            method="trf",
            x_scale="jac",
            loss=loss,
            f_scale=f_scale,
            max_nfev=max_nfev,
            xtol=1e-12,
            ftol=1e-12,
            gtol=1e-12,
        )
        x, converged, nfev = sol.x, bool(sol.status > 0), nfev + int(sol.nfev)
    else:
        x = x0
    r, a = evaluate(x)
    n_rows = len(r0)
    if rows is not None:  # the stated cost includes the prior rows (zero at nominal)
        r = np.concatenate([r, -rows[1] * x[at]])
    if whiten is not None:
        label = "lm (noise-weighted)"
    else:
        label = f"lm ({loss} loss)" if loss != "linear" else "lm"
    return Result(
        params=expand(x),
        names=problem.full_layout.names,
        stopped=converged,
        iterations=nfev,
        initial_residual_norm=float(np.linalg.norm(r0)),
        residual_norm=float(np.linalg.norm(r)),
        n_residuals=n_rows,
        rank=len(subset),
        seconds=time.perf_counter() - began,
        method=label,
        identifiability=ident,
        problem=problem,
        whiten=whiten,
        loss=loss,
        f_scale=f_scale,
        prior=prior,
    )


def identify(
    problem: Problem,
    options: SolverOptions | None = None,
    identifiability: Identifiability | None = None,
) -> Result:
    """Identify the parameters of ``problem`` as ``options`` say.

    Parameters
    ----------
    problem : Problem
        The identification problem.
    options : SolverOptions, optional
        The solver (default: Levenberg-Marquardt, linear loss).
    identifiability : Identifiability, optional
        The analysis at the nominal model (:func:`relcal.analyse_problem`), if the caller has
        it; computed otherwise.

    Returns
    -------
    Result
        The estimate ``(P,)`` (m, rad) over ``problem.full_layout``, its covariance, costs and
        whether it converged.

    Raises
    ------
    ArgumentError
        ``problem`` not a :class:`Problem`, ``options`` not :class:`SolverOptions`, or
        measurements that are not finite.

    Examples
    --------
    >>> import numpy as np, relcal
    >>> sim = relcal.simulate(relcal.get_robot("a465"), n_poses=20, seed=0)  # no noise
    >>> result = relcal.identify(sim.problem)
    >>> result.converged, result.rank
    (True, 22)
    >>> bool(result.final_cost_per_observation < 1e-12)
    True
    """
    from relcal.checks import check_instance

    check_instance(problem, Problem, "problem", "a Problem (relcal.Problem(model, layout, ...))")
    check_measured(problem)
    if options is not None:
        check_instance(options, SolverOptions, "options", "SolverOptions(method=..., loss=...)")
    if identifiability is not None:
        check_instance(
            identifiability,
            Identifiability,
            "identifiability",
            "an Identifiability (relcal.analyse_problem(problem)) or None",
        )
    o = options or SolverOptions()
    if o.method == "published":
        return identify_published(
            problem,
            o.rcond,
            o.tol,
            o.max_iterations,
            identifiability,
            loss=o.loss,
            f_scale=o.f_scale,
        )
    return identify_lm(problem, o.max_iterations, identifiability, o.loss, o.f_scale)


def identify_weighted(
    problem: Problem,
    noise: Noise,
    covariances: np.ndarray | None = None,
    identifiability: Identifiability | None = None,
    whiten: np.ndarray | None = None,
    max_nfev: int = 200,
) -> Result:
    """Levenberg-Marquardt on the identifiable subset with the residuals whitened by their full
    noise covariance (correlations between pairs included): the estimator whose covariance is the
    Cramer-Rao bound of :func:`uncertainty.parameter_covariance`.

    The weights come from ``noise`` (or per-pose ``covariances`` ``(N, 6, 6)``) at the measured
    relative motions (frame-invariant) and the nominal joint Jacobians; ``whiten`` ``(r, M)``
    (from :func:`uncertainty.whitener`) replaces them. Where each measurement is one pose's own
    (the board formulation, absolute poses) the poses' errors are independent and the whitening
    is block diagonal, one block per pose (:func:`uncertainty.pose_whitener`, a sparse matrix):
    time and memory linear in the poses, where the dense whitening of all ``M = 6 N`` rows is
    quadratic in memory and each solver step in time (and its SVD cubic).
    """
    if whiten is None and problem.formulation in PER_POSE:
        whiten = pose_whitener(problem, noise, covariances)
    if whiten is None:
        whiten = whitener(noise_factor(problem, noise, covariances, measured=True))
    return identify_lm(problem, max_nfev, identifiability, whiten=whiten)


def calibrated_handeye(problem: Problem, result: Result) -> np.ndarray:
    """The hand-eye transform ``X`` implied by the result (the guess when not estimated)."""
    if problem.formulation not in ("invariant", "board"):
        return problem.handeye
    n_geo = problem.layout.size
    return problem.handeye @ tf.from_vector(result.params[n_geo : n_geo + 6])
