"""``relcal compensate``: corrected joint targets computed with the calibrated model."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from relcal.cli.common import existing_file, json_arg, output_file

if TYPE_CHECKING:
    import numpy as np

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


def check_limits(path: Path, model, ids, q: np.ndarray, joint_unit: str) -> None:
    """A joint program ``q`` (rad, m) outside the model's joint limits is refused, naming the
    target and the joint."""
    import numpy as np

    from relcal.data.dataset import joints_in_unit
    from relcal.errors import RelcalError

    slack = 1e-9
    bad = (q < model.lower - slack) | (q > model.upper + slack)
    if not bad.any():
        return
    k, j = np.argwhere(bad)[0]
    unit = "m" if model.prismatic[j] else joint_unit
    shown = joints_in_unit(model, q, joint_unit)[k, j]
    lo, hi = (
        joints_in_unit(model, lim[None], joint_unit)[0, j] for lim in (model.lower, model.upper)
    )
    raise RelcalError(
        f"{path}: target {ids[k]}: q{j + 1} = {shown:g} {unit} is outside the joint limits "
        f"[{lo:g}, {hi:g}] {unit} of '{model.name}' ({int(bad.any(axis=1).sum())} target(s) "
        "outside); wrong --joint-unit or wrong robot?"
    )


def covered_ranges(model_path: Path):
    """The joint ranges the calibration covered (``joint_ranges`` of the ``results.json``
    written beside its model file), or None when there is no such record."""
    import json

    from relcal.calibration.verify import JointRanges
    from relcal.limits import read_input

    doc_path = Path(model_path).parent / "results.json"
    try:
        doc = json.loads(read_input(doc_path, "text"))
        return JointRanges.from_dict(doc["joint_ranges"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def outside_warnings(ranges, ids, q: np.ndarray, joint_unit: str) -> list[str]:
    """One warning per target whose joints ``q`` ``(N, n)`` (rad, m) lie beyond the ranges the
    calibration covered (by more than their slack): its accuracy there was never validated."""
    import numpy as np

    if ranges is None or len(ranges.names) != q.shape[1]:
        return []
    outside = ranges.outside(q)
    lines = []
    for k in np.flatnonzero(outside.any(axis=1)):
        joints = []
        for j in np.flatnonzero(outside[k]):
            conv, unit = (
                (1.0, "m")
                if ranges.prismatic[j]
                else ((np.degrees(1.0), "deg") if joint_unit == "deg" else (1.0, "rad"))
            )
            joints.append(
                f"{ranges.names[j]} = {q[k, j] * conv:.4g} {unit} (covered "
                f"{ranges.lower[j] * conv:.4g} .. {ranges.upper[j] * conv:.4g})"
            )
        lines.append(
            f"target {ids[k]}: {', '.join(joints)}: outside the joint ranges the calibration "
            "covered; its accuracy there is not validated"
        )
    return lines


def validated_error(model_path: Path) -> dict | None:
    """The held-out error that ``results.json`` beside a ``model.yaml`` of ``relcal calibrate``
    records for that very file (``artifacts``, matched by the SHA-256 of its content after the
    run's comment line): ``{"position_rms_mm", "n_samples", "matches"}``; ``matches`` False when
    the file was changed since. None without such a record."""
    import json

    from relcal.calibration.verify import model_file_record
    from relcal.limits import read_input

    results = model_path.parent / "results.json"
    if model_path.name != "model.yaml" or not results.is_file():
        return None
    try:
        doc = json.loads(read_input(results, "text"))
    except (OSError, ValueError):
        return None  # not a relcal calibration set: nothing to say
    return model_file_record(model_path, doc) if isinstance(doc, dict) else None


def check_same_robot(given: str, nominal, model_path: str, calibrated) -> None:
    """Refuse a --nominal robot that is not the one calibrated (another robot's model would
    turn every target into a wild joint move or a target "not reached"), naming both and the
    library robot the calibrated model comes from when there is one."""
    from relcal.calibration.compensate import robot_mismatch
    from relcal.errors import RelcalError
    from relcal.robot.loading import get_robot
    from relcal.robot.model import library_names

    why = robot_mismatch(nominal, calibrated)
    if why is None:
        return
    base = calibrated.name.removesuffix(" (calibrated)")
    hint = next((n for n in library_names() if get_robot(n).name == base), None)
    raise RelcalError(
        f"--nominal {given} ({nominal.name}) is not the robot of the calibrated model "
        f"{model_path} ({calibrated.name}): {why}; give --nominal the robot that was calibrated"
        + (f" (--nominal {hint})" if hint else " (its model file or URDF)")
    )


def validation_note(model_path: Path, found: dict | None) -> str | None:
    """One line on what the model file's held-out error is, for standard error."""
    if found is None:
        return None
    if not found["matches"]:
        return (
            f"relcal: warning: {model_path} differs from the model.yaml that results.json "
            "validated: its held-out error is unknown"
        )
    if found["position_rms_mm"] is None:
        return f"relcal: {model_path}: not validated (calibrated without held-out samples)"
    return (
        f"relcal: {model_path}: held-out position RMS {found['position_rms_mm']:.3f} mm over "
        f"{found['n_samples']} samples (results.json; measured on this file read back)"
    )


SINGULAR = 0.02  # inverse condition number (translation over 0.5 m) below which we warn


def near_singular(model, q: np.ndarray) -> np.ndarray:
    """Inverse condition number ``(N,)`` of the joint Jacobian at ``q`` (0 at a singularity)."""
    from relcal.design.feasibility import inverse_condition

    return inverse_condition(model, q, 0.5)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from relcal.calibration.compensate import compensate
    from relcal.data.dataset import joints_in_unit, read_targets
    from relcal.errors import RelcalError
    from relcal.io import File, json_text, write_set
    from relcal.outputset import check
    from relcal.reporting.documents import compensation_document
    from relcal.reporting.text import compensation_csv
    from relcal.robot.kinematics import fk
    from relcal.robot.loading import get_robot
    from relcal.robot.model import load_model

    calibrated = load_model(args.model)
    validated = validated_error(Path(args.model))
    nominal = get_robot(args.nominal) if args.nominal else None
    if nominal is not None:
        check_same_robot(args.nominal, nominal, args.model, calibrated)
    ids, poses, q_program = read_targets(Path(args.targets), calibrated, args.joint_unit)
    if poses is None:
        check_limits(Path(args.targets), calibrated, ids, q_program, args.joint_unit)
        if nominal is None:
            raise RelcalError(
                f"{args.targets}: a joint program needs --nominal (the model it was computed with)"
            )
        poses = fk(nominal, q_program)
    check([File(p, b"", what) for p, what in ((args.out, "--out"), (args.json, "--json")) if p])
    comp = compensate(calibrated, poses, nominal=nominal, q_nominal=q_program)

    q = joints_in_unit(calibrated, comp.q, args.joint_unit)
    dq = None
    if comp.q_nominal is not None:
        dq = q - joints_in_unit(calibrated, comp.q_nominal, args.joint_unit)
    text = compensation_csv(ids, q, comp, dq)
    failed = int((~comp.converged).sum())
    items = [File(args.out, text, "--out")] if args.out else []
    if args.json:
        units = np.where(calibrated.prismatic, "m", args.joint_unit).tolist()
        inputs = {"model": args.model, "targets_file": args.targets, "nominal": args.nominal}
        inputs["model_validation"] = validated
        doc = {**inputs, **compensation_document(ids, q, comp, dq, units)}
        items.append(File(args.json, json_text(doc), "--json"))
    write_set(*items)
    if not args.out:
        print(text, end="")
    if failed:  # the outputs mark them (converged False); the exit status tells
        if not args.quiet:
            print(
                f"relcal: {failed} target(s) not reached within joint limits (of {len(ids)})",
                file=sys.stderr,
            )
        return 1
    cond = near_singular(calibrated, comp.q)
    if not args.quiet:
        ranges = covered_ranges(Path(args.model))
        for line in outside_warnings(ranges, ids, comp.q, args.joint_unit):
            print(f"relcal: warning: {line}", file=sys.stderr)
        for k in np.flatnonzero(cond < SINGULAR):
            swing = (
                ""
                if dq is None
                else f", corrections up to {np.max(np.abs(dq[k])):.3g} {args.joint_unit}"
            )
            print(
                f"relcal: warning: target {ids[k]} is near a singularity (inverse condition "
                f"{cond[k]:.2g}{swing}); the corrected joints may swing: check before running",
                file=sys.stderr,
            )
        summary = f"{len(ids)} target(s) compensated"
        if dq is not None:
            summary += (
                f", largest correction {np.max(np.abs(dq)):.3g} {args.joint_unit}, predicted "
                f"nominal miss up to {np.max(comp.predicted_position_mm):.3g} mm"
            )
        where = f" -> {args.out}" if args.out else ""
        print(f"relcal: {summary}{where}", file=sys.stderr)
        note = validation_note(Path(args.model), validated)
        if note:
            print(note, file=sys.stderr)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "compensate",
        help="corrected joint targets computed with the calibrated model",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--model",
        required=True,
        type=existing_file,
        help="calibrated model YAML (from relcal calibrate)",
    )
    p.add_argument(
        "--targets",
        required=True,
        type=existing_file,
        help="CSV of target poses or a joint program",
    )
    p.add_argument(
        "--nominal", help="nominal robot (name or YAML): seeds branches, predicts corrections"
    )
    p.add_argument("--joint-unit", choices=("deg", "rad"), default="deg")
    p.add_argument("--out", type=output_file, help="output CSV (default: standard output)")
    json_arg(p, "the corrected joints, corrections and a summary")
    p.add_argument(
        "--quiet",
        action="store_true",
        help="no summary, singularity warning or note about unreached targets on standard error",
    )
    p.set_defaults(func=run)
