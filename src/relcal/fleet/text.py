"""Text and JSON of the fleet commands: history, comparisons, fleet runs (mm and degrees)."""

from __future__ import annotations

from typing import Any

from relcal.fleet.drift import Comparison, display
from relcal.fleet.registry import Run, VerificationRun
from relcal.reporting.quantities import parameter_json
from relcal.robot.kinematics import relabel


def _time(run: Run) -> str:
    return run.created_at.strftime("%Y-%m-%d %H:%M:%S")


def _errors(errors: dict) -> str:
    b, a = errors.get("baseline_position_rms_mm"), errors.get("calibrated_position_rms_mm")
    if b is None or a is None:
        return "no held-out set"
    return f"{b:.3f} -> {a:.3f}"


def _table(rows: list[list[str]], right: set[int] = frozenset()) -> list[str]:
    widths = [max(len(r[k]) for r in rows) for k in range(len(rows[0]))]
    return [
        "  ".join(
            c.rjust(w) if k in right else c.ljust(w)
            for k, (c, w) in enumerate(zip(r, widths, strict=True))
        ).rstrip()
        for r in rows
    ]


def run_metric(run: Run) -> str | None:
    """What a run's held-out errors measure (``pairs of poses``, ``points``, ``placements``:
    :func:`relcal.fleet.records.held_out_metric`), from its settings or, for older records,
    its validation."""
    if "held_out_metric" in run.settings:
        return run.settings["held_out_metric"]
    from relcal.fleet.records import held_out_metric

    return held_out_metric({"validation": run.validation})


def verdict_text(c: Comparison | None) -> str:
    if c is None:
        return ""
    if not c.drift:
        return f"agree (p={c.p_value:.2g})"
    moved = ", ".join(c.label(n) for n in c.flagged) or "as a whole"
    return f"DRIFT (p={c.p_value:.2g}; {moved})"


def history_text(
    robot_id: str,
    runs: list[Run],
    comparisons: list,
    where: str,
    verifications: list[VerificationRun] = (),
) -> str:
    """The runs of one robot over time, the verdict against the previous run, the parameters
    (identified error +- std) per run, and the verifications of its calibrations on new
    sessions."""
    if not runs:
        head = f"{robot_id}: no calibration in {where}"
        return "\n".join([head, *verifications_text(list(verifications))])
    models = list(dict.fromkeys(r.model_name for r in runs))
    if len(models) > 1:  # one id, several robots: each model's runs on their own
        lines = [f"warning: {mixed_models(robot_id, runs)}"]
        for model in models:
            keep = [k for k, r in enumerate(runs) if r.model_name == model]
            part = history_text(
                robot_id, [runs[k] for k in keep], [comparisons[k] for k in keep], where
            )
            lines += ["", *part.splitlines()]
        return "\n".join([*lines, *verifications_text(list(verifications))])
    lines = [f"{robot_id} ({runs[-1].model_name}): {len(runs)} calibration(s) in {where}", ""]
    rows = [["run", "time (UTC)", "session", "relcal", "held-out position RMS mm", "held out"]]
    rows[0].append("vs previous")
    for run, c in zip(runs, comparisons, strict=True):
        rows.append(
            [
                str(run.id),
                _time(run),
                run.session or "",
                run.relcal_version,
                _errors(run.errors) + ("" if run.converged else " (not converged)"),
                run_metric(run) or "",
                verdict_text(c),
            ]
        )
    lines += _table(rows, {0})
    lines += ["", "parameters (identified error in its kind's unit, +- one standard deviation):"]
    labels: dict[str, str] = {}  # URDF robots: joint names, as each calibration showed them
    for run in runs:
        labels |= run.labels
    header = ["name", "unit"] + [f"run {r.id}" for r in runs]
    table = [header]
    never: dict[str, list[str]] = {"n/i": [], "-": []}
    points = combined = 0
    for name in runs[-1].names:
        if name.startswith("point["):  # a coincidence group's point: the session's own
            points += 1
            continue
        cells, unit = [], ""
        for run in runs:
            try:
                p = run.parameter(name)
            except KeyError:
                cells.append("")
                continue
            if p["value"] is None:  # not identifiable, or left out by model selection
                cells.append("-" if p["identifiable"] else "n/i")
                continue
            value, unit = display(p["value"], p["unit"])
            std = display(p["std"], p["unit"])[0] if p["std"] is not None else float("nan")
            combination = p.get("status") == "combination"
            combined += combination
            cells.append(f"{value:+.4f} +- {std:.4f}" + (" c" if combination else ""))
        shown = {c for c in cells if c}
        if shown <= {"n/i", "-"}:
            never["n/i" if shown == {"n/i"} else "-"].append(labels.get(name, name))
        else:
            table.append([labels.get(name, name), unit, *cells])
    lines += _table(table, set(range(2, len(header))))
    if never["n/i"]:
        lines.append("not identifiable (n/i) in any run: " + ", ".join(never["n/i"]))
    if never["-"]:
        lines.append("not in any run's chosen model (-): " + ", ".join(never["-"]))
    if combined:
        lines.append(
            "c: the value of a combination whose other members are held at nominal, not the "
            "parameter's own (results.json: combination)"
        )
    if points:
        lines.append(
            f"not shown: the {points // 3} group points of run {runs[-1].id} (where its sockets "
            "were: each session's own)"
        )
    lines += verifications_text(list(verifications))
    return "\n".join(lines)


