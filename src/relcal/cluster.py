"""Dask clusters for work in parallel: a local cluster of worker processes or a running one, and
the set-up every relcal task makes on its worker.

Two defaults of Dask's workers cost relcal's many small NumPy arrays dearly, both measured on
fleet sessions of 30 samples (one worker process against the same loop in one process):

- the nanny starts workers with ``MALLOC_TRIM_THRESHOLD_=65536``. Setting that variable also
  freezes glibc's threshold for serving allocations with ``mmap`` at 128 KiB, so every array
  of a few hundred KiB (Jacobians of 100 poses) is mapped, zero-filled by page faults and unmapped
  again: 1.4x to 1.6x slower. :func:`prepare_worker` raises both thresholds again, at run time,
  also on workers started by hand;
- the workers' statistical profiler samples the task thread's stack every few milliseconds and
  holds the GIL often enough to make calibrations about twice as slow. A local cluster starts
  without it; for ``dask worker`` set ``DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED=False``.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from relcal.errors import RelcalError

# glibc's mallopt parameters (malloc.h) and the largest mmap threshold it would reach by itself
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
_MMAP_THRESHOLD = 32 << 20
_prepared = False
_blas_limit = None  # a Dask worker's BLAS limit, held for the life of the process


def prepare_worker() -> None:
    """Call at the start of a task (once per process has effect): undo ``MALLOC_TRIM_THRESHOLD_``
    (a no-op where it is unset or the C library is not glibc), and on a Dask worker keep BLAS on
    one thread for good (threadpoolctl takes milliseconds a call; relcal's matrices are small)."""
    global _prepared, _blas_limit
    if _prepared:
        return
    _prepared = True
    if _on_dask_worker():
        from threadpoolctl import threadpool_limits

        _blas_limit = threadpool_limits(limits=1)
    if "MALLOC_TRIM_THRESHOLD_" not in os.environ:
        return
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc: the variable meant nothing there either
        return
    mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD)
    mallopt(_M_TRIM_THRESHOLD, 2 * _MMAP_THRESHOLD)


def _on_dask_worker() -> bool:
    """Whether this runs in a Dask worker's task (never imports Dask to find out)."""
    distributed = sys.modules.get("distributed")
    if distributed is None:
        return False
    try:
        distributed.get_worker()
    except ValueError:
        return False
    return True


def local_cluster(workers: int):
    """A local Dask cluster of ``workers`` single-threaded worker processes, without the workers'
    statistical profiler (see the module's docstring)."""
    import dask
    from distributed import LocalCluster

    from relcal.limits import check_workers

    if workers < 1:
        raise RelcalError(f"workers={workers}: expected at least 1 worker process")
    check_workers(workers)
    with dask.config.set({"distributed.worker.profile.enabled": False}):
        return LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.CRITICAL,
        )


def connect(scheduler: str | None, workers: int = 2) -> tuple[Any, Any]:
    """``(client, cluster)``: a client of the running cluster at ``scheduler`` (cluster None), or
    of a new local cluster of ``workers`` processes. Close the client, then the cluster."""
    try:
        from distributed import Client
    except ImportError:
        raise RelcalError(
            "work on a Dask cluster needs Dask distributed: pip install 'relcal[fleet]'"
        ) from None
    if scheduler:
        try:
            return Client(scheduler, timeout="20s"), None
        except (OSError, TimeoutError) as exc:
            raise RelcalError(f"--scheduler {scheduler}: cannot connect: {exc}") from None
    cluster = client = None
    try:
        with _interrupts_deferred():  # a cluster half started cannot be closed (see below)
            cluster = local_cluster(workers)
            client = Client(cluster)
    except BaseException:  # an interrupt delivered now, or a failed start: close what started
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
        raise
    return client, cluster


@contextmanager
def _interrupts_deferred() -> Iterator[None]:
    """SIGINT and SIGTERM noted during the block and delivered once it is done (a second one
    is delivered at once). A local cluster interrupted while its workers start is unreachable
    (the constructor never returned it) and its workers are still starting: Dask's own exit
    handler then fails on them with an AssertionError traceback. Deferred, the interrupt
    arrives once the cluster is up, and the caller closes it as for any other interrupt.
    Only the Python handlers are swapped, never the signal mask, which the worker processes
    would inherit."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    sigs = (signal.SIGINT, signal.SIGTERM)
    caught: list[int] = []
    old = {s: signal.getsignal(s) for s in sigs}

    def note(signum, frame):
        if caught:  # asked twice: the user means it
            handler = old.get(signum)
            if callable(handler):
                handler(signum, frame)
            raise KeyboardInterrupt
        caught.append(signum)

    for s in sigs:
        signal.signal(s, note)
    try:
        yield
    finally:
        for s, handler in old.items():
            signal.signal(s, signal.SIG_DFL if handler is None else handler)
        for n in dict.fromkeys(caught):
            signal.raise_signal(n)


def n_workers(client) -> int:
    """Workers of ``client``'s cluster now (at least 1)."""
    return max(1, len(client.scheduler_info().get("workers", {})))
