"""The fleet report: one self-contained HTML page of a fleet run (like the calibration report:
inline CSS, plots as PNG ``data:`` URIs, no script, nothing fetched).

Sections: ``summary`` (cards, and one row per robot model), ``robots`` (one row per session:
status, baseline and calibrated held-out errors, drift against the previous calibration),
``failed`` (the reasons), ``verifications`` (the latest ``relcal verify`` of each robot), one
``units-<model>`` section per model of two or more units (their corrections side by side, the
units off named with the joint), and one ``parameters-<model>`` section per robot model with
the identified errors of every robot, one small plot per parameter (image
``plot-parameters-<model>``): robots whose value lies far from the others of their model (robust
z above 3.5) are drawn in red and listed.
"""

from __future__ import annotations

import re

import matplotlib
import numpy as np
from matplotlib.figure import Figure

from relcal.fleet.drift import display
from relcal.reporting import htmlkit as hk
from relcal.reporting.htmlkit import DPI, Html
from relcal.reporting.plots import AFTER, BAD, BEFORE, FIG_WIDTH, PLOT_STYLE

# Whole-pixel line heights: every box, and so every plot, starts on a pixel row (a plot of fine
# lines drawn half a pixel off would be resampled, and blurred, by the browser).
PIXEL_CSS = """
body { line-height:22px; } header h1 { line-height:32px; } header .meta, nav a { line-height:20px; }
h2 { line-height:28px; } h3 { line-height:22px; } th, td { line-height:20px; }
p.hint, figcaption, .note { line-height:20px; } .card .label, .badge { line-height:18px; }
.card .value { line-height:26px; } .cards.wide .card .value { line-height:30px; }
#robots td:first-child { white-space:nowrap; }
"""
OUTLIER_Z = 3.5  # robust z (median, 1.4826 MAD) among the robots of one model
MIN_ROBOTS = 8  # fewer robots of a model: no robust spread to judge "far" by


def _slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-") or "model"


def _summary(doc: dict, entries: list[dict]) -> tuple:
    ok = [e for e in entries if e["status"] == "ok"]
    drifted = [e for e in entries if (e.get("drift") or {}).get("verdict") == "drift"]
    robots = {e.get("robot_id") for e in entries}
    models = doc.get("models") or []
    cards = [
        ("sessions", str(len(entries)), f"{len(robots)} robots of {len(models)} model(s)"),
        ("calibrated", str(len(ok)), f"{len(entries) - len(ok)} failed"),
        ("drift flagged", str(len(drifted)), ", ".join(e["robot_id"] for e in drifted) or "none"),
        ("time", f"{doc.get('seconds', 0):.1f} s", _where(doc)),
    ]
    rows = []
    for m in models:
        row = [
            m["model"] or "(unknown: failed before loading)",
            str(m["n_sessions"]),
            str(len(m["robots"])),
            str(m["n_ok"]),
            str(m["n_failed"]),
            ", ".join(m["drift_robots"]) or "none",
        ]
        held = m.get("held_out") or [{"metric": None}]
        for h in held:  # one row per kind of held-out metric: never one median over two
            rows.append(
                row
                + [
                    h["metric"] or "–",
                    hk.fmt(h.get("median_baseline_position_rms_mm"), ".3f"),
                    hk.fmt(h.get("median_calibrated_position_rms_mm"), ".3f"),
                ]
            )
            row = [""] * len(row)
    head = ["robot model", "sessions", "robots", "calibrated", "failed", "drift flagged"]
    head += ["held out", "baseline mm", "calibrated mm"]
    return hk.section(
        "summary",
        "Summary",
        hk.cards(cards, "wide"),
        hk.paragraph(
            "Per robot model (robots of one model compare, of two do not): held-out position RMS, "
            "median over the model's calibrated sessions, one row per kind of held-out metric "
            "(relative poses, points and placements measure different things)."
        ),
        hk.table(head, rows, "num"),
        hk.paragraph(
            "Drift: each session against the robot's previous calibration, over the parameters "
            f"both identify (alpha {doc.get('alpha', 0.01):g}; without a change at most "
            f"{2 * doc.get('alpha', 0.01):.0%} of comparisons are flagged)."
        ),
    )


