"""Device time to the capture loop's clock (and :func:`~relcal.errors.require`, with which
drivers import their optional libraries lazily).

A robot controller or a camera stamps its samples on its own clock (the controller's uptime, the
camera's hardware counter, ROS time). The loop compares stamps on *its* clock (:class:`Clock`),
so every driver converts. :class:`ClockMap` does it the way a network time client does without a
round trip: each sample received gives ``loop_now - device_stamp`` = offset + transport latency,
latency is never negative, so the smallest value seen over the last ``window`` seconds is the
offset plus the smallest latency. Converted stamps are therefore late by at most that smallest
latency (a millisecond or two on a wired link), never early: a frame is never taken for fresher
than it is.

A device clock may run at another rate than the loop's: crystal drift is negligible, but a
simulator (franky-sim, a Gazebo controller) runs slower than real time on a loaded machine, its
seconds lasting 1.1 to 10 loop seconds. Then the offset grows while samples arrive, and the
smallest one of the window, taken at its face value, would put every stamp up to ``window``
times the slowdown too early (3.5 s was seen in a CI run). So the rate (loop seconds per device
second) is estimated too, from the fastest-delivered samples at both ends of the last
``rate_window`` device seconds, and every older sample's offset is carried forward at that rate
before the smallest is taken (rates within :data:`RATE_DEAD_BAND` of 1 are taken as 1: there
the estimate is latency noise).
"""

from __future__ import annotations

from collections import deque

import numpy as np

from relcal.capture.interfaces import Clock, RealClock
from relcal.errors import require

__all__ = ["ClockMap", "clock_rate", "require"]

RATE_DEAD_BAND = 0.02  # rates within 2 % of 1 are taken as 1
RATE_BIN = 0.005  # s of device time: the rate is estimated from the least delayed sample of each
RATE_EVERY = 10  # bins between two estimates of the rate


def clock_rate(device: np.ndarray, received: np.ndarray, min_span: float = 0.3) -> float | None:
    """Loop seconds per device second from samples stamped ``device`` ``(N,)`` (s, device
    clock) and received at ``received`` ``(N,)`` (s, loop clock), device stamps increasing.

    The slope between the least delayed sample (smallest ``received - rate * device``, the rate
    refined in a few rounds from 1) of the first quarter of the span and that of the last
    quarter: latency only ever delays a sample, so the least delayed ones lie on the line of the
    clocks. ``None`` when the samples span less
    than ``min_span`` device seconds (too short to tell).
    """
    device = np.asarray(device, float)
    received = np.asarray(received, float)
    if len(device) < 2 or device[-1] - device[0] < min_span:
        return None
    quarter = 0.25 * (device[-1] - device[0])
    early = np.flatnonzero(device <= device[0] + quarter)
    late = np.flatnonzero(device >= device[-1] - quarter)
    rate = 1.0
    for _ in range(4):  # "least delayed" is relative to the line: refine it with the slope
        a = early[np.argmin(received[early] - rate * device[early])]
        b = late[np.argmin(received[late] - rate * device[late])]
        if device[b] <= device[a]:
            return None
        rate = float(np.clip((received[b] - received[a]) / (device[b] - device[a]), 0.01, 100.0))
    return rate


class ClockMap:
    """Map device timestamps (s) to the loop's clock (s).

    Parameters
    ----------
    clock : Clock
        The loop's clock.
    window : float
        Seconds of device time over which the smallest ``now - stamp`` is taken (older samples
        are forgotten, so that a change of the transport is followed).
    rate_window : float
        Seconds of device time over which the rate of the device clock is estimated
        (:func:`clock_rate`); 0 assumes both clocks run at the same rate.
    """

    def __init__(
        self, clock: Clock | None = None, window: float = 0.25, rate_window: float = 5.0
    ) -> None:
        self.clock = clock or RealClock()
        self.window = float(window)
        self.rate_window = float(rate_window)
        self._recent: deque[tuple[float, float]] = deque()  # (device stamp, received)
        self._bins: deque[tuple[int, float, float]] = deque()  # (bin, device stamp, received)
        self._newest = -np.inf  # the newest device stamp seen
        self.rate: float | None = None  # loop seconds per device second (None: not known yet)

    def observe(self, device_stamp: float, received: float | None = None) -> float:
        """Record one sample stamped ``device_stamp`` (s, device clock) received at ``received``
        (s, loop clock; default now) and return its stamp on the loop clock.

        Cost: the samples of the last ``window`` device seconds, plus every
        :data:`RATE_EVERY` bins of :data:`RATE_BIN` device seconds a rate estimate over at most
        ``rate_window / RATE_BIN`` samples (about 0.2 ms, 20 times a device second)."""
        d = float(device_stamp)
        now = float(self.clock.now() if received is None else received)
        if d < self._newest - self.window:  # the device clock restarted: everything goes
            self._recent.clear()
            self._bins.clear()
            self._newest = -np.inf
            self.rate = None
        self._newest = max(self._newest, d)
        recent = self._recent
        recent.append((d, now))
        while recent and recent[0][0] < self._newest - self.window:
            recent.popleft()
        if self.rate_window <= 0:
            self.rate = 1.0
        else:
            self._bin(d, now)
        return self.to_loop(d)

    def _bin(self, d: float, now: float) -> None:
        """Keep the least delayed sample of each :data:`RATE_BIN` of device time; re-estimate
        the rate every :data:`RATE_EVERY` bins (every bin while it is not known)."""
        bins = self._bins
        index = int(np.floor(d / RATE_BIN))
        slope = 1.0 if self.rate is None else self.rate
        for k in range(len(bins) - 1, max(len(bins) - 6, -1), -1):  # the newest few bins
            b, bd, br = bins[k]
            if b == index:
                if now - slope * d < br - slope * bd:
                    bins[k] = (index, d, now)
                return
        bins.append((index, d, now))
        while bins and bins[0][1] < self._newest - self.rate_window:
            bins.popleft()
        if len(bins) > 2 and (self.rate is None or index % RATE_EVERY == 0):
            stamps = np.array([(bd, br) for _, bd, br in bins])
            stamps = stamps[np.argsort(stamps[:, 0], kind="stable")]  # delivered out of order
            rate = clock_rate(stamps[:, 0], stamps[:, 1])
            # within the dead band the estimate is latency noise (crystals differ by 1e-5)
            self.rate = 1.0 if rate is not None and abs(rate - 1.0) < RATE_DEAD_BAND else rate

    def to_loop(self, device_stamp: float) -> float:
        """``device_stamp`` (s, device clock) on the loop clock, with the offset known so far:
        the smallest ``received + rate * (device_stamp - stamp)`` over the samples of the last
        ``window`` device seconds. While the rate is not known yet (the first ``0.3`` device
        seconds), only the newest sample is used, at rate 1: late by its latency, never early by
        a slowdown."""
        if not self._recent:
            raise RuntimeError("ClockMap.to_loop before any observed sample")
        if self.rate is None:
            return min(r + device_stamp - d for d, r in self._recent if d == self._newest)
        rate = self.rate
        return min(r + rate * (device_stamp - d) for d, r in self._recent)

    @property
    def offset(self) -> float | None:
        """Loop clock minus device clock (s, plus the smallest latency) at the newest sample,
        ``None`` before any sample."""
        if not self._recent:
            return None
        return self.to_loop(self._newest) - self._newest
