"""Pose-planning rows of ``make bench``: ``plan()`` of a large candidate set on a local Dask
cluster of 2 worker processes against one process.

- the whole plan (A465 with Hayati's beta, 30 poses, ``worst`` criterion, greedy + exchange,
  ``N_CANDIDATES`` feasible candidates, 20 random sets): wall time on 2 workers against the same
  call without a client (goal 1.5x on 2 cores); the plans must be identical (checked);
- the selection alone (greedy + exchange on the same pool's information), as milliseconds per
  scoring step: the rows sent once, one shard per worker held by a Dask actor, one actor call
  per shard and step, against the same blocks scored in this process; the note has the CPU time
  per step of the one process, of each worker and of the client.

Wall times, the least of ``REPEAT`` interleaved runs; the cluster is started and warmed up before
timing. The kernel's autogroup scheduling shares the CPU between sessions, not processes: while
other jobs keep both cores busy, the two workers share one session's part with the client, and
the wall-time ratio stays near 1 whatever the work's split (the CPU times show the split).
Run ``python bench/plan.py`` for the rows; ``run()`` returns them.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # as bench/run.py: one BLAS thread

import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

N_CANDIDATES = 20_000
K = 30
REPEAT = 2
WORKERS = 2


def _setup():
    from relcal.design.cell import Cell
    from relcal.robot.loading import get_robot
    from relcal.robot.model import auto_hayati

    return auto_hayati(get_robot("a465")), Cell()


def _selection(info, scorer) -> tuple[np.ndarray, int]:
    """Greedy + exchange with ``scorer``; the chosen set and the number of scoring steps."""
    from relcal.design.plan import exchange, greedy

    steps = [0]
    best = scorer.best

    def counted(*args):
        steps[0] += 1
        return best(*args)

    scorer.best = counted
    chosen, _ = exchange(info, greedy(info, K, "worst", scorer), "worst", scorer=scorer)
    return chosen, steps[0]


def measure(n_candidates: int = N_CANDIDATES, repeat: int = REPEAT) -> dict:
    """Wall seconds of the plan and of the selection, in one process and on the cluster."""
    from distributed import Client

    from relcal.cluster import local_cluster
    from relcal.design.plan import (
        DEFAULT_NOISE,
        Constraints,
        Scorer,
        candidates,
        information,
        plan,
        selection_problem,
    )

    model, cell = _setup()
    times = {"plan_one": np.inf, "plan_dask": np.inf, "sel_one": np.inf, "sel_dask": np.inf}
    with local_cluster(WORKERS) as cluster, Client(cluster) as client:
        plan(model, cell, n_poses=5, n_candidates=300, random_sets=1, client=client)  # warm up
        for _ in range(repeat):  # interleaved, the least of each: bursts of load pass
            started = time.perf_counter()
            one = plan(model, cell, n_poses=K, n_candidates=n_candidates)
            times["plan_one"] = min(times["plan_one"], time.perf_counter() - started)
            started = time.perf_counter()
            there = plan(model, cell, n_poses=K, n_candidates=n_candidates, client=client)
            times["plan_dask"] = min(times["plan_dask"], time.perf_counter() - started)
            assert np.array_equal(one.q, there.q), "the cluster's plan differs"
        pool, _ = candidates(model, cell, Constraints(), n_candidates, seed=0, client=client)
        info = information(selection_problem(model, cell, pool), DEFAULT_NOISE, 0.5)
        for _ in range(repeat):
            with Scorer(info) as scorer:
                started, cpu = time.perf_counter(), time.process_time()
                chosen, steps = _selection(info, scorer)
                if time.perf_counter() - started < times["sel_one"]:
                    times["sel_one"] = time.perf_counter() - started
                    times["cpu_one"] = time.process_time() - cpu
            with Scorer(info, client) as scorer:
                started, cpu = time.perf_counter(), time.process_time()
                remote, steps_remote = _selection(info, scorer)
                if time.perf_counter() - started < times["sel_dask"]:
                    times["sel_dask"] = time.perf_counter() - started
                    times["cpu_client"] = time.process_time() - cpu
                    times["cpu_workers"] = [c for _, c in scorer.remote_seconds]
            assert np.array_equal(chosen, remote) and steps == steps_remote
    times["steps"] = steps
    times["n"] = len(pool)
    times["load"] = os.getloadavg()[0]
    return times


def run() -> list[dict]:
    t = measure()
    steps = t["steps"]
    return [
        {
            "task": f"plan of {t['n']} candidates (30 poses, exchange), {WORKERS} Dask workers",
            "value": t["plan_dask"],
            "unit": "s",
            "peer": t["plan_one"],
            "peer_name": "one process (same plan)",
            "goal": ">= 1.5x one process",
            "goal_ratio": 1.5,
            "note": f"wall time; IK batches as tasks, scoring by actors; load {t['load']:.1f}",
        },
        {
            "task": f"one scoring step of {t['n']} candidates, {WORKERS} Dask workers",
            "value": 1e3 * t["sel_dask"] / steps,
            "unit": "ms",
            "peer": 1e3 * t["sel_one"] / steps,
            "peer_name": "one process",
            "goal": ">= 1.5x one process",
            "goal_ratio": 1.5,
            "note": f"greedy + exchange, {steps} steps; CPU ms per step: one process "
            f"{1e3 * t['cpu_one'] / steps:.0f}, workers "
            + "/".join(f"{1e3 * c / steps:.0f}" for c in t["cpu_workers"])
            + f" + client {1e3 * t['cpu_client'] / steps:.0f}",
        },
    ]


if __name__ == "__main__":
    started = time.perf_counter()
    if len(sys.argv) > 1:
        print(measure(int(sys.argv[1]), 1))
    else:
        for row in run():
            print(
                f"{row['task']}: {row['value']:.4g} {row['unit']} vs {row['peer_name']} "
                f"{row['peer']:.4g} (ratio {row['peer'] / row['value']:.2f}); {row['note']}"
            )
    print(f"{time.perf_counter() - started:.1f} s")
