"""Subcommands of the ``relcal`` command line, one module each with ``register(subparsers)``.

To add a command, write a module here with a ``register`` function and list it in ``COMMANDS``.
Building the parser imports every command module, so they stay light at import: ``register``
and the option types here need only argparse and the standard library; NumPy, SciPy, OpenCV,
SQLAlchemy and the calibration modules are imported inside the functions that run a command
(``relcal --help`` starts in tens of milliseconds, not a second).
"""

from __future__ import annotations

import argparse
import importlib
import math
import os
import re
from collections.abc import Callable
from pathlib import Path

COMMANDS = [
    "simulate",
    "calibrate",
    "imports",
    "compensate",
    "board",
    "observability",
    "study",
    "plan",
    "capture",
    "fleet",
    "history",
    "verify",
    "handeye",
]


def register_all(sub: argparse._SubParsersAction) -> None:
    for name in COMMANDS:
        importlib.import_module(f"relcal.cli.{name}").register(sub)


def robot_args(
    parser: argparse.ArgumentParser, default: str | None = "a465", help: str | None = None
) -> None:
    """``--robot`` and ``--hayati``, shared by every command that takes a robot model
    (``default`` None: the command finds the robot elsewhere, ``help`` says where)."""
    parser.add_argument(
        "--robot",
        default=default,
        help=help or "built-in robot name, model YAML path or URDF file (.urdf) (default a465)",
    )
    parser.add_argument(
        "--root",
        metavar="LINK",
        help="URDF robots: first link of the chain (default: the tree's root)",
    )
    parser.add_argument(
        "--tip",
        metavar="LINK",
        help="URDF robots: last link of the chain (default: the end of the tree's serial chain)",
    )
    parser.add_argument(
        "--parametrisation",
        choices=("minimal", "origins"),
        default="minimal",
        help="URDF robots: errors as modified-DH parameters (minimal) or as joint origins "
        "(origins: xyz, rotation and zero offset per joint)",
    )
    parser.add_argument(
        "--hayati",
        choices=("off", "auto"),
        default="off",
        help="add Hayati's beta to joints whose axis is parallel to the previous one (auto)",
    )


def load_robot(args: argparse.Namespace):
    """The model named by ``--robot`` (``--root``/``--tip`` for a URDF), with Hayati joints if
    ``--hayati auto``."""
    from relcal.robot.loading import get_robot
    from relcal.robot.model import auto_hayati

    model = get_robot(
        args.robot,
        getattr(args, "root", None),
        getattr(args, "tip", None),
        getattr(args, "parametrisation", "minimal"),
    )
    return auto_hayati(model) if args.hayati == "auto" else model


def json_arg(parser: argparse.ArgumentParser, what: str) -> None:
    """``--json FILE``, shared by every command: ``what`` is the document written."""
    parser.add_argument(
        "--json", metavar="FILE", type=output_file, help=f"write {what} as JSON to FILE"
    )


# ---------------------------------------------------------------- option types (argparse type=)
# Each returns the parsed value or raises argparse.ArgumentTypeError, which argparse reports as
# "relcal COMMAND: error: argument --x: ..." with exit status 2, before any work.


def _number(text: str) -> float:
    from relcal.numbers import NotANumber, parse_number

    try:
        return parse_number(text)
    except NotANumber as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _integer(text: str) -> int:
    import re

    if not re.fullmatch(r"\s*[-+]?\d+\s*", text):
        hint = " (no underscores: write the digits alone)" if "_" in text else ""
        raise argparse.ArgumentTypeError(f"'{text}' is not a whole number{hint}")
    return int(text)


def finite_float(text: str) -> float:
    """Any finite number."""
    return _number(text)


def positive_float(text: str) -> float:
    """A finite number > 0."""
    value = _number(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"'{text}': expected a number greater than 0")
    return value


def nonnegative_float(text: str) -> float:
    """A finite number >= 0."""
    value = _number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"'{text}': expected a number of 0 or more")
    return value


def int_at_least(low: int) -> Callable[[str], int]:
    """A whole number >= ``low``."""

    def parse(text: str) -> int:
        value = _integer(text)
        if value < low:
            raise argparse.ArgumentTypeError(f"'{text}': expected a whole number of {low} or more")
        return value

    parse.__name__ = f"integer >= {low}"
    return parse


positive_int = int_at_least(1)


