"""Any robot, moved by the operator: relcal shows each planned target, the operator jogs the arm
there with the teach pendant and confirms; the joints are then read from another driver (one that
can read but need not move, e.g. ``ur`` or ``ros``) or typed in. The camera takes the image as
usual. The questions and answers go through two functions (``ask``, ``tell``) so that a test or a
GUI can stand in for the keyboard.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from relcal.capture.interfaces import (
    CaptureError,
    Clock,
    JointReading,
    MoveFailed,
    RealClock,
    Robot,
)
from relcal.errors import RelcalError

SKIP = ("s", "skip")


class ManualRobot:
    """The operator moves the robot; relcal asks.

    Parameters
    ----------
    joint_names : sequence of str
        The robot model's joint names (the order of ``q``).
    clock : Clock
        The capture loop's clock.
    source : Robot, optional
        A driver the joints are read from; without it the operator types them at each pose.
    unit : {"deg", "rad"}
        The unit of the targets shown and of the joints typed (prismatic joints in m).
    prismatic : sequence of bool, optional
        Which joints are prismatic (shown and typed in m); default none.
    ask : callable
        ``ask(prompt) -> answer``: one line from the operator (default :func:`input`).
    tell : callable
        ``tell(text)``: shows a line to the operator (default :func:`print`).
    """

    def __init__(
        self,
        *,
        joint_names: Sequence[str],
        clock: Clock | None = None,
        source: Robot | None = None,
        unit: str = "deg",
        prismatic: Sequence[bool] | None = None,
        ask: Callable[[str], str] = input,
        tell: Callable[[str], None] = print,
    ) -> None:
        if unit not in ("deg", "rad"):
            raise RelcalError(f"manual option unit: '{unit}': expected deg or rad")
        self.joint_names = tuple(joint_names)
        self._clock = clock or RealClock()
        self._source = source
        self._unit = unit
        n = len(self.joint_names)
        self._prismatic = np.zeros(n, bool) if prismatic is None else np.asarray(prismatic, bool)
        self._ask, self._tell = ask, tell
        self._typed: np.ndarray | None = None
        # the flange poses are those of the source driver (typed joints come without one)
        self.reports_flange = bool(getattr(source, "reports_flange", False))

    def _to_unit(self, q: np.ndarray) -> np.ndarray:
        return np.where(self._prismatic, q, np.degrees(q)) if self._unit == "deg" else q

    def _from_unit(self, values: np.ndarray) -> np.ndarray:
        if self._unit == "rad":
            return values
        return np.where(self._prismatic, values, np.radians(values))

    def _show(self, q: np.ndarray) -> str:
        return ", ".join(
            f"{name} {v:.3f}" for name, v in zip(self.joint_names, self._to_unit(q), strict=True)
        )

    def move(self, q: np.ndarray, timeout: float) -> None:
        """Show the target and wait for the operator: Enter when there (with a source driver),
        the joint values reached (without one), or ``s`` to skip the pose.

        ``timeout`` does not apply: the operator takes the time needed.

        Raises
        ------
        MoveFailed
            The operator skipped the pose.
        """
        q = np.asarray(q, dtype=float)
        n = len(self.joint_names)
        self._tell(f"jog to ({self._unit}): {self._show(q)}")
        while True:
            if self._source is not None:
                answer = self._ask("press Enter when the arm is there and still (s: skip) ")
            else:
                answer = self._ask(
                    f"type the {n} joint values reached ({self._unit}, comma-separated; "
                    "Enter: exactly the target; s: skip) "
                )
            answer = answer.strip()
            if answer.lower() in SKIP:
                raise MoveFailed("manual: the operator skipped this pose")
            if self._source is not None:
                if answer:
                    self._tell("answer with Enter or s")
                    continue
                reached = self._source.read().q
                self._tell(f"read: {self._show(reached)}")
                return
            if not answer:
                self._typed = q.copy()
                return
            try:
                values = np.array([float(v) for v in answer.replace(";", ",").split(",")])
            except ValueError:
                values = np.array([])
            if values.shape != (n,) or not np.isfinite(values).all():
                self._tell(f"expected {n} numbers separated by commas, got '{answer}'")
                continue
            self._typed = self._from_unit(values)
            return

    def read(self) -> JointReading:
        """The joints (and the flange pose, where it reads one) from the source driver, or the
        joints typed last, stamped now (the operator vouches that the arm stands still)."""
        if self._source is not None:
            return self._source.read()
        if self._typed is None:
            raise CaptureError("manual: no joint values yet (the first pose has not been reached)")
        return JointReading(self._typed.copy(), self._clock.now())

    def stop(self) -> None:
        """Ask the operator to stop (relcal cannot)."""
        self._tell("stop the robot now")
        if self._source is not None:
            self._source.stop()

    def close(self) -> None:
        if self._source is not None:
            self._source.close()