def mixed_models(robot_id: str, runs: list[Run]) -> str | None:
    """None when every run of ``robot_id`` calibrated one robot model; else, in words, which
    models and runs, and what it means."""
    models: dict[str, list[str]] = {}
    for run in runs:
        models.setdefault(run.model_name, []).append(str(run.id))
    if len(models) < 2:
        return None
    listed = "; ".join(
        f"{name} (run{'s' if len(ids) > 1 else ''} {', '.join(ids)})"
        for name, ids in models.items()
    )
    return (
        f"robot id {robot_id!r} has calibrations of {len(models)} robot models: {listed}; a robot "
        "id names one physical robot, so one of them is recorded under the wrong id (a robot_id "
        "copied into another dataset.yaml, or --robot-id mistyped?); each model's runs are "
        "listed and compared on their own, never with the other's"
    )


def _test_name(c: Comparison) -> str:
    if c.noise_dof == float("inf"):
        return f"chi-square test on {c.dof} degrees of freedom"
    return f"F test on ({c.dof}, {c.noise_dof:.0f}) degrees of freedom (noise levels estimated)"


def comparison_text(c: Comparison) -> str:
    """The verdict, the chi-square test, and per parameter: both values, the difference, its
    standard deviation from both covariances and z."""
    a, b = c.run_a, c.run_b
    lines = [
        f"run {a.id} ({a.robot_id}, {a.session}, {_time(a)}) -> run {b.id} ({b.robot_id}, "
        f"{b.session}, {_time(b)}): {'DRIFT' if c.drift else 'the two calibrations agree'}",
        f"chi-square {c.chi2:.1f} over the {len(c.parameters)} parameters both determine (rank "
        f"{c.dof}), " + _test_name(c) + f": p = {c.p_value:.3g} (drift below alpha {c.alpha:g})",
        f"per parameter: |z| > {c.z_threshold:.2f} flags a change (alpha {c.alpha:g}, Bonferroni "
        f"over {len(c.parameters)})",
        "",
    ]
    rows = [["name", "unit", f"run {a.id}", f"run {b.id}", "difference", "std", "z", ""]]
    for p in c.parameters:
        va, unit = display(p.a, p.unit)
        vb = display(p.b, p.unit)[0]
        d = display(p.difference, p.unit)[0]
        s = display(p.std, p.unit)[0]
        rows.append(
            [
                c.label(p.name),
                unit,
                f"{va:+.4f}",
                f"{vb:+.4f}",
                f"{d:+.4f}",
                f"{s:.4f}",
                f"{p.z:+.2f}",
                "changed" if p.flagged else "",
            ]
        )
    lines += _table(rows, {2, 3, 4, 5, 6})
    lengths = [display(p.std, p.unit)[0] for p in c.parameters if p.unit == "m"]
    angles = [display(p.std, p.unit)[0] for p in c.parameters if p.unit == "rad"]
    if lengths or angles:
        parts = []
        if lengths:
            parts.append(f"{min(lengths):.4f} to {max(lengths):.4f} mm")
        if angles:
            parts.append(f"{min(angles):.5f} to {max(angles):.5f} deg")
        lines += ["", "repeatability (std of the difference of two sessions): " + ", ".join(parts)]
    rest = [n for n in c.left_out if n not in set(c.one_sided)]
    points = [n for n in rest if n.startswith("point[")]  # each session's own sockets
    rest = [n for n in rest if not n.startswith("point[")]
    if rest:
        lines.append(
            "not compared (not estimated or not identifiable in both, or hand-eye): "
            + ", ".join(c.label(n) for n in rest)
        )
    if points:
        lines.append(f"not compared: the group points ({len(points) // 3}, each session's own)")
    lines += [f"note: {relabel(n, c.labels)}" for n in c.notes]
    return "\n".join(lines)


