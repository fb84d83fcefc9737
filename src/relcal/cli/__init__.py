"""The ``relcal`` command line. Subcommands live in :mod:`relcal.cli`.

Exit codes: 0 success, 1 the run finished but a check failed (e.g. no convergence), 2 bad input
(the message names the file and field), 130 interrupted.
"""

from __future__ import annotations

import os

# Small matrices dominate relcal's linear algebra; BLAS threads only add overhead to them (up to
# tens of times on 2 cores). Set before NumPy loads; a user's own setting wins.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
from collections.abc import Callable, Sequence  # noqa: E402

import numpy as np  # noqa: E402

from relcal.cli.common import register_all  # noqa: E402
from relcal.errors import RelcalError  # noqa: E402


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
