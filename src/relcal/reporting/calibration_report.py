"""The calibration report: one self-contained HTML file that opens offline.

Plots (:mod:`relcal.reporting.plots`) are embedded as base64 PNG ``data:`` URIs; the CSS is
inline (:mod:`relcal.reporting.htmlkit`) and there is no JavaScript. Every plot is an ``<img>``
with an ``id`` and an ``alt`` text, every part of the page a ``<section>`` with an ``id``
(``summary``, ``parameters``, ``singular-values``, ``residuals``, ``per-pair``, ``rejected``,
``settings``), so that tests and people can find them. All text from data is escaped. The report
reads a :class:`relcal.Calibration` and its results document; it computes nothing.
"""

from __future__ import annotations

import matplotlib
import numpy as np

from relcal.calibration.identifiability import Identifiability
from relcal.calibration.outcome import Calibration
from relcal.calibration.validate import stats
from relcal.reporting import htmlkit as hk
from relcal.reporting.documents import relabel
from relcal.reporting.htmlkit import Html
from relcal.reporting.plots import (
    PLOT_STYLE,
    QUANTITIES,
    calibration_parameter_figure,
    histogram_figure,
    per_pair_figure,
    singular_value_figure,
)
from relcal.reporting.text import pose_noise_parts

__all__ = ["calibration_report", "singular_value_parts"]


def _error_sets(cal: Calibration) -> tuple[np.ndarray, np.ndarray, str, str]:
    """Per-pair errors before and after (:attr:`relcal.Calibration.comparison`), a short label
    and a sentence saying where they come from."""
    c = cal.comparison
    if c.source == "held-out placements":
        v = cal.validation
        sentence = (
            f"Held-out validation: {c.count} samples of {len(v.placements)} placement(s) "
            f"({', '.join(v.placements)}) that the identification did not use, each sample's "
            "predicted tool point against its group's point refitted there (kinematics and tool "
            "point frozen: a new plate position); before = nominal kinematics with the tool "
            "point and the group points fitted to the training samples, after = the exported "
            "model."
        )
    elif c.source == "held-out points":
        sentence = (
            f"Held-out validation: absolute position errors of {c.count} points that the "
            "identification did not use; before = nominal model with the instrument transform and "
            "marker fitted to the training points, after = calibrated model."
        )
    elif c.source == "held-out poses":
        sentence = (
            f"Held-out validation: {c.count} poses that the identification did not use, each "
            "predicted in the world frame (W F(q) X, the world and hand-eye transforms from the "
            "training fit) against the measured one; before = the baseline (nominal kinematics "
            "with the frames fitted on the training samples, the best a user gets without "
            "kinematic calibration), after = the exported model."
        )
    elif c.source == "held-out pairs":
        sentence = (
            f"Held-out validation: {c.count} pairs among {len(cal.test)} samples that the "
            "identification did not use; before = the baseline (nominal kinematics with the "
            "hand-eye transform fitted on the training samples, the best a user gets without "
            "kinematic calibration), after = the exported model."
        )
    else:
        sentence = (
            f"No held-out samples: training residuals of {c.count} pairs "
            "(optimistic: the fit saw them)."
        )
    if cal.worse:  # after = the chosen model, which the baseline replaced
        sentence += (
            " The chosen model shown as after is worse than the baseline on these samples and "
            "was not exported: the exported files hold the baseline."
        )
    return c.before, c.after, c.source, sentence


def _accuracy_cards(before: dict, after: dict, label: str) -> list[tuple[str, str, str]]:
    cards = []
    for _, (name, unit, key) in QUANTITIES.items():
        if key in before:
            b, a = before[key]["rms"], after[key]["rms"]
            cards.append(
                (
                    f"{label.split()[0]} {name.split()[1]} error, RMS",
                    f"{b:.3g} → {a:.3g} {unit}",
                    f"{label}, against the baseline: {_change(b, a)}",
                )
            )
    return cards


def _change(before: float, after: float) -> str:
    """``2.4× smaller``, ``unchanged`` or ``12 % larger``: never a factor that hides a loss."""
    if after <= 0:
        return "smaller"
    ratio = after / before
    if abs(ratio - 1) < 0.005:
        return "unchanged (within 0.5 %)"
    if ratio < 1:
        return f"{1 / ratio:.2f}× smaller" if ratio < 0.5 else f"{(1 - ratio) * 100:.1f} % smaller"
    return f"{(ratio - 1) * 100:.1f} % larger"