def _verifications(doc: dict) -> tuple:
    """The latest verification of each robot of the fleet (``relcal verify --registry``): the
    prediction error of its calibration on a new session, against the nominal baseline and
    against the calibration's own held-out error."""
    found = doc.get("verifications") or []
    if not found:
        return hk.section(
            "verifications",
            "Verifications on new sessions",
            Html(
                '<p class="none">none recorded for these robots (relcal verify CALIBRATION '
                "SESSION --registry ...)</p>"
            ),
        )
    rows = []
    for v in found:
        ci = (v.get("intervals") or {}).get("calibrated_position_mm")
        now = v.get("calibrated_position_rms_mm")
        rows.append(
            [
                v["robot_id"],
                v["created_at"][:19].replace("T", " "),
                f"run {v['calibration_id']}" if v.get("calibration_id") else v["calibration"],
                v.get("session") or "",
                str(v["n_samples"]),
                hk.fmt(v.get("baseline_position_rms_mm"), ".3f"),
                hk.fmt(now, ".3f") + (f" ({ci[0]:.3f}..{ci[1]:.3f})" if ci else ""),
                hk.fmt(v.get("at_calibration_position_rms_mm"), ".3f"),
                hk.badge(v["verdict"] == "holds", v["verdict"], v["verdict"]),
            ]
        )
    head = ["robot", "time (UTC)", "calibration", "session", "samples", "baseline mm"]
    head += ["calibrated mm", "at calibration mm", "verdict"]
    return hk.section(
        "verifications",
        "Verifications on new sessions",
        hk.paragraph(
            "The latest verification of each robot: its calibration's prediction error on a new "
            "session (kinematics frozen, the session's hand-eye or instrument and marker refitted "
            "by cross-fitting, for the calibration and the nominal baseline alike), beside the "
            "calibration's own held-out error. 'degraded': still better than the nominal model, "
            "but worse than at calibration beyond the interval."
        ),
        hk.table(head, rows, "num"),
    )


def _where(doc: dict) -> str:
    if doc.get("scheduler"):
        return f"cluster {doc['scheduler']}"
    return f"{doc.get('workers')} local worker processes"


def _drift_cell(e: dict) -> Html | str:
    drift = e.get("drift")
    if not drift:
        return "–"
    if drift["verdict"] == "agree":
        return hk.badge(True, f"agree (p={drift['p_value']:.2g})")
    what = ", ".join(drift.get("flagged_labels") or drift["flagged"]) or "as a whole"
    return hk.badge(False, no=f"drift: {what} (p={drift['p_value']:.2g})")


def _robots(entries: list[dict]) -> tuple:
    rows = []
    for e in entries:
        ok = e["status"] == "ok"
        rows.append(
            [
                e["session"],
                e.get("robot_id", ""),
                e.get("model") or "–",
                hk.badge(ok, e["status"], e["status"]),
                e.get("held_out_metric") or "–",
                hk.fmt(e.get("baseline_position_rms_mm"), ".3f"),
                hk.fmt(e.get("calibrated_position_rms_mm"), ".3f"),
                hk.fmt(e.get("baseline_orientation_rms_deg"), ".4f"),
                hk.fmt(e.get("calibrated_orientation_rms_deg"), ".4f"),
                _drift_cell(e),
            ]
        )
    head = [
        "session",
        "robot",
        "model",
        "status",
        "held out",
        "baseline mm",
        "calibrated mm",
        "baseline deg",
        "calibrated deg",
        "drift vs previous",
    ]
    return hk.section(
        "robots",
        "Robots",
        hk.paragraph(
            "Held-out errors, of the kind each session's data give (held out): poses, RMS over "
            "the held-out poses predicted in the world frame; pairs of poses, RMS over the "
            "held-out pairs; points, RMS over the held-out points (mm only); placements (a ball "
            "in sockets), RMS distance of the held-out placements' samples from their sockets' "
            "refitted points (mm only)."
        ),
        hk.table(head, rows, "num"),
    )