def worker_processes(text: str) -> int:
    """A number of local worker processes: a whole number from 1 to
    :func:`relcal.limits.max_workers` (4 per core, at least 8)."""
    from relcal.limits import max_workers, workers_excess

    value = positive_int(text)
    if value > max_workers():
        raise argparse.ArgumentTypeError(f"'{text}': {workers_excess(value)}")
    return value


def simulated_poses(text: str) -> int:
    """A number of simulated poses: a whole number from 3 (the fewest that determine anything)
    to :data:`relcal.limits.MAX_SIMULATED_POSES` (10,000 take minutes to reach; ten million
    took days)."""
    from relcal.limits import MAX_SIMULATED_POSES

    value = _integer(text)
    if not 3 <= value <= MAX_SIMULATED_POSES:
        raise argparse.ArgumentTypeError(
            f"'{text}': expected a whole number of simulated poses, 3 or more and at most "
            f"{MAX_SIMULATED_POSES:,} (each is reached by inverse kinematics, about 20 ms)"
        )
    return value


def poses_or_file(text: str) -> str | int:
    """A CSV of joint configurations (an existing file) or a number of simulated poses
    (:func:`simulated_poses`)."""
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: is a folder, expected a CSV file or a number")
    if path.exists():
        return text
    try:
        return simulated_poses(text)
    except argparse.ArgumentTypeError as exc:
        if not re.fullmatch(r"\s*[-+]?\d+\s*", text):
            raise argparse.ArgumentTypeError(
                f"'{text}': not a file and not a number (a CSV of joint configurations, or a "
                "whole number of simulated poses)"
            ) from None
        raise exc from None


nonnegative_int = int_at_least(0)


def fraction(text: str) -> float:
    """A number strictly between 0 and 1."""
    value = _number(text)
    if not 0 < value < 1:
        raise argparse.ArgumentTypeError(f"'{text}': expected a fraction between 0 and 1")
    return value


def fraction_at_most_one(text: str) -> float:
    """A number in (0, 1]."""
    value = _number(text)
    if not 0 < value <= 1:
        raise argparse.ArgumentTypeError(f"'{text}': expected a number above 0, at most 1")
    return value


def holdout_fraction(text: str) -> float:
    """A share in [0, 1): 0 holds nothing out."""
    value = _number(text)
    if not 0 <= value < 1:
        raise argparse.ArgumentTypeError(
            f"'{text}': expected a share from 0 (no validation) up to, not including, 1"
        )
    return value


def length_m(low: float, high: float) -> Callable[[str], float]:
    """A length in metres, ``low < value <= high`` (a bound that catches millimetres)."""

    def parse(text: str) -> float:
        value = _number(text)
        if not low < value <= high:
            raise argparse.ArgumentTypeError(
                f"'{text}': expected a length in metres between {low:g} and {high:g} "
                "(millimetres given as metres?)"
            )
        return value

    parse.__name__ = "length"
    return parse


def seed(text: str) -> int:
    """A random seed: a whole number from 0 up."""
    value = _integer(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"'{text}': expected a seed, a whole number of 0 or more")
    return value


def interval(low: float, high: float, unit: str) -> Callable[[str], tuple[float, float]]:
    """``LOW,HIGH`` with ``low <= LOW < HIGH <= high`` (in ``unit``)."""

    def parse(text: str) -> tuple[float, float]:
        parts = text.split(",")
        if len(parts) != 2:
            raise argparse.ArgumentTypeError(
                f"'{text}': expected two numbers LOW,HIGH ({unit}), e.g. {low:g},{high:g}"
            )
        lo, hi = (_number(p.strip()) for p in parts)
        if not lo < hi:
            raise argparse.ArgumentTypeError(
                f"'{text}': the low end must be below the high end (LOW,HIGH, {unit}); "
                f"swapped? {parts[1].strip()},{parts[0].strip()}"
            )
        if lo < low or hi > high:
            raise argparse.ArgumentTypeError(
                f"'{text}': expected LOW,HIGH within {low:g} to {high:g} {unit}"
            )
        return lo, hi

    parse.__name__ = "interval"
    return parse


def numbers(counts: tuple[int, ...], what: str, bound: float = 1e6) -> Callable[[str], list]:
    """Comma-separated finite numbers, as many as one of ``counts``, each within ``bound``."""

    def parse(text: str) -> list[float]:
        parts = text.split(",")
        if len(parts) not in counts:
            want = " or ".join(map(str, counts))
            raise argparse.ArgumentTypeError(f"'{text}': expected {want} numbers: {what}")
        values = [_number(p.strip()) for p in parts]
        if any(abs(v) > bound for v in values):
            raise argparse.ArgumentTypeError(f"'{text}': {what}: each within +-{bound:g}")
        return values

    parse.__name__ = "numbers"
    return parse