def run_document(run: Run) -> dict[str, Any]:
    return {
        "id": run.id,
        "uid": run.uid,
        "robot_id": run.robot_id,
        "session": run.session,
        "created_at": run.created_at.isoformat(),
        "relcal_version": run.relcal_version,
        "model": run.model_name,
        "dataset": run.dataset_path,
        "outputs": run.outputs_path,
        "converged": run.converged,
        "rank": run.rank,
        "settings": run.settings,
        "input_hashes": run.input_hashes,
        "errors": run.errors,
        "held_out_metric": run_metric(run),
        "parameters": [parameter_document(p, run.label(p["name"])) for p in run.parameters],
        "parameter_unit": PARAMETER_UNIT,
    }


#: How every JSON document gives a parameter's values (results.json, history, compare).
PARAMETER_UNIT = (
    "values in each parameter's unit, as results.json: mm for lengths, deg for angles, ppm for "
    "joint scales, urad/Nm or um/N for compliances"
)


def parameter_document(p: dict, label: str) -> dict[str, Any]:
    """A registry parameter (SI) as the JSON documents give it: ``name`` (the key), ``label``
    (the name shown), ``unit`` and the values in the unit a person reads
    (:func:`relcal.reporting.quantities.parameter_json`), as results.json does."""
    out = {"name": p["name"], "label": label}
    unit = parameter_json(None, p["unit"])[1]
    out["unit"] = unit
    for key in ("value", "std", "calibration_std"):
        if key in p:
            out[key] = parameter_json(p[key], p["unit"])[0]
    out |= {k: v for k, v in p.items() if k not in (*out, "unit")}
    return out


def comparison_document(c: Comparison) -> dict[str, Any]:
    return {
        "run_a": c.run_a.id,
        "run_b": c.run_b.id,
        "robot_id": [c.run_a.robot_id, c.run_b.robot_id],
        "verdict": c.verdict,
        "alpha": c.alpha,
        "chi2": c.chi2,
        "dof": c.dof,
        "noise_dof": None if c.noise_dof == float("inf") else c.noise_dof,
        "p_value": c.p_value,
        "z_threshold": c.z_threshold,
        "flagged": c.flagged,
        "parameter_labels": c.labels,  # the names the parameters are shown by
        "parameters": [
            {
                "name": p.name,
                "label": c.label(p.name),
                "unit": parameter_json(None, p.unit)[1],
                "a": parameter_json(p.a, p.unit)[0],
                "b": parameter_json(p.b, p.unit)[0],
                "difference": parameter_json(p.difference, p.unit)[0],
                "std": parameter_json(p.std, p.unit)[0],
                "z": p.z,
                "p_value": p.p_value,
                "flagged": p.flagged,
            }
            for p in c.parameters
        ],
        "parameter_unit": PARAMETER_UNIT,
        "common_model": c.common_model,  # both refitted on it (their chosen models differed)
        "left_out": list(c.left_out),
        "one_sided": list(c.one_sided),  # of left_out: estimated in one run only
        "notes": list(c.notes),
    }


