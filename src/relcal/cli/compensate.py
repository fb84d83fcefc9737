"""``relcal compensate CALIBRATION``: corrected joint targets computed with the calibrated model."""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from relcal.cli.common import existing_file, json_arg, output_file, registry_arg

if TYPE_CHECKING:
    import numpy as np

EPILOG = """\
examples:
  relcal compensate cal/ --targets poses.csv --out joints.csv
  relcal compensate cal/ --targets plan.csv --json joints.json          # a plan or joint program
  relcal compensate 12 --registry history.sqlite --targets poses.csv --out joints.csv
  relcal compensate cal/ --targets program.csv --nominal controller.yaml --out joints.csv

CALIBRATION: the output folder of relcal calibrate (model.yaml, results.json), or a registry run
(with --registry). The robot, its chain (root and tip links of a URDF), its joints and the joint
ranges the calibration covered come from it. --nominal is only needed when the targets were
computed with another model than the calibration's nominal one (another controller's model); it
is refused when its joints or its chain are not the calibration's.

targets: a CSV with a header: id and either a tool pose in the base frame, x,y,z (m) with
         qx,qy,qz,qw or roll,pitch,yaw (--pose-angle-unit) or rx,ry,rz (rotation vector, rad),
         or one column per joint (the robot's joint names, or q1..qn): a joint program computed
         with the nominal model, relcal's plan files included. Any other column, or another
         number of joints, is refused.
output:  id, q1..qn (corrected), converged, dq1..dqn (correction), predicted_position_mm,
         predicted_rotation_deg (what the nominal joints would miss by, per the calibrated model);
         angles in the --joint-unit (a plan's own unit when it states one)
gate:    a correction larger than the calibration can produce (measured: the calibrated model
         against its nominal model at 64 configurations over the joint ranges, twice the largest,
         plus a floor) is refused and nothing is written: another robot or chain, a branch flip
         of the inverse kinematics, or a target at a singularity. Targets outside the joint
         ranges the calibration covered are warned one by one.
--json:  the same per target (q, dq as lists with joint_units), plus n_targets, n_not_converged,
         the calibration, the nominal model and the gate
the former spelling  relcal compensate --model CAL/model.yaml --nominal ROBOT ...  still works
(with a note); a --model file outside a calibration folder needs --nominal for joint programs.
"""


