"""The robot drivers and cameras ``relcal capture`` can open, by name: a table of lazy import
paths (nothing is imported until a device is opened, so a missing optional library only matters
to whoever uses that device), and one function per kind that opens a device from its name and
its options as text (the command line's ``--robot-driver NAME --robot-option KEY=VALUE``).

A new driver is a class implementing :class:`~relcal.capture.interfaces.Robot` or
:class:`~relcal.capture.interfaces.Camera` plus one line in :data:`ROBOTS` or :data:`CAMERAS`.
Robot classes take the keyword arguments ``joint_names`` and ``clock``, cameras ``clock``; their
other keyword arguments are the options, converted from text by their type hints.
"""

from __future__ import annotations

import importlib
import inspect
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from relcal.errors import RelcalError


@dataclass(frozen=True)
class Device:
    """One entry of the registry: ``target`` is ``module:Class``; ``extra`` the optional
    dependency group that installs its library (``None``: in the core); ``summary`` one line."""

    target: str
    extra: str | None
    summary: str

    def load(self) -> type:
        """The driver class (imports its module, not yet its optional library)."""
        module, _, name = self.target.partition(":")
        return getattr(importlib.import_module(module), name)


ROBOTS: dict[str, Device] = {
    "ur": Device("relcal.capture.robots.ur:URRobot", "ur", "Universal Robots over RTDE (ur_rtde)"),
    "franka": Device(
        "relcal.capture.robots.franka:FrankaRobot", "franka", "Franka FR3 / Panda (franky)"
    ),
    "ros": Device(
        "relcal.capture.robots.ros:RosRobot",
        "ros",
        "any ros2_control arm through rosbridge (roslibpy)",
    ),
    "manual": Device(
        "relcal.capture.robots.manual:ManualRobot",
        None,
        "the operator jogs; joints typed or read from another driver (option source=NAME)",
    ),
}
ROBOTS["sim"] = Device(
    "relcal.capture.virtual:VirtualRobot",
    "virtual",
    "the virtual cell (MuJoCo): an arm with planted errors; with --camera sim",
)

CAMERAS: dict[str, Device] = {
    "opencv": Device(
        "relcal.capture.cameras.opencv:OpenCVCamera", None, "OpenCV VideoCapture (UVC, V4L2)"
    ),
    "realsense": Device(
        "relcal.capture.cameras.realsense:RealSenseCamera",
        "realsense",
        "Intel RealSense (pyrealsense2)",
    ),
    "genicam": Device(
        "relcal.capture.cameras.genicam:GenICamCamera",
        "genicam",
        "GenICam cameras through a GenTL producer (harvesters)",
    ),
    "folder": Device(
        "relcal.capture.cameras.folder:FolderCamera",
        None,
        "new image files another program writes into a folder",
    ),
}
CAMERAS["sim"] = Device(
    "relcal.capture.virtual:VirtualCamera",
    "virtual",
    "the virtual cell's flange camera (with --robot-driver sim), or a virtual camera that "
    "follows any other driver's joints",
)

CONTEXT = ("joint_names", "clock", "source", "ask", "tell", "prismatic")  # given, not options


def parse_options(items: Sequence[str], what: str) -> dict[str, str]:
    """``KEY=VALUE`` items (each may hold several, comma-separated) as a dict."""
    options: dict[str, str] = {}
    for item in items:
        for part in _split(item):
            key, sep, value = part.partition("=")
            if not sep or not key.strip():
                raise RelcalError(f"{what} '{part}': expected KEY=VALUE")
            options[key.strip()] = value.strip()
    return options


def _split(item: str) -> list[str]:
    """Split at commas that start a new ``KEY=``, so values may hold commas (joint lists)."""
    parts: list[str] = []
    for piece in item.split(","):
        if parts and "=" not in piece:
            parts[-1] += "," + piece
        elif piece.strip():
            parts.append(piece)
    return parts


def _convert(value: str, hint, name: str, kind: str, device: str):
    origin = typing.get_origin(hint)
    args = [a for a in typing.get_args(hint) if a is not type(None)]
    if origin is not None and args:  # Optional[X] / X | None
        hint = args[0]
    try:
        if hint is bool:
            if value.lower() in ("1", "true", "yes", "on"):
                return True
            if value.lower() in ("0", "false", "no", "off"):
                return False
            raise ValueError(value)
        if hint in (int, float):
            return hint(value)
        return value
    except ValueError:
        expected = {bool: "true or false", int: "an integer", float: "a number"}[hint]
        message = f"{kind} {device} option {name}: '{value}': expected {expected}"
        raise RelcalError(message) from None


def _open(table: Mapping[str, Device], kind: str, name: str, options, context: dict):
    if name not in table:
        raise RelcalError(f"{kind} '{name}': expected one of {', '.join(sorted(table))}")
    cls = table[name].load()
    params = inspect.signature(cls).parameters
    hints = typing.get_type_hints(cls.__init__)
    accepted = [p for p in params if p not in CONTEXT and p not in context and p != "self"]
    kwargs = {k: v for k, v in context.items() if k in params}
    for key, value in dict(options).items():
        if key not in accepted:
            raise RelcalError(
                f"{kind} {name}: unknown option '{key}'; its options are {', '.join(accepted)}"
            )
        kwargs[key] = _convert(value, hints.get(key, str), key, kind, name)
    missing = [
        p for p, spec in params.items()
        if spec.default is inspect.Parameter.empty and p not in kwargs and p != "self"
        and spec.kind not in (spec.VAR_POSITIONAL, spec.VAR_KEYWORD)
    ]  # fmt: skip
    if missing:
        raise RelcalError(f"{kind} {name}: option {', '.join(missing)}=... is required")
    return cls(**kwargs)


def open_robot(
    name: str,
    options: Mapping[str, str],
    *,
    joint_names: Sequence[str],
    clock=None,
    **context,
):
    """Open robot driver ``name`` with its text ``options`` for a robot model with
    ``joint_names``; the manual driver's option ``source=NAME`` opens driver ``NAME`` with the
    other options to read the joints from. Further keyword arguments (``context``) go to the
    driver's constructor where it has a parameter of that name (e.g. the virtual cell's shared
    world), never taken as options."""
    options = dict(options)
    context = {"joint_names": tuple(joint_names), "clock": clock, **context}
    if name == "manual" and "source" in options:
        source = options.pop("source")
        manual_keys = {"unit"}
        inner = {k: v for k, v in options.items() if k not in manual_keys}
        options = {k: v for k, v in options.items() if k in manual_keys}
        context["source"] = open_robot(source, inner, joint_names=joint_names, clock=clock)
    return _open(ROBOTS, "--robot-driver", name, options, context)


def open_camera(name: str, options: Mapping[str, str], *, clock=None, **context):
    """Open camera ``name`` with its text ``options``; ``context`` as in :func:`open_robot`
    (e.g. ``robot=`` for a camera that needs the robot driver, as the virtual cell's does)."""
    return _open(CAMERAS, "--camera", name, options, {"clock": clock, **context})


def describe() -> str:
    """The drivers and cameras with their extras, for ``--help``."""
    lines = ["robot drivers:"]
    for table, title in ((ROBOTS, None), (CAMERAS, "cameras:")):
        if title:
            lines.append(title)
        for key, dev in table.items():
            extra = f" [extra {dev.extra}]" if dev.extra else ""
            lines.append(f"  {key:10s} {dev.summary}{extra}")
    return "\n".join(lines)
