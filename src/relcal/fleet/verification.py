"""Verifications in the registry: which calibration ``relcal verify`` checks (an output folder or a
registry run), and the record of what it found.

A calibration given as a registry run is rebuilt from its record (the nominal model of the
session's robot with the recorded errors applied, the chosen families of non-geometric terms
switched on), unless its output folder still holds that very calibration (same dataset, same
held-out error), whose ``model.yaml`` (what a user loads) and per-sample held-out errors are then
used. A calibration given as a folder is looked up in the registry (the latest run written to
that folder with the same held-out error), so that its verifications list under its run.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

import relcal
from relcal.calibration.verify import (
    Assessment,
    CalibrationFiles,
    JointRanges,
    Reference,
    Verification,
    load_calibration,
)
from relcal.errors import RelcalError
from relcal.fleet.registry import Registry, Run
from relcal.robot.model import RobotModel

HELD_OUT = "calibrated_position_rms_mm"  # the record's column matched against results.json


@dataclass(frozen=True)
class Source:
    """The calibration a session is verified against, and what it says about itself."""

    label: str  # in words: the folder, or the run and its registry
    model: RobotModel  # as a user loads it (model.yaml), or rebuilt from the record
    results: dict | None  # results.json when read
    run: Run | None  # its registry run, when known
    reference: Reference | None  # its own held-out errors
    ranges: JointRanges | None
    ranges_note: str
    tool_points: tuple[np.ndarray, np.ndarray] | None = None
    notes: tuple[str, ...] = ()
    changed: str | None = None  # why model.yaml is not the file the calibration validated

    @property
    def exported(self) -> str | None:
        if self.results is not None:
            return self.results.get("exported")
        chosen = (self.run.settings or {}).get("chosen_model") if self.run else None
        if chosen is None:
            return None
        return (
            "baseline"
            if chosen in ("hand-eye only", "instrument and marker only")
            else ("calibrated")
        )

    @property
    def kind(self) -> str | None:
        """What the calibration's own held-out errors measure: ``pose`` (relative poses),
        ``position`` (points) or ``coincidence``; None when unknown."""
        from relcal.calibration.verify import FORMULATIONS

        settings = (self.results or {}).get("settings") or (self.run.settings if self.run else {})
        return FORMULATIONS.get((settings or {}).get("formulation"))

    def reference_for(self, kind: str) -> tuple[Reference | None, str | None]:
        """The calibration's held-out errors if they measure what a session of ``kind`` does;
        else None, and why."""
        if self.reference is None:
            return None, None
        if self.kind != kind:
            words = {"pose": "relative poses", "position": "points", "coincidence": "coincidences"}
            return None, (
                f"the calibration was validated on {words.get(self.kind, 'other data')}, this "
                f"session has {words[kind]}: its held-out error at calibration does not compare"
            )
        return self.reference, None

    @property
    def chosen_model(self) -> str | None:
        if self.results is not None:
            return (self.results.get("model_selection") or {}).get("chosen")
        return (self.run.settings or {}).get("chosen_model") if self.run else None


def _held_out(results: dict) -> float | None:
    """The calibrated held-out position RMS (mm) of a results document (for coincidence data the
    spread of the held-out placements' samples, as the record's column holds)."""
    summary = (results.get("validation") or {}).get("calibrated") or {}
    value = summary.get("position_mm") or summary.get("spread_mm") or {}
    rms = value.get("rms")
    return None if rms is None else float(rms)


def _same(a: float | None, b: float | None) -> bool:
    return a is not None and b is not None and bool(np.isclose(a, b, rtol=1e-9, atol=0.0))


def find_run(registry: Registry | None, files: CalibrationFiles) -> Run | None:
    """The registry run of a calibration folder: the latest run written to that folder whose
    dataset and held-out error are those of its ``results.json`` (None if none is)."""
    if registry is None:
        return None
    folder = str(files.folder.resolve())
    dataset = files.results.get("dataset")
    dataset = str(Path(dataset).resolve()) if dataset else None
    held = _held_out(files.results)
    found = [
        r
        for r in registry.runs()
        if r.outputs_path == folder
        and (dataset is None or r.dataset_path == dataset)
        and (held is None or _same(r.errors.get(HELD_OUT), held))
    ]
    return found[-1] if found else None


def _from_files(files: CalibrationFiles, run: Run | None, label: str) -> Source:
    ranges, note = files.covered_ranges()
    return Source(
        label=label,
        model=files.model,
        results=files.results,
        run=run,
        reference=files.reference,
        ranges=ranges,
        ranges_note=note,
        tool_points=files.tool_points,
        changed=files.changed,
    )


def record_tool_points(run: Run) -> tuple[np.ndarray, np.ndarray] | None:
    """(calibrated, baseline) tool points (tip frame, m) of a coincidence calibration's record
    (its settings' ``tool_points_xyz_m``), for the model :func:`model_from_record` rebuilds;
    None for other records."""
    found = (run.settings or {}).get("tool_points_xyz_m")
    if not found:
        return None
    return np.asarray(found["calibrated"], dtype=float), np.asarray(found["baseline"], dtype=float)


def model_from_record(run: Run, nominal: RobotModel) -> RobotModel:
    """The calibrated model of a registry record: ``nominal`` (the session's robot) with the
    record's Hayati joints, the non-geometric families it estimated switched on, and its
    identified errors applied (hand-eye, instrument and marker values, which belong to the
    calibration's session, and a coincidence calibration's tool point and group points left out:
    :func:`record_tool_points`)."""
    from relcal.calibration.outcome import exported_model
    from relcal.robot.export import calibrated_model
    from relcal.robot.kinematics import make_layout
    from relcal.robot.model import NONGEOMETRIC_KINDS, with_nongeometric

    if run.model_name != nominal.name:
        raise RelcalError(
            f"run {run.id} calibrated '{run.model_name}', the session's robot is '{nominal.name}': "
            "give the session of that robot (or the calibration's output folder)"
        )
    hayati = (run.settings or {}).get("hayati_joints")
    model = nominal
    if hayati is not None:
        mask = np.zeros(model.n_joints, dtype=bool)
        mask[[j - 1 for j in hayati]] = True
        model = replace(model, hayati=mask)
    values = {p["name"]: p["value"] for p in run.parameters if p.get("value") is not None}
    kinds = {n.split("[")[0] for n in values}
    terms = {"harmonic" if k.startswith("harmonic") else k for k in kinds}
    families = sorted(terms & {"scale", "compliance", "harmonic"})
    if families:
        model = with_nongeometric(model, tuple(families))
    layout = make_layout(model)
    params = np.zeros(layout.size)
    frames = ("handeye.", "board.", "instrument.", "marker.", "tool_point.", "point[")
    unknown = [n for n in values if n not in layout.names and not n.startswith(frames)]
    if unknown:
        raise RelcalError(
            f"run {run.id}: parameters {', '.join(unknown[:4])} are not parameters of the "
            f"session's model of '{nominal.name}' (another parametrisation or Hayati setting?)"
        )
    for k, name in enumerate(layout.names):
        params[k] = values.get(name, 0.0)
    chosen = {k for k in layout.kinds if k in NONGEOMETRIC_KINDS and k in kinds}
    return exported_model(calibrated_model(model, layout, params), chosen)


def resolve(
    calibration: str, registry: Registry | None, nominal: RobotModel, where: str | None = None
) -> Source:
    """The calibration named on the command line: an output folder of ``relcal calibrate``, or
    a registry run (its id, or 6+ characters of its uid) when ``registry`` is given."""
    path = Path(calibration)
    if path.is_dir():
        files = load_calibration(path)
        run = find_run(registry, files)
        label = f"{path}" + (f" (registry run {run.id})" if run else "")
        return _from_files(files, run, label)
    if registry is None:
        raise RelcalError(
            f"{calibration}: not a calibration folder (the output folder of relcal calibrate, with "
            "model.yaml and results.json); a registry run id needs --registry PATH|URL"
        )
    run = registry.get(calibration)
    label = f"run {run.id} of {where or 'the registry'}"
    out = Path(run.outputs_path) if run.outputs_path else None
    if out is not None and (out / "results.json").is_file() and (out / "model.yaml").is_file():
        files = load_calibration(out)
        same_data = files.results.get("dataset") is None or str(
            Path(files.results["dataset"]).resolve()
        ) == str(run.dataset_path)
        if same_data and _same(_held_out(files.results), run.errors.get(HELD_OUT)):
            return _from_files(files, run, f"{label} ({out})")
    model = model_from_record(run, nominal)
    doc = (run.settings or {}).get("joint_ranges")
    ranges = JointRanges.from_dict(doc) if doc else None
    note = "the registry record" if doc else "the registry record holds no joint ranges"
    held = run.errors.get(HELD_OUT)
    orientation = run.errors.get("calibrated_orientation_rms_deg")
    reference = None if held is None else Reference.fixed(held, orientation)
    why = (
        f"its output folder {out} is gone or holds another calibration"
        if out is not None
        else "no output folder recorded"
    )
    return Source(
        label=f"{label} (rebuilt from the record: {why})",
        model=model,
        results=None,
        run=run,
        reference=reference,
        ranges=ranges,
        ranges_note=note,
        tool_points=record_tool_points(run),
        notes=(
            "the calibration's held-out error at calibration is taken from the registry record, "
            "without its samples: its interval is not included",
        )
        if reference is not None
        else (),
    )


def verification_record(
    source: Source,
    ver: Verification,
    a: Assessment,
    dataset_path: str | Path,
    robot_id: str,
    session: str | None,
    input_hashes: dict | None = None,
) -> dict[str, Any]:
    """The registry record (:meth:`Registry.add_verification`) of a verification."""
    pos = "position_mm"
    ori = "orientation_deg"

    def rms(summary: dict | None, key: str) -> float | None:
        value = ((summary or {}).get(key) or {}).get("rms")
        return None if value is None else float(value)

    intervals = {
        "baseline_position_mm": a.baseline[pos].get("ci95"),
        "calibrated_position_mm": a.calibrated[pos].get("ci95"),
        "ratio_position": a.ratio[pos]["ci95"],
    }
    if ori in a.ratio:
        intervals.update(
            baseline_orientation_deg=a.baseline[ori].get("ci95"),
            calibrated_orientation_deg=a.calibrated[ori].get("ci95"),
            ratio_orientation=a.ratio[ori]["ci95"],
        )
    if a.ratio_to_calibration:
        intervals["ratio_to_calibration_position"] = a.ratio_to_calibration[pos]["ci95"]
    return {
        "calibration_id": None if source.run is None else source.run.id,
        "calibration": source.label,
        "robot_id": robot_id,
        "session": session,
        "dataset_path": str(Path(dataset_path).resolve()),
        "relcal_version": relcal.__version__,
        "kind": ver.kind,
        "n_samples": a.n_samples,
        "folds": ver.n_folds,
        "baseline_position_rms_mm": rms(a.baseline, pos),
        "calibrated_position_rms_mm": rms(a.calibrated, pos),
        "baseline_orientation_rms_deg": rms(a.baseline, ori),
        "calibrated_orientation_rms_deg": rms(a.calibrated, ori),
        "ratio_position": float(a.ratio[pos]["after_over_before"]),
        "at_calibration_position_rms_mm": rms(a.at_calibration, pos),
        "verdict": a.verdict,
        "intervals": intervals,
        "details": {
            "reason": a.reason,
            "warnings": list(a.warnings),
            "outside_ranges": a.outside,
            "scheme": ver.scheme,
            "seed": ver.seed,
            "input_hashes": input_hashes or {},
        },
    }
