"""Device time to the capture loop's clock (and :func:`~relcal.errors.require`, with which
drivers import their optional libraries lazily).

A robot controller or a camera stamps its samples on its own clock (the controller's uptime, the
camera's hardware counter, ROS time). The loop compares stamps on *its* clock (:class:`Clock`),
so every driver converts. :class:`ClockMap` does it the way a network time client does without a
round trip: each sample received gives ``loop_now - device_stamp`` = offset + transport latency,
latency is never negative, so the smallest value seen over the last ``window`` seconds is the
offset plus the smallest latency. Converted stamps are therefore late by at most that smallest
latency (a millisecond or two on a wired link), never early: a frame is never taken for fresher
than it is. A device clock that runs at another rate than the loop's (a simulator slower than
real time; crystal drift is negligible) adds at most the rate difference times ``window``.
"""

from __future__ import annotations

from collections import deque

from relcal.capture.interfaces import Clock, RealClock
from relcal.errors import require

__all__ = ["ClockMap", "require"]


class ClockMap:
    """Map device timestamps (s) to the loop's clock (s).

    Parameters
    ----------
    clock : Clock
        The loop's clock.
    window : float
        Seconds of device time over which the smallest ``now - stamp`` is taken (older samples
        are forgotten, so that a drift between the two clocks is followed).
    """

    def __init__(self, clock: Clock | None = None, window: float = 0.25) -> None:
        self.clock = clock or RealClock()
        self.window = float(window)
        self._samples: deque[tuple[float, float]] = deque()  # (device stamp, now - stamp)

    def observe(self, device_stamp: float, received: float | None = None) -> float:
        """Record one sample stamped ``device_stamp`` (s, device clock) received at ``received``
        (s, loop clock; default now) and return its stamp on the loop clock."""
        now = self.clock.now() if received is None else received
        samples = self._samples
        while samples and (
            samples[0][0] < device_stamp - self.window or samples[0][0] > device_stamp
        ):  # too old, or the device clock restarted
            samples.popleft()
        samples.append((device_stamp, now - device_stamp))
        return device_stamp + min(o for _, o in samples)

    def to_loop(self, device_stamp: float) -> float:
        """``device_stamp`` (s, device clock) on the loop clock, with the offset known so far."""
        if not self._samples:
            raise RuntimeError("ClockMap.to_loop before any observed sample")
        return device_stamp + min(o for _, o in self._samples)

    @property
    def offset(self) -> float | None:
        """Loop clock minus device clock (s, plus the smallest latency), ``None`` before any
        sample."""
        return min(o for _, o in self._samples) if self._samples else None
