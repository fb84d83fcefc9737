"""Franka Research 3 and Panda through ``franky`` (``pip install 'relcal[franka]'``).

``franky`` talks the libfranka protocol to the robot's FCI (or to ``franky-sim``, its simulator).
A move is one :class:`franky.JointWaypointMotion` to the target, executed asynchronously and
joined with the timeout; franky's trajectory generator ends the motion when the *commanded*
trajectory reaches the target, while the arm is still moving by a few mrad under the joint
impedance controller: the loop's settle check is what decides when it is still. Joint readings
are ``RobotState.q`` and ``RobotState.dq`` (the velocities the settle check uses) stamped with
``RobotState.time`` (the controller's clock) mapped to the loop
clock (:class:`~relcal.capture.timesync.ClockMap`). The flange pose of each reading is the
controller's: ``RobotState.O_T_EE`` (the end effector in the base frame, from the same state's
joints) with the end effector's offset from the flange, ``RobotState.F_T_EE`` (set in Desk for
the hand, or none), taken off.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from relcal.capture.interfaces import CaptureError, Clock, JointReading, MoveFailed, RealClock
from relcal.capture.timesync import ClockMap, require
from relcal.errors import RelcalError

N_JOINTS = 7


class FrankaRobot:
    """A Franka arm at ``host`` (the FCI address; ``franky-sim`` prints its own).

    Parameters
    ----------
    host : str
        The robot's FCI IP address or host name.
    joint_names : sequence of str
        The robot model's 7 joint names, in order (the order of ``q``).
    clock : Clock
        The capture loop's clock.
    dynamics : float
        franky's relative dynamics factor in (0, 1]: the fraction of the robot's velocity,
        acceleration and jerk limits a move uses (default 0.1, slow and smooth).
    realtime : bool
        Require a real-time kernel (libfranka's ``RealtimeConfig.Enforce``); off by default, as
        a capture only makes point-to-point moves.
    """

    def __init__(
        self,
        host: str,
        *,
        joint_names: Sequence[str],
        clock: Clock | None = None,
        dynamics: float = 0.1,
        realtime: bool = False,
    ) -> None:
        self._franky = franky = require("franky", "franka", "the Franka driver")
        if len(joint_names) != N_JOINTS:
            raise RelcalError(
                f"--robot-driver franka: the robot model has {len(joint_names)} joints, a Franka "
                f"arm has {N_JOINTS}; load a 7-joint model (e.g. --robot franka_fr3)"
            )
        if not 0 < dynamics <= 1:
            raise RelcalError(f"franka option dynamics: {dynamics}: expected a number in (0, 1]")
        self.joint_names = tuple(joint_names)
        self.reports_flange = True
        self._clock = clock or RealClock()
        self._map = ClockMap(self._clock)
        config = franky.RealtimeConfig.Enforce if realtime else franky.RealtimeConfig.Ignore
        try:
            self._robot = franky.Robot(host, realtime_config=config)
            self._robot.relative_dynamics_factor = dynamics
            self._robot.recover_from_errors()
        except franky.Exception as exc:
            raise CaptureError(
                f"franka: cannot connect to the robot at '{host}': {exc} (is FCI activated in "
                "Desk, the brakes open and the address right?)"
            ) from None

    def read(self) -> JointReading:
        """The measured joint angles ``(7,)`` (rad) and velocities ``(7,)`` (rad/s), stamped with
        the controller's time of that state, and the flange pose ``(4, 4)`` (m, base frame)."""
        try:
            state = self._robot.state
        except self._franky.Exception as exc:
            raise CaptureError(f"franka: lost the robot state: {exc}") from None
        stamp = self._map.observe(state.time.to_sec())
        ee = np.asarray(state.O_T_EE.matrix, dtype=float)
        offset = np.asarray(state.F_T_EE.matrix, dtype=float)
        flange = ee @ np.linalg.inv(offset)
        q, dq = np.array(state.q, dtype=float), np.array(state.dq, dtype=float)
        return JointReading(q, stamp, dq, flange)

    def move(self, q: np.ndarray, timeout: float) -> None:
        """Move to ``q`` ``(7,)`` (rad); returns when franky reports the motion finished.

        Raises
        ------
        MoveFailed
            The controller refused or aborted the motion (a reflex, a limit), or it did not end
            within ``timeout`` seconds (then the arm is stopped).
        CaptureError
            The connection to the robot is lost.
        """
        franky = self._franky
        q = np.asarray(q, dtype=float)
        if q.shape != (N_JOINTS,):
            raise MoveFailed(f"franka: target has shape {q.shape}, expected ({N_JOINTS},)")
        motion = franky.JointWaypointMotion([franky.JointWaypoint(q.tolist())])
        try:
            self._robot.move(motion, asynchronous=True)
            finished = self._robot.join_motion(timeout)
        except franky.NetworkException as exc:
            raise CaptureError(f"franka: connection lost during a move: {exc}") from None
        except franky.Exception as exc:
            self._recover()
            raise MoveFailed(f"franka: the controller aborted the move: {exc}") from None
        if not finished:
            self.stop()
            raise MoveFailed(f"franka: the move did not finish within {timeout:g} s")

    def _recover(self) -> None:
        try:
            self._robot.recover_from_errors()
        except self._franky.Exception:
            pass

    def stop(self) -> None:
        """Stop the running motion (franky ramps it down)."""
        try:
            self._robot.stop()
            self._robot.join_motion(5.0)
        except self._franky.Exception:
            self._recover()

    def close(self) -> None:
        """Stop; the connection closes with the object."""
        self.stop()
        self._robot = None
