"""``relcal compensate``: corrected joint targets computed with the calibrated model."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

EPILOG = """\
examples:
  relcal compensate --model out/model.yaml --targets poses.csv --nominal a465 --out joints.csv
  relcal compensate --model out/model.yaml --targets program.csv --joint-unit deg

targets: a CSV with a header, either  id,x,y,z,qx,qy,qz,qw  (tool poses in the base frame, m)
         or  id,q1..qn  (a joint program computed with the nominal model)
output:  id, q1..qn (corrected), converged, dq1..dqn (correction), predicted_position_mm,
         predicted_rotation_deg (what the nominal joints would miss by, per the calibrated model);
         angles in the --joint-unit
"""


def read_targets(path: Path, model, joint_unit: str):
    """``(ids, poses (N,4,4) or None, q (N,n) or None)`` from a targets CSV."""
    from scipy.spatial.transform import Rotation

    from relcal import transforms as tf
    from relcal.dataset import POSE_COLUMNS, parse_number
    from relcal.errors import RelcalError
    from relcal.io import read_table

    header, data = read_table(path, "target")
    joints = [f"q{i + 1}" for i in range(model.n_joints)]
    cols = list(POSE_COLUMNS) if set(POSE_COLUMNS) <= set(header) else joints
    if not set(cols) <= set(header) or "id" not in header:
        raise RelcalError(
            f"{path} line 1: header: expected id and either {', '.join(POSE_COLUMNS)} or "
            f"{', '.join(joints)}"
        )
    idx = [header.index(c) for c in cols]
    ids, values = [], []
    for line, row in enumerate(data, start=2):
        if len(row) != len(header):
            raise RelcalError(f"{path} line {line}: {len(row)} fields, expected {len(header)}")
        ids.append(row[header.index("id")].strip())
        values.append([parse_number(path, line, c, row[i]) for c, i in zip(cols, idx, strict=True)])
    values = np.array(values)
    if cols == joints:
        q = np.where(model.prismatic, values, np.radians(values)) if joint_unit == "deg" else values
        return ids, None, q
    quat = values[:, 3:]
    norms = np.linalg.norm(quat, axis=1)
    if np.any(np.abs(norms - 1) > 1e-3):
        line = int(np.argmax(np.abs(norms - 1))) + 2
        raise RelcalError(f"{path} line {line}: qx, qy, qz, qw: expected a unit quaternion")
    rot = Rotation.from_quat(quat / norms[:, None]).as_matrix()
    return ids, tf.homogeneous(rot, values[:, :3]), None


def run(args: argparse.Namespace) -> int:
    from relcal.compensate import compensate
    from relcal.errors import RelcalError
    from relcal.io import write_text
    from relcal.kinematics import fk
    from relcal.model import get_robot, load_model

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

    def angles(q):
        return np.where(calibrated.prismatic, q, np.degrees(q)) if args.joint_unit == "deg" else q

    n = calibrated.n_joints
    header = ["id", *[f"q{i + 1}" for i in range(n)], "converged"]
    if comp.q_nominal is not None:
        header += [f"dq{i + 1}" for i in range(n)] + [
            "predicted_position_mm",
            "predicted_rotation_deg",
        ]
    lines = [",".join(header)]
    for k, sid in enumerate(ids):
        cells = [sid, *[f"{v:.10g}" for v in angles(comp.q[k])], str(bool(comp.converged[k]))]
        if comp.q_nominal is not None:
            dq = angles(comp.q[k]) - angles(comp.q_nominal[k])
            cells += [f"{v:.6g}" for v in dq]
            cells += [
                f"{comp.predicted_position_mm[k]:.6g}",
                f"{comp.predicted_rotation_deg[k]:.6g}",
            ]
        lines.append(",".join(cells))
    text = "\n".join(lines) + "\n"
    if args.out:
        write_text(args.out, text)
    else:
        print(text, end="")
    failed = int((~comp.converged).sum())
    if failed:
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
    p.set_defaults(func=run)