def drift_summary(c: Comparison | None, against: str | None) -> dict[str, Any] | None:
    """The short drift entry of a fleet session (against the previous calibration)."""
    if c is None:
        return None
    return {
        "against": against,
        "verdict": c.verdict,
        "p_value": c.p_value,
        "chi2": c.chi2,
        "dof": c.dof,
        "flagged": c.flagged,
        "flagged_labels": [c.label(n) for n in c.flagged],  # as they are shown
    }


def units_text(units: list[dict]) -> list[str]:
    """The comparison of the units of each robot model (:func:`relcal.fleet.units.compare_units`):
    per parameter each unit's correction +- std, then the units named off (unit, parameter with
    its joint, difference from the median of the other units, in combined std), and notes."""
    lines: list[str] = []
    for m in units:
        if len(m["robots"]) < 2:
            continue
        robots = m["robots"]
        lines += [
            "",
            f"units of {m['model']}: {', '.join(robots)} (latest calibration of each; correction "
            "+- one std, mm or deg)",
        ]
        rows = [["parameter", "unit", *robots]]
        for row in m["parameters"]:
            cells = []
            for r in robots:
                u = row["units"].get(r)
                cells.append("" if u is None else f"{u['value']:+.4f} +- {u['std']:.4f}")
            rows.append([row["label"], row["unit"], *cells])
        lines += ["  " + line for line in _table(rows, set(range(2, len(robots) + 2)))]
        head = (
            f"off (more than {m['z_threshold']:.2f} combined std from the median of the other "
            f"units; {m['n_tests']} comparisons, alpha {m['alpha']:g}):"
        )
        lines.append(head + (" none" if not m["off"] else ""))
        lines += [f"  {o['text']}" for o in m["off"]]
        lines += [f"note: {n}" for n in m["notes"]]
    return lines


def fleet_text(
    entries: list[dict],
    models: list[dict] | None = None,
    verifications: list[dict] | None = None,
    units: list[dict] | None = None,
) -> str:
    """The sessions of a fleet run (status, held-out errors, drift), the failures, a summary per
    robot model, the latest verification of each robot (when a registry has them) and the
    comparison of the units of each model (``units``, :func:`relcal.fleet.units.compare_units`)."""
    rows = [
        ["session", "robot", "status", "held-out position RMS mm", "held out", "drift vs previous"]
    ]
    for e in entries:
        drift = e.get("drift")
        text = ""
        if drift:
            text = f"{drift['verdict']} (p={drift['p_value']:.2g}"
            flagged = drift.get("flagged_labels") or drift["flagged"]
            text += f"; {', '.join(flagged)})" if flagged else ")"
        rows.append(
            [
                e["session"],
                str(e.get("robot_id", "")),
                e["status"],
                _errors(e) if e["status"] != "failed" else "",
                (e.get("held_out_metric") or "") if e["status"] != "failed" else "",
                text,
            ]
        )
    lines = _table(rows)
    for e in entries:
        if e["status"] == "failed":
            lines.append(f"failed {e['session']}: {e['reason']}")
    for m in models or []:
        errors = ""
        for h in m.get("held_out") or []:  # one median per kind of metric, never pooled
            base, after = (
                h["median_baseline_position_rms_mm"],
                h["median_calibrated_position_rms_mm"],
            )
            if base is not None and after is not None and h["metric"] is not None:
                errors += (
                    f"; held-out position RMS on {h['metric']} {base:.3f} -> {after:.3f} mm "
                    f"(median of {h['n_sessions']})"
                )
        lines.append(
            f"{m['model'] or '(model unknown)'}: {m['n_sessions']} sessions of "
            f"{len(m['robots'])} robots, {m['n_ok']} calibrated, {m['n_failed']} failed, drift: "
            + (", ".join(m["drift_robots"]) or "none")
            + errors
        )
    for v in verifications or []:
        at = v.get("at_calibration_position_rms_mm")
        base, after = v.get("baseline_position_rms_mm"), v.get("calibrated_position_rms_mm")
        errors = f", position RMS {base:.3f} -> {after:.3f} mm" if None not in (base, after) else ""
        lines.append(
            f"latest verification of {v['robot_id']} ({v['created_at'][:10]}, session "
            f"{v.get('session')}): {v['verdict']}{errors}"
            + (f" (at calibration {at:.3f} mm)" if at is not None else "")
        )
    lines += units_text(units or [])
    return "\n".join(lines)


