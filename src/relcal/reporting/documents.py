"""Every JSON document the commands write, one function per result: ``<what>_document(result)``.

Every number carries its unit in its key or in a ``unit`` field (SI units unless the key says mm or
deg). The domain modules return dataclasses; only this module turns them into dictionaries.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from relcal.calibration.artifacts import Artifact
from relcal.calibration.artifacts import frames as artifact_frames
from relcal.calibration.compensate import Compensation
from relcal.calibration.identifiability import INDEX_NAMES, NUISANCE_KINDS, Indices
from relcal.calibration.measurement import tracker_frames
from relcal.calibration.outcome import Calibration
from relcal.calibration.uncertainty import Accuracy
from relcal.calibration.validate import (
    PlacementValidation,
    Validation,
    pooled,
    stats,
)
from relcal.calibration.verdict import Verdict, held_out_what
from relcal.calibration.verify import FROZEN, Assessment, JointRanges, Verification
from relcal.data.dataset import Dataset
from relcal.data.imaging import Measurements
from relcal.data.importers import Imported
from relcal.data.order import natural, sample_digests
from relcal.design.criteria import Quality
from relcal.design.handeye import MotionQuality
from relcal.design.observability import Report
from relcal.design.plan import PlanResult
from relcal.reporting.quantities import point_json, transform_json
from relcal.robot.kinematics import DISPLAY_UNITS, relabel
from relcal.robot.kinematics import parameter_labels as robot_parameter_labels
from relcal.robot.model import KINDS, NONGEOMETRIC_KINDS, RobotModel, model_to_dict
from relcal.sim.simulate import Simulation
from relcal.sim.study import StudyResult
from relcal.vision.boards import Board, board_to_spec, sheet_size


def measurements_document(dataset: Dataset, m: Measurements) -> dict:
    """What ``relcal measure`` found: samples posed and rejected (with the reason), reprojection
    RMS per posed sample (px), and the intrinsics report."""
    ok = m.ok
    return {
        "n_samples": len(ok),
        "n_posed": int(ok.sum()),
        "rejected": [
            {"id": dataset.ids[i], "reason": m.reasons[i]} for i in range(len(ok)) if not ok[i]
        ],
        "reprojection_rms_px": {
            dataset.ids[i]: float(m.rms_px[i])
            for i in range(len(ok))
            if ok[i] and m.rms_px[i] == m.rms_px[i]
        },
        "intrinsics": m.intrinsics_report,
    }


def parameter_status(cal: Calibration) -> list[str]:
    """Per parameter: ``estimated`` (in the chosen model and determined by the data on its own),
    ``combination`` (in the chosen model, but it carries an identifiable combination with
    parameters held at nominal), ``not supported`` (identifiable, left out by model selection)
    or ``unidentifiable`` (no share of the data determines it; held at nominal)."""
    chosen = set(cal.selection[cal.chosen].candidate.columns.tolist()) if cal.selection else None
    free = set(np.flatnonzero(np.isfinite(cal.result.std)).tolist())
    ident = cal.result.identifiability
    out = []
    for k in range(len(cal.result.params)):
        if k in free and (chosen is None or k in chosen):
            out.append("estimated" if ident.identifiable[k] else "combination")
        elif ident.identifiable[k]:
            out.append("not supported")
        else:
            out.append("unidentifiable")
    return out


def parameter_labels(cal: Calibration) -> dict[str, str]:
    """Each parameter's label where it differs from its name
    (:func:`relcal.robot.kinematics.parameter_labels`: for a robot loaded from a URDF, a joint
    parameter named after its joint, ``theta_off[3]`` -> ``theta_off[arm_right_2_joint]``);
    empty for other robots (their joints are numbered)."""
    return robot_parameter_labels(cal.dataset.model, cal.problem.full_layout.names)


def residual_unit(cal: Calibration) -> str:
    """The unit of the weighted residual rows the fit minimised: learned noise standard
    deviations (whitened rows), or metres (relative poses weighted plainly: translation in m,
    rotation in rad times 0.1 m/rad)."""
    problem = cal.problem
    if problem.formulation in POINT_FORMULATIONS or problem.pair_weights is not None:
        return "noise standard deviations (rows whitened by the learned noise)"
    return "m (rows: translation in m, rotation in rad x 0.1 m/rad)"


def parameter_rows(cal: Calibration) -> list[dict]:
    """One row per parameter: name, unit, nominal value, identified error, standard deviation
    (predicted, and from a bootstrap over training samples), significance (error / std) and
    status (:func:`parameter_status`). Lengths in mm, angles in degrees, scales in ppm,
    compliances in urad/Nm (the units people read).
    """
    layout = cal.problem.full_layout
    angle = layout.is_angle()
    factors, units = layout.display()
    std, boot = cal.std, cal.bootstrap_std
    model = cal.problem.model
    labels = parameter_labels(cal)
    rows = []
    for k, ((kind, index), status) in enumerate(zip(layout, parameter_status(cal), strict=True)):
        nominal = float(model.geometric(kind)[index]) if kind in KINDS + NONGEOMETRIC_KINDS else 0.0
        scale = np.degrees(1.0) if angle[k] else 1e3
        if units[k] not in ("mm", "deg"):
            scale = factors[k]
        ok = status in ("estimated", "combination")
        value = float(cal.result.params[k])
        rows.append(
            {
                "name": layout.names[k],
                "label": labels.get(layout.names[k], layout.names[k]),
                "unit": units[k],
                "nominal": nominal * scale,
                "error": value * scale if ok else None,
                "std": float(std[k]) * scale if ok and np.isfinite(std[k]) else None,
                "bootstrap_std": float(boot[k]) * scale
                if ok and boot is not None and np.isfinite(boot[k])
                else None,
                "significance": abs(value) / std[k] if ok and std[k] > 0 else None,
                "status": status,
                "identifiable": bool(cal.result.identifiability.identifiable[k]),
            }
        )
    return rows


def combination_rows(cal: Calibration) -> list[dict]:
    """Value and standard deviation of the identifiable combination of each two-parameter
    unidentifiable pair (e.g. ``d[2] + d[3]`` where only the sum is determined), in mm or deg."""
    names = cal.result.names
    std = cal.std
    out = []
    for combo in cal.result.identifiability.combinations:
        if len(combo.names) != 2 or any(n.split(".")[0] in NUISANCE_KINDS for n in combo.names):
            continue
        if combo.is_angle[0] != combo.is_angle[1] or len(set(combo.units)) > 1:
            continue  # e.g. a scale with a length: no sum to show
        (a, b), (va, vb) = combo.names, combo.coefficients
        c = -va / vb  # a + c b is orthogonal to the null direction (va, vb)
        ia, ib = names.index(a), names.index(b)
        value = cal.result.params[ia] + c * cal.result.params[ib]
        var = np.nansum([std[ia] ** 2, (c * std[ib]) ** 2])
        scale, unit = (np.degrees(1.0), "deg") if combo.is_angle[0] else (1e3, "mm")
        if combo.units and combo.units[0] not in ("m", "rad"):
            scale, unit = DISPLAY_UNITS[combo.units[0]]  # scales, compliances
        out.append(
            {
                "text": f"{a} {'+' if c >= 0 else '-'} {abs(c):.3g} {b}".replace(" 1 ", " "),
                "unit": unit,
                "value": float(value) * scale,
                "std": float(np.sqrt(var)) * scale if var > 0 else None,
                "reason": combo.reason,
            }
        )
    return out


def selection_document(cal: Calibration) -> dict:
    """The candidate models with their cross-validated held-out errors, and the choice."""
    layout = cal.problem.full_layout
    return {
        "folds": cal.settings.get("selection_folds"),
        "candidates": [
            {
                "name": s.candidate.name,
                "weighting": s.candidate.weighting,
                "n_params": len(s.candidate.columns),
                "cv_position_rms_mm": s.position_rms * 1e3,
                "cv_orientation_rms_deg": float(np.degrees(s.orientation_rms))
                if cal.problem.formulation not in POINT_FORMULATIONS
                else None,
                "chosen": k == cal.chosen,
            }
            for k, s in enumerate(cal.selection)
        ],
        "chosen": cal.selection[cal.chosen].candidate.name if cal.selection else None,
        "weighting": cal.settings.get("weighting"),
        "reason": cal.reason,
        "exported": cal.exported,
        "export_reason": cal.export_reason,
        "parameters": [
            layout.names[k]
            for k in (cal.selection[cal.chosen].candidate.columns if cal.selection else [])
        ],
    }


def noise_document(cal: Calibration) -> dict | None:
    """The learned pose noise: standard deviations and correlations of the body-frame error."""
    if cal.noise is None:
        return None
    n = cal.noise
    return {
        "std_mm": [float(v) * 1e3 for v in n.std[:3]],
        "std_deg": [float(np.degrees(v)) for v in n.std[3:]],
        "correlation": [[float(v) for v in row] for row in n.correlation],
        "max_translation_rotation_correlation": n.max_translation_rotation_correlation(),
        "covariance_si": [[float(v) for v in row] for row in n.covariance],
        "n_pairs": n.n_pairs,
        "downweighted_pairs": n.downweighted,
    }


POINT_FORMULATIONS = ("tracker", "coincidence")  # a point per sample, no orientation


def placement_document(val: PlacementValidation, ids: list[str] | None = None) -> dict:
    """Held-out placements of coincidence data: the spread of the predicted points per group
    and the error of the known distances (mm, RMS and max) of the baseline and the calibrated
    model, the spread's RMS ratio to the baseline with its interval; with the sample ``ids``,
    also the spread of every sample and per group."""
    doc: dict = {
        "held_out": "placements",
        "placements": list(val.placements),
        "n_samples": len(val.samples),
        "n_groups": len(val.calibrated.names),
        "baseline": val.baseline.summary(),
        "calibrated": val.calibrated.summary(),
        "ratio_to_baseline": {"spread_mm": val.ratio()},
    }
    if ids is None:
        return doc
    doc["groups"] = {"baseline": val.baseline.per_group(), "calibrated": val.calibrated.per_group()}
    names = val.calibrated.names
    doc["samples"] = [
        {
            "id": ids[k],
            "group": names[g],
            "baseline_spread_mm": float(b) * 1e3,
            "calibrated_spread_mm": float(a) * 1e3,
        }
        for k, g, b, a in zip(
            val.samples,
            val.calibrated.groups,
            val.baseline.spread,
            val.calibrated.spread,
            strict=True,
        )
    ]
    return doc


def validation_document(
    val: Validation | PlacementValidation, ids: list[str] | None = None
) -> dict:
    """Held-out errors: statistics (mm, deg) of each model and the RMS ratio to the baseline with
    its interval, keys naming what is compared; with the sample ``ids``, also the error of every
    pair under each model. Held-out placements: :func:`placement_document`."""
    if isinstance(val, PlacementValidation):
        return placement_document(val, ids)
    doc: dict = {
        "held_out": held_out_what(val),
        "n_pairs": len(val.pairs),
        "n_samples": len(np.unique(val.pairs)),
        "n_configurations": val.n_configurations,
        "baseline_handeye_guess": stats(val.guess),
    }
    if ids is not None:  # held-out samples that fit badly under every model, left out
        doc["outliers"] = [ids[i] for i in val.outliers]
    if val.baseline is not None:
        doc["baseline"] = stats(val.baseline)
    doc["calibrated"] = stats(val.calibrated)
    doc["ratio_to_baseline"] = val.interval(val.before, val.calibrated)
    if val.baseline is not None:
        doc["ratio_to_baseline_handeye_guess"] = val.interval(val.guess, val.calibrated)
    if ids is None:
        return doc

    def norms(errors: np.ndarray, cols: slice, scale: float) -> list[float | None]:
        values = np.linalg.norm(errors[:, cols], axis=1) * scale
        return [None if np.isnan(v) else float(v) for v in values]

    models = {"baseline_handeye_guess": val.guess, "calibrated": val.calibrated}
    if val.baseline is not None:
        models["baseline"] = val.baseline
    columns = {}
    for name, errors in models.items():
        columns[f"{name}_mm"] = norms(errors, slice(0, 3), 1e3)
        columns[f"{name}_deg"] = norms(errors, slice(3, 6), np.degrees(1.0))
    rows = [
        {"ids": [ids[i], ids[j]], **{key: col[k] for key, col in columns.items()}}
        for k, (i, j) in enumerate(val.pairs)
    ]
    key = dict(zip(natural(ids), range(len(ids)), strict=True))  # ids as a person lists them
    doc["pairs"] = sorted(rows, key=lambda r: (key[r["ids"][0]], key[r["ids"][1]]))
    return doc


def cross_validation_document(folds: Sequence[Calibration]) -> dict:
    """Held-out errors per fold and pooled over all folds (each sample held out once)."""
    done = [f.validation for f in folds if f.validation]
    return {
        "k": len(folds),
        "folds": [validation_document(f.validation) if f.validation else None for f in folds],
        "chosen": [f.selection[f.chosen].candidate.name for f in folds],
        "pooled": validation_document(pooled(done)),
        "artifacts": pooled_artifacts(folds),
    }


def pooled_artifacts(folds: Sequence[Calibration]) -> dict[str, dict]:
    """Each loadable file's own held-out errors pooled over the folds (every fold's file read
    back and validated on that fold's held-out samples): ``{file: {"holds", "position_rms_mm",
    "ratio_to_baseline", "refused_in_folds"}}``; files not validated in every fold left out."""
    out = {}
    for name in [a.name for a in folds[0].artifacts] if folds else []:
        mine = [a for f in folds for a in f.artifacts if a.name == name]
        vals = [a.validation for a in mine if a.validation is not None]
        if len(vals) != len(folds):
            continue
        both = pooled(vals)
        out[name] = {
            "holds": mine[0].holds,
            "position_rms_mm": both.rms("calibrated"),
            "ratio_to_baseline": both.ratio(),
            "refused_in_folds": sum(not a.written for a in mine),
        }
    return out


def frames_json(frames: dict[str, np.ndarray]) -> dict:
    """Measurement frames (SI arrays by name: transforms ``(4, 4)``, points ``(3,)`` or
    ``(G, 3)``) as JSON, each quantity by its one serializer (:mod:`relcal.reporting.quantities`):
    a transform ``{"xyz_m", "rpy_deg"}`` under its name, a point in m under ``NAME_xyz_m``."""
    out: dict = {}
    for name, value in frames.items():
        value = np.asarray(value, dtype=float)
        if value.shape == (4, 4):
            out[name] = transform_json(value)
        else:
            out[f"{name}_xyz_m"] = point_json(value)
    return out


def _nuisance_frames(cal: Calibration) -> dict:
    """The estimated instrument-from-base transform and marker position (tracker formulation),
    or the tool point and the group points (coincidence)."""
    if cal.problem.formulation == "coincidence":
        from relcal.calibration.coincidence import split_params

        _, tool, points = split_params(cal.problem, cal.exported_fit.params)
        base_tool = split_params(cal.problem, cal.baseline.params)[1]
        names = cal.problem.coincidence.names
        return {
            "tool_point_xyz_m": point_json(tool),
            # the nominal kinematics' own tool point: what `relcal verify` checks its baseline by
            "baseline_tool_point_xyz_m": point_json(base_tool),
            "tool_point_in_model": True,  # model.yaml's and the URDF's tool end at tool_point
            "group_points_xyz_m": {n: point_json(p) for n, p in zip(names, points, strict=True)},
        }
    if cal.problem.formulation != "tracker":
        return {}
    instrument, marker = tracker_frames(cal.problem, cal.exported_fit.params)
    return {"instrument": transform_json(instrument), "marker_xyz_m": point_json(marker)}


def results_document(cal: Calibration) -> dict:
    """Everything a calibration found, JSON-ready."""
    r = cal.result
    m = cal.measurements
    labels = parameter_labels(cal)  # every sentence names parameters as the tables do
    return {
        "robot": cal.dataset.model.name,
        "dataset": str(cal.dataset.root),
        "settings": cal.settings,
        "n_samples": len(cal.dataset.ids),
        "n_used": int(m.ok.sum()),
        "train_ids": natural(cal.dataset.ids[i] for i in cal.train),
        "held_out_ids": natural(cal.dataset.ids[i] for i in cal.test),
        "outliers": natural(cal.outliers),
        "held_out_outliers": (
            natural(cal.dataset.ids[i] for i in cal.validation.outliers) if cal.validation else []
        ),
        "rejected": [
            {"id": cal.dataset.ids[i], "reason": m.reasons[i]} for i in np.flatnonzero(~m.ok)
        ],
        "reprojection_rms_px": {
            cal.dataset.ids[i]: float(m.rms_px[i]) for i in np.flatnonzero(np.isfinite(m.rms_px))
        },
        "identification": {
            "method": r.method,
            "converged": r.converged,
            "iterations": r.iterations,
            "rank": r.identifiability.rank,
            "solver_rank": r.rank,
            "n_params": len(r.params),
            "initial_residual_rms": r.initial_residual_norm / np.sqrt(r.n_residuals),
            "residual_rms": r.residual_norm / np.sqrt(r.n_residuals),
            "residual_unit": residual_unit(cal),
            "n_estimated": int(
                sum(s in ("estimated", "combination") for s in parameter_status(cal))
            ),
            "seconds": r.seconds,
            "singular_values": [float(s) for s in r.identifiability.singular_values],
            "unidentifiable": [relabel(t, labels) for t in r.unidentifiable],
            # issue 18: held by priors or at nominal, and candidates the data do not determine
            "weak_directions": [
                relabel(w["text"], labels) for w in cal.settings.get("weak_directions", [])
            ],
            "dropped_candidates": [d["reason"] for d in cal.settings.get("dropped_candidates", [])],
            "plausibility_warnings": [relabel(t, labels) for t in getattr(cal, "warnings", ())],
        },
        "parameters": parameter_rows(cal),
        "identifiable_combinations": [
            {**c, "text": relabel(c["text"], labels)} for c in combination_rows(cal)
        ],
        "model_selection": selection_document(cal),
        "noise_model": noise_document(cal),
        "exported": cal.exported,
        "handeye": None
        if cal.problem.formulation in POINT_FORMULATIONS
        else transform_json(cal.handeye),
        **_nuisance_frames(cal),
        # what the held-out numbers measure (the verdict's words): never pooled with another kind
        "held_out_metric": (
            held_out_what(cal.validation, cal.problem.formulation) if cal.validation else None
        ),
        "validation": (
            validation_document(cal.validation, cal.dataset.ids) if cal.validation else None
        ),
        "verdict": verdict_document(cal.verdict()),
        "artifacts": artifacts_document(cal),
        "parameter_labels": labels,
        "calibrated_model": model_to_dict(cal.model),
        "nominal_robot": nominal_robot_document(cal.dataset.model),
        "joint_ranges": JointRanges.of(cal.dataset.model, cal.dataset.q[cal.train]).to_dict(),
        "training": training_document(cal),
    }


def training_document(cal: Calibration) -> dict:
    """The training samples as ``relcal verify`` recognises them: their joint values
    (``configurations``, rad and m) and a digest of each sample (joints and measurement,
    :func:`relcal.data.order.sample_digests`): a session that repeats them is not new."""
    ds, train = cal.dataset, cal.train
    groups = None if ds.groups is None else [ds.groups[k] for k in train]
    poses = None if ds.measured == "coincidence" else cal.measurements.poses[train]
    return {
        "configurations": ds.q[train].tolist(),
        "digests": sample_digests(ds.q[train], poses, groups),
    }


def nominal_robot_document(model: RobotModel) -> dict:
    """The robot a calibration started from, as ``relcal compensate`` needs it to apply the
    calibration without being told again: its ``name``, ``joint_names`` and joint ``types``, the
    URDF ``chain`` (file as given, its SHA-256, ``root`` and ``tip`` links; None for a robot not
    loaded from a URDF) and the nominal ``model`` itself (the model file's form, degrees)."""
    chain = None
    if model.urdf is not None:
        u = model.urdf
        chain = {
            "urdf": str(u.path),
            "urdf_sha256": hashlib.sha256(u.data).hexdigest(),
            "robot_name": u.robot_name,
            "root": u.root,
            "tip": u.tip,
            "parametrisation": u.parametrisation,
        }
    return {
        "name": model.name,
        "joint_names": list(model.joint_names),
        "types": ["prismatic" if p else "revolute" for p in model.prismatic],
        "chain": chain,
        "model": model_to_dict(model),
    }


def verdict_document(v: Verdict) -> dict:
    """The verdict: ``code``, ``text`` (the line a person reads), ``factor`` (baseline RMS over
    calibrated RMS, > 1 better) with its 95 % ``interval``, ``n_held_out`` samples and
    ``warnings``."""
    return {
        "code": v.code,
        "text": v.text,
        "factor": v.factor,
        "interval": None if v.interval is None else list(v.interval),
        "held_out_interval": None if v.held_out_interval is None else list(v.held_out_interval),
        "n_held_out": v.n_held_out,
        "n_configurations": v.n_configurations,
        "not_validated": list(v.limits),
        "warnings": list(v.warnings),
    }


def artifact_document(cal: Calibration, a: Artifact) -> dict:
    """One loadable file: what it holds, whether it was written (or why not), and its own
    held-out errors measured on the file read back (position mm, orientation deg; the spread for
    coincidences), its ratio to the baseline, and the measurement frames it was validated with
    (SI)."""
    val = a.validation
    doc: dict = {
        "file": a.name,
        "holds": a.holds,
        "model": "geometry-only refit" if a.refit else "the validated model",
        "written": a.written,
        "refused": a.refused,
        "sha256": hashlib.sha256(a.content).hexdigest(),
        "frames": frames_json(artifact_frames(cal, a.fit, a.name)),
    }
    if val is None:
        doc["held_out"] = None
        return doc
    if isinstance(val, PlacementValidation):
        doc["held_out"] = {
            "n_samples": len(val.samples),
            "calibrated": val.calibrated.summary(),
            "ratio_to_baseline": {"spread_mm": val.ratio()},
        }
    else:
        doc["held_out"] = {
            "n_samples": len(np.unique(val.pairs)),
            "n_pairs": len(val.pairs),
            "calibrated": stats(val.calibrated),
            "ratio_to_baseline": val.interval(val.before, val.calibrated),
        }
    doc["held_out"]["position_rms_mm"] = val.rms("calibrated")
    return doc


def artifacts_document(cal: Calibration) -> dict:
    """Every file a user can load, validated on its own (:attr:`Calibration.artifacts`), and
    whether the geometry-only files hold the validated model (``geometry_is_validated_model``:
    no non-geometric term chosen, nothing refitted)."""
    return {
        "geometry_is_validated_model": not any(a.refit for a in cal.artifacts),
        "measured_on": "each file as written, read back (model.yaml by relcal's model loader, "
        "URDF by relcal's URDF loader, vendor files written into the nominal URDF's joint "
        "origins), on the held-out samples of the validation",
        "files": [artifact_document(cal, a) for a in cal.artifacts],
    }


def indices_document(ind: Indices) -> dict[str, float]:
    """O1..O5 and the condition number."""
    return {k: float(getattr(ind, k)) for k in (*INDEX_NAMES, "condition_number")}


def accuracy_document(acc: Accuracy) -> dict[str, dict[str, float]]:
    """Mean, RMS, 95th percentile and maximum over the pairs, in mm and degrees."""
    out = {}
    for key, values in (
        ("position_mm", acc.position * 1e3),
        ("orientation_deg", np.degrees(acc.orientation)),
    ):
        out[key] = {
            "mean": float(np.mean(values)),
            "rms": float(np.sqrt(np.mean(values**2))),
            "p95": float(np.percentile(values, 95)),
            "max": float(np.max(values)),
        }
    return out


def observability_document(rep: Report) -> dict:
    """JSON-ready (SI units)."""
    ident = rep.identifiability
    out: dict = {
        "robot": rep.robot,
        "formulation": rep.formulation,
        "measure": rep.measure,
        "handeye": rep.handeye,
        "n_poses": rep.n_poses,
        "n_measurements": rep.n_measurements,
        "n_rows": rep.n_rows,
        "n_params": len(rep.names),
        "rank": ident.rank,
        "rcond": ident.rcond,
        "singular_values": [float(s) for s in ident.singular_values],
        "subset_singular_values": [float(s) for s in rep.subset_singular_values],
        "indices": indices_document(rep.indices),
        "identifiable_subset": [rep.names[k] for k in ident.subset],
        "parameter_labels": rep.labels,  # the names the parameters are shown by
        "not_estimated": rep.not_estimated,
        "unidentifiable": [
            {
                "names": list(c.names),
                "coefficients": list(c.coefficients),
                "reason": c.reason,
                "text": c.describe(),
            }
            for c in ident.combinations
        ],
        "parallel_axes": [
            {
                "joints": list(p.joints),
                "angle_deg": p.angle_deg,
                "hayati": p.hayati,
                "misalignment_deg": p.misalignment_deg,
                "std_d_m": list(p.std_d) if p.std_d else None,
            }
            for p in rep.parallel
        ],
    }
    if rep.uncertainty is not None and rep.noise is not None:
        unc = rep.uncertainty
        out["noise"] = {
            "position_m": rep.noise.position,
            "orientation_rad": rep.noise.orientation,
            "joints_rad": rep.noise.joints,
        }
        out["estimator"] = unc.estimator
        out["parameters"] = [
            {
                "name": unc.names[k],
                "unit": unc.units[k] if unc.units else ("rad" if unc.is_angle[k] else "m"),
                "std": float(unc.std[k]),
                "crb_std": float(unc.crb_std[k]),
                "identifiable": bool(unc.identifiable[k]),
            }
            for k in unc.subset
        ]
        out["correlations"] = [
            {"a": a, "b": b, "rho": rho} for a, b, rho in unc.strongest_correlations(12)
        ]
    if rep.accuracy is not None:
        out["predicted_accuracy"] = accuracy_document(rep.accuracy)
    return out


def plan_document(res: PlanResult, model: RobotModel) -> dict:
    """JSON-ready: the joints (rad, m), and per set the standard deviations (m, rad)."""

    def one(q: Quality) -> dict:
        unc = q.uncertainty
        out = {
            "worst": {"name": q.worst[0], "std_equivalent_m": q.worst[1]},
            "worst_length": {"name": q.worst_length[0], "std_m": q.worst_length[1]},
            "worst_angle": {"name": q.worst_angle[0], "std_rad": q.worst_angle[1]},
            "median_std_equivalent_m": q.median,
            "indices": indices_document(q.indices),
            "std": {unc.names[p]: float(unc.crb_std[p]) for p in unc.subset},
        }
        if q.accuracy is not None:
            out["predicted_accuracy"] = accuracy_document(q.accuracy)
        return out

    return {
        "robot": model.name,
        "criterion": res.criterion,
        "algorithm": res.algorithm,
        "exchanges": res.swaps,
        "n_candidates": res.n_candidates,
        "rejected": res.rejected,
        "seconds": res.seconds,
        "joint_names": list(model.joint_names),
        "joints": [[float(v) for v in row] for row in res.q],
        "travel": travel_document(res, model),
        "plan": one(res.plan),
        "random": [one(r) for r in res.random],
        # no random sets (random_sets=0): nothing to compare with, null rather than NaN
        "random_median_worst_m": res.random_median_worst if res.random else None,
        "improvement": res.improvement if res.random else None,
        "purpose": res.purpose,
        "mode": res.mode,
        "handeye": None
        if res.motion is None
        else {
            "what": (
                "predicted standard deviations of the hand-eye X, the board on the flange "
                "(Cramer-Rao bound, kinematics known, camera pose eliminated)"
                if res.mode == "eye_to_hand"
                else "predicted standard deviations of the hand-eye X (Cramer-Rao bound, "
                "kinematics known, board pose eliminated)"
            )
            + " in the flange frame, and the spread of the relative rotations of every pair of "
            "poses",
            "plan": motion_document(res.motion),
            "random_median": None
            if res.random_motion is None
            else motion_document(res.random_motion),
        },
    }


def motion_document(m: MotionQuality) -> dict:
    """What a set of poses gives the hand-eye (:class:`relcal.design.handeye.MotionQuality`):
    standard deviations in mm and deg, rotations in deg."""
    return {
        "n_poses": m.n_poses,
        "std_xyz_mm": [float(v) * 1e3 for v in m.xyz_std],
        "std_rotation_deg": [float(np.degrees(v)) for v in m.rotation_std],
        "frame": "the flange's (translation along, rotation about its x, y, z axes)",
        "axis_spread": [float(v) for v in m.axis_spread],
        "min_pair_rotation_deg": float(np.degrees(m.min_rotation)),
        "max_pair_rotation_deg": float(np.degrees(m.max_rotation)),
        "pairs_near_180_deg_or_still": m.bad_pairs,
        "fixed_camera": None
        if m.camera_std is None
        else {
            "what": "the fixed camera in the base frame, what eye-to-hand delivers",
            "std_xyz_mm": [float(v) * 1e3 for v in m.camera_std[0]],
            "std_rotation_deg": [float(np.degrees(v)) for v in m.camera_std[1]],
            "frame": "the base's (translation along, rotation about its x, y, z axes)",
        },
    }


def travel_document(res: PlanResult, model: RobotModel) -> dict | None:
    """The route's longest single joint move and its total (rad, or m for a prismatic joint)."""
    if res.route is None:
        return None
    move, joint, value = res.route.longest
    return {
        "longest_move": {
            "joint": model.joint_names[joint],
            "from_pose": move + 1,
            "to_pose": move + 2,
            "value": value,
        },
        "total_of_largest_joint_moves": res.route.total,
        "max_move": res.route.max_move,
        "moves_beyond_max_move": [
            {
                "joint": model.joint_names[j],
                "from_pose": int(m) + 1,
                "to_pose": int(m) + 2,
                "value": float(res.route.moves[m, j]),
            }
            for m, j in res.route.over
        ],
        "exchanged_for_max_move": res.move_exchanges,
        "added_for_max_move": max(0, len(res.q) - res.requested) if res.requested else 0,
    }


def simulation_document(sim: Simulation) -> dict:
    """The JSON document of the README (SI units)."""
    r = sim.result
    return {
        "robot": sim.problem.model.name,
        "formulation": sim.formulation,
        "pairing": sim.pairing,
        "measure": sim.measure,
        "method": r.method,
        "n_poses": len(sim.problem.q),
        "n_measurement_rows": r.n_residuals,
        "noise": {
            "position_m": sim.noise.position,
            "orientation_rad": sim.noise.orientation,
            "joints_rad": sim.noise.joints,
        },
        "rank": r.identifiability.rank,
        "solver_rank": r.rank,
        "n_params": len(r.params),
        "determined_at_estimate": list(r.identifiability.determined),
        "unidentifiable": r.unidentifiable,
        "iterations": r.iterations,
        "converged": r.converged,
        "initial_residual_norm": r.initial_residual_norm,
        "residual_norm": r.residual_norm,
        "seconds": r.seconds,
        "parameters": [
            {
                "name": name,
                "unit": unit,
                "specified": float(s),
                "identified": float(v),
                "identifiable": bool(ok),
            }
            for name, unit, s, v, ok in zip(
                sim.layout.names,
                sim.layout.units(),
                sim.specified,
                r.params,
                r.identifiable,
                strict=True,
            )
        ],
    }


def study_document(res: StudyResult) -> dict:
    """JSON-ready numbers (SI units)."""
    chi2, p = res.bias_test()
    lo, hi = res.ratio_interval()
    return {
        "trials": res.trials,
        "converged": int(res.converged.sum()),
        "estimator": res.estimator,
        "sampling": res.sampling,
        "seconds": res.seconds,
        "overall_ratio": res.overall_ratio,
        "ratio_interval_95": [lo, hi],
        "bias_chi2": chi2,
        "bias_p": p,
        "parameters": [
            {
                "name": res.names[p_],
                "unit": "rad" if res.is_angle[p_] else "m",
                "identifiable": bool(res.predicted.identifiable[p_]),
                "truth": float(res.truth[p_]),
                "reference": float(res.reference[p_]),
                "predicted_std": float(ps),
                "empirical_std": float(es),
                "ratio": float(es / ps),
                "bias": float(b),
                "bias_t": float(t),
            }
            for p_, ps, es, b, t in zip(
                res.subset,
                res.predicted_std,
                res.empirical_std,
                res.bias,
                res.bias_t,
                strict=True,
            )
        ],
    }


def compensation_document(
    ids: list[str],
    q: np.ndarray,
    comp: Compensation,
    dq: np.ndarray | None,
    units: list[str],
    status: list[str] | None = None,
) -> dict:
    """The ``--json`` document: the CSV's content per target (joints in ``units``, one per
    joint; ``status`` why a target has none), and a summary. Non-finite numbers become null."""

    def number(v: float) -> float | None:
        return float(v) if np.isfinite(v) else None

    targets = []
    for k, sid in enumerate(ids):
        row = {"id": sid, "q": [number(v) for v in q[k]], "converged": bool(comp.converged[k])}
        if dq is not None:
            row["dq"] = [number(v) for v in dq[k]]
            row["predicted_position_mm"] = number(comp.predicted_position_mm[k])
            row["predicted_rotation_deg"] = number(comp.predicted_rotation_deg[k])
        if status is not None:
            row["status"] = status[k]
        targets.append(row)
    summary = {"n_targets": len(ids), "n_not_converged": int((~comp.converged).sum())}
    if status is not None:
        summary["n_refused"] = sum(s.startswith("refused") for s in status)
    return {"joint_units": units, "targets": targets, "summary": summary}


def board_document(board: Board, path: Path, dpi: float) -> dict:
    """What ``relcal board`` wrote: the board's geometry (the YAML fields with their unit (m) in
    the key, the white margin and dot diameter in effect, the one-line description), the file and
    the sheet size (mm; for PNG also pixels at ``dpi``)."""
    lengths = ("square", "spacing", "marker", "diameter", "margin")
    doc = {f"{k}_m" if k in lengths else k: v for k, v in board_to_spec(board).items()}
    doc["margin_m"] = board.border
    if board.type in ("circles", "acircles"):
        doc["diameter_m"] = board.dot_diameter
    return {
        **doc,
        "description": board.describe(),
        "file": str(path),
        **_page_size(board, path, dpi),
    }


def _page_size(board: Board, path: Path, dpi: float) -> dict:
    width, height = (v * 1e3 for v in sheet_size(board))
    doc = {"page_width_mm": round(width, 3), "page_height_mm": round(height, 3)}
    if path.suffix.lower() == ".png":
        px = 1e-3 / 0.0254 * dpi
        doc |= {
            "page_width_px": round(width * px),
            "page_height_px": round(height * px),
            "dpi": dpi,
        }
    return doc


def import_document(done: Imported, source_format: str, source: str) -> dict:
    """What ``relcal import`` wrote: the source, the dataset folder, its files and samples."""
    return {
        "format": source_format,
        "source": source,
        "dataset": str(done.folder),
        "files": [str(f) for f in done.files],
        "n_samples": done.n_samples,
    }


def verification_document(
    ver: Verification,
    a: Assessment,
    calibration: dict,
    session: dict,
    nuisance_words: str,
    ranges_note: str,
) -> dict:
    """What ``relcal verify`` found: the calibration and the session, what was refitted and how,
    both models' errors (mm, deg) with their intervals, the ratio to the baseline and to the
    calibration's own held-out error, every sample, the joints outside the covered ranges, the
    warnings and the verdict (with the exit status it gives)."""
    return {
        "calibration": calibration,
        "session": {**session, "kind": ver.kind, "n_evaluated": a.n_samples},
        "nuisance": {
            "refitted": nuisance_words,
            "frozen": FROZEN[ver.kind],
            "scheme": ver.scheme,
            "folds": ver.n_folds,
            "seed": ver.seed,
            "fitted_to_all_samples": {
                name: {"values": frames_json(n.frames), "converged": n.converged}
                for name, n in ver.nuisance.items()
            },
        },
        "baseline": a.baseline,
        "calibrated": a.calibrated,
        "ratio_to_baseline": a.ratio,
        "at_calibration": a.at_calibration,
        "ratio_to_calibration": a.ratio_to_calibration,
        "identical_to_nominal": a.identical,
        "samples": a.samples,
        "joint_ranges": {"checked": a.ranges_checked, "source": ranges_note, "outside": a.outside},
        "warnings": list(a.warnings),
        "verdict": {"code": a.verdict, "reason": a.reason, "exit_status": a.exit_status},
    }
