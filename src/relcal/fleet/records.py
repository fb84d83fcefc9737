"""A registry record from a finished calibration: what was calibrated, with what, and what came out.

``BASELINE`` names the held-out summary of ``results.json`` that counts as the baseline (the
error a user has without kinematic calibration); it is the only line to change when the results
document carries a different baseline.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

import numpy as np

import relcal
from relcal.calibration.outcome import Calibration
from relcal.errors import RelcalError
from relcal.io import load_yaml

BASELINE = "baseline"  # held-out errors of the hand-eye-only fit (``validation.baseline``)


def held_out_errors(doc: dict) -> dict[str, float | None]:
    """Baseline and calibrated held-out RMS errors (mm, deg) of a results document; None where
    it has no held-out set. For coincidence data (held-out placements) the position error is the
    spread of the predicted tool points around their groups' points (``spread_mm``)."""
    val = doc.get("validation") or {}
    base, after = val.get(BASELINE) or {}, val.get("calibrated") or {}

    def rms(summary: dict, key: str) -> float | None:
        if key == "position_mm" and key not in summary:
            key = "spread_mm"
        value = (summary.get(key) or {}).get("rms")
        return None if value is None else float(value)

    return {
        "baseline_position_rms_mm": rms(base, "position_mm"),
        "baseline_orientation_rms_deg": rms(base, "orientation_deg"),
        "calibrated_position_rms_mm": rms(after, "position_mm"),
        "calibrated_orientation_rms_deg": rms(after, "orientation_deg"),
    }


def held_out_metric(doc: dict) -> str | None:
    """What the held-out numbers of a results document measure, in the verdict's words
    (:func:`relcal.calibration.verdict.held_out_what`: ``pairs of poses``, ``points``,
    ``placements``; ``held_out_metric`` of the document), so that numbers of different kinds are
    never pooled; for documents older than that key, read from the validation's shape. None
    without a held-out set."""
    if "held_out_metric" in doc:
        return doc["held_out_metric"]
    val = doc.get("validation") or {}
    if not val:
        return None
    if val.get("held_out") == "placements":
        return "placements"
    return "points" if val.get("n_pairs") == val.get("n_samples") else "pairs of poses"


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def input_hashes(root: str | Path, images: tuple[Path, ...] | None = None) -> dict[str, str]:
    """SHA-256 of ``dataset.yaml``, of every file it names (robot, board, camera, samples) and,
    with images, one digest over the images' own digests in sample order."""
    root = Path(root)
    spec = root / "dataset.yaml"
    out = {"dataset.yaml": _sha256(spec)}
    try:
        data, _ = load_yaml(spec)  # the one YAML loader (sizes and aliases bounded)
    except RelcalError:
        data = {}
    named = {"samples": "samples.csv", **data} if isinstance(data, dict) else {}
    for key in ("robot", "board", "camera", "samples"):
        value = named.get(key)
        if isinstance(value, str) and (root / value).is_file():
            out[value] = _sha256(root / value)
    if images:
        digest = hashlib.sha256()
        for path in images:
            digest.update(_sha256(Path(path)).encode())
        out["images"] = digest.hexdigest()
    return out


def covariance(cal: Calibration) -> tuple[list[str], np.ndarray]:
    """Names and ``(k, k)`` covariance (SI) of the estimated subset, for comparing sessions: the
    calibration's own (``cal.result.covariance``: the pose noise learned as a 6x6 covariance,
    propagated through the pair structure), whose standard deviations are those
    ``results.json`` prints.

    Measured on 100 noise-only pairs of 30-pose synthetic sessions
    (``bench/drift_covariance.py 100 10``): identified minus true errors have z with a standard
    deviation of 1.01 (0.97 with the isotropic robust noise level the registry used before), the
    drift p-values are uniform (Kolmogorov-Smirnov p 0.2, against 0.01), 1 of 100 pairs is
    flagged and 10 of 10 planted 0.3 mm changes are."""
    columns = np.flatnonzero(np.isfinite(cal.std))
    names = [cal.problem.full_layout.names[k] for k in columns]
    return names, cal.result.covariance[np.ix_(columns, columns)]


