"""Monte Carlo study: many noisy simulated calibrations against the predicted covariance.

One :class:`relcal.sim.scenario.Scenario` fixes the robot, the joint configurations, the true
geometric errors and hand-eye transform, and the noise model. Each trial measures the same poses
with new noise (seeded per trial, so results do not depend on the number of worker processes),
identifies the parameters on the identifiable subset, and keeps the estimate. The empirical
standard deviation of every estimated parameter is then compared with the prediction of
:mod:`relcal.calibration.uncertainty` for the same estimator (the Cramer-Rao bound for the
noise-weighted one), and the mean with the noise-free estimate (the bias test).

With ``sampling="random"`` the trials are independent draws; the sample standard deviation of T
trials then scatters by about ``1/sqrt(2 (T - 1))`` (5 % at 200 trials) around the true one, so a
per-parameter agreement is judged against that interval. ``sampling="matched"`` (moment matching)
makes the noise vectors of the trials have exactly the modelled sample covariance (needs more
trials than noise dimensions): the sampling scatter of the linear part vanishes, and what remains
is the error of the prediction itself (noise propagation, linearisation, estimator).
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import time
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from typing import Literal

import numpy as np

from relcal.calibration.identifiability import analyse_problem
from relcal.calibration.identify import identify_lm, identify_weighted
from relcal.calibration.measurement import Problem
from relcal.calibration.uncertainty import (
    Estimator,
    Uncertainty,
    parameter_covariance,
)
from relcal.errors import RelcalError
from relcal.sim.scenario import Scenario, clean_poses, noisy_measurement, problem_for, truth_vector

Sampling = Literal["random", "matched"]


def standard_normals(seed: int, trials: int, dim: int, sampling: Sampling) -> np.ndarray:
    """``(trials, dim)`` standard normals; row t is drawn from the seed ``(seed, t)``. ``matched``
    centres and whitens the columns so that their sample covariance is exactly the identity."""
    z = np.stack([np.random.default_rng([seed, t]).standard_normal(dim) for t in range(trials)])
    if sampling == "random":
        return z
    if sampling != "matched":
        raise ValueError(f"unknown sampling '{sampling}': use random or matched")
    if trials <= dim + 1:
        raise RelcalError(
            f"matched sampling needs more trials than noise dimensions: {trials} trials for "
            f"{dim} (use at least {dim + 2} trials, fewer poses, or --sampling random)"
        )
    z = z - z.mean(axis=0)
    chol = np.linalg.cholesky(z.T @ z / (trials - 1))
    return np.linalg.solve(chol, z.T).T


# --- trials (run in worker processes) ------------------------------------------------------------

_CONTEXT: dict = {}
_BLAS_THREADS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


@contextlib.contextmanager
def _single_threaded_blas() -> Iterator[None]:
    """Workers started meanwhile use one BLAS thread each (the matrices are small; threads of
    several processes competing for the cores make them many times slower)."""
    saved = {k: os.environ.get(k) for k in _BLAS_THREADS}
    os.environ.update({k: "1" for k in _BLAS_THREADS})
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def _init(context: dict) -> None:
    _CONTEXT.clear()
    _CONTEXT.update(context)


def _estimate(problem: Problem, context: dict) -> tuple[np.ndarray, bool]:
    if context["estimator"] == "weighted":
        result = identify_weighted(
            problem,
            context["scenario"].noise,
            identifiability=context["ident"],
        )
    else:
        result = identify_lm(problem, identifiability=context["ident"])
    return result.params, result.converged


def _run_on_worker(context: dict, rows: list[tuple[int, np.ndarray]]) -> list:
    """A Dask task: ``rows`` with ``context`` (scattered once, the same object for every task of
    one worker), BLAS on one thread (:func:`relcal.cluster.prepare_worker`)."""
    from relcal.cluster import prepare_worker

    prepare_worker()
    if _CONTEXT.get("token") != context["token"]:
        _init(context)
    return _run_trials(rows)


def _dask_results(client, context: dict, rows: list, trial_seconds: float):
    """Results of the trials as Dask tasks on ``client``'s cluster: the context scattered to
    every worker once, trials in chunks of about ``TASK_SECONDS`` (so that Dask's few
    milliseconds per task stay a small share), yielded as they finish."""
    from distributed import as_completed as dask_completed

    from relcal.cluster import n_workers

    chunk = int(np.clip(TASK_SECONDS / max(trial_seconds, 1e-6), 1, len(rows) / n_workers(client)))
    token = f"study-{os.getpid()}-{time.time_ns()}"
    shared = client.scatter({**context, "token": token}, broadcast=True, hash=False)
    futures = [
        client.submit(_run_on_worker, shared, rows[i : i + chunk], pure=False)
        for i in range(0, len(rows), chunk)
    ]
    for future in dask_completed(futures):
        yield future.result()


def _run_trials(rows: list[tuple[int, np.ndarray]]) -> list[tuple[int, np.ndarray, bool]]:
    ctx = _CONTEXT
    out = []
    for t, z in rows:
        q, poses = noisy_measurement(ctx["scenario"], ctx["clean"], z)
        params, ok = _estimate(problem_for(ctx["scenario"], q, poses), ctx)
        out.append((t, params, ok))
    return out


# --- the study -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class StudyResult:
    """Estimates of every trial and their comparison with the prediction (SI units)."""

    names: tuple[str, ...]
    is_angle: np.ndarray  # (P,)
    subset: np.ndarray  # (k,) estimated parameters
    truth: np.ndarray  # (P,)
    reference: np.ndarray  # (P,) noise-free estimate
    estimates: np.ndarray  # (T, P)
    converged: np.ndarray  # (T,)
    predicted: Uncertainty
    estimator: Estimator
    sampling: Sampling
    seconds: float

    @property
    def trials(self) -> int:
        return len(self.estimates)

    @property
    def empirical_std(self) -> np.ndarray:
        """``(k,)`` sample standard deviations of the estimated parameters."""
        return np.std(self.estimates[:, self.subset], axis=0, ddof=1)

    @property
    def predicted_std(self) -> np.ndarray:
        return self.predicted.std[self.subset]

    @property
    def ratio(self) -> np.ndarray:
        """``(k,)`` empirical over predicted standard deviation."""
        return self.empirical_std / self.predicted_std

    @property
    def overall_ratio(self) -> float:
        """Root mean of the squared ratios (empirical over predicted variance, averaged)."""
        return float(np.sqrt(np.mean(self.ratio**2)))

    def ratio_interval(self, level: float = 0.95) -> tuple[float, float]:
        """Interval that the ratio of one parameter falls in with probability ``level`` when the
        prediction is exact and the trials are independent (chi-square with T - 1 dof)."""
        dof = self.trials - 1
        import scipy.stats  # here: worker processes need not import it

        lo, hi = scipy.stats.chi2.ppf([(1 - level) / 2, (1 + level) / 2], dof)
        return float(np.sqrt(lo / dof)), float(np.sqrt(hi / dof))

    @property
    def bias(self) -> np.ndarray:
        """``(k,)`` mean estimate minus the noise-free estimate."""
        return self.estimates[:, self.subset].mean(axis=0) - self.reference[self.subset]

    @property
    def bias_t(self) -> np.ndarray:
        """``(k,)`` bias in units of its predicted standard error ``std / sqrt(T)``."""
        return self.bias / (self.predicted_std / np.sqrt(self.trials))

    def bias_test(self) -> tuple[float, float]:
        """``(chi2, p)``: ``T b^T Cov^-1 b`` against chi-square with k dof (p small: biased)."""
        cov = self.predicted.covariance
        d = np.sqrt(np.diag(cov))
        b = self.bias / d
        chi2 = float(self.trials * b @ np.linalg.solve(cov / np.outer(d, d), b))
        import scipy.stats

        return chi2, float(scipy.stats.chi2.sf(chi2, len(b)))

    @property
    def reference_error(self) -> np.ndarray:
        """``(P,)`` noise-free estimate minus truth (zero for individually identifiable ones)."""
        return self.reference - self.truth


WORKER_STARTUP_S = 1.0  # s (CPU): a spawned worker imports NumPy, SciPy and relcal
TASK_SECONDS = 0.25  # s: the work of one Dask task of a study (its overhead is a few ms)


def study(
    scenario: Scenario,
    trials: int = 200,
    seed: int = 0,
    workers: int = 2,
    estimator: Estimator = "weighted",
    sampling: Sampling = "random",
    progress: bool = True,
    chunk: int = 5,
    client=None,
) -> StudyResult:
    """Run ``trials`` noisy calibrations of ``scenario`` over up to ``workers`` processes (1: in
    this process), or as tasks on the Dask cluster of ``client`` (a ``distributed.Client``),
    with a progress bar, and compare them with the predicted covariance.

    A study whose workers would save less than :data:`WORKER_STARTUP_S` (judged by the CPU
    time of the noise-free reference estimate, which a busy machine does not inflate) runs in
    this process: starting a worker costs about that much.
    The estimates do not depend on where they run.
    """
    from tqdm import tqdm

    start = time.perf_counter()
    clean = clean_poses(scenario)
    base = problem_for(scenario, scenario.q, clean)
    ident = analyse_problem(base)
    context = {"scenario": scenario, "clean": clean, "ident": ident, "estimator": estimator}
    # The reference's CPU time, not the wall clock's: on a busy machine the wall-clock time of
    # this one call grows with the load (a short study then looked worth its workers), while
    # the trials and the workers' start would compete for the same cores.
    tick = time.thread_time()
    reference, _ = _estimate(base, context)
    # Noisy trials take about twice the noise-free reference (more iterations).
    trial_seconds = 2 * (time.thread_time() - tick)
    if workers > 1 and client is None:  # workers pay when they save more than they cost
        saved = trials * trial_seconds * (1 - 1 / workers)
        workers = workers if saved > WORKER_STARTUP_S else 1
    predicted = parameter_covariance(
        base, scenario.noise, ident, params=reference, estimator=estimator
    )
    z = standard_normals(seed, trials, scenario.noise_dimension, sampling)
    rows = list(enumerate(z))
    batches = [rows[i : i + chunk] for i in range(0, len(rows), chunk)]
    estimates = np.empty((trials, base.full_layout.size))
    converged = np.zeros(trials, dtype=bool)
    with tqdm(total=trials, desc="trials", disable=not progress, unit="trial") as bar:
        if client is not None:
            for out in _dask_results(client, context, rows, trial_seconds):
                for t, params, ok in out:
                    estimates[t], converged[t] = params, ok
                bar.update(len(out))
        elif workers <= 1:
            _init(context)
            done = (_run_trials(b) for b in batches)
            for out in done:
                for t, params, ok in out:
                    estimates[t], converged[t] = params, ok
                bar.update(len(out))
        else:
            with (
                _single_threaded_blas(),
                ProcessPoolExecutor(
                    workers,
                    mp_context=mp.get_context("spawn"),
                    initializer=_init,
                    initargs=(context,),
                ) as pool,
            ):
                futures = [pool.submit(_run_trials, b) for b in batches]
                for future in as_completed(futures):
                    out = future.result()
                    for t, params, ok in out:
                        estimates[t], converged[t] = params, ok
                    bar.update(len(out))
    return StudyResult(
        names=base.full_layout.names,
        is_angle=base.full_layout.is_angle(),
        subset=predicted.subset,
        truth=truth_vector(scenario),
        reference=reference,
        estimates=estimates,
        converged=converged,
        predicted=predicted,
        estimator=estimator,
        sampling=sampling,
        seconds=time.perf_counter() - start,
    )


def worst(res: StudyResult, length_scale: float = 0.5) -> tuple[str, float, str, float]:
    """Worst parameter by predicted and by empirical standard deviation, angles counted as the
    displacement ``length_scale`` m away: ``(name, predicted m, name, empirical m)``. The board
    formulation's board transform (``board.*``, where the board happens to sit) is not one of
    them."""
    keep = np.array([not res.names[k].startswith("board.") for k in res.subset])
    w = np.where(res.is_angle[res.subset], length_scale, 1.0)
    p, e = (res.predicted_std * w)[keep], (res.empirical_std * w)[keep]
    names = [res.names[k] for k in res.subset[keep]]
    return names[int(np.argmax(p))], float(p.max()), names[int(np.argmax(e))], float(e.max())