def _fit_cards(cal: Calibration, doc: dict) -> list[tuple[str, str, str]]:
    r = cal.result
    ident = doc["identification"]
    return [
        (
            "identification",
            "converged" if r.converged else "NOT converged",
            f"{r.method}, {r.iterations} iterations; weighted residual RMS "
            f"{ident['initial_residual_rms']:.3g} → {ident['residual_rms']:.3g} "
            f"{ident['residual_unit']}",
        ),
        (
            "rank",
            f"{ident['rank']} of {ident['n_params']}",
            f"parameters (identification Jacobian); {ident['n_estimated']} estimated in the "
            f"chosen model; {len(r.unidentifiable)} unidentifiable combination(s)",
        ),
        (
            "samples",
            f"{doc['n_used']} of {doc['n_samples']} used",
            f"{len(cal.train)} fit, {len(cal.test)} held out, {len(doc['rejected'])} rejected, "
            f"{len(doc.get('outliers', []))} outlier(s)",
        ),
    ]


def _stats_table(
    before: dict, after: dict, interval: dict | None = None, guess: dict | None = None
) -> Html:
    """Statistics before (the baseline) and after; ``interval``: the held-out ratio to the
    baseline (after / before, bootstrap over samples); ``guess``: the nominal model with the
    hand-eye guess, shown beside it."""
    keys = [q for q in QUANTITIES.values() if q[2] in before]
    head = [""] + [f"{n.split()[1]} {w} ({u})" for n, u, _ in keys for w in ("before", "after")]
    rows = []
    for stat, label in (
        ("mean", "mean"),
        ("rms", "RMS"),
        ("median", "median"),
        ("p95", "95th percentile"),
        ("max", "max"),
    ):
        rows.append([label] + [hk.fmt(s[k][stat]) for _, _, k in keys for s in (before, after)])
    ratio = ["RMS after / before"]
    for _, _, k in keys:
        ratio += ["", hk.fmt(after[k]["rms"] / max(before[k]["rms"], 1e-300), ".3f")]
    rows.append(ratio)
    if interval:
        row = ["95 % interval of after / before (bootstrap over held-out samples)"]
        for _, _, k in keys:
            lo, hi = interval[k]["ci95"]
            row += ["", f"{hk.fmt(lo, '.3f')} – {hk.fmt(hi, '.3f')}"]
        rows.append(row)
    if guess:
        row = ["RMS of the nominal model with the hand-eye guess"]
        for _, _, k in keys:
            row += [hk.fmt(guess[k]["rms"]), ""]
        rows.append(row)
    return hk.table(head, rows, "num")


def _summary(cal: Calibration, doc: dict, errors: tuple) -> tuple[str, str, Html]:
    before, after, label, sentence = errors
    b, a = stats(before), stats(after)
    converged = cal.result.converged
    ident = doc["identification"]
    interval = (doc.get("validation") or {}).get("ratio_to_baseline")
    if interval and "spread_mm" in interval:  # held-out placements: the spread is the position
        interval = {"position_mm": interval["spread_mm"]}
    return hk.section(
        "summary",
        "Summary",
        _verdict(doc),
        hk.cards(_accuracy_cards(b, a, label), "wide"),
        hk.cards(_fit_cards(cal, doc)),
        hk.paragraph(sentence),
        _stats_table(b, a, interval, (doc.get("validation") or {}).get("baseline_handeye_guess")),
        _artifacts(doc),
        _selection(doc),
        Html(
            "<p>Convergence: "
            + hk.badge(converged, "converged", "not converged")
            + hk.escape(
                f" after {cal.result.iterations} iterations of {cal.result.method}; "
                f"weighted residual RMS {ident['initial_residual_rms']:.4g} → "
                f"{ident['residual_rms']:.4g} {ident['residual_unit']}."
            )
            + "</p>"
        ),
    )


