"""A registry writer process for the concurrency test (imports only the registry)."""

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
