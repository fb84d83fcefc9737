"""Throughput of the Monte Carlo study: trials per second of ``study.study`` (the function
behind ``relcal study``), each trial a seeded noisy simulated calibration identified on the
identifiable subset.

The scenario is the A465 with Hayati's beta on its parallel axes (``auto_hayati``), 27 reachable
poses of the simulation's spiral over the board, frame-invariant formulation, full pose,
consecutive pairs, and the command's default noise (0.05 mm, 0.01 deg per camera pose axis and
0.001 deg per joint reading). The trials use ``estimator="least_squares"`` (``identify_lm``, the
analytic identification Jacobian), so that the peer solves exactly the same problem.

Two rows, both measured in this run (wall times, ``time.perf_counter``, the least of a few
interleaved repeats, so that a burst of load from another process passes):

- one worker against the way a user without relcal would run the same trials: a plain Python
  loop that, per trial, builds the same noisy problem (same seeded noise) and solves it with
  ``scipy.optimize.least_squares`` (LM, 2-point finite-difference Jacobian, same tolerances) on
  the same identifiable subset. The peer is given the noise-free poses and the subset for free;
  relcal's time is the whole ``study()`` call, including its identifiability analysis, the
  noise-free reference estimate and the predicted covariance. Both must reach the same estimates
  (checked, and reported in the note);
- two worker processes against one on the 2-core machine: the parallel speed-up of ``study()``
  on a longer run, with the start-up of the spawned workers (a fresh Python importing relcal,
  NumPy and SciPy) included, as a user pays it.

Run ``python bench/montecarlo.py`` for the rows; ``run()`` returns them.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # as bench/run.py: one BLAS thread (workers inherit it)

import multiprocessing  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from peers import fd_least_squares  # noqa: E402

from relcal.calibration.identifiability import analyse_problem  # noqa: E402
from relcal.calibration.noise import Noise  # noqa: E402
from relcal.design.cell import Cell, joint_path  # noqa: E402
from relcal.robot.loading import get_robot  # noqa: E402
from relcal.robot.model import auto_hayati  # noqa: E402
from relcal.sim.scenario import (  # noqa: E402
    Scenario,
    clean_poses,
    make_scenario,
    noisy_measurement,
    problem_for,
)
from relcal.sim.study import StudyResult, standard_normals, study  # noqa: E402

N_POSES = 27
NOISE = "0.05,0.01,0.001"  # POS_MM,ORI_DEG,JOINT_DEG: the default of ``relcal study --noise``
SEED = 0
ESTIMATOR = "least_squares"  # identify_lm: the estimator the finite-difference peer reproduces
TRIALS = 200  # row 1: relcal against the peer (the peer takes ~20 ms a trial)
PARALLEL_TRIALS = 8000  # row 2: long enough for the workers' start-up to be paid back
WORKERS = 2
REPEATS = 2  # row 1 (the peer's loop takes ~5 s)
PARALLEL_REPEATS = 2  # row 2 (~25 s a pair)
PARALLEL_GOAL = 1.5


def scenario() -> Scenario:
    """The A465 with ``auto_hayati``, ``N_POSES`` reachable spiral poses, the default noise."""
    model = auto_hayati(get_robot("a465"))
    # Some spiral poses are out of reach: ask for a few more until N_POSES are reachable.
    for requested in range(N_POSES, N_POSES + 10):
        q = joint_path(model, Cell(), requested, np.random.default_rng(SEED))
        if len(q) >= N_POSES:
            break
    else:
        raise RuntimeError(f"only {len(q)} reachable poses for the A465")
    return make_scenario(model, q[:N_POSES], Noise.parse(NOISE), seed=SEED)


def _relcal(sc: Scenario, trials: int, workers: int) -> tuple[float, StudyResult]:
    """Wall time of one whole ``study()`` call (worker start-up included), and its result."""
    start = time.perf_counter()
    res = study(sc, trials=trials, seed=SEED, workers=workers, estimator=ESTIMATOR, progress=False)
    seconds = time.perf_counter() - start
    if not res.converged.all():
        raise RuntimeError(f"{int((~res.converged).sum())} of {trials} relcal trials diverged")
    return seconds, res


def _peer(
    sc: Scenario, trials: int, clean: np.ndarray, subset: np.ndarray
) -> tuple[float, np.ndarray]:
    """The same trials in a plain loop, each solved by ``scipy.optimize.least_squares`` with a
    2-point finite-difference Jacobian on ``subset``: wall time and estimates ``(T, P)``."""
    size = problem_for(sc, sc.q, clean).full_layout.size
    start = time.perf_counter()
    z = standard_normals(SEED, trials, sc.noise_dimension, "random")  # the study's noise
    estimates = np.zeros((trials, size))
    for t in range(trials):
        problem = problem_for(sc, *noisy_measurement(sc, clean, z[t]))
        estimates[t], converged = fd_least_squares(problem, subset)
        if not converged:
            raise RuntimeError(f"peer trial {t} did not converge")
    return time.perf_counter() - start, estimates


def peer_row(sc: Scenario) -> dict:
    """Row 1: relcal ``study()`` on one worker against the finite-difference loop."""
    clean = clean_poses(sc)
    subset = analyse_problem(problem_for(sc, sc.q, clean)).subset
    ours, theirs = np.inf, np.inf
    for _ in range(REPEATS):
        seconds, res = _relcal(sc, TRIALS, 1)
        ours = min(ours, seconds)
        seconds, peer_estimates = _peer(sc, TRIALS, clean, subset)
        theirs = min(theirs, seconds)
    if not np.array_equal(np.sort(res.subset), np.sort(subset)):
        raise RuntimeError("relcal and the peer estimate different parameters")
    diff = np.abs(peer_estimates[:, subset] - res.estimates[:, subset]).max(axis=0)
    worst_diff = float((diff / res.predicted.std[subset]).max())
    std_ratio = np.std(peer_estimates[:, subset], axis=0, ddof=1) / res.empirical_std
    std_gap = 100 * float(np.abs(std_ratio - 1).max())
    value, peer = TRIALS / ours, TRIALS / theirs
    return {
        "task": f"Monte Carlo study, A465 auto_hayati, {N_POSES} poses, noise {NOISE} "
        f"(mm, deg, deg), {TRIALS} trials, 1 worker: study(estimator='{ESTIMATOR}')",
        "value": round(value, 1),
        "unit": "trials/s",
        "peer": round(peer, 1),
        "peer_name": "scipy least_squares FD (2-point), Python loop",
        "ratio": round(value / peer, 3),
        "note": f"same {TRIALS} seeded trials, same {len(subset)} parameters: estimates agree "
        f"to {worst_diff:.0e} predicted std, empirical std to {std_gap:.1g}%; relcal timed as "
        "the whole study() call (analysis, reference, prediction), peer given the subset",
    }


def _burn(n: int) -> float:
    """Seconds of a pure-Python loop of ``n`` steps."""
    start, x = time.perf_counter(), 0
    for i in range(n):
        x += i * i
    return time.perf_counter() - start


def parallel_capacity(workers: int = WORKERS, n: int = 3_000_000) -> float:
    """Cores the machine gives ``workers`` busy processes now: ``workers`` times one loop's time
    alone over the slowest of ``workers`` copies run at once (forked, start-up not counted).
    A shared virtual machine may give fewer than it has, and it varies by the minute."""
    if "fork" not in multiprocessing.get_all_start_methods():
        return float("nan")
    with multiprocessing.get_context("fork").Pool(workers) as pool:
        alone = _burn(n)
        together = max(pool.map(_burn, [n] * workers))
    return workers * alone / together


def parallel_row(sc: Scenario) -> dict:
    """Row 2: ``study()`` over ``WORKERS`` processes against one, same trials."""
    one, many, capacity = np.inf, np.inf, []
    for _ in range(PARALLEL_REPEATS):
        seconds, serial = _relcal(sc, PARALLEL_TRIALS, 1)
        one = min(one, seconds)
        capacity.append(parallel_capacity())
        seconds, parallel = _relcal(sc, PARALLEL_TRIALS, WORKERS)
        many = min(many, seconds)
    same = np.array_equal(serial.estimates, parallel.estimates)
    value, peer = PARALLEL_TRIALS / many, PARALLEL_TRIALS / one
    overhead = many - one / WORKERS
    return {
        "task": f"Monte Carlo study, as above, {PARALLEL_TRIALS} trials: {WORKERS} worker "
        "processes vs 1",
        "value": round(value, 1),
        "unit": "trials/s",
        "peer": round(peer, 1),
        "peer_name": "relcal study, 1 worker",
        "ratio": round(value / peer, 3),
        "goal_ratio": PARALLEL_GOAL,
        "note": f"parallel speed-up; {os.cpu_count()} CPUs, of which {WORKERS} busy processes got "
        f"{np.mean(capacity):.1f} cores meanwhile (pure-Python check); wall time includes "
        f"spawning the workers ({overhead:.2f} s over an ideal split); estimates "
        + ("identical to 1 worker" if same else "DIFFER from 1 worker"),
    }


def run() -> list[dict]:
    """Monte Carlo trials per second of relcal's study, against a finite-difference loop and
    over 2 worker processes against 1.

    Returns
    -------
    list of dict
        Rows ``{"task", "value", "unit", "peer", "peer_name", "ratio", "note"}`` (the second also
        ``goal_ratio``): ``value`` is relcal's rate in trials per second, ``peer`` the peer's
        (the finite-difference loop; relcal on one worker), ``ratio = value / peer`` (above 1:
        relcal, or the parallel run, is faster).
    """
    sc = scenario()
    return [peer_row(sc), parallel_row(sc)]


if __name__ == "__main__":
    started = time.perf_counter()
    for row in run():
        print(
            f"{row['task']}: {row['value']} {row['unit']} vs {row['peer_name']} {row['peer']} "
            f"(ratio {row['ratio']}); {row['note']}"
        )
    print(f"{time.perf_counter() - started:.1f} s")