def _verdict(doc: dict) -> Html:
    """The verdict line (:mod:`relcal.calibration.verdict`) and its warnings."""
    v = doc.get("verdict")
    if not v:
        return Html("")
    warnings = "".join(f'<p class="hint">warning: {hk.escape(w)}</p>' for w in v["warnings"])
    return Html(
        f'<div id="verdict" class="{hk.escape(v["code"].replace(" ", "-"))}"><p><strong>'
        f"Verdict:</strong> {hk.escape(v['text'])}</p>{warnings}</div>"
    )


def _artifacts(doc: dict) -> Html:
    """Every loadable file with its own held-out RMS, measured on the file read back."""
    art = doc.get("artifacts")
    if not art or not art.get("files"):
        return Html("")
    rows = []
    for f in art["files"]:
        held = f["held_out"]
        key = "position_mm"
        if held and "spread_mm" in held["ratio_to_baseline"]:
            key = "spread_mm"
        ratio = held["ratio_to_baseline"][key] if held else None
        rows.append(
            [
                Html(f"<code>{hk.escape(f['file'])}</code>"),
                f["holds"],
                f["model"],
                hk.fmt(held["position_rms_mm"] if held else None, ".3f"),
                hk.fmt(ratio["after_over_before"] if ratio else None, ".3f"),
                f"{ratio['ci95'][0]:.3f} – {ratio['ci95'][1]:.3f}" if ratio else "–",
                "written" if f["written"] else f"not written: {f['refused']}",
            ]
        )
    head = [
        "file",
        "holds",
        "model",
        "held-out RMS (mm)",
        "RMS / baseline",
        "95 % interval",
        "",
    ]
    note = (
        "Each file was read back as written and its own forward kinematics evaluated on the "
        "held-out samples of the validation. "
        + (
            "The geometry-only files hold the validated model itself (no non-geometric term "
            "chosen)."
            if art["geometry_is_validated_model"]
            else "The geometry-only files cannot hold the chosen model's non-geometric terms: "
            "they hold the geometry refitted without them; model.yaml (and relcal compensate) "
            "carries the validated accuracy."
        )
    )
    return Html(
        '<div id="artifacts"><h3>Exported files, each validated on its own</h3>'
        + hk.table(head, rows, "num")
        + f'<p class="hint">{hk.escape(note)}</p></div>'
    )


def _parameter_table(cal: Calibration, doc: dict) -> tuple[Html, str]:
    rows = doc["parameters"]
    std = [row.get("std") for row in rows]
    source = (
        "Standard deviations: least-squares covariance of the fit (pair correlations included), "
        "with the pose noise estimated robustly from the residuals."
    )
    body = [
        [
            Html(f"<code>{hk.escape(row.get('label', row['name']))}</code>"),
            row["unit"],
            hk.fmt(row["nominal"], ".3f"),
            hk.fmt(row["error"], "+.4f"),
            hk.fmt(s, ".2g"),
            hk.fmt(row.get("bootstrap_std"), ".2g"),
            hk.fmt(row.get("significance"), ".1f"),
            row.get("status", "estimated" if row["identifiable"] else "unidentifiable"),
        ]
        for row, s in zip(rows, std, strict=True)
    ]
    head = [
        "parameter",
        "unit",
        "nominal",
        "identified error",
        "std",
        "bootstrap std",
        "|error| / std",
        "status",
    ]
    return hk.table(head, body, "num"), source


def _selection(doc: dict) -> Html:
    """The candidate models with their cross-validated held-out errors, the choice and why."""
    sel = doc.get("model_selection")
    if not sel or not sel.get("candidates"):
        return Html("")
    rows = [
        [
            ("▶ " if c["chosen"] else "") + c["name"],
            c["weighting"],
            str(c["n_params"]),
            hk.fmt(c["cv_position_rms_mm"], ".4f"),
            hk.fmt(c["cv_orientation_rms_deg"], ".4f"),
        ]
        for c in sel["candidates"]
    ]
    head = [
        "candidate model",
        "row weighting",
        "parameters",
        "CV position RMS (mm)",
        "CV orientation RMS (deg)",
    ]
    note = f"Chosen: {sel['chosen']} ({sel['weighting']}): {sel['reason']}."
    if sel["exported"] == "baseline":
        reason = sel.get("export_reason") or "the data support no kinematic correction"
        note += (
            f" {reason[0].upper()}{reason[1:]}: the exported model is the nominal kinematics "
            "with the measurement frames fitted."
        )
    noise = doc.get("noise_model")
    if noise:
        mm, deg, rho = pose_noise_parts(noise)
        note += (
            f" Learned pose noise (camera frame): {mm} mm and {deg} deg; largest "
            f"translation-rotation correlation {rho}."
        )
    return Html(
        f"<h3>Model selection ({sel['folds']}-fold cross-validation on the training samples)</h3>"
        + hk.table(head, rows, "num")
        + f'<p class="hint">{hk.escape(note)}</p>'
    )


