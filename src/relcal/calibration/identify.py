"""Identification: the published iterated SVD least squares, and Levenberg-Marquardt.

Both take a :class:`measurement.Problem` and return a :class:`Result` with the parameter
estimate (errors relative to the nominal model, SI units), convergence, cost, rank and the
identifiability analysis at the nominal model.
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.optimize

from relcal import geometry as tf
from relcal.calibration.identifiability import (
    DEFAULT_RCOND,
    Identifiability,
    analyse,
    identifiable_mask,
    scaled,
)
from relcal.calibration.measurement import Problem, residuals
from relcal.errors import RelcalError
from relcal.robot.kinematics import pose_jacobian

Method = Literal["published", "lm"]


@functools.cache
def _blas_threads():
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()  # created once, after NumPy and SciPy have loaded their BLAS


def one_blas_thread(function):
    """Run ``function`` with BLAS/LAPACK on one thread.

    Identification factorises tall, narrow matrices (hundreds of rows, tens of columns) many
    times: OpenBLAS's threads cost more than they gain there, up to six times slower on a busy
    two-core machine. The limit holds only during the call.
    """

    @functools.wraps(function)
    def limited(*args, **kwargs):
        with _blas_threads().limit(limits=1, user_api="blas"):
            return function(*args, **kwargs)

    return limited


def _final_identifiable(
    problem: Problem, params: np.ndarray, ident: Identifiability, jac: np.ndarray | None = None
) -> np.ndarray:
    """Parameters identifiable both at the nominal model and at the estimate.

    Exact symmetries (base motion, hand-eye absorption) are curved in parameter space: a parameter
    outside the nominal null space can still drift along it at second order, which the null space
    at the estimate reveals. ``jac``: the Jacobian at ``params`` if the caller has it.
    """
    if jac is None:
        _, jac = residuals(problem, params)
    return ident.identifiable & identifiable_mask(jac, ident.rcond)


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


def explainer(problem: Problem):
    """A function naming why a null-space direction (parameter units) leaves the data unchanged."""
    model, layout = problem.model, problem.full_layout
    n_geo = problem.layout.size

    @functools.cache
    def jacobians() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The parameters' effect on the tool at the nominal model ``(N, 6, P)``: at the tool
        point in the base frame, as a spatial twist (about the base origin) and as a body twist
        (in the tool frame). Computed on the first explanation only (problems without a null
        space never need them), so that each explanation is a few matrix-vector products."""
        tip, jac = pose_jacobian(model, problem.q, problem.layout)
        spatial = jac.copy()
        spatial[:, :3] += tf.skew(tip[:, :3, 3]) @ jac[:, 3:]  # v_0 = v_tip - w x tip
        body = tf.rotate_twist(np.swapaxes(tip[:, :3, :3], -1, -2), jac)
        return jac, spatial, body

    def constant(twists: np.ndarray) -> bool:
        scale = np.abs(twists).max()
        return scale > 0 and np.abs(twists - twists.mean(axis=0)).max() < 1e-6 * scale

    def explain(v: np.ndarray) -> str:
        involved = np.flatnonzero(np.abs(v) > 1e-6 * np.abs(v).max())
        kinds = {layout.kinds[i] for i in involved}
        jac, spatial, body = jacobians()
        geometric = v[:n_geo]
        motion = jac @ geometric  # (N, 6): tip velocity and angular velocity, base frame
        if len(involved) == 1 and np.abs(motion).max() < 1e-12:
            return "has no effect on the tool pose"
        if kinds == {"d"} and len(involved) > 1:
            joints = sorted({layout.index[i] + 1 for i in involved})
            return (
                f"translations along parallel axes of joints {', '.join(map(str, joints))}: "
                "only their sum is identifiable (Hayati's beta cures it)"
            )
        if "handeye" not in kinds and constant(spatial @ geometric):
            return "acts as a rigid motion of the robot base: cancels in relative measurements"
        if "handeye" in kinds or constant(body @ geometric):
            if problem.formulation == "invariant":
                return "acts like a change of the hand-eye transform X, which absorbs it"
            return "acts like a change of the tool transform"
        return "linearly dependent at these poses: vary the poses or fix one of them"

    return explain


@one_blas_thread
def analyse_problem(
    problem: Problem, rcond: float = DEFAULT_RCOND, jac: np.ndarray | None = None
) -> Identifiability:
    """Identifiability of ``problem`` at its nominal model (all errors zero); ``jac``: the
    identification Jacobian there, if the caller has it already."""
    if jac is None:
        _, jac = residuals(problem, np.zeros(problem.full_layout.size))
    return analyse(jac, problem.full_layout, rcond, explainer(problem))


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
        identifiable=_final_identifiable(problem, params, ident, jac=a),
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
        identifiable=_final_identifiable(problem, expand(sol.x), ident, jac=a),
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
