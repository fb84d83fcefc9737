"""Worker set-up of relcal's Dask tasks (relcal.cluster)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

FAULTS = """
import resource, sys
import numpy as np
from relcal.cluster import prepare_worker

def faults():
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(200):
        a = np.ones(1 << 17)  # 1 MiB: above the frozen 128 KiB mmap threshold
        del a
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before

faults()
frozen = faults()
prepare_worker()
faults()
print(frozen, faults())
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc only")
def test_prepare_worker_undoes_the_nannys_malloc_trim_threshold():
    """With ``MALLOC_TRIM_THRESHOLD_`` set (as Dask's nanny does) every 1 MiB array is mapped
    and faulted in afresh; after prepare_worker the heap serves it again."""
    env = {**os.environ, "MALLOC_TRIM_THRESHOLD_": "65536"}
    out = subprocess.run(
        [sys.executable, "-c", FAULTS], env=env, capture_output=True, text=True, check=True
    )
    frozen, prepared = map(int, out.stdout.split())
    assert frozen > 200 * 200  # about 256 page faults per array
    assert prepared < frozen / 20


def test_prepare_worker_leaves_a_normal_process_alone(monkeypatch):
    import relcal.cluster as cluster

    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)
    monkeypatch.setattr(cluster, "_prepared", False)
    monkeypatch.setattr(cluster.ctypes, "CDLL", None)  # would raise if it were called
    cluster.prepare_worker()
    assert cluster._prepared
