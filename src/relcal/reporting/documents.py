"""The results document of a calibration (JSON): every number with its unit."""

from __future__ import annotations

import numpy as np

from relcal.calibration.identifiability import NUISANCE_KINDS
from relcal.calibration.measurement import tracker_frames
from relcal.calibration.pipeline import Calibration
from relcal.geometry import to_xyz_rpy
from relcal.robot.model import model_to_dict


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


def parameter_rows(cal: Calibration) -> list[dict]:
    """One row per parameter: name, unit, nominal value, identified error, standard deviation
    (predicted, and from a bootstrap over training samples), significance (error / std) and
    status (:func:`parameter_status`). Lengths in mm, angles in degrees (the units people read).
    """
    layout = cal.problem.full_layout
    angle = layout.is_angle()
    std, boot = cal.std, cal.bootstrap_std
    model = cal.problem.model
    rows = []
    for k, ((kind, index), status) in enumerate(zip(layout, parameter_status(cal), strict=True)):
        nominal = (
            float(model.geometric(kind)[index])
            if kind in ("theta_off", "a", "d", "alpha", "beta")
            else 0.0
        )
        scale = np.degrees(1.0) if angle[k] else 1e3
        ok = status in ("estimated", "combination")
        value = float(cal.result.params[k])
        rows.append(
            {
                "name": layout.names[k],
                "unit": "deg" if angle[k] else "mm",
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
        if combo.is_angle[0] != combo.is_angle[1]:
            continue
        (a, b), (va, vb) = combo.names, combo.coefficients
        c = -va / vb  # a + c b is orthogonal to the null direction (va, vb)
        ia, ib = names.index(a), names.index(b)
        value = cal.result.params[ia] + c * cal.result.params[ib]
        var = np.nansum([std[ia] ** 2, (c * std[ib]) ** 2])
        scale = np.degrees(1.0) if combo.is_angle[0] else 1e3
        out.append(
            {
                "text": f"{a} {'+' if c >= 0 else '-'} {abs(c):.3g} {b}".replace(" 1 ", " "),
                "unit": "deg" if combo.is_angle[0] else "mm",
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
                if cal.problem.formulation != "tracker"
                else None,
                "chosen": k == cal.chosen,
            }
            for k, s in enumerate(cal.selection)
        ],
        "chosen": cal.selection[cal.chosen].candidate.name if cal.selection else None,
        "weighting": cal.settings.get("weighting"),
        "reason": cal.reason,
        "exported": cal.exported,
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


def validation_document(cal: Calibration) -> dict | None:
    """Held-out summary and the error of every held-out pair before and after (mm, deg)."""
    val = cal.validation
    if val is None:
        return None
    ids = cal.dataset.ids

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
    pairs = [
        {"ids": [ids[i], ids[j]], **{key: col[k] for key, col in columns.items()}}
        for k, (i, j) in enumerate(val.pairs)
    ]
    return {**val.summary(), "pairs": pairs}


def _tracker_frames(cal: Calibration) -> dict:
    """The estimated instrument-from-base transform and marker position (tracker formulation)."""
    if cal.problem.formulation != "tracker":
        return {}
    instrument, marker = tracker_frames(cal.problem, cal.result.params)
    xyz, rpy = to_xyz_rpy(instrument)
    return {
        "instrument": {
            "xyz_m": [float(v) for v in xyz],
            "rpy_deg": [float(np.degrees(v)) for v in rpy],
        },
        "marker_xyz_m": [float(v) for v in marker],
    }


def results_document(cal: Calibration) -> dict:
    """Everything a calibration found, JSON-ready."""
    r = cal.result
    handeye = cal.handeye
    xyz, rpy = to_xyz_rpy(handeye)
    m = cal.measurements
    return {
        "robot": cal.dataset.model.name,
        "dataset": str(cal.dataset.root),
        "settings": cal.settings,
        "n_samples": len(cal.dataset.ids),
        "n_used": int(m.ok.sum()),
        "train_ids": [cal.dataset.ids[i] for i in cal.train],
        "held_out_ids": [cal.dataset.ids[i] for i in cal.test],
        "outliers": list(cal.outliers),
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
            "residual_unit": "standard deviations of the measurement noise (rows weighted)",
            "seconds": r.seconds,
            "singular_values": [float(s) for s in r.identifiability.singular_values],
            "unidentifiable": r.unidentifiable,
        },
        "parameters": parameter_rows(cal),
        "identifiable_combinations": combination_rows(cal),
        "model_selection": selection_document(cal),
        "noise_model": noise_document(cal),
        "exported": cal.exported,
        "handeye": None
        if cal.problem.formulation == "tracker"
        else {
            "xyz_m": [float(v) for v in xyz],
            "rpy_deg": [float(np.degrees(v)) for v in rpy],
        },
        **_tracker_frames(cal),
        "validation": validation_document(cal),
        "calibrated_model": model_to_dict(cal.model),
    }
