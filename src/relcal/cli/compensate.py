"""``relcal compensate``: corrected joint targets computed with the calibrated model."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from relcal.cli.common import json_arg

EPILOG = """\
examples:
  relcal compensate --model out/model.yaml --targets poses.csv --nominal a465 --out joints.csv
  relcal compensate --model out/model.yaml --targets program.csv --nominal a465 --joint-unit rad
  relcal compensate --model out/model.yaml --targets poses.csv --out j.csv --json j.json --quiet

targets: a CSV with a header, either  id,x,y,z,qx,qy,qz,qw  (tool poses in the base frame, m)
         or  id,q1..qn  (a joint program computed with the nominal model)
output:  id, q1..qn (corrected), converged, dq1..dqn (correction), predicted_position_mm,
         predicted_rotation_deg (what the nominal joints would miss by, per the calibrated model);
         angles in the --joint-unit
--json:  the same per target (q, dq as lists with joint_units), plus n_targets, n_not_converged
"""


def run(args: argparse.Namespace) -> int:
    from relcal.calibration.compensate import compensate
    from relcal.data.dataset import joints_in_unit, read_targets
    from relcal.errors import RelcalError
    from relcal.io import write_json, write_text
    from relcal.reporting.documents import compensation_document
    from relcal.reporting.text import compensation_csv
    from relcal.robot.kinematics import fk
    from relcal.robot.model import get_robot, load_model

    calibrated = load_model(args.model)
    nominal = get_robot(args.nominal) if args.nominal else None
    if nominal is not None and nominal.n_joints != calibrated.n_joints:
        raise RelcalError(
            f"--nominal {args.nominal} has {nominal.n_joints} joints, the calibrated model "
            f"{calibrated.n_joints}"
        )
    ids, poses, q_program = read_targets(Path(args.targets), calibrated, args.joint_unit)
    if poses is None:
        if nominal is None:
            raise RelcalError(
                f"{args.targets}: a joint program needs --nominal (the model it was computed with)"
            )
        poses = fk(nominal, q_program)
    comp = compensate(calibrated, poses, nominal=nominal, q_nominal=q_program)

    q = joints_in_unit(calibrated, comp.q, args.joint_unit)
    dq = None
    if comp.q_nominal is not None:
        dq = q - joints_in_unit(calibrated, comp.q_nominal, args.joint_unit)
    text = compensation_csv(ids, q, comp, dq)
    if args.out:
        write_text(args.out, text)
    else:
        print(text, end="")
    if args.json:
        units = np.where(calibrated.prismatic, "m", args.joint_unit).tolist()
        inputs = {"model": args.model, "targets_file": args.targets, "nominal": args.nominal}
        write_json(args.json, {**inputs, **compensation_document(ids, q, comp, dq, units)})
    failed = int((~comp.converged).sum())
    if failed and not args.quiet:
        print(f"relcal: {failed} target(s) not reached within joint limits", file=sys.stderr)
    return 0 if failed == 0 else 1


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "compensate",
        help="corrected joint targets computed with the calibrated model",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--model", required=True, help="calibrated model YAML (from relcal calibrate)")
    p.add_argument("--targets", required=True, help="CSV of target poses or a joint program")
    p.add_argument(
        "--nominal", help="nominal robot (name or YAML): seeds branches, predicts corrections"
    )
    p.add_argument("--joint-unit", choices=("deg", "rad"), default="deg")
    p.add_argument("--out", help="output CSV (default: standard output)")
    json_arg(p, "the corrected joints, corrections and a summary")
    p.add_argument(
        "--quiet",
        action="store_true",
        help="no note about unreached targets on standard error (exit code 1 still tells)",
    )
    p.set_defaults(func=run)