def _handeye_table(doc: dict) -> Html:
    he = doc.get("handeye")
    if not he:
        return Html("")
    xyz = [hk.fmt(v * 1e3, ".3f") for v in he["xyz_m"]]
    rpy = [hk.fmt(v, ".4f") for v in he["rpy_deg"]]
    return hk.table(
        ["calibrated hand-eye X", "x / roll", "y / pitch", "z / yaw"],
        [["translation (mm)", *xyz], ["rotation rpy (deg)", *rpy]],
        "num",
    )


def _held_at_nominal(doc: dict) -> Html:
    """The parameters the calibration did not estimate, by reason, in compact form."""
    parts = []
    for status, why in (
        ("unidentifiable", "Unidentifiable (the data cannot determine them)"),
        ("not supported", "Not supported by model selection (left out of the chosen model)"),
    ):
        names = [r.get("label", r["name"]) for r in doc["parameters"] if r["status"] == status]
        if names:
            parts.append(f"{why}, nominal kept: {hk.compact_names(names)}.")
    if not parts:
        return Html("")
    return Html(f'<p class="hint">{hk.escape(" ".join(parts))}</p>')


def _parameter_plot(cal: Calibration, doc: dict) -> Html:
    kinds = cal.problem.full_layout.kinds
    names = [r["name"] for r in doc["parameters"]]
    if tuple(names) != tuple(cal.problem.full_layout.names):
        return Html("")  # a document of another calibration: no plot rather than a wrong one
    return hk.figure_html(
        "plot-parameters",
        "Identified error of each parameter with ± 1 standard deviation (blue: predicted, "
        "orange: bootstrap over the training samples; often smaller than the dot), lengths and "
        "angles of the geometry and the non-geometric terms of the chosen model on separate "
        "axes; grey marks at zero: held at nominal",
        calibration_parameter_figure(doc["parameters"], kinds),
    )


def _frames_sentence(formulation: str) -> str:
    """What the nuisance rows of the parameter table are."""
    if formulation == "tracker":
        return (
            "instrument.* and marker.* are corrections to the guesses of the instrument "
            "transform and of the marker position"
        )
    if formulation == "coincidence":
        return "tool_point.* and the group points are corrections to their guesses"
    return "handeye.* are corrections to the hand-eye guess"


def _parameters(cal: Calibration, doc: dict) -> tuple[str, str, Html]:
    table, source = _parameter_table(cal, doc)
    ident = doc["identification"]
    return hk.section(
        "parameters",
        "Parameters",
        hk.paragraph(
            "Identified errors are corrections to the nominal model, each in the unit of its "
            f"kind (lengths in mm, angles in degrees, non-geometric terms in their own units); "
            f"{_frames_sentence(cal.problem.formulation)} (in the table, not the plot). "
            "Unidentifiable parameters keep their nominal value."
        ),
        _parameter_plot(cal, doc),
        _held_at_nominal(doc),
        table,
        Html(f'<p class="hint">{hk.escape(source)}</p>'),
        Html("<h3>Unidentifiable combinations, with the reason</h3>"),
        hk.bullet_list(
            [relabel(t, doc.get("parameter_labels") or {}) for t in ident["unidentifiable"]],
            "none: every parameter is identifiable",
        ),
        Html("<h3>Weakly determined directions, held (by priors or at nominal)</h3>"),
        hk.bullet_list(
            doc["identification"].get("weak_directions", [])
            + [
                f"candidates dropped: {t}"
                for t in doc["identification"].get("dropped_candidates", [])
            ],
            "none: the data determine every estimated parameter more than its prior does",
        ),
        Html("<h3>Hand-eye transform</h3>"),
        _handeye_table(doc),
    )


