"""Identification: the published iterated SVD least squares, and Levenberg-Marquardt.

Both take a :class:`measurement.Problem` and return a :class:`Result` with the parameter
estimate (errors relative to the nominal model, SI units), convergence, cost, rank and the
identifiability analysis at the nominal model.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.optimize

from relcal import geometry as tf
from relcal.calibration.blas import one_blas_thread
from relcal.calibration.identifiability import (
    Identifiability,
    analyse_problem,
    identifiable_at,
    scaled,
)
from relcal.calibration.measurement import Problem, residuals
from relcal.errors import RelcalError

Method = Literal["published", "lm"]


@dataclass(frozen=True)
class Result:
    """Outcome of one identification. ``params`` follows ``problem.full_layout``."""

    params: np.ndarray
    names: tuple[str, ...]
    converged: bool
    iterations: int
    initial_residual_norm: float
    residual_norm: float
    n_residuals: int
    rank: int
    seconds: float
    method: str
    identifiability: Identifiability
    identifiable: np.ndarray  # (P,) bool, individually determined (nominal and at the estimate)

    @property
    def unidentifiable(self) -> list[str]:
        return [c.describe() for c in self.identifiability.combinations]


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
) -> Result:
    """Iterated linear least squares with an SVD pseudo-inverse (Lu & Hayes).

    Each step solves ``A dp = r`` on unit-norm columns with singular values below
    ``rcond * s_max`` zeroed, and stops when ``|dp|`` (scaled) falls below ``tol`` times the
    scaled parameter norm (or an absolute 1e-15).
    """
    _check(problem)
    start = time.perf_counter()
    params = np.zeros(problem.full_layout.size)
    r, a = residuals(problem, params)
    ident = identifiability or analyse_problem(problem, jac=a)
    initial = float(np.linalg.norm(r))
    converged, it = False, 0
    for it in range(1, max_iter + 1):
        unit, norms = scaled(a)
        step, keep = _truncated_svd_solve(unit, r, rcond)
        step = step / norms
        previous = (params, r, a)
        params = params + step
        r, a = residuals(problem, params)
        if np.linalg.norm(r) > np.linalg.norm(previous[1]):
            # The linearisation no longer holds (with noise, typically a weakly determined
            # direction such as nearly parallel axes): keep the better estimate and stop there.
            params, r, a = previous
            converged = True
            break
        size = np.linalg.norm(step * norms)
        # Negligible correction, or a residual that no longer decreases (at round-off level a
        # curved exact symmetry can keep a tiny singular value above rcond and move forever).
        stalled = np.linalg.norm(r) >= np.linalg.norm(previous[1]) * (1 - 1e-6) and it > 1
        if size <= tol * max(np.linalg.norm(params * norms), 1e-3) or stalled:
            converged = True
            break
    return Result(
        params=params,
        names=problem.full_layout.names,
        converged=converged,
        iterations=it,
        initial_residual_norm=initial,
        residual_norm=float(np.linalg.norm(r)),
        n_residuals=len(r),
        rank=int(np.sum(keep)),
        seconds=time.perf_counter() - start,
        method="published",
        identifiability=ident,
        identifiable=identifiable_at(problem, params, ident, jac=a),
    )


@one_blas_thread
def identify_lm(
    problem: Problem,
    max_nfev: int = 200,
    identifiability: Identifiability | None = None,
    loss: str = "linear",
    f_scale: float = 1.0,
    whiten: np.ndarray | None = None,
) -> Result:
    """Levenberg-Marquardt (trust region) on the identifiable subset with column scaling.

    Parameters outside the QR-pivoted identifiable subset stay at their nominal values.
    ``whiten`` ``(r, M)`` multiplies the residual rows first (a full noise covariance's inverse
    root: :func:`relcal.calibration.uncertainty.identify_weighted`).
    """
    _check(problem)
    start = time.perf_counter()
    full = np.zeros(problem.full_layout.size)
    r0, a0 = residuals(problem, full)
    ident = identifiability or analyse_problem(problem, jac=a0)
    subset = ident.subset
    # The latest evaluation, residual and full Jacobian together: the solver asks for the
    # Jacobian at the point it has just evaluated (the start, then each accepted step), and
    # both cost little more than the residual alone.
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

    def fun(x: np.ndarray) -> np.ndarray:
        r = evaluate(x)[0]
        return -(r if whiten is None else whiten @ r)

    def jac(x: np.ndarray) -> np.ndarray:
        a = evaluate(x)[1][:, subset]
        return a if whiten is None else whiten @ a

    method = "lm" if loss == "linear" else "trf"
    sol = scipy.optimize.least_squares(
        fun,
        np.zeros(len(subset)),
        jac=jac,
        method=method,
        x_scale="jac",
        loss=loss,
        f_scale=f_scale,
        max_nfev=max_nfev,
        xtol=1e-12,
        ftol=1e-12,
        gtol=1e-12,
    )
    r, a = evaluate(sol.x)
    if whiten is not None:
        label = "lm (noise-weighted)"
    else:
        label = f"lm ({loss} loss)" if loss != "linear" else "lm"
    return Result(
        params=expand(sol.x),
        names=problem.full_layout.names,
        converged=bool(sol.status > 0),
        iterations=int(sol.nfev),
        initial_residual_norm=float(np.linalg.norm(r0)),
        residual_norm=float(np.linalg.norm(r)),
        n_residuals=len(r0),
        rank=len(subset),
        seconds=time.perf_counter() - start,
        method=label,
        identifiability=ident,
        identifiable=identifiable_at(problem, expand(sol.x), ident, jac=a),
    )


def identify(problem: Problem, method: Method = "published", **kwargs) -> Result:
    """Run the chosen identification method."""
    if method == "published":
        return identify_published(problem, **kwargs)
    if method == "lm":
        return identify_lm(problem, **kwargs)
    raise ValueError(f"unknown identification method '{method}': use published or lm")


def calibrated_handeye(problem: Problem, result: Result) -> np.ndarray:
    """The hand-eye transform ``X`` implied by the result (the guess when not estimated)."""
    if problem.formulation != "invariant":
        return problem.handeye
    return problem.handeye @ tf.from_vector(result.params[problem.layout.size :])
