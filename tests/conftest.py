"""Shared fixtures: robots, random configurations, and the real data folder."""

import signal
from pathlib import Path

import numpy as np
import pytest

from relcal.robot.loading import get_robot

# A run started in the background by a shell without job control (`make test &` in a script)
# inherits SIGINT ignored; the tests of interrupts need Python's own handler, as a terminal has.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def pytest_addoption(parser):
    parser.addoption(
        "--update-docs",
        action="store_true",
        help="tests/test_docs_commands.py rewrites the figures the pages quote (text output "
        "blocks, <!--out ...--> figures) from what the commands print, instead of failing; "
        "review the diff (docs/contributing.md)",
    )


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)


@pytest.fixture
def a465():
    return get_robot("a465")


def random_q(model, n: int, rng: np.random.Generator, scale: float = 0.9) -> np.ndarray:
    """Random configurations inside the joint limits (or +-pi where unlimited)."""
    lo = np.where(np.isfinite(model.lower), model.lower, -np.pi)
    hi = np.where(np.isfinite(model.upper), model.upper, np.pi)
    mid, half = (lo + hi) / 2, (hi - lo) / 2 * scale
    return rng.uniform(mid - half, mid + half, (n, model.n_joints))
