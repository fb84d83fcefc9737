"""The drivers ``relcal capture`` can open: a table ``name -> factory`` for robots and one for
cameras.

A factory is named by ``"module:function"`` and imported only when chosen, so that ``relcal
--help`` and the core never import a driver's library; a library that is missing becomes one
line naming the extra to install. A driver module registers itself by adding a line to the
tables below (or, from outside relcal, with :func:`register_robot` / :func:`register_camera`).

A factory takes a :class:`DriverContext` and returns an object implementing
:class:`relcal.capture.interfaces.Robot` or :class:`relcal.capture.interfaces.Camera`. It reads
its settings from ``context.options`` (``--robot-option KEY=VALUE`` / ``--camera-option
KEY=VALUE``, strings), refuses unknown keys with :func:`check_options`, may set
``context.clock`` when its device keeps time of its own (the virtual cell's simulated clock), and
may leave objects in ``context.shared`` for the other device's factory (robot first, then camera).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from relcal.errors import RelcalError

if TYPE_CHECKING:  # the tables are read by `relcal capture --help`: nothing heavy at import
    from relcal.capture.interfaces import Camera, Robot


def _real_clock():
    from relcal.capture.interfaces import RealClock

    return RealClock()


@dataclass(frozen=True)
class Driver:
    """One entry of a table.

    Attributes
    ----------
    target : str
        ``"package.module:function"``, the factory.
    extra : str or None
        The relcal extra that installs its library (``pip install 'relcal[EXTRA]'``).
    library : str or None
        The top-level module of that library (a missing import of it names the extra).
    summary : str
        One line for ``--help``.
    """

    target: str
    extra: str | None = None
    library: str | None = None
    summary: str = ""


ROBOTS: dict[str, Driver] = {
    "sim": Driver(
        "relcal.capture.virtual:open_robot",
        "virtual",
        "mujoco",
        "the virtual cell: a robot with planted errors, rendered with MuJoCo",
    ),
}

CAMERAS: dict[str, Driver] = {
    "sim": Driver(
        "relcal.capture.virtual:open_camera",
        "virtual",
        "mujoco",
        "the virtual cell's flange camera (with --robot-driver sim)",
    ),
}


def register_robot(name: str, driver: Driver) -> None:
    """Add or replace a robot driver."""
    ROBOTS[name] = driver


def register_camera(name: str, driver: Driver) -> None:
    """Add or replace a camera driver."""
    CAMERAS[name] = driver


@dataclass
class DriverContext:
    """What a factory is given.

    Attributes
    ----------
    model : RobotModel
        The robot (joint names, limits, units).
    options : dict of str to str
        ``--robot-option`` / ``--camera-option`` values for this driver.
    board : Board
    plan_ids : tuple of str
    plan_targets : ndarray, shape (K, n)
        The plan (rad, m).
    clock : Clock
        The loop's clock; a factory may replace it (a simulated device).
    shared : dict
        Objects one factory leaves for the other.
    """

    model: Any
    options: dict[str, str] = field(default_factory=dict)
    board: Any = None
    plan_ids: tuple[str, ...] = ()
    plan_targets: Any = None  # ndarray (K, n)
    clock: Any = field(default_factory=_real_clock)
    shared: dict[str, Any] = field(default_factory=dict)
    what: str = "--robot-driver"


def check_options(context: DriverContext, known: dict[str, str], name: str) -> None:
    """Refuse option keys ``known`` (key -> what it sets) does not list."""
    unknown = sorted(set(context.options) - set(known))
    if unknown:
        flag = "--robot-option" if context.what == "--robot-driver" else "--camera-option"
        listed = "; ".join(f"{k}: {v}" for k, v in known.items()) or "none"
        raise RelcalError(
            f"{flag} {', '.join(unknown)}: not an option of the {name} driver (it takes: {listed})"
        )


def parse_options(pairs: list[str] | None, flag: str) -> dict[str, str]:
    """``["KEY=VALUE", ...]`` to a mapping; a pair without ``=`` is an error naming ``flag``."""
    out: dict[str, str] = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            raise RelcalError(f"{flag} '{pair}': expected KEY=VALUE")
        out[key.strip().lower().replace("_", "-")] = value.strip()
    return out


def _load(table: dict[str, Driver], name: str, what: str):
    if name not in table:
        raise RelcalError(f"{what} '{name}': unknown driver; known: {', '.join(sorted(table))}")
    driver = table[name]
    module, _, function = driver.target.partition(":")
    try:
        return getattr(importlib.import_module(module), function)
    except ImportError as exc:
        missing = getattr(exc, "name", None) or ""
        if driver.library and missing.split(".")[0] == driver.library:
            hint = (
                f"pip install 'relcal[{driver.extra}]'"
                if driver.extra
                else f"pip install {missing}"
            )
            raise RelcalError(
                f"{what} {name}: needs the Python package '{missing}', which is not installed: "
                f"{hint}"
            ) from None
        raise


def open_robot(name: str, context: DriverContext) -> Robot:
    """The robot driver ``name`` opened with ``context``."""
    context.what = "--robot-driver"
    robot = _load(ROBOTS, name, "--robot-driver")(context)
    if tuple(robot.joint_names) != tuple(context.model.joint_names):
        given = ", ".join(robot.joint_names)
        robot.close()
        raise RelcalError(
            f"--robot-driver {name}: the robot reports joints {given}, the model "
            f"{context.model.name} has {', '.join(context.model.joint_names)}; is --robot the "
            "robot connected?"
        )
    return robot


def open_camera(name: str, context: DriverContext) -> Camera:
    """The camera driver ``name`` opened with ``context``."""
    context.what = "--camera"
    return _load(CAMERAS, name, "--camera")(context)