HANDEYE_REACH_M = 2.0  # a camera, board or marker mounted further from the flange: not metres
CELL_REACH_M = 20.0  # a camera placed further from the base: not metres (as compensate's targets)


def pose_numbers(counts: tuple[int, ...], what: str, reach: float) -> Callable[[str], list]:
    """``X,Y,Z[,ROLL,PITCH,YAW]`` (m, deg) as :func:`numbers` reads them, as many as one of
    ``counts``: a position further than ``reach`` metres is refused as millimetres given for
    metres, an angle beyond +-360 as not degrees."""
    read = numbers(counts, what, math.inf)

    def parse(text: str) -> list[float]:
        values = read(text)
        far = math.hypot(*values[:3])
        if far > reach:
            raise argparse.ArgumentTypeError(
                f"'{text}': {what}: X,Y,Z is {far:.4g} m away, more than {reach:g} m "
                f"(millimetres given? {', '.join(f'{v / 1000:g}' for v in values[:3])} in m)"
            )
        if any(abs(v) > 360.0 for v in values[3:]):
            raise argparse.ArgumentTypeError(f"'{text}': {what}: angles in deg, within +-360")
        return values

    parse.__name__ = "pose_numbers"
    return parse


def noise_levels(text: str) -> str:
    """``POS_MM,ORI_DEG[,JOINT_DEG]`` non-negative standard deviations, or ``none``."""
    if text.strip().lower() == "none":
        return "none"
    from relcal.numbers import NotANumber, noise_numbers

    try:
        noise_numbers(text)
    except NotANumber as exc:
        raise argparse.ArgumentTypeError(
            f"'{text}': expected POS_MM,ORI_DEG[,JOINT_DEG] standard deviations: {exc}"
        ) from None
    return text


def existing_file(text: str) -> str:
    """A path to an existing file (not a folder)."""
    path = Path(text)
    if not path.exists():
        raise argparse.ArgumentTypeError(f"{text}: file not found")
    if path.is_dir():
        raise ArgumentTypeError(f"{text}: is a folder, expected a file")
    return text


def output_file(text: str) -> str:
    """A file to write: not a folder, in a place that can be written (devices are fine)."""
    from relcal.errors import RelcalError
    from relcal.outputset import File, check_file

    if not text.strip():
        raise ArgumentTypeError("expected a file name")
    try:
        check_file(File(text, b"", "file"))
    except RelcalError as exc:
        raise ArgumentTypeError(str(exc).removeprefix("file ")) from None
    return text


def output_folder(text: str) -> str:
    """A folder to write: not an existing file, in a place that can be written."""
    from relcal.outputset import _nearest_existing, is_stream

    path = Path(text)
    if not text.strip():
        raise ArgumentTypeError("expected a folder name")
    if is_stream(path) or (path.exists() and not path.is_dir()):
        raise ArgumentTypeError(f"{text}: exists and is not a folder")
    base = _nearest_existing(path.parent)
    if not base.is_dir():
        raise ArgumentTypeError(f"{text}: {base} is a file, not a folder")
    if not os.access(base, os.W_OK | os.X_OK):
        raise ArgumentTypeError(f"{text}: cannot write in {base} (permission denied)")
    return text


ArgumentTypeError = argparse.ArgumentTypeError


def registry_arg(parser: argparse.ArgumentParser) -> None:
    """``--registry PATH|URL``: the calibration registry (default ``$RELCAL_REGISTRY``)."""
    parser.add_argument(
        "--registry",
        metavar="PATH|URL",
        help="calibration registry: a SQLite file or a SQLAlchemy URL "
        "(default $RELCAL_REGISTRY; none if unset)",
    )


# --pairing (--pairs) of calibrate, fleet calibrate, simulate, study and observability:
# relcal.calibration.measurement.PAIRINGS, written out here so that the parsers import no NumPy
PAIRINGS = ("auto", "all", "consecutive", "star", "board")
PAIRS_HELP = (
    "how poses are compared: auto (default: board), board (each pose against the world (board) "
    "transform, which is estimated: the maximum-likelihood form, linear in the samples and "
    "independent of their order), or relative pairs: all (every pair: quadratic), "
    "consecutive, star; --pairs is its former name"
)
SIMULATION_PAIRS_HELP = (
    "how the poses are compared, as calibrate's --pairing and with its default: auto (default: "
    "board for the frame-invariant formulation, what calibrate uses; for the published and "
    "absolute formulations all pairs up to 300 poses), all (every pair), consecutive, star, "
    "or board (each camera pose against the board, its transform board.* estimated; "
    "frame-invariant formulation only); --pairs is its former name"
)


