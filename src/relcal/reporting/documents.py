"""The results document of a calibration (JSON): every number with its unit."""

from __future__ import annotations

import numpy as np

from relcal.calibration.identify import calibrated_handeye
from relcal.calibration.pipeline import Calibration
from relcal.geometry import to_xyz_rpy
from relcal.robot.export import calibrated_model
from relcal.robot.model import model_to_dict


def parameter_rows(cal: Calibration) -> list[dict]:
    """One row per parameter: name, unit, nominal value, identified error, standard deviation,
    identifiable. Lengths in mm, angles in degrees (the units people read)."""
    layout = cal.problem.full_layout
    angle = layout.is_angle()
    std = cal.std
    model = cal.problem.model
    rows = []
    for k, (kind, index) in enumerate(layout):
        nominal = (
            float(model.geometric(kind)[index])
            if kind in ("theta_off", "a", "d", "alpha", "beta")
            else 0.0
        )
        scale = np.degrees(1.0) if angle[k] else 1e3
        ok = bool(cal.result.identifiable[k])
        rows.append(
            {
                "name": layout.names[k],
                "unit": "deg" if angle[k] else "mm",
                "nominal": nominal * scale,
                "error": float(cal.result.params[k]) * scale if ok else None,
                "std": float(std[k]) * scale
                if std is not None and ok and np.isfinite(std[k])
                else None,
                "identifiable": ok,
            }
        )
    return rows


def validation_document(cal: Calibration) -> dict | None:
    """Held-out summary and the error of every held-out pair before and after (mm, deg)."""
    val = cal.validation
    if val is None:
        return None
    ids = cal.dataset.ids

    def norms(errors: np.ndarray, cols: slice, scale: float) -> list[float | None]:
        values = np.linalg.norm(errors[:, cols], axis=1) * scale
        return [None if np.isnan(v) else float(v) for v in values]

    columns = {
        "before_mm": norms(val.before, slice(0, 3), 1e3),
        "after_mm": norms(val.after, slice(0, 3), 1e3),
        "before_deg": norms(val.before, slice(3, 6), np.degrees(1.0)),
        "after_deg": norms(val.after, slice(3, 6), np.degrees(1.0)),
    }
    pairs = [
        {"ids": [ids[i], ids[j]], **{key: col[k] for key, col in columns.items()}}
        for k, (i, j) in enumerate(val.pairs)
    ]
    return {**val.summary(), "pairs": pairs}


def results_document(cal: Calibration) -> dict:
    """Everything a calibration found, JSON-ready."""
    r = cal.result
    layout = cal.problem.layout
    handeye = calibrated_handeye(cal.problem, r)
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
        "handeye": {
            "xyz_m": [float(v) for v in xyz],
            "rpy_deg": [float(np.degrees(v)) for v in rpy],
        },
        "validation": validation_document(cal),
        "calibrated_model": model_to_dict(calibrated_model(cal.problem.model, layout, r.params)),
    }
