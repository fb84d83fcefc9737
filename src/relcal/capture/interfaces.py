"""What the capture loop needs from a robot, a camera and a clock: the whole contract a driver
implements.

Every timestamp is in seconds on the clock the loop is given (:class:`Clock`); a driver whose
device stamps on another clock converts to it, so that "this frame was exposed after the arm
became still" is a comparison of two numbers. Joint values are in the robot model's units
(rad for revolute joints, m for prismatic ones), in the order of ``joint_names``.

A driver that reads the controller's flange pose (the flange in the robot's base frame, computed
by the controller from the same joint measurement) says so with a class attribute
``reports_flange = True`` and puts the pose in :attr:`JointReading.flange`; the loop then records
it beside the joints (columns ``fx`` .. ``fqw``), so that ``relcal handeye`` needs no robot
model. The attribute is optional: a driver without it reports none.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from relcal.errors import RelcalError
from relcal.vision.camera import Camera as Intrinsics


class CaptureError(RelcalError):
    """A device failed in a way that ends the run (connection lost, protective stop)."""


class MoveFailed(RelcalError):
    """One move did not reach its target (unreachable, timeout, rejected by the controller):
    the loop retries or skips that pose and goes on."""


@dataclass(frozen=True)
class JointReading:
    """One joint measurement: ``q`` ``(n,)`` (rad, m) stamped ``stamp`` (s, the loop's clock),
    the joint velocities ``dq`` ``(n,)`` (rad/s, m/s) where the controller reports them
    (``None`` otherwise: the loop then judges stillness from positions alone), and the
    controller's flange pose ``flange`` ``(4, 4)`` (the flange in the robot's base frame, m) at
    the same instant where the driver reads it (``None`` otherwise)."""

    q: np.ndarray
    stamp: float
    dq: np.ndarray | None = None
    flange: np.ndarray | None = None


@dataclass(frozen=True)
class Frame:
    """One camera frame: ``image`` ``(H, W)`` or ``(H, W, 3)`` uint8 (BGR), exposed at ``stamp``
    (s, the loop's clock: the middle of the exposure where the device says so, else the time the
    driver received it). ``sequence``: the device's frame counter when it has one."""

    image: np.ndarray
    stamp: float
    sequence: int | None = None
    meta: dict = field(default_factory=dict)


@runtime_checkable
class Clock(Protocol):
    """Time for the loop and the devices: real (:class:`RealClock`) or simulated."""

    def now(self) -> float:
        """Seconds, monotonic."""
        ...

    def sleep(self, seconds: float) -> None: ...


@runtime_checkable
class Robot(Protocol):
    """A robot arm the loop can move and read."""

    joint_names: tuple[str, ...]

    def read(self) -> JointReading:
        """The current joint values, stamped."""
        ...

    def move(self, q: np.ndarray, timeout: float) -> None:
        """Move to joint target ``q`` ``(n,)`` and return when the driver reports the motion
        done (not necessarily settled: the loop checks that itself). Raises :class:`MoveFailed`
        when the target is not reached within ``timeout`` seconds or is refused."""
        ...

    def stop(self) -> None:
        """Stop any motion now (called on interrupt and on errors)."""
        ...

    def close(self) -> None: ...


@runtime_checkable
class Camera(Protocol):
    """A camera the loop can take frames from."""

    def grab(self, timeout: float) -> Frame:
        """The next frame the device delivers (possibly one buffered before the call: the loop
        discards frames stamped too early). Raises :class:`CaptureError` after ``timeout``
        seconds without one."""
        ...

    def intrinsics(self) -> Intrinsics | None:
        """The device's own intrinsics, where it knows them (else ``None``)."""
        ...

    def close(self) -> None: ...


class RealClock:
    """The wall of :func:`time.monotonic`."""

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        time.sleep(max(seconds, 0.0))