def singular_value_parts(ident: Identifiability, ident_id: str = "plot-singular-values"):
    """The singular-value plot and its explanation (shared with the simulation report)."""
    s = ident.singular_values
    cond = ident.condition_number
    return (
        hk.figure_html(
            ident_id,
            f"Singular values of the scaled identification Jacobian (log scale): rank "
            f"{ident.rank} of {len(s)}, tolerance {ident.rcond:g} × the largest",
            singular_value_figure(ident),
        ),
        hk.paragraph(
            f"Columns scaled to unit norm so that metres and radians compare; condition number "
            f"of the identifiable part {cond:.3g}. Directions below the tolerance are the null "
            "space: the unidentifiable combinations listed with the parameters."
        ),
    )


def _rejected(doc: dict) -> tuple[str, str, Html]:
    rejected = doc.get("rejected", [])
    outliers = doc.get("outliers", [])
    kept = not doc["settings"].get("reject_outliers", True)
    parts: list[object] = []
    if rejected:
        rows = [[r["id"], r["reason"]] for r in rejected]
        parts.append(hk.table(["sample", "reason"], rows, "ids"))
    else:
        parts.append(Html('<p class="none">none: every sample gave a camera pose</p>'))
    parts.append(Html("<h3>Outliers</h3>"))
    if outliers:
        why = "kept in the fit (--keep-outliers)" if kept else "left out of the final fit"
        rows = [[o, f"its pairs fit badly after a robust fit; {why}"] for o in outliers]
        parts.append(hk.table(["sample", "reason"], rows, "ids"))
    else:
        parts.append(Html('<p class="none">none</p>'))
    return hk.section("rejected", "Rejected images", *parts)


def _training_measurements(cal: Calibration) -> tuple[str, str]:
    """The settings row of what the fit compared: pairs of poses for relative poses, else one
    measurement per training sample (poses against the board, points, seated samples)."""
    problem = cal.problem
    named = {
        "board": "training poses (each against the board)",
        "tracker": "training points",
        "absolute": "training poses",
        "coincidence": "training samples (seated tool points)",
    }
    if problem.formulation in named:
        return named[problem.formulation], str(len(problem.q))
    return "training pairs of poses", str(len(problem.pair_indices()))


def _settings(cal: Calibration, doc: dict) -> tuple[str, str, Html]:
    rows = [
        ("robot", doc["robot"]),
        ("dataset", doc["dataset"]),
        ("identification method", cal.result.method),
        (
            "rank tolerance (relative to the largest singular value)",
            f"{cal.result.identifiability.rcond:g}",
        ),
        _training_measurements(cal),
    ]
    rows += hk.flatten(doc["settings"])
    return hk.section("settings", "Settings", hk.table(["setting", "value"], rows))


def calibration_report(cal: Calibration, doc: dict) -> str:
    """The HTML report of a calibration; ``doc`` is :func:`documents.results_document`."""
    errors = _error_sets(cal)
    before, after, label, sentence = errors
    unit, kind = {
        "held-out points": ("point", "Absolute position"),
        "held-out poses": ("pose", "World-frame pose"),
        "held-out placements": ("sample", "Spread"),
    }.get(label, ("pair", "Relative pose"))
    with matplotlib.rc_context(PLOT_STYLE):
        sections = [
            _summary(cal, doc, errors),
            _parameters(cal, doc),
            hk.section(
                "singular-values",
                "Singular value spectrum",
                *singular_value_parts(cal.result.identifiability),
            ),
            hk.section(
                "residuals",
                "Residual histograms",
                hk.paragraph(sentence),
                hk.figure_html(
                    "plot-residuals",
                    f"Histograms of the {kind.lower()} errors of {label} before and after "
                    "calibration (logarithmic bins)",
                    histogram_figure(before, after, label),
                ),
            ),
            hk.section(
                "per-pair",
                f"Errors per {unit}, before and after",
                hk.figure_html(
                    "plot-per-pair",
                    f"{kind} error of each of the {len(before)} {label} before (grey) and "
                    "after (blue) calibration, log scale",
                    per_pair_figure(before, after, label),
                ),
            ),
            _rejected(doc),
            _settings(cal, doc),
        ]
    meta = [
        ("robot", doc["robot"]),
        ("dataset", doc["dataset"]),
        ("samples", f"{doc['n_used']} of {doc['n_samples']}"),
    ]
    return hk.page("Calibration report", meta, sections)
