"""Universal Robots (CB3 and e-Series) through ``ur_rtde`` (``pip install 'relcal[ur]'``).

Two RTDE connections, as ``ur_rtde`` has them: :class:`rtde_receive.RTDEReceiveInterface` for the
measured joints (``getActualQ``) and the controller's time of the same packet (``getTimestamp``,
seconds since the controller started, mapped to the loop clock by
:class:`~relcal.capture.timesync.ClockMap`), and :class:`rtde_control.RTDEControlInterface` for
the moves: ``moveJ`` (linear in joint space) sent asynchronously, then polled until the
controller reports the operation over, so that a timeout can stop the arm with ``stopJ``.
The flange pose of each reading is the controller's own: ``getActualTCPPose`` (the tool centre
point in the base frame, computed by the controller with its calibrated kinematics from the same
packet's joints) with the active TCP offset (``getTCPOffset``, read at connection) taken off;
it is in the controller's base frame (``base`` in UR's ROS description, turned 180 deg about z
from ``base_link``). The
control interface uploads its own URScript: the robot must be in remote control mode (e-Series),
and no other program may run on the teach pendant.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from relcal.capture.interfaces import CaptureError, Clock, JointReading, MoveFailed, RealClock
from relcal.capture.timesync import ClockMap, require
from relcal.errors import RelcalError

N_JOINTS = 6
POLL = 0.01  # s between two looks at the asynchronous move's status


def pose_matrix(pose) -> np.ndarray:
    """A UR pose ``(x, y, z, rx, ry, rz)`` (m, rotation vector in rad) as a ``(4, 4)``."""
    from relcal import geometry as tf

    pose = np.asarray(pose, dtype=float)
    return tf.homogeneous(tf.exp_rotation(pose[3:]), pose[:3])


class URRobot:
    """A UR arm at ``host`` (readings carry the controller's flange pose).

    Parameters
    ----------
    host : str
        The controller's IP address or host name.
    joint_names : sequence of str
        The robot model's 6 joint names (base to wrist 3, the order of ``q``).
    clock : Clock
        The capture loop's clock.
    speed : float
        Leading-axis joint speed of ``moveJ``, rad/s (default 0.5).
    acceleration : float
        Leading-axis joint acceleration of ``moveJ``, rad/s^2 (default 0.8).
    frequency : float
        RTDE frequency, Hz (-1: the controller's default, 500 Hz on e-Series, 125 Hz on CB3).
    """

    def __init__(
        self,
        host: str,
        *,
        joint_names: Sequence[str],
        clock: Clock | None = None,
        speed: float = 0.5,
        acceleration: float = 0.8,
        frequency: float = -1.0,
    ) -> None:
        control = require("rtde_control", "ur", "the Universal Robots driver")
        receive = require("rtde_receive", "ur", "the Universal Robots driver")
        if len(joint_names) != N_JOINTS:
            raise RelcalError(
                f"--robot-driver ur: the robot model has {len(joint_names)} joints, a UR arm has "
                f"{N_JOINTS}; load a UR model (e.g. --robot ur5e)"
            )
        for name, value, top in (("speed", speed, 3.15), ("acceleration", acceleration, 40.0)):
            if not 0 < value <= top:
                raise RelcalError(f"ur option {name}: {value}: expected a number in (0, {top:g}]")
        self.joint_names = tuple(joint_names)
        self.reports_flange = True
        self.speed, self.acceleration = float(speed), float(acceleration)
        self._clock = clock or RealClock()
        self._map = ClockMap(self._clock)
        try:
            self._receive = receive.RTDEReceiveInterface(host, frequency)
            self._control = control.RTDEControlInterface(host, frequency)
        except RuntimeError as exc:
            raise CaptureError(
                f"ur: cannot connect to the controller at '{host}': {exc} (is the robot on, in "
                "remote control mode, and the address right?)"
            ) from None
        from relcal import geometry as tf

        self._tool = tf.invert(pose_matrix(self._control.getTCPOffset()))  # TCP -> flange

    def read(self) -> JointReading:
        """The measured joint angles ``(6,)`` (rad) and velocities ``(6,)`` (rad/s), stamped with
        the controller's time, and the controller's flange pose ``(4, 4)`` (m, base frame)."""
        if not self._receive.isConnected():
            raise CaptureError("ur: the RTDE receive connection is lost")
        device_time = float(self._receive.getTimestamp())
        q = np.array(self._receive.getActualQ(), dtype=float)
        dq = np.array(self._receive.getActualQd(), dtype=float)
        flange = pose_matrix(self._receive.getActualTCPPose()) @ self._tool
        return JointReading(q, self._map.observe(device_time), dq, flange)

    def _check_safety(self) -> None:
        if self._receive.isProtectiveStopped() or self._receive.isEmergencyStopped():
            raise CaptureError(
                "ur: the robot is in a protective or emergency stop; clear it on the teach "
                "pendant, then resume the capture"
            )

    def move(self, q: np.ndarray, timeout: float) -> None:
        """``moveJ`` to ``q`` ``(6,)`` (rad); returns when the controller reports it over.

        Raises
        ------
        MoveFailed
            The target is outside the safety limits, the controller refused the move, or it did
            not end within ``timeout`` seconds (then the arm is stopped with ``stopJ``).
        CaptureError
            A protective or emergency stop, or the connection is lost.
        """
        q = np.asarray(q, dtype=float)
        if q.shape != (N_JOINTS,):
            raise MoveFailed(f"ur: target has shape {q.shape}, expected ({N_JOINTS},)")
        self._check_safety()
        target = q.tolist()
        if not self._control.isJointsWithinSafetyLimits(target):
            raise MoveFailed("ur: the target is outside the controller's safety joint limits")
        before = self._control.getAsyncOperationProgressEx().operationId()
        if not self._control.moveJ(target, self.speed, self.acceleration, True):
            self._check_safety()
            raise MoveFailed("ur: the controller refused moveJ")
        start = self._clock.now()
        while True:
            status = self._control.getAsyncOperationProgressEx()
            if status.operationId() != before and not status.isAsyncOperationRunning():
                break
            if self._clock.now() - start > timeout:
                self.stop()
                raise MoveFailed(f"ur: moveJ did not finish within {timeout:g} s")
            if not self._control.isConnected():
                raise CaptureError("ur: the RTDE control connection is lost during a move")
            self._clock.sleep(POLL)
        self._check_safety()

    def stop(self) -> None:
        """Decelerate every joint to rest (``stopJ``)."""
        self._control.stopJ(2.0)

    def close(self) -> None:
        """Stop the control script and close both connections."""
        try:
            self._control.stopScript()
        finally:
            self._control.disconnect()
            self._receive.disconnect()