def _verification_errors(v: VerificationRun) -> str:
    b, a = v.baseline_position_rms_mm, v.calibrated_position_rms_mm
    ci = (v.intervals or {}).get("calibrated_position_mm")
    shown = f"{b:.3f} -> {a:.3f}" if b is not None and a is not None else "-"
    return shown + (f" ({ci[0]:.3f}..{ci[1]:.3f})" if ci else "")


def _at_calibration(v: VerificationRun) -> str:
    ref, a = v.at_calibration_position_rms_mm, v.calibrated_position_rms_mm
    if ref is None or a is None:
        return "-"
    return f"{ref:.3f} (now x{a / max(ref, 1e-300):.2f})"


VERDICT_WORDS = {
    "holds": "holds",
    "degraded": "DEGRADED",
    "inconclusive": "inconclusive",
    "worse": "WORSE",
}


def verifications_text(verifications: list[VerificationRun]) -> list[str]:
    """The verifications of a robot's calibrations on new sessions: the prediction error of the
    calibrated model (the nominal baseline's beside it, both with the session's nuisance
    refitted), the calibration's own held-out error and the verdict."""
    if not verifications:
        return []
    lines = [
        "",
        "verifications on new sessions (position RMS mm, kinematics frozen, the session's "
        "nuisance refitted; baseline -> calibrated (interval); the calibration's own held-out "
        "error):",
    ]
    rows = [["id", "time (UTC)", "calibration", "session", "samples", "on the session"]]
    rows[0] += ["at calibration", "verdict"]
    for v in verifications:
        rows.append(
            [
                str(v.id),
                v.created_at.strftime("%Y-%m-%d %H:%M:%S"),
                f"run {v.calibration_id}" if v.calibration_id is not None else v.calibration,
                v.session or "",
                str(v.n_samples),
                _verification_errors(v),
                _at_calibration(v),
                VERDICT_WORDS.get(v.verdict, v.verdict),
            ]
        )
    return lines + _table(rows, {0, 4})


def verification_run_document(v: VerificationRun) -> dict[str, Any]:
    """A stored verification as JSON (mm and degrees, intervals as [low, high])."""
    return {
        "id": v.id,
        "uid": v.uid,
        "calibration_id": v.calibration_id,
        "calibration": v.calibration,
        "robot_id": v.robot_id,
        "session": v.session,
        "dataset": v.dataset_path,
        "created_at": v.created_at.isoformat(),
        "relcal_version": v.relcal_version,
        "kind": v.kind,
        "n_samples": v.n_samples,
        "folds": v.folds,
        "baseline_position_rms_mm": v.baseline_position_rms_mm,
        "calibrated_position_rms_mm": v.calibrated_position_rms_mm,
        "baseline_orientation_rms_deg": v.baseline_orientation_rms_deg,
        "calibrated_orientation_rms_deg": v.calibrated_orientation_rms_deg,
        "ratio_position": v.ratio_position,
        "at_calibration_position_rms_mm": v.at_calibration_position_rms_mm,
        "intervals": v.intervals,
        "verdict": v.verdict,
        "details": v.details,
    }
