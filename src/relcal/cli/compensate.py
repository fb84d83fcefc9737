"""``relcal compensate``: corrected joint targets computed with the calibrated model."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from relcal.cli.common import json_arg

if TYPE_CHECKING:
    from relcal.calibration.compensate import Compensation

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


def read_targets(path: Path, model, joint_unit: str):
    """``(ids, poses (N,4,4) or None, q (N,n) or None)`` from a targets CSV."""
    from scipy.spatial.transform import Rotation

    from relcal import geometry as tf
    from relcal.data.dataset import POSE_COLUMNS, parse_number
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
    for row in data:
        line = row.line
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
    from relcal.calibration.compensate import compensate
    from relcal.errors import RelcalError
    from relcal.io import write_json, write_text
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

    def angles(q):
        return np.where(calibrated.prismatic, q, np.degrees(q)) if args.joint_unit == "deg" else q

    q = angles(comp.q)
    dq = None if comp.q_nominal is None else q - angles(comp.q_nominal)
    text = joints_csv(ids, q, comp, dq)
    if args.out:
        write_text(args.out, text)
    else:
        print(text, end="")
    if args.json:
        units = np.where(calibrated.prismatic, "m", args.joint_unit).tolist()
        inputs = {"model": args.model, "targets_file": args.targets, "nominal": args.nominal}
        write_json(args.json, {**inputs, **joints_document(ids, q, comp, dq, units)})
    failed = int((~comp.converged).sum())
    if failed and not args.quiet:
        print(f"relcal: {failed} target(s) not reached within joint limits", file=sys.stderr)
    return 0 if failed == 0 else 1


def joints_csv(ids: list[str], q: np.ndarray, comp: Compensation, dq: np.ndarray | None) -> str:
    """The output CSV: corrected joints ``q`` and corrections ``dq`` (display units) per id."""
    n = q.shape[1]
    header = ["id", *[f"q{i + 1}" for i in range(n)], "converged"]
    if dq is not None:
        header += [f"dq{i + 1}" for i in range(n)]
        header += ["predicted_position_mm", "predicted_rotation_deg"]
    lines = [",".join(header)]
    for k, sid in enumerate(ids):
        cells = [sid, *[f"{v:.10g}" for v in q[k]], str(bool(comp.converged[k]))]
        if dq is not None:
            cells += [f"{v:.6g}" for v in dq[k]]
            cells += [
                f"{comp.predicted_position_mm[k]:.6g}",
                f"{comp.predicted_rotation_deg[k]:.6g}",
            ]
        lines.append(",".join(cells))
    return "\n".join(lines) + "\n"


def joints_document(
    ids: list[str],
    q: np.ndarray,
    comp: Compensation,
    dq: np.ndarray | None,
    units: list[str],
) -> dict:
    """The ``--json`` document: the CSV's content per target (joints in ``units``, one per
    joint), and a summary. Non-finite numbers become null."""

    def number(v: float) -> float | None:
        return float(v) if np.isfinite(v) else None

    targets = []
    for k, sid in enumerate(ids):
        row = {"id": sid, "q": [number(v) for v in q[k]], "converged": bool(comp.converged[k])}
        if dq is not None:
            row["dq"] = [number(v) for v in dq[k]]
            row["predicted_position_mm"] = number(comp.predicted_position_mm[k])
            row["predicted_rotation_deg"] = number(comp.predicted_rotation_deg[k])
        targets.append(row)
    return {
        "joint_units": units,
        "targets": targets,
        "summary": {
            "n_targets": len(ids),
            "n_not_converged": int((~comp.converged).sum()),
        },
    }


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
