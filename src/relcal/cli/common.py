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


def robot_args(parser: argparse.ArgumentParser) -> None:
    """``--robot`` and ``--hayati``, shared by every command that takes a robot model."""
    parser.add_argument(
        "--robot",
        default="a465",
        help="built-in robot name, model YAML path or URDF file (.urdf) (default a465)",
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
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"'{text}': expected a finite number")
    return value


def _integer(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a whole number") from None


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


def noise_levels(text: str) -> str:
    """``POS_MM,ORI_DEG[,JOINT_DEG]`` non-negative standard deviations, or ``none``."""
    if text.strip().lower() == "none":
        return "none"
    parts = text.split(",")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if not 2 <= len(values) <= 3 or any(not math.isfinite(v) or v < 0 for v in values):
        raise argparse.ArgumentTypeError(
            f"'{text}': expected POS_MM,ORI_DEG[,JOINT_DEG] as non-negative numbers"
        )
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
        raise ArgumentTypeError(str(exc).removeprefix(f"file {text}: ")) from None
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
    "how relative poses are compared: auto (default: all pairs up to 300 usable samples, board "
    "above), all (every pair: quadratic), consecutive, star, or board (each pose against the "
    "board, its transform estimated: the information of all pairs, linear in the samples); "
    "--pairs is its former name"
)
SIMULATION_PAIRS_HELP = (
    "how the poses are compared, as calibrate's --pairing and with its default: auto (default: "
    "all pairs up to 300 poses, board above, what calibrate uses for these poses), all (every "
    "pair), consecutive, star, or board (each camera pose against the board, its transform "
    "board.* estimated; frame-invariant formulation only); --pairs is its former name"
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