def pairing_arg(parser: argparse.ArgumentParser, calibration: bool = True) -> None:
    """``--pairing`` (``--pairs`` its former name): which samples form relative measurements,
    the same choices and the same default, ``auto``, everywhere: a simulation, study or
    observability report (``calibration=False``, which words the help for poses) pairs its
    poses as ``relcal calibrate`` will pair them (:func:`relcal.limits.resolve_pairing`)."""
    help_ = PAIRS_HELP if calibration else SIMULATION_PAIRS_HELP
    parser.add_argument(
        "--pairing", "--pairs", dest="pairs", choices=PAIRINGS, default="auto", help=help_
    )


# ------------------------------------------------------------ the run's destinations and inputs

# Options whose values are never paths (link names, topics, ids, drivers' options, URLs).
_NOT_PATHS = {"robot_id", "run_a", "run_b", "format", "command", "fleet_command"}
_READ_IN_FOLDERS = ("dataset.yaml", "model.yaml", "results.json")  # a dataset's, a calibration's
_NOT_PATH_METAVARS = {"LINK", "TOPIC", "ID", "KEY=VALUE", "tcp://HOST:8786", "NAME"}


def _chosen_actions(parser: argparse.ArgumentParser, args: argparse.Namespace) -> list:
    """The argparse actions of the (sub)command ``args`` was parsed for."""
    actions = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            chosen = action.choices.get(getattr(args, action.dest, None) or "")
            if chosen is not None:
                actions += _chosen_actions(chosen, args)
        else:
            actions.append(action)
    return actions


def _option_name(action: argparse.Action) -> str:
    return action.option_strings[0] if action.option_strings else action.dest.upper()


def declare_run(
    parser: argparse.ArgumentParser, args: argparse.Namespace, argv: list[str] | None = None
) -> None:
    """Before any work: every option that names an output (typed :func:`output_file` or
    :func:`output_folder`) is declared as a destination of the run
    (:func:`relcal.outputset.declare`), every other argument that names an existing file or
    folder is noted as an input, and the registry (``--registry`` or ``$RELCAL_REGISTRY``) is
    noted as one; a destination that is an input, the registry, an existing registry, the
    working folder, or given twice is refused now, and every later write of the run checks the
    destinations again against what it has read (see :mod:`relcal.outputset`)."""
    from relcal.outputset import File, Folder, declare, note_input, note_registry

    destinations: list = []
    for action in _chosen_actions(parser, args):
        value = getattr(args, action.dest, None)
        if value is None or action.dest in ("help", "version"):
            continue
        name = _option_name(action)
        if action.type is output_file:
            destinations.append(File(value, b"", name))
        elif action.type is output_folder:
            destinations.append(Folder(value, what=name))
        elif action.dest == "registry" or action.dest in _NOT_PATHS or action.choices:
            continue
        elif action.metavar in _NOT_PATH_METAVARS:
            continue
        else:
            for text in value if isinstance(value, list) else [value]:
                if isinstance(text, str) and text.strip():
                    path = text[1:] if text.startswith("@") else text
                    if os.path.lexists(path):
                        note_input(path)
                        for name in _READ_IN_FOLDERS:  # named in messages: the file read
                            if os.path.isdir(path) and os.path.isfile(os.path.join(path, name)):
                                note_input(os.path.join(path, name))
    if any(a.dest == "registry" for a in _chosen_actions(parser, args)):
        where = getattr(args, "registry", None) or os.environ.get("RELCAL_REGISTRY")
        path = _registry_file(where)
        if path is not None:
            note_registry(path)
    order = list(argv or [])

    def given_at(item) -> int:  # the command line's order: a repeat names the earlier option
        return order.index(item.what) if item.what in order else len(order)

    declare(*sorted(destinations, key=given_at))


def _registry_file(where: str | None) -> str | None:
    """The SQLite file a ``--registry`` value names (a path or ``sqlite:///PATH``), else None."""
    if not where or not where.strip():
        return None
    if "://" not in where:
        return os.path.expanduser(where)
    if where.startswith("sqlite:///") and len(where) > len("sqlite:///"):
        return where[len("sqlite:///") :].split("?", 1)[0]
    return None