def noise_rows(cal: Calibration) -> int:
    """Independent noise components of the training data: 6 per training sample but one
    (relative poses), or for coincidence samples 3 per training sample (its point) and one per
    known distance."""
    coincidence = cal.problem.coincidence if cal.problem.formulation == "coincidence" else None
    if coincidence is not None:
        return 3 * len(coincidence.index) + len(coincidence.lengths)
    return 6 * (len(cal.train) - 1)


def chosen_model(cal: Calibration) -> str | None:
    """The name of the candidate model that model selection chose (None without selection)."""
    return cal.selection[cal.chosen].candidate.name if cal.selection else None


def _tool_points(doc: dict) -> dict:
    """A coincidence calibration's tool points, its own and its baseline's (tip frame, m), with
    which `relcal verify` checks the model rebuilt from the record (whose tool they are not in)."""
    tool, base = doc.get("tool_point_xyz_m"), doc.get("baseline_tool_point_xyz_m")
    if tool is None or base is None:
        return {}
    return {"tool_points_xyz_m": {"calibrated": tool, "baseline": base}}


def calibration_record(
    cal: Calibration,
    doc: dict,
    outputs: str | Path | None = None,
    session: str | None = None,
    robot_id: str | None = None,
) -> dict[str, Any]:
    """The registry record (:meth:`Registry.add`) of a calibration and its results document;
    ``robot_id`` (default: the dataset's) is the robot it is recorded under."""
    names, cov = covariance(cal)
    layout = cal.problem.full_layout
    units = layout.units()  # m, rad, 1 (a joint scale), rad/(N m) or m/N (compliances)
    std = cal.std  # of the covariance recorded: `std` and `calibration_std` (older records) agree
    # results.json's word for each: estimated, combination (a value of a combination whose other
    # members are held), unidentifiable, not in the chosen model, ...
    status = {p["name"]: p.get("status") for p in doc.get("parameters") or []}
    parameters = []
    for k, name in enumerate(layout.names):
        estimated = bool(np.isfinite(std[k]))
        value = float(std[k]) if estimated else None
        parameters.append(
            {
                "name": name,
                "unit": units[k],
                "value": float(cal.result.params[k]) if estimated else None,
                "std": value,
                "calibration_std": value,
                "identifiable": bool(cal.result.identifiable[k]),
                "estimated": estimated,
                "status": status.get(name),
            }
        )
    root = Path(cal.dataset.root).resolve()
    return {
        "robot_id": robot_id or cal.dataset.robot_id or root.name,
        "session": session or root.name,
        "relcal_version": relcal.__version__,
        "model_name": cal.dataset.model.name,
        "dataset_path": str(root),
        "outputs_path": None if outputs is None else str(Path(outputs).resolve()),
        "settings": {
            **cal.settings,
            "chosen_model": chosen_model(cal),
            "joint_ranges": doc.get("joint_ranges"),  # what `relcal verify` checks a session by
            **_tool_points(doc),
            "verdict": (doc.get("verdict") or {}).get("code"),
            "held_out_metric": held_out_metric(doc),  # what `errors` measure
            # URDF robots: parameters named after their joints, as the calibration showed them
            "parameter_labels": doc.get("parameter_labels") or {},
            # every loadable file with its own held-out error (documents.artifacts_document)
            "artifacts": [
                {
                    "file": f["file"],
                    "holds": f["holds"],
                    "written": f["written"],
                    "position_rms_mm": (f["held_out"] or {}).get("position_rms_mm"),
                }
                for f in (doc.get("artifacts") or {}).get("files", [])
            ],
        },
        "input_hashes": input_hashes(root, cal.dataset.images),
        "converged": bool(cal.result.converged),
        "rank": int(cal.result.identifiability.rank),
        "parameters": parameters,
        "covariance": {
            "names": names,
            "matrix": cov.tolist(),
            # independent noise components left after the fit, less the estimated parameters:
            # what the noise level rests on
            "residual_dof": noise_rows(cal) - len(names),
            "noise_rows": noise_rows(cal),
        },
        "errors": held_out_errors(doc),
        "validation": {k: v for k, v in (doc.get("validation") or {}).items() if k != "pairs"}
        or None,
    }