def _failed(entries: list[dict]) -> tuple:
    failed = [e for e in entries if e["status"] != "ok"]
    if not failed:
        return hk.section("failed", "Failed sessions", Html('<p class="none">none</p>'))
    rows = [[e["session"], e.get("reason") or ""] for e in failed]
    return hk.section("failed", "Failed sessions", hk.table(["session", "reason"], rows, "ids"))


def _parameter_values(group: list[dict]) -> tuple[list[str], dict]:
    """Geometric parameter names estimated in the group, and per name the points
    ``(robot index, value, std, session)`` in mm or deg."""
    robots = sorted({e["robot_id"] for e in group})
    names: list[str] = []
    points: dict[str, list] = {}
    for e in group:
        for p in e["record"]["parameters"]:
            name = p["name"]
            if (
                name.startswith(("handeye.", "board."))
                or p["value"] is None
                or not p["identifiable"]
            ):
                continue
            if name not in points:
                names.append(name)
                points[name] = []
            value, unit = display(p["value"], p["unit"])
            std = display(p["std"], p["unit"])[0] if p["std"] is not None else 0.0
            points[name].append((robots.index(e["robot_id"]), value, std, e["session"], unit))
    return names, points


def _outliers(robot: np.ndarray, values: np.ndarray, std: np.ndarray) -> np.ndarray:
    """Points of robots whose latest value lies more than ``OUTLIER_Z`` robust standard
    deviations from the median of the robots (at least ``MIN_ROBOTS``; the spread is at least the
    median standard deviation, so that noise alone is never an outlier)."""
    far = np.zeros(len(values), dtype=bool)
    latest = {int(r): k for k, r in enumerate(robot)}  # the last point of each robot
    if len(latest) < MIN_ROBOTS:
        return far
    last = np.array([values[k] for k in latest.values()])
    median = np.median(last)
    spread = max(1.4826 * np.median(np.abs(last - median)), float(np.median(std)), 1e-12)
    for k in latest.values():
        far[k] = abs(values[k] - median) / spread > OUTLIER_Z
    return far


