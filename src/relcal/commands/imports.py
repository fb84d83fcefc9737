"""``relcal import``: convert other tools' measurement files into relcal dataset folders."""

from __future__ import annotations

import argparse


def run(args: argparse.Namespace) -> int:
    from relcal.importers import import_rct_positioner

    out = import_rct_positioner(args.file, args.out)
    if not args.quiet:
        print(f"dataset written to {out} (dataset.yaml, samples.csv, positioner.yaml)")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "import",
        help="convert robot_cal_tools measurements into a dataset folder",
        description="Convert ROS-Industrial robot_cal_tools' positioner kinematic measurements "
        "(joint angles + camera-to-target poses) into a relcal dataset folder.",
        epilog="example:\n  relcal import rct-positioner positioner_kinematic_measurements.yaml "
        "--out positioner/\n  relcal calibrate positioner/",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("format", choices=("rct-positioner",), help="input format")
    p.add_argument("file", help="input file")
    p.add_argument("--out", required=True, help="dataset folder to write")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=run)
