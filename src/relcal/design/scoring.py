"""The best candidate of a pool for a base information: scored block by block in this process,
or on a Dask cluster by actors holding shards of the pool's rows (:class:`Scorer`). Scores are
computed in the same fixed blocks of pool indices in both cases, so the choice is the same."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from relcal.cluster import prepare_worker
from relcal.design.criteria import Information, _prepare, _scores

BLOCK = 1024  # candidates scored at once: bounds the temporaries (a few MB)
# Fewest candidates worth a worker's scoring step (about 10 ms of work against an actor call's
# 2 ms and the client's 5 ms; the README has the measured numbers).
MIN_SHARD = 4096


def _block_best(
    info: Information,
    prepared: tuple,
    rows: np.ndarray,
    offset: int,
    excluded: np.ndarray,
    name: str,
    n_meas: int,
    block: int = BLOCK,
) -> tuple[float, int]:
    """``(value, index)`` of the best candidate among ``rows`` (pool indices from ``offset``)
    that is not ``excluded``, scored in blocks of ``block`` pool indices; ``(-inf, -1)`` if
    there is none. NaN scores count as -inf; ties go to the lowest index."""
    best, where = -np.inf, -1
    start = offset
    while start < offset + len(rows):
        stop = min((start // block + 1) * block, offset + len(rows))  # blocks align on the pool
        part = rows[start - offset : stop - offset]
        vals = np.asarray(_scores(info, prepared, part, name, n_meas))
        allowed = np.ones(stop - start, dtype=bool)
        allowed[excluded[(excluded >= start) & (excluded < stop)] - start] = False
        vals = np.where(allowed & ~np.isnan(vals), vals, -np.inf)
        i = int(np.argmax(vals))
        if allowed.any() and not allowed[i]:  # every allowed score is -inf
            i = int(np.argmax(allowed))
        if allowed.any() and (where < 0 or vals[i] > best):
            best, where = float(vals[i]), start + i
        start = stop
    return best, where


class Scorer:
    """Best candidate of a pool for a base information, in this process or on a Dask cluster.

    With ``client``, the pool's rows go once to the workers, one contiguous shard (whole blocks
    of ``block`` candidates, at least ``min_shard``, by default :data:`MIN_SHARD`) per worker
    held by a Dask actor, and
    each step asks every actor for its best ``(value, index)``. Actor calls go from this process
    to the workers directly: a task would pass the scheduler twice per step, tens of ms on a
    busy machine. The scores are computed block by block exactly as in this process, so the
    choice is the same; a pool too small for two shards is scored here. Should the cluster fail
    (a worker lost), the remaining steps run here, with the same result. Use as a context manager
    (it releases the actors)."""

    def __init__(
        self,
        info: Information,
        client=None,
        block: int | None = None,
        min_shard: int | None = None,
    ) -> None:
        self.info, self.client = info, client
        self.block = block = block or BLOCK
        self.n = len(info.rows)
        self._actors: list = []
        self._futures: list = []
        if client is None:
            return
        workers = list(client.scheduler_info().get("workers", {}))
        blocks = -(-self.n // block)
        shards = min(len(workers), blocks, self.n // (min_shard or MIN_SHARD))
        if shards < 2:
            self.client = None
            return
        parts = np.array_split(np.arange(blocks), shards)
        light = replace(info, rows=info.rows[:0])
        for part, worker in zip(parts, workers, strict=False):
            lo, hi = int(part[0]) * block, min(self.n, (int(part[-1]) + 1) * block)
            rows = client.scatter(info.rows[lo:hi], workers=[worker], hash=False)
            future = client.submit(
                _Shard, light, rows, lo, block, workers=[worker], actor=True, pure=False
            )
            self._futures.append(future)
            self._actors.append(future.result())
            rows.release()

    def best(self, base: np.ndarray, excluded: np.ndarray, name: str, n_meas: int):
        """``(value, index)`` of the candidate not in ``excluded`` that maximises the criterion
        of ``base`` plus its information."""
        prepared = _prepare(self.info, base, name)
        excluded = np.unique(np.asarray(excluded, dtype=int))
        if self._actors:
            try:
                calls = [a.best(prepared, excluded, name, n_meas) for a in self._actors]
                found = [vi for vi in (c.result() for c in calls) if vi[1] >= 0]
                return max(found, key=lambda vi: (vi[0], -vi[1]), default=(-np.inf, -1))
            except Exception as exc:  # a lost worker, a closed cluster: carry on here
                import warnings

                warnings.warn(f"scoring on the cluster failed ({exc}); scoring here", stacklevel=2)
                self.close()
        rows = self.info.rows
        return _block_best(self.info, prepared, rows, 0, excluded, name, n_meas, self.block)

    @property
    def remote_calls(self) -> list[int]:
        """Steps each actor has scored (empty in this process)."""
        return [a.calls for a in self._actors]

    @property
    def remote_seconds(self) -> list[tuple[float, float]]:
        """Wall and CPU time each actor has spent scoring, s (empty in this process)."""
        return [(a.seconds, a.cpu_seconds) for a in self._actors]

    def close(self) -> None:
        for future in self._futures:
            future.release()
        self._actors, self._futures = [], []

    def __enter__(self) -> Scorer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class _Shard:
    """A Dask actor: the rows ``(M, r, Q)`` of pool indices ``offset..offset + M`` and the pool's
    information without rows; :meth:`best` is one step's best candidate among them."""

    calls: int = 0  # steps scored (on the class: a Dask actor's proxy reads attributes it knows)
    seconds: float = 0.0  # wall time spent scoring them
    cpu_seconds: float = 0.0  # CPU time of the scoring thread

    def __init__(self, info: Information, rows: np.ndarray, offset: int, block: int) -> None:
        # a copy of its own: the received array lives in a network buffer, often unaligned
        # (NumPy's matmul then bypasses BLAS, slower and rounding differently) and read-only
        self.info, self.rows, self.offset, self.block = info, np.array(rows), offset, block

    def best(self, prepared, excluded, name: str, n_meas: int) -> tuple[float, int]:
        import time

        started, cpu = time.perf_counter(), time.thread_time()
        prepare_worker()
        info, rows = self.info, self.rows
        prepared = tuple(np.array(x) for x in prepared)  # aligned copies, as the rows
        found = _block_best(info, prepared, rows, self.offset, excluded, name, n_meas, self.block)
        self.calls += 1
        self.seconds += time.perf_counter() - started
        self.cpu_seconds += time.thread_time() - cpu
        return found
