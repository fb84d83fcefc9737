"""BLAS threads: relcal's small, tall factorisations run fastest on one."""

from __future__ import annotations

import functools
import threading

_limited = threading.local()  # set while this thread runs under the limit


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
        if getattr(_limited, "on", False):  # nested: the caller holds the limit already
            return function(*args, **kwargs)
        with _blas_threads().limit(limits=1, user_api="blas"):
            _limited.on = True
            try:
                return function(*args, **kwargs)
            finally:
                _limited.on = False

    return limited