@dataclass(frozen=True)
class Applied:
    """The calibration applied: what it is, and what it says about its robot."""

    label: str
    calibrated: Any  # RobotModel as a user loads it
    model_path: Path | None  # its model.yaml, when there is one
    results: dict | None
    reference: Any  # RobotModel | None: the nominal model the calibration started from
    chain: dict | None  # URDF chain of the calibration: root, tip, urdf
    ranges: Any  # JointRanges | None


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

    doc_path = Path(model_path).parent / "results.json"
    try:
        doc = json.loads(doc_path.read_text())
        return JointRanges.from_dict(doc["joint_ranges"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _shown_unit(prismatic: bool, joint_unit: str) -> tuple[float, str]:
    """The factor from SI and the unit a joint's value is shown in: m for a prismatic joint,
    else ``joint_unit`` (deg or rad)."""
    import math

    if prismatic:
        return 1.0, "m"
    return (math.degrees(1.0), "deg") if joint_unit == "deg" else (1.0, "rad")


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
            conv, unit = _shown_unit(bool(ranges.prismatic[j]), joint_unit)
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
    records for that very file (:func:`relcal.calibration.verify.model_file_record`:
    ``{"position_rms_mm", "n_samples", "matches"}``, ``matches`` False when the file was changed
    since). None without such a record."""
    import json

    from relcal.calibration.verify import model_file_record

    results = model_path.parent / "results.json"
    if model_path.name != "model.yaml" or not results.is_file():
        return None
    try:
        doc = json.loads(results.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None  # not a relcal calibration set: nothing to say
    return model_file_record(model_path, doc)


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
    from relcal.robot.ik import inverse_condition

    return inverse_condition(model, q, 0.5)


# --- what is applied -----------------------------------------------------------------------------


def _reference(results: dict | None, where: Path | None):
    """The nominal model and URDF chain a results document records (``nominal_robot``); for an
    older document the robot of the dataset it names, when that still loads; else None."""
    from relcal.errors import RelcalError
    from relcal.robot.model import model_from_dict

    if results is None:
        return None, None
    found = results.get("nominal_robot")
    if isinstance(found, dict) and isinstance(found.get("model"), dict):
        model = model_from_dict(found["model"], f"{where}: nominal_robot")
        return model, found.get("chain")
    dataset = results.get("dataset")
    if dataset:
        from relcal.data.dataset import load_dataset

        try:
            model = load_dataset(dataset).model
        except RelcalError:
            return None, None
        chain = None
        if model.urdf is not None:
            chain = {"root": model.urdf.root, "tip": model.urdf.tip, "urdf": model.urdf.path}
        return model, chain
    return None, None


def _from_folder(folder: Path, label: str, run=None) -> Applied:
    from relcal.calibration.verify import JointRanges, load_calibration

    files = load_calibration(folder)
    reference, chain = _reference(files.results, folder / "results.json")
    doc = files.results.get("joint_ranges")
    try:
        ranges = JointRanges.from_dict(doc) if doc else None
    except (KeyError, TypeError):
        ranges = None
    if run is not None:
        label += f" (registry run {run.id})"
    return Applied(
        label, files.model, folder / "model.yaml", files.results, reference, chain, ranges
    )


def resolve_calibration(args: argparse.Namespace, nominal) -> Applied:
    """The calibration named by CALIBRATION (a folder or a registry run) or the former
    ``--model FILE``."""
    from relcal.errors import RelcalError

    if args.calibration is not None and args.model is not None:
        raise RelcalError(
            "give the calibration once: CALIBRATION (its folder) or the former --model FILE"
        )
    if args.calibration is None and args.model is None:
        raise RelcalError(
            "relcal compensate: give CALIBRATION, the output folder of relcal calibrate (or a "
            "registry run with --registry)"
        )
    if args.model is not None:
        path = Path(args.model)
        if path.name == "model.yaml" and (path.parent / "results.json").is_file():
            if not args.quiet:
                print(
                    f"relcal: note: --model is the former spelling: relcal compensate "
                    f"{path.parent} --targets ... (the robot, chain and nominal model come "
                    "from the calibration)",
                    file=sys.stderr,
                )
            return _from_folder(path.parent, str(path.parent))
        from relcal.robot.model import load_model

        return Applied(str(path), load_model(path), path, None, None, None, covered_ranges(path))
    target = Path(args.calibration)
    if target.is_dir():
        return _from_folder(target, str(target))
    if target.is_file() and target.suffix in (".yaml", ".yml"):
        if target.name == "model.yaml" and (target.parent / "results.json").is_file():
            return _from_folder(target.parent, str(target.parent))
    from relcal.fleet.registry import open_registry

    registry = open_registry(args.registry)
    if registry is None:
        raise RelcalError(
            f"{args.calibration}: not a calibration folder (the output folder of relcal "
            "calibrate, with model.yaml and results.json); a registry run id needs --registry "
            "PATH|URL"
        )
    try:
        run = registry.get(args.calibration)
        where = registry.engine.url.render_as_string(hide_password=True)
    finally:
        registry.close()
    out = Path(run.outputs_path) if run.outputs_path else None
    if out is not None and (out / "model.yaml").is_file() and (out / "results.json").is_file():
        return _from_folder(out, f"run {run.id} of {where} ({out})")
    from relcal.fleet.verification import model_from_record

    base = nominal
    if base is None:
        from relcal.data.dataset import load_dataset

        try:
            base = load_dataset(run.dataset_path).model
        except RelcalError as exc:
            raise RelcalError(
                f"run {run.id}: its output folder is gone and its dataset does not load "
                f"({exc}); give --nominal, the robot it calibrated"
            ) from None
    from relcal.calibration.verify import JointRanges

    doc = (run.settings or {}).get("joint_ranges")
    chain = None
    if base.urdf is not None:
        chain = {"root": base.urdf.root, "tip": base.urdf.tip, "urdf": base.urdf.path}
    return Applied(
        f"run {run.id} of {where} (rebuilt from the record)",
        model_from_record(run, base),
        None,
        None,
        base,
        chain,
        JointRanges.from_dict(doc) if doc else None,
    )


def load_nominal(args: argparse.Namespace, chain: dict | None):
    """``--nominal``: a built-in name, a model YAML, a URDF (its chain by --root/--tip, else the
    calibration's), a URDF chain mapping or a dataset.yaml; None when not given."""
    from relcal.data.dataset import robot_from_file
    from relcal.robot.loading import get_robot

    if args.nominal is None:
        if args.root or args.tip:
            from relcal.errors import RelcalError

            raise RelcalError("--root and --tip name the chain of --nominal: give --nominal too")
        return None
    root, tip = args.root, args.tip
    urdf = Path(args.nominal).suffix.lower() in (".urdf", ".xacro")
    if urdf and chain and root is None and tip is None:
        root, tip = chain.get("root"), chain.get("tip")
    if Path(args.nominal).suffix.lower() in (".yaml", ".yml", ".urdf", ".xacro"):
        return robot_from_file(args.nominal, root, tip)
    return get_robot(args.nominal, root, tip)


def check_nominal(nominal, applied: Applied, given: str) -> None:
    """``--nominal`` must be the calibration's robot: the same joints (names, kinds), for a URDF
    the same chain, and the same geometry within what a calibration changes
    (:func:`relcal.calibration.compensate.robot_mismatch`)."""
    import numpy as np

    from relcal.errors import RelcalError

    cal = applied.calibrated
    names, theirs = tuple(cal.joint_names), tuple(nominal.joint_names)
    if names != theirs or not np.array_equal(cal.prismatic, nominal.prismatic):
        raise RelcalError(
            f"--nominal {given}: joints {', '.join(theirs)} ({len(theirs)}), the calibration "
            f"{applied.label} has {', '.join(names)} ({len(names)}): another robot or another "
            "chain of its URDF; leave --nominal out to use the calibration's own"
        )
    chain = applied.chain
    if chain and nominal.urdf is not None:
        ours = (chain.get("root"), chain.get("tip"))
        found = (nominal.urdf.root, nominal.urdf.tip)
        if ours != found:
            raise RelcalError(
                f"--nominal {given}: chain {found[0]} -> {found[1]}, the calibration's is "
                f"{ours[0]} -> {ours[1]}: the tool poses would be those of another link; give "
                f"--root {ours[0]} --tip {ours[1]} (or leave them out), or leave --nominal out"
            )
    from relcal.calibration.compensate import robot_mismatch

    why = robot_mismatch(nominal, cal)  # same joint names, another geometry: another robot
    if why is not None:
        raise RelcalError(
            f"--nominal {given} ({nominal.name}) is not the robot the calibration "
            f"{applied.label} calibrated ({cal.name}): {why}; leave --nominal out to use the "
            "calibration's own nominal model (or give that robot's controller model)"
        )


def gate_message(path, ids, comp, gate, bad, joint_unit, model, one: bool = False) -> str:
    """Why the targets ``bad`` are refused: all of them (the model does not fit), or with
    ``one`` the first alone (reached only on another branch)."""
    import numpy as np

    k = int(np.flatnonzero(bad)[0])
    dq = np.abs(comp.q[k] - comp.q_nominal[k]) if comp.q_nominal is not None else None
    parts = []
    if dq is not None and (dq > gate.joint).any():
        j = int(np.argmax(dq / gate.joint))
        f, unit = _shown_unit(bool(model.prismatic[j]), joint_unit)
        parts.append(
            f"{model.joint_names[j]} corrected by {dq[j] * f:.4g} {unit} (at most "
            f"{gate.joint[j] * f:.3g} {unit} is plausible)"
        )
    if comp.predicted_position_mm is not None and comp.predicted_position_mm[k] > gate.position_mm:
        parts.append(
            f"the nominal joints would miss by {comp.predicted_position_mm[k]:.4g} mm (at most "
            f"{gate.position_mm:.3g} mm is plausible)"
        )
    if (
        comp.predicted_rotation_deg is not None
        and comp.predicted_rotation_deg[k] > gate.rotation_deg
    ):
        parts.append(
            f"and by {comp.predicted_rotation_deg[k]:.4g} deg (at most {gate.rotation_deg:.3g})"
        )
    if one:
        return (
            f"{path}: target {ids[k]}: {'; '.join(parts)}: the calibrated arm reaches it only on "
            "another branch of its inverse kinematics (near the edge of the workspace or a "
            "joint limit); refused, no joints written for it"
        )
    others = int(bad.sum()) - 1
    return (
        f"{path}: target {ids[k]}: {'; '.join(parts)}"
        + (f" ({others} more target(s) beyond the gate)" if others else "")
        + ": larger than this calibration can produce; nothing written. Likely another robot "
        "or chain than the one calibrated (--nominal: its model, root and tip), or targets in "
        "another unit or frame"
    )


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from relcal.calibration.compensate import compensate, correction_gate, implausible
    from relcal.data.dataset import joints_in_unit, read_target_file
    from relcal.errors import RelcalError
    from relcal.io import File, json_text, write_set
    from relcal.outputset import check
    from relcal.reporting.documents import compensation_document
    from relcal.reporting.text import compensation_csv
    from relcal.robot.kinematics import fk

    nominal_given = None
    if args.nominal is not None and args.calibration is not None:
        target = Path(args.calibration)
        if not target.exists():  # a registry run rebuilt from its record needs the robot first
            nominal_given = load_nominal(args, None)
    applied = resolve_calibration(args, nominal_given)
    calibrated = applied.calibrated
    validated = validated_error(applied.model_path) if applied.model_path else None
    nominal = nominal_given or load_nominal(args, applied.chain)
    if nominal is not None:
        check_nominal(nominal, applied, args.nominal)
    elif applied.reference is not None:
        nominal = applied.reference
        if tuple(nominal.joint_names) != tuple(calibrated.joint_names):
            raise RelcalError(
                f"{applied.label}: the calibrated model's joints are not its nominal robot's: "
                "a results.json of another calibration?"
            )
    robot_name = applied.reference.name if applied.reference is not None else None
    if robot_name is None:
        robot_name = calibrated.name.removesuffix(" (calibrated)")
    found = read_target_file(
        Path(args.targets), calibrated, args.joint_unit, args.pose_angle_unit, robot_name
    )
    ids, poses, q_program = found.ids, found.poses, found.q
    joint_unit = found.unit or args.joint_unit or "deg"
    if poses is None:
        check_limits(Path(args.targets), calibrated, ids, q_program, joint_unit)
        if nominal is None:
            raise RelcalError(
                f"{args.targets}: a joint program needs --nominal (the model it was computed with)"
            )
        poses = fk(nominal, q_program)
    check([File(p, b"", what) for p, what in ((args.out, "--out"), (args.json, "--json")) if p])
    comp = compensate(calibrated, poses, nominal=nominal, q_nominal=q_program)

    gate, refused = None, np.zeros(len(ids), dtype=bool)
    if nominal is not None:
        gate = correction_gate(calibrated, applied.reference or nominal)
        bad = implausible(comp, gate, calibrated)
        model_misfit = comp.predicted_position_mm > gate.position_mm
        model_misfit |= comp.predicted_rotation_deg > gate.rotation_deg
        if (bad & model_misfit).any():  # another robot or chain: nothing is written
            raise RelcalError(
                gate_message(
                    args.targets, ids, comp, gate, bad & model_misfit, joint_unit, calibrated
                )
            )
        refused = bad  # reached only on another branch: those targets get no joints

    q = joints_in_unit(calibrated, comp.q, joint_unit)
    dq = None
    if comp.q_nominal is not None:
        dq = q - joints_in_unit(calibrated, comp.q_nominal, joint_unit)
    status = [
        "refused: beyond the gate (another branch)"
        if refused[k]
        else ("ok" if comp.converged[k] else "not reached")
        for k in range(len(ids))
    ]
    if refused.any():
        q[refused] = np.nan
        comp = replace(comp, converged=comp.converged & ~refused)
    text = compensation_csv(ids, q, comp, dq, status)
    failed = int((~comp.converged).sum())
    items = [File(args.out, text, "--out")] if args.out else []
    if args.json:
        units = np.where(calibrated.prismatic, "m", joint_unit).tolist()
        inputs: dict[str, Any] = {
            "calibration": applied.label,
            "model": None if applied.model_path is None else str(applied.model_path),
            "targets_file": args.targets,
            "nominal": args.nominal or (None if nominal is None else "the calibration's"),
            "nominal_robot": None if nominal is None else nominal.name,
            "chain": applied.chain,
        }
        inputs["model_validation"] = validated
        if gate is not None:
            inputs["gate"] = {
                "joint": gate.joint.tolist(),
                "joint_units": np.where(calibrated.prismatic, "m", "rad").tolist(),
                "position_mm": gate.position_mm,
                "rotation_deg": gate.rotation_deg,
                "n_samples": gate.n_samples,
            }
        doc = {**inputs, **compensation_document(ids, q, comp, dq, units, status)}
        items.append(File(args.json, json_text(doc), "--json"))
    write_set(*items)
    if not args.out:
        print(text, end="")
    if failed:  # the outputs mark them (converged False); the exit status tells
        if not args.quiet:
            for k in np.flatnonzero(refused):
                alone = np.arange(len(ids)) == k
                text_k = gate_message(
                    args.targets, ids, comp, gate, alone, joint_unit, calibrated, one=True
                )
                print(f"relcal: warning: {text_k}", file=sys.stderr)
            unreached = failed - int(refused.sum())
            if unreached:
                print(
                    f"relcal: {unreached} target(s) not reached within joint limits "
                    f"(of {len(ids)})",
                    file=sys.stderr,
                )
        return 1
    cond = near_singular(calibrated, comp.q)
    if not args.quiet:
        for line in outside_warnings(applied.ranges, ids, comp.q, joint_unit):
            print(f"relcal: warning: {line}", file=sys.stderr)
        for k in np.flatnonzero(cond < SINGULAR):
            swing = (
                ""
                if dq is None
                else f", corrections up to {np.max(np.abs(dq[k])):.3g} {joint_unit}"
            )
            print(
                f"relcal: warning: target {ids[k]} is near a singularity (inverse condition "
                f"{cond[k]:.2g}{swing}); the corrected joints may swing: check before running",
                file=sys.stderr,
            )
        summary = f"{len(ids)} target(s) compensated"
        if dq is not None:
            summary += (
                f", largest correction {np.max(np.abs(dq)):.3g} {joint_unit}, predicted "
                f"nominal miss up to {np.max(comp.predicted_position_mm):.3g} mm"
            )
        where = f" -> {args.out}" if args.out else ""
        print(f"relcal: {summary}{where}", file=sys.stderr)
        if applied.model_path is not None:
            note = validation_note(applied.model_path, validated)
            if note:
                print(note, file=sys.stderr)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "compensate",
        help="corrected joint targets computed with the calibrated model",
        description="Apply a calibration: the joint values that reach wanted tool poses (or "
        "the poses a nominal joint program aims at) with the calibrated model, each correction "
        "checked against what the calibration can produce.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "calibration",
        nargs="?",
        metavar="CALIBRATION",
        help="output folder of relcal calibrate (model.yaml, results.json), or a registry run "
        "id (with --registry)",
    )
    p.add_argument(
        "--targets",
        required=True,
        type=existing_file,
        help="CSV of target poses or a joint program (relcal's plan files included)",
    )
    p.add_argument(
        "--nominal",
        metavar="ROBOT",
        help="only for targets computed with another model than the calibration's nominal one: "
        "built-in name, model YAML, URDF (its chain: --root/--tip, default the calibration's), "
        "or a YAML with urdf/root/tip; refused when its joints or chain differ",
    )
    p.add_argument("--root", metavar="LINK", help="with a URDF --nominal: first link of its chain")
    p.add_argument("--tip", metavar="LINK", help="with a URDF --nominal: last link of its chain")
    p.add_argument(
        "--model",
        type=existing_file,
        help="former spelling: the calibrated model YAML (CAL/model.yaml: the same as CAL)",
    )
    p.add_argument(
        "--joint-unit",
        choices=("deg", "rad"),
        help="angle unit of joint targets and of the output (default deg; a plan file's own)",
    )
    p.add_argument(
        "--pose-angle-unit",
        choices=("deg", "rad"),
        default="deg",
        help="unit of roll, pitch, yaw in pose targets (default deg)",
    )
    p.add_argument("--out", type=output_file, help="output CSV (default: standard output)")
    json_arg(p, "the corrected joints, corrections and a summary")
    registry_arg(p)
    p.add_argument(
        "--quiet",
        action="store_true",
        help="no summary, singularity warning or note about unreached targets on standard error",
    )
    p.set_defaults(func=run)
