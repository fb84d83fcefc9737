"""Device time to the capture loop's clock, and the optional libraries drivers import lazily.

A robot controller or a camera stamps its samples on its own clock (the controller's uptime, the
camera's hardware counter, ROS time). The loop compares stamps on *its* clock (:class:`Clock`),
so every driver converts. :class:`ClockMap` does it the way a network time client does without a
round trip: each sample received gives ``loop_now - device_stamp`` = offset + transport latency,
latency is never negative, so the smallest value seen over a recent window is the offset plus the
smallest latency. Converted stamps are therefore late by at most the smallest latency of the
window (a millisecond or two on a wired link), never early: a frame is never taken for fresher
than it is.
"""

from __future__ import annotations

import importlib
from collections import deque
from types import ModuleType

from relcal.capture.interfaces import Clock, RealClock
from relcal.errors import RelcalError


class ClockMap:
    """Map device timestamps (s) to the loop's clock (s).

    Parameters
    ----------
    clock : Clock
        The loop's clock.
    window : int
        Samples over which the smallest ``now - stamp`` is taken (older ones are forgotten, so a
        slow drift between the two clocks is followed).
    """

    def __init__(self, clock: Clock | None = None, window: int = 500) -> None:
        self.clock = clock or RealClock()
        self._offsets: deque[float] = deque(maxlen=window)

    def observe(self, device_stamp: float, received: float | None = None) -> float:
        """Record one sample stamped ``device_stamp`` (s, device clock) received at ``received``
        (s, loop clock; default now) and return its stamp on the loop clock."""
        now = self.clock.now() if received is None else received
        self._offsets.append(now - device_stamp)
        return device_stamp + min(self._offsets)

    def to_loop(self, device_stamp: float) -> float:
        """``device_stamp`` (s, device clock) on the loop clock, with the offset known so far."""
        if not self._offsets:
            raise RuntimeError("ClockMap.to_loop before any observed sample")
        return device_stamp + min(self._offsets)

    @property
    def offset(self) -> float | None:
        """Loop clock minus device clock (s, plus the smallest latency), ``None`` before any
        sample."""
        return min(self._offsets) if self._offsets else None


def require(module: str, extra: str, what: str) -> ModuleType:
    """Import the optional library ``module`` of a driver, or raise a :class:`RelcalError`
    naming the extra that installs it (``pip install 'relcal[extra]'``)."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise RelcalError(
            f"{what} needs the Python module '{module}', which is not installed ({exc}); "
            f"install it with: pip install 'relcal[{extra}]'"
        ) from None
