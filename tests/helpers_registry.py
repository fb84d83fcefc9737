"""Registry writer processes for the concurrency tests (a writer imports only the registry)."""

import multiprocessing
import time
from queue import Empty

from relcal.fleet.registry import Registry


def writer(url: str, record: dict, worker: int, count: int, barrier, queue) -> None:
    """Open the registry (racing the others for the migration), wait until every writer has it
    open, then write ``count`` records as fast as possible; report the ids or the error."""
    try:
        with Registry(url) as registry:
            barrier.wait(timeout=120)
            ids = [registry.add({**record, "session": f"w{worker}-{k}"}) for k in range(count)]
        queue.put(("ok", ids))
    except Exception as exc:  # reported to the test
        queue.put(("error", repr(exc)))


def write_concurrently(url: str, record: dict, n_proc: int, count: int) -> list[tuple]:
    """``n_proc`` spawned :func:`writer` processes at once, ``count`` records each: their
    reports, ``("ok", ids)`` or ``("error", repr)``, one per process."""
    ctx = multiprocessing.get_context("spawn")
    queue, barrier = ctx.Queue(), ctx.Barrier(n_proc)
    procs = [
        ctx.Process(target=writer, args=(url, record, w, count, barrier, queue))
        for w in range(n_proc)
    ]
    for p in procs:
        p.start()
    results: list[tuple] = []
    deadline = time.monotonic() + 600  # a loaded CI machine: spawning and importing take long
    while len(results) < n_proc and time.monotonic() < deadline:
        try:
            results.append(queue.get(timeout=2))
        except Empty:
            if not any(p.is_alive() for p in procs) and queue.empty():
                break  # a writer died without reporting: say how, below
    for p in procs:
        p.join(timeout=60)
    if len(results) < n_proc:
        codes = [p.exitcode for p in procs]
        results.append(("missing", f"{n_proc - len(results)} writer(s) silent; exit codes {codes}"))
    return results
