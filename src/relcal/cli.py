"""The ``relcal`` command line. Subcommands live in :mod:`relcal.commands`.

Exit codes: 0 success, 1 the run finished but a check failed (e.g. no convergence), 2 bad input
(the message names the file and field), 130 interrupted.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence

import numpy as np

from relcal.commands import register_all
from relcal.errors import RelcalError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="relcal",
        description="Calibrate serial robot kinematics from relative camera measurements.",
        epilog="exit codes: 0 ok, 1 finished but did not converge, 2 bad input, 130 interrupted",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    register_all(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    func: Callable[[argparse.Namespace], int] = args.func
    try:
        with np.errstate(all="ignore"):
            return func(args)
    except RelcalError as exc:
        print(f"relcal: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("relcal: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
