"""``relcal import``: convert other tools' measurement files into relcal dataset folders."""

from __future__ import annotations

import argparse

from relcal.cli.common import json_arg

EPILOG = """\
examples:
  relcal import rct-positioner positioner_kinematic_measurements.yaml --out positioner/
  relcal import rct-positioner measurements.yaml --out positioner/ --quiet --json import.json
  relcal calibrate positioner/                    # then calibrate the dataset folder
"""


def run(args: argparse.Namespace) -> int:
    from relcal.data.importers import import_rct_positioner
    from relcal.io import write_json

    done = import_rct_positioner(args.file, args.out)
    if args.json:
        write_json(
            args.json,
            {
                "format": args.format,
                "source": args.file,
                "dataset": str(done.folder),
                "files": [str(f) for f in done.files],
                "n_samples": done.n_samples,
            },
        )
    if not args.quiet:
        names = ", ".join(f.name for f in done.files)
        print(f"dataset written to {done.folder} ({names})")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "import",
        help="convert robot_cal_tools measurements into a dataset folder",
        description="Convert ROS-Industrial robot_cal_tools' positioner kinematic measurements "
        "(joint angles + camera-to-target poses) into a relcal dataset folder.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("format", choices=("rct-positioner",), help="input format")
    p.add_argument("file", help="input file")
    p.add_argument("--out", required=True, help="dataset folder to write")
    json_arg(p, "the list of files written and the number of samples")
    p.add_argument("--quiet", action="store_true", help="print nothing but errors")
    p.set_defaults(func=run)