def parameter_figure(group: list[dict], model: str) -> tuple[Figure, list[str]]:
    """One small plot per parameter: each robot's identified error (+- std) per session; far
    values among the robots of this model in red. Returns the figure and the outliers."""
    names, points = _parameter_values(group)
    labels: dict[str, str] = {}  # as the calibrations showed the parameters
    for e in group:
        labels |= (e["record"].get("settings") or {}).get("parameter_labels") or {}
    robots = sorted({e["robot_id"] for e in group})
    cols = 6
    rows = max(1, -(-len(names) // cols))
    flagged = []
    with matplotlib.rc_context(PLOT_STYLE):
        fig = Figure(figsize=(FIG_WIDTH, 1.75 * rows + 0.6), layout="constrained")
        axes = fig.subplots(rows, cols, squeeze=False)
        for ax in axes.flat[len(names) :]:
            ax.set_visible(False)
        for ax, name in zip(axes.flat, names, strict=False):
            pts = points[name]
            x = np.array([p[0] for p in pts], dtype=float)
            v = np.array([p[1] for p in pts])
            s = np.array([p[2] for p in pts])
            far = _outliers(x, v, s)
            jitter = (np.arange(len(x)) % 3 - 1) * 0.12
            ax.errorbar(x + jitter, v, yerr=s, fmt="none", ecolor=BEFORE, elinewidth=1)
            ax.scatter(x[~far] + jitter[~far], v[~far], s=10, color=AFTER, zorder=3)
            ax.scatter(x[far] + jitter[far], v[far], s=16, color=BAD, zorder=4)
            label = labels.get(name, name)
            flagged += [
                f"{label}: {pts[k][3]} ({v[k]:+.4f} {pts[k][4]})" for k in np.flatnonzero(far)
            ]
            ax.set_title(f"{label} ({pts[0][4]})", fontsize=9)
            ax.set_xticks(range(len(robots)))
            ax.set_xticklabels(robots if len(robots) <= 8 else [], rotation=90, fontsize=6)
            ax.tick_params(axis="y", labelsize=7)
            ax.set_xlim(-0.6, len(robots) - 0.4)
        fig.suptitle(f"{model}: identified errors per robot (+- one std)", fontsize=10.5)
    return fig, flagged


def _parameters(entries: list[dict]) -> list[tuple]:
    ok = [e for e in entries if e["status"] == "ok" and e.get("record")]
    models = sorted({e["model"] for e in ok})
    sections = []
    for model in models:
        group = [e for e in ok if e["model"] == model]
        slug = _slug(model)
        fig, flagged = parameter_figure(group, model)
        robots = sorted({e["robot_id"] for e in group})
        sections.append(
            hk.section(
                f"parameters-{slug}",
                f"Parameters across the fleet: {model}",
                hk.paragraph(
                    f"{len(group)} sessions of {len(robots)} robots ("
                    + ", ".join(robots)
                    + f", left to right). Red: a robot whose latest value lies more than "
                    f"{OUTLIER_Z} robust standard deviations from the median of the robots of "
                    f"this model (with {MIN_ROBOTS} robots or more)."
                ),
                hk.figure_html(
                    f"plot-parameters-{slug}",
                    f"identified errors of every {model} robot, one plot per parameter",
                    fig,
                ),
                hk.paragraph("Far from the others: " + ("; ".join(flagged) if flagged else "none")),
            )
        )
    return sections


def _units(doc: dict) -> list[tuple]:
    """One ``units-<model>`` section per robot model with two or more units
    (:func:`relcal.fleet.units.compare_units`): every parameter's correction +- std per unit,
    the cells of a unit named off in red with z, and the list of units off."""
    sections = []
    for m in doc.get("units") or []:
        robots = m["robots"]
        if len(robots) < 2:
            continue
        rows = []
        for row in m["parameters"]:
            cells: list[object] = [row["label"], row["unit"]]
            for r in robots:
                u = row["units"].get(r)
                if u is None:
                    cells.append("–")
                    continue
                text = f"{u['value']:+.4f} ± {u['std']:.4f}"
                if abs(u["z"]) > m["z_threshold"]:
                    cells.append(hk.badge(False, no=f"{text} (z {u['z']:+.1f})"))
                else:
                    cells.append(text)
            rows.append(cells)
        off = [o["text"] for o in m["off"]]
        sections.append(
            hk.section(
                f"units-{_slug(m['model'])}",
                f"Units compared: {m['model']}",
                hk.paragraph(
                    f"The latest calibration of each of the {len(robots)} units ("
                    + ", ".join(robots)
                    + "): every correction with one standard deviation. A unit is off in a "
                    "parameter (red) when its correction lies more than "
                    f"{m['z_threshold']:.2f} combined standard deviations from the median of the "
                    f"other units ({m['n_tests']} comparisons, alpha {m['alpha']:g})."
                ),
                hk.table(["parameter", "unit", *robots], rows, "num"),
                hk.paragraph("Units off, largest first:"),
                hk.bullet_list(off, "none"),
                hk.paragraph("Notes:") if m["notes"] else "",
                hk.bullet_list(m["notes"], "") if m["notes"] else "",
            )
        )
    return sections


def fleet_report(doc: dict, entries: list[dict]) -> str:
    """The page of a fleet run: ``doc`` as ``relcal fleet calibrate --json`` writes it (with the
    comparison of the units of each model under ``units``), and the entries of
    :func:`relcal.fleet.runner.run_fleet` (with their registry records)."""
    sections = [_summary(doc, entries), _robots(entries), _failed(entries), _verifications(doc)]
    sections += _units(doc)
    sections += _parameters(entries)
    meta = [("root", str(doc.get("root", ""))), ("sessions", str(len(entries)))]
    if doc.get("registry"):
        meta.append(("registry", doc["registry"]))
    page = hk.page("relcal fleet report", meta, sections)
    return page.replace("</style>", PIXEL_CSS + "</style>", 1)


__all__ = ["fleet_report", "parameter_figure", "DPI"]
