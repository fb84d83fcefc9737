"""The simulation report of ``relcal simulate --report``: each run's specified against
identified errors (plot and table), singular values and residual histograms, one self-contained
HTML page like the calibration report. It reads :class:`relcal.Simulation` results."""

from __future__ import annotations

from collections.abc import Sequence

import matplotlib
import numpy as np

from relcal.calibration.validate import stats
from relcal.reporting import htmlkit as hk
from relcal.reporting.calibration_report import singular_value_parts
from relcal.reporting.htmlkit import Html
from relcal.reporting.plots import (
    PLOT_STYLE,
    histogram_figure,
    parameter_figure,
)
from relcal.reporting.text import simulated_text
from relcal.sim.simulate import Simulation

__all__ = ["simulation_report"]


def _sim_title(sim: Simulation) -> str:
    return f"{simulated_text(sim)}, {sim.result.method} solver"


def _kind_rms(sim: Simulation) -> tuple[float, float]:
    """RMS of identified minus specified over identifiable parameters: lengths mm, angles deg."""
    lengths, angles = sim.identification_rms()
    return lengths * 1e3, float(np.degrees(angles))


def _sim_summary(runs: Sequence[Simulation]) -> tuple[str, str, Html]:
    head = ["", *[f"run {k}: {s.measure}" for k, s in enumerate(runs, 1)]]
    rows: list[list[object]] = [
        [label]
        for label in (
            "formulation / solver",
            "poses / measurement rows",
            "rank: solver / identifiability analysis",
            "convergence",
            "residual norm (m, rad)",
            "position error RMS (mm)",
            "orientation error RMS (deg)",
            "identified − specified, RMS lengths (mm)",
            "identified − specified, RMS angles (deg)",
        )
    ]
    for sim in runs:
        r = sim.result
        b, a = (stats(e) for e in sim.pair_errors())
        lengths, angles = _kind_rms(sim)
        col = [
            f"{sim.formulation} / {r.method}",
            f"{len(sim.problem.q)} / {r.n_residuals}",
            f"{r.rank} / {r.identifiability.rank} of {len(r.params)}",
            hk.badge(r.converged, f"converged ({r.iterations} it.)", "NOT converged"),
            f"{r.initial_residual_norm:.3g} → {r.residual_norm:.3g}",
        ]
        for key in ("position_mm", "orientation_deg"):
            col.append(f"{b[key]['rms']:.4g} → {a[key]['rms']:.4g}" if key in b else "–")
        col += [hk.fmt(lengths, ".2e"), hk.fmt(angles, ".2e")]
        for row, cell in zip(rows, col, strict=True):
            row.append(cell)
    return hk.section(
        "summary",
        "Summary",
        hk.paragraph(
            "Known geometric errors, simulated relative measurements, identification. Residual "
            "errors are training residuals (before = nominal model, after = identified)."
        ),
        hk.table(head, rows, "num"),
    )


def _sim_parameter_table(sim: Simulation) -> Html:
    rows = []
    factors, units = sim.layout.display()
    for name, scale, unit, spec, value, ok in zip(
        sim.layout.names,
        factors,
        units,
        sim.specified,
        sim.result.params,
        sim.result.identifiable,
        strict=True,
    ):
        rows.append(
            [
                Html(f"<code>{hk.escape(name)}</code>"),
                unit,
                hk.fmt(spec * scale, "+.4f"),
                hk.fmt(value * scale, "+.4f") if ok else "n/i",
                hk.fmt((value - spec) * scale, "+.2e") if ok else "–",
                hk.badge(bool(ok)),
            ]
        )
    head = ["parameter", "unit", "specified", "identified", "difference", "identifiable"]
    return hk.table(head, rows, "num")


def _sim_sections(sim: Simulation, k: int) -> list[tuple[str, str, Html]]:
    before, after = sim.pair_errors()
    title = _sim_title(sim)
    if sim.formulation == "board":
        errors = f"errors of the {len(before)} camera poses against the board"
        where = "measured poses against the board"
    else:
        errors, where = f"relative errors of the {len(before)} measured pairs", "measured pairs"
    return [
        hk.section(
            f"run{k}-parameters",
            f"Run {k}: specified vs identified",
            hk.paragraph(title[0].upper() + title[1:] + "."),
            hk.figure_html(
                f"plot-run{k}-parameters",
                f"Run {k}: specified and identified error of every parameter (n/i: not "
                "identifiable)",
                parameter_figure(sim),
            ),
            _sim_parameter_table(sim),
            Html("<h3>Unidentifiable combinations, with the reason</h3>"),
            hk.bullet_list(sim.result.unidentifiable, "none: every parameter is identifiable"),
        ),
        hk.section(
            f"run{k}-singular-values",
            f"Run {k}: singular value spectrum",
            *singular_value_parts(sim.result.identifiability, f"plot-run{k}-singular-values"),
        ),
        hk.section(
            f"run{k}-residuals",
            f"Run {k}: residuals",
            hk.figure_html(
                f"plot-run{k}-residuals",
                f"Run {k}: histograms of the {errors} before and after identification "
                "(logarithmic bins)",
                histogram_figure(before, after, where),
            ),
        ),
    ]


def _sim_settings(runs: Sequence[Simulation]) -> tuple[str, str, Html]:
    head = ["setting", *[f"run {k}" for k in range(1, len(runs) + 1)]]
    rows = [
        ["robot", *[s.problem.model.name for s in runs]],
        ["formulation", *[s.formulation for s in runs]],
        ["measure", *[s.measure for s in runs]],
        ["method", *[s.result.method for s in runs]],
        ["poses", *[str(len(s.problem.q)) for s in runs]],
        ["pairing", *[s.pairing for s in runs]],
        ["measurements (pairs, or poses against the board)", *[_count(s) for s in runs]],
        ["noise position (mm)", *[f"{s.noise.position * 1e3:g}" for s in runs]],
        ["noise orientation (deg)", *[f"{np.degrees(s.noise.orientation):g}" for s in runs]],
        ["noise joints (deg)", *[f"{np.degrees(s.noise.joints):g}" for s in runs]],
        ["rank tolerance (relative)", *[f"{s.result.identifiability.rcond:g}" for s in runs]],
        ["hayati joints", *[_hayati(s) for s in runs]],
    ]
    return hk.section("settings", "Settings", hk.table(head, rows))


def _count(sim: Simulation) -> str:
    n = len(sim.problem.pair_indices())
    return f"{n} poses" if sim.formulation == "board" else f"{n} pairs"


def _hayati(sim: Simulation) -> str:
    joints = [str(i + 1) for i in np.flatnonzero(sim.problem.model.hayati)]
    return ", ".join(joints) or "none"


def simulation_report(sims: Simulation | Sequence[Simulation]) -> str:
    """The HTML report of one simulation run, or of several (e.g. position and pose) in one."""
    runs = [sims] if isinstance(sims, Simulation) else list(sims)
    with matplotlib.rc_context(PLOT_STYLE):
        sections = [_sim_summary(runs)]
        for k, sim in enumerate(runs, 1):
            sections += _sim_sections(sim, k)
        sections.append(_sim_settings(runs))
    meta = [("robot", runs[0].problem.model.name), ("runs", str(len(runs)))]
    return hk.page("Simulation report", meta, sections)
