"""Subcommands of the ``relcal`` command line, one module each with ``register(subparsers)``.

To add a command, write a module here with a ``register`` function and list it in ``COMMANDS``.
"""

from __future__ import annotations

import argparse
import importlib

COMMANDS = [
    "simulate",
    "calibrate",
    "imports",
    "compensate",
    "board",
    "observability",
    "study",
    "plan",
    "fleet",
    "history",
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
    from relcal.robot.model import auto_hayati, get_robot

    model = get_robot(
        args.robot,
        getattr(args, "root", None),
        getattr(args, "tip", None),
        getattr(args, "parametrisation", "minimal"),
    )
    return auto_hayati(model) if args.hayati == "auto" else model


def json_arg(parser: argparse.ArgumentParser, what: str) -> None:
    """``--json FILE``, shared by every command: ``what`` is the document written."""
    parser.add_argument("--json", metavar="FILE", help=f"write {what} as JSON to FILE")


def registry_arg(parser: argparse.ArgumentParser) -> None:
    """``--registry PATH|URL``: the calibration registry (default ``$RELCAL_REGISTRY``)."""
    parser.add_argument(
        "--registry",
        metavar="PATH|URL",
        help="calibration registry: a SQLite file or a SQLAlchemy URL "
        "(default $RELCAL_REGISTRY; none if unset)",
    )