def record_calibration(
    where: str | Path | None, cal: Calibration, doc: dict, outputs: str | Path | None = None
) -> int | None:
    """Record a calibration in the registry at ``where`` (or ``$RELCAL_REGISTRY``) on its own,
    without outputs; its run id, or None when no registry is given. (A command writing outputs
    records them in one transaction: :func:`relcal.reporting.outputs.write_calibration` with
    ``registry=``.)"""
    from relcal.fleet.registry import open_for_writing

    registry = open_for_writing(where)
    if registry is None:
        return None
    with registry:
        return registry.add(calibration_record(cal, doc, outputs))


def handeye_record(
    he: Any,
    doc: dict,
    dataset: Any,
    outputs: str | Path | None = None,
    session: str | None = None,
    robot_id: str | None = None,
) -> dict[str, Any]:
    """The registry record of a hand-eye job (``relcal handeye``): a row of the calibrations
    table whose ``settings.job`` is ``handeye`` and whose parameters are the delivered
    transform(s), ``PARENT->CHILD.x`` .. ``.yaw`` (two transforms for robot-world) in m and rad
    with their standard deviations (rotations: about the parent's axes); the held-out errors
    of the exported estimate (and, as the baseline, of the best closed form) go where a
    calibration's go."""
    import math

    from relcal import geometry as tf

    root = Path(dataset.root).resolve()
    parameters = []
    for d in he.delivered:
        xyz, rpy = tf.to_xyz_rpy(d.transform)
        stds = [*d.xyz_std, *d.rotation_std]  # rotations: about the parent's axes
        for k, (c, v) in enumerate(zip(("x", "y", "z", "roll", "pitch", "yaw"), (*xyz, *rpy),
                                       strict=True)):  # fmt: skip
            sd = float(stds[k])
            known = math.isfinite(sd) and not d.undetermined
            parameters.append(
                {
                    # named by the frames: never confused with a calibration's handeye.*
                    # (corrections of a guess, not the transform itself)
                    "name": f"{d.parent}->{d.child}.{c}",
                    "unit": "m" if k < 3 else "rad",
                    "value": float(v) if known else None,
                    "std": sd if known else None,
                    "calibration_std": sd if known else None,
                    "identifiable": known,
                    "estimated": known,
                    "status": "estimated" if known else "not determined",
                }
            )
    val = doc.get("validation") or {}
    methods = {m["method"]: m for m in val.get("methods", [])}
    mine = methods.get(he.exported or "refined") or {}
    closed = [m for k, m in methods.items() if k != "refined" and m.get("position_mm")]
    best = min(closed, key=lambda m: m["position_mm"]["rms"], default={})

    def rms(entry: dict, key: str) -> float | None:
        return (entry.get(key) or {}).get("rms")

    estimated = [p for p in parameters if p["estimated"]]
    return {
        "robot_id": robot_id or dataset.robot_id or root.name,
        "session": session or root.name,
        "relcal_version": relcal.__version__,
        "model_name": dataset.model.name,
        "dataset_path": str(root),
        "outputs_path": None if outputs is None else str(Path(outputs).resolve()),
        "settings": {
            **doc.get("settings", {}),
            "job": "handeye",
            "exported": he.exported,
            "frames": {d.key: [d.parent, d.child] for d in he.delivered},
            "verdict": (doc.get("verdict") or {}).get("code"),
            "baseline": None if not best else f"closed form {best['title']}",
        },
        "input_hashes": input_hashes(root, dataset.images),
        "converged": bool(he.fit.converged),
        "rank": len(estimated),
        "parameters": parameters,
        "covariance": {
            "names": [p["name"] for p in estimated],
            "matrix": np.diag([p["std"] ** 2 for p in estimated]).tolist(),
            "diagonal_only": True,
        },
        "errors": {
            "baseline_position_rms_mm": rms(best, "position_mm"),
            "baseline_orientation_rms_deg": rms(best, "orientation_deg"),
            "calibrated_position_rms_mm": rms(mine, "position_mm"),
            "calibrated_orientation_rms_deg": rms(mine, "orientation_deg"),
        },
        "validation": {k: v for k, v in val.items() if k != "samples"} or None,
    }
