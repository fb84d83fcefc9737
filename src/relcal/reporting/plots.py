"""The reports' plots: Matplotlib figures (Agg, no pyplot state) of singular values, residual
histograms, per-pair errors and parameters, in one style (:data:`PLOT_STYLE`), with log-axis
labels chosen after the layout so that no two overlap. They read results; they compute nothing
but what is drawn (norms in display units, bins, ticks).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Patch
from matplotlib.ticker import (
    Formatter,
    Locator,
    LogLocator,
    MaxNLocator,
    NullFormatter,
    NullLocator,
)

from relcal.calibration.identifiability import NUISANCE_KINDS, Identifiability
from relcal.calibration.validate import error_norms
from relcal.reporting.htmlkit import DPI
from relcal.robot.model import NONGEOMETRIC_KINDS
from relcal.sim.simulate import Simulation

BEFORE, AFTER, SPECIFIED, BAD = "#b0b8c1", "#1f6feb", "#e8833a", "#cf222e"
FIG_WIDTH = 9.0  # inches: 990 px, shown unscaled in the 1014 px wide sections
QUANTITIES = {
    "position": ("relative position error", "mm", "position_mm"),
    "orientation": ("relative orientation error", "deg", "orientation_deg"),
}
PLOT_STYLE = {
    "font.family": "DejaVu Sans",
    "font.size": 9.5,
    "axes.titlesize": 10.5,
    "axes.titleweight": "bold",
    "axes.spines.top": False,
    "axes.spines.right": False,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "legend.frameon": False,
}
__all__ = [
    "AFTER",
    "BAD",
    "BEFORE",
    "DPI",
    "FIG_WIDTH",
    "PLOT_STYLE",
    "QUANTITIES",
    "SPECIFIED",
    "calibration_parameter_figure",
    "histogram_figure",
    "log_bins",
    "parameter_figure",
    "per_pair_figure",
    "singular_value_figure",
]


def display_norms(errors: np.ndarray) -> dict[str, np.ndarray]:
    """Per-pair error norms in the units a person reads: position (mm) and orientation (deg,
    absent when not measured); the norms are :func:`relcal.calibration.validate.error_norms`."""
    norms = error_norms(errors)
    out = {"position": norms["position"] * 1e3}
    if "orientation" in norms:
        out["orientation"] = np.degrees(norms["orientation"])
    return out


def finish(ax) -> None:
    ax.grid(True, which="major", alpha=0.3)
    ax.set_axisbelow(True)


def singular_value_figure(ident: Identifiability, title: str = "") -> Figure:
    """Singular values of the unit-column Jacobian on a log scale, with the rank tolerance."""
    s = np.asarray(ident.singular_values, dtype=float)
    tol = ident.rcond * s[0]
    floor = s[0] * 1e-17
    fig = Figure(figsize=(FIG_WIDTH, 3.6), dpi=DPI, layout="constrained")
    ax = fig.add_subplot()
    index = np.arange(1, len(s) + 1)
    ax.bar(index, np.maximum(s, floor), color=np.where(s > tol, AFTER, BAD), width=0.7)
    ax.axhline(tol, color="#444", ls="--", lw=1)
    ax.text(
        len(s) + 0.6,
        tol * 2,
        f"rank tolerance {ident.rcond:g} × s_max",
        va="bottom",
        ha="right",
        bbox={"fc": "white", "ec": "none", "pad": 1.5},
    )
    ax.set(yscale="log", xlim=(0.3, len(s) + 0.7), xlabel="index (descending)")
    ax.set_ylabel("singular value")
    ax.set_ylim(floor / 3, s[0] * 4)
    ax.set_title(
        title
        or f"Scaled identification Jacobian: rank {ident.rank} of {len(s)} "
        f"(blue identifiable directions, red null space)"
    )
    finish(ax)
    _log_ticks(fig, [ax.yaxis])
    return fig


def _tick_texts(values: np.ndarray) -> list[str]:
    """Tick labels: plain numbers (0.002, 1, 5000) where every label of the axis stays short,
    else powers of ten (mathtext) for all of them, so that one axis never mixes the two."""
    plain = [f"{v:g}" for v in values]
    if not any("e" in t for t in plain):
        return plain
    out = []
    for v in values:
        exponent = int(np.floor(np.log10(v) + 1e-9))
        mantissa = float(f"{v / 10.0**exponent:.3g}")
        power = f"10^{{{exponent}}}"
        out.append(f"${power}$" if mantissa == 1 else rf"${mantissa:g}\times{power}$")
    return out


class FixedTexts(Formatter):
    """The labels chosen for the tick values of an axis (others, if any, by ``%g``)."""

    def __init__(self, texts: dict[float, str]) -> None:
        self.texts = texts

    def __call__(self, x, pos=None) -> str:
        for value, text in self.texts.items():
            if np.isclose(value, x, rtol=1e-9, atol=0):
                return text
        return f"{x:g}"


def _log_tick_choices(decades: float) -> list[tuple[Locator, Locator]]:
    """Major and minor locators for a log axis spanning ``decades``, in order of preference:
    1-2-..-9, 1-2-5, every decade, every k-th decade; nice linear steps for a range under one
    decade (first under half a decade, where they read best)."""
    every = range(1, 10)
    logs: list[tuple[Locator, Locator]] = [
        (LogLocator(subs=subs, numticks=999), LogLocator(subs=every, numticks=999))
        for subs in (every, (1, 2, 5), (1,))
    ]
    logs += [
        (LogLocator(numticks=n), LogLocator(subs="auto", numticks=n)) for n in range(12, 1, -1)
    ]
    steps = [1, 2, 2.5, 5, 10]
    linear = [(MaxNLocator(n, steps=steps), NullLocator()) for n in (8, 6, 4, 3)]
    if decades >= 1:
        return logs
    return linear + logs if decades < 0.5 else logs + linear


def _label_spacing_ok(axis, renderer, values: np.ndarray, lo: float, hi: float) -> bool:
    """Whether labels at ``values`` leave a gap of 1.5 (x) or 1.2 (y) font sizes between
    neighbours, as the renderer measures them, on the axis drawn in ``(lo, hi)``."""
    ax = axis.axes
    along_x = axis is ax.xaxis
    length = ax.bbox.width if along_x else ax.bbox.height
    scale = axis.get_transform()
    t = scale.transform(np.concatenate([[lo, hi], values]))
    at = (t[2:] - t[0]) / (t[1] - t[0]) * length
    prop = axis.get_major_ticks()[0].label1.get_fontproperties()
    size = prop.get_size_in_points() * ax.figure.dpi / 72
    gap = 1.5 * size if along_x else 1.2 * size
    if np.any(np.diff(at) < gap):  # too close whatever the labels say: no need to measure them
        return False
    extent = []
    for text in _tick_texts(values):
        w, h, _ = renderer.get_text_width_height_descent(text, prop, ismath=text.startswith("$"))
        extent.append(w if along_x else h)
    extent = np.array(extent)
    return bool(np.all(np.diff(at) >= (extent[1:] + extent[:-1]) / 2 + gap))


def _log_ticks(fig: Figure, axes: Sequence) -> None:
    """Choose the ticks of each log axis in ``axes`` after the layout is known: the preferred
    (densest) of :func:`_log_tick_choices` whose labels do not crowd at the drawn length, with at
    least three labels if any choice fits three, else the one with the most (at least two)."""
    canvas = fig.canvas if isinstance(fig.canvas, FigureCanvasAgg) else FigureCanvasAgg(fig)
    for axis in axes:  # provisional few ticks: the default minor labels make layout slow
        axis.set_major_locator(LogLocator(numticks=5))
        axis.set_minor_locator(NullLocator())
        axis.set_major_formatter(FixedTexts({}))
    fig.draw_without_rendering()
    renderer = canvas.get_renderer()
    for axis in axes:
        lo, hi = sorted(axis.get_view_interval())
        best, most = None, 0
        for major, minor in _log_tick_choices(np.log10(hi / lo)):
            values = np.asarray(major.tick_values(lo, hi), dtype=float)
            values = values[(values >= lo * (1 - 1e-9)) & (values <= hi * (1 + 1e-9))]
            values = values[values > 0]
            if len(values) < 2 or not _label_spacing_ok(axis, renderer, values, lo, hi):
                continue
            if len(values) >= 3:
                best = (major, minor)
                break
            if len(values) > most:
                best, most = (major, minor), len(values)
        major, minor = best or (LogLocator(numticks=2), NullLocator())
        axis.set_major_locator(major)
        axis.set_minor_locator(minor)
        values = np.asarray(major.tick_values(lo, hi), dtype=float)
        texts = dict(zip(values, _tick_texts(np.maximum(values, 1e-300)), strict=True))
        axis.set_major_formatter(FixedTexts(texts))
        axis.set_minor_formatter(NullFormatter())


def log_bins(*arrays: np.ndarray, n: int = 30) -> np.ndarray:
    """About ``n`` logarithmic bin edges over the positive values of ``arrays``, on a fixed grid
    of ``10 ** (k / per)`` with ``per`` (bins per decade) from 1-2-5 steps: every histogram of the
    report bins the same way, and a range of one value still gets a few bins around it."""
    values = np.concatenate([a[np.isfinite(a) & (a > 0)] for a in arrays])
    if values.size == 0:
        return np.geomspace(1e-3, 1.0, n + 1)
    lo, hi = np.log10(values.min()), np.log10(values.max())
    if hi - lo < 0.1:  # (nearly) one value: a tenth of a decade around it
        lo, hi = (lo + hi) / 2 - 0.05, (lo + hi) / 2 + 0.05
    steps = np.array([m * 10.0**e for e in range(-1, 4) for m in (1, 2, 5)])
    per = steps[np.argmin(np.abs(np.log(steps * (hi - lo) / n)))]
    k = np.arange(np.floor(lo * per - 0.5), np.ceil(hi * per + 0.5) + 1)  # half a bin spare
    return 10.0 ** (k / per)


def _series(where: str) -> tuple[str, str]:
    """Legend labels of the two series: the calibrated model, and what it is compared with."""
    if where.startswith("held-out points"):
        return "after (calibrated)", "before: baseline (nominal, instrument and marker fitted)"
    if where.startswith(("measured pairs", "measured poses")):  # a simulation: nothing fitted
        return "after (identified)", "before (nominal model)"
    return "after (calibrated)", "before: baseline (nominal, hand-eye fitted)"


def histogram_figure(before: np.ndarray, after: np.ndarray, where: str) -> Figure:
    """Histograms of per-pair error norms before and after, one panel per measured quantity
    (position mm, orientation deg), logarithmic bins from :func:`log_bins` shared by the two
    series of a panel; the calibrated series is drawn over the baseline and listed first."""
    b, a = display_norms(before), display_norms(after)
    fig = Figure(figsize=(FIG_WIDTH, 3.4), dpi=DPI, layout="constrained")
    axes = fig.subplots(1, len(b), squeeze=False)[0]
    after_label, before_label = _series(where)
    absolute = where.startswith(("held-out points", "held-out poses", "measured poses"))
    for ax, key in zip(axes, b, strict=True):
        label, unit, _ = QUANTITIES[key]
        label = label.replace("relative ", "") if absolute else label
        bins = log_bins(b[key], a[key])
        ax.hist(b[key], bins=bins, histtype="stepfilled", color=BEFORE, zorder=2)
        ax.hist(b[key], bins=bins, histtype="step", color="#7d8793", lw=1, zorder=2)
        ax.hist(a[key], bins=bins, histtype="stepfilled", color=AFTER, alpha=0.7, zorder=3)
        ax.hist(a[key], bins=bins, histtype="step", color=AFTER, lw=1.2, zorder=3)
        ax.set(xscale="log", xlim=(bins[0], bins[-1]), xlabel=f"{label} ({unit})")
        ax.set_ylabel(("poses" if "poses" in where else "points") if absolute else "pairs")
        ax.yaxis.set_major_locator(MaxNLocator(integer=True, steps=[1, 2, 2.5, 5, 10]))
        ax.set_title(f"{label.capitalize()}, {where}")
        finish(ax)
    handles = [Patch(fc=AFTER, ec=AFTER, alpha=0.7), Patch(fc=BEFORE, ec="#7d8793")]
    fig.legend(handles, [after_label, before_label], loc="outside upper center", ncols=2)
    _log_ticks(fig, [ax.xaxis for ax in axes])
    return fig


def per_pair_figure(before: np.ndarray, after: np.ndarray, where: str) -> Figure:
    """Error norm of every pair before and after (log scale), one panel per quantity; a thin
    line joins the two values of a pair, the calibrated points lie on top and come first in the
    legend."""
    b, a = display_norms(before), display_norms(after)
    fig = Figure(figsize=(FIG_WIDTH, 2.5 + 2.1 * len(b)), dpi=DPI, layout="constrained")
    axes = fig.subplots(len(b), 1, squeeze=False, sharex=True)[:, 0]
    after_label, before_label = _series(where)
    item = {"held-out points": "point", "held-out poses": "pose"}.get(where.split(" (")[0], "pair")
    x = np.arange(1, len(before) + 1)
    for ax, key in zip(axes, b, strict=True):
        label, unit, _ = QUANTITIES[key]
        label = label.replace("relative ", "") if item != "pair" else label
        low, high = np.fmin(a[key], b[key]), np.fmax(a[key], b[key])
        ax.vlines(x, low, high, color="#d5dae0", lw=1, zorder=1)
        ax.plot(x, b[key], "o", ms=3.5, color="#7d8793", zorder=2, label=before_label)
        ax.plot(x, a[key], "o", ms=3.5, color=AFTER, zorder=3, label=after_label)
        ax.set(yscale="log", ylabel=f"{key} ({unit})")
        ax.set_title(f"{label.capitalize()} per {item}, {where}")
        finish(ax)
    axes[-1].set_xlabel(item)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles[::-1], labels[::-1], loc="outside upper center", ncols=2)
    _log_ticks(fig, [ax.yaxis for ax in axes])
    return fig


def parameter_figure(sim: Simulation) -> Figure:
    """Specified and identified errors per parameter, lengths (mm) and angles (deg) apart;
    unidentifiable parameters are marked ``n/i`` (scales and compliances: in the table only)."""
    layout, result = sim.layout, sim.result
    units = np.array(layout.units())
    fig = Figure(figsize=(FIG_WIDTH, 6.4), layout="constrained")
    axes = fig.subplots(2, 1)
    for ax, is_angle, unit in ((axes[0], False, "mm"), (axes[1], True, "deg")):
        idx = np.flatnonzero(units == ("rad" if is_angle else "m"))
        scale = np.degrees(1.0) if is_angle else 1e3
        x = np.arange(len(idx))
        ok = result.identifiable[idx]
        ax.bar(x - 0.2, sim.specified[idx] * scale, 0.4, color=SPECIFIED, label="specified")
        ident = np.where(ok, result.params[idx] * scale, 0.0)
        ax.bar(x + 0.2, ident, 0.4, color=AFTER, label="identified")
        for k in np.flatnonzero(~ok):
            ax.text(x[k] + 0.2, 0, "n/i", rotation=90, ha="center", va="bottom", color=BAD)
        ax.axhline(0, color="#444", lw=0.8)
        ax.set_xticks(x, [layout.names[i] for i in idx], rotation=60, ha="right", fontsize=8)
        ax.set(xlim=(-0.7, len(idx) - 0.3), ylabel=f"error ({unit})")
        ax.set_title(f"{'Angles' if is_angle else 'Lengths'}: specified vs identified ({unit})")
        finish(ax)
    fig.legend(*axes[0].get_legend_handles_labels(), loc="outside upper center", ncols=2)
    return fig


HELD = {  # status of a parameter held at nominal -> (marker, legend label)
    "unidentifiable": ("x", "unidentifiable: nominal kept"),
    "not supported": ("D", "not supported by model selection: nominal kept"),
}
MUTED = "#8c959f"


def _parameter_panels(rows: Sequence[dict], kinds: Sequence[str]) -> list[tuple[str, list]]:
    """``(title, rows)`` per panel: the geometry's lengths (mm) and angles (deg), then the
    non-geometric terms of the chosen model, one panel per unit. Hand-eye, instrument and marker
    corrections are left out (they are nuisance transforms, shown in their own table)."""
    panels: dict[str, list] = {}
    for row, kind in zip(rows, kinds, strict=True):
        if kind in NUISANCE_KINDS:
            continue
        if kind in NONGEOMETRIC_KINDS:
            if row["status"] in HELD:
                continue  # listed under the plot: a row of markers at zero says nothing
            title = f"Non-geometric terms ({row['unit']})"
        else:
            title = {"mm": "Lengths (mm)", "deg": "Angles (deg)"}.get(row["unit"], row["unit"])
        panels.setdefault(title, []).append(row)
    order = {"Lengths (mm)": 0, "Angles (deg)": 1}
    return sorted(panels.items(), key=lambda item: order.get(item[0], 2))


def calibration_parameter_figure(rows: Sequence[dict], kinds: Sequence[str]) -> Figure:
    """The identified error of every parameter with error bars of one standard deviation
    (predicted, and from the bootstrap beside it), one panel per kind (:func:`_parameter_panels`);
    parameters held at nominal are marked at zero and their names greyed. ``rows`` are the
    ``parameters`` of :func:`documents.results_document` (display units), ``kinds`` the layout's
    kind of each."""
    panels = _parameter_panels(rows, kinds)
    fig = Figure(figsize=(FIG_WIDTH, 0.9 + 2.55 * len(panels)), dpi=DPI, layout="constrained")
    axes = fig.subplots(len(panels), 1, squeeze=False)[:, 0]
    legend: dict[str, object] = {}
    for ax, (title, group) in zip(axes, panels, strict=True):
        x = np.arange(len(group))
        for k, row in enumerate(group):
            if row["status"] in HELD:
                marker, label = HELD[row["status"]]
                (h,) = ax.plot(
                    k,
                    0,
                    marker,
                    ms=6 if marker == "x" else 4.5,
                    color=MUTED,
                    mfc="none",
                    mew=1.5,
                    zorder=3,
                )
                legend.setdefault(label, h)
                continue
            boot = row.get("bootstrap_std")
            if boot is not None:
                h = ax.errorbar(
                    k + 0.22,
                    row["error"],
                    yerr=boot,
                    fmt="none",
                    ecolor=SPECIFIED,
                    elinewidth=1.2,
                    capsize=2.5,
                    zorder=2,
                )
                legend.setdefault("± 1 std, bootstrap over the training samples", h)
            combination = row["status"] == "combination"
            h = ax.errorbar(
                k,
                row["error"],
                yerr=row.get("std") or 0.0,
                fmt="o",
                ms=5,
                color=AFTER,
                mfc="white" if combination else AFTER,
                mew=1.3,
                elinewidth=1.6,
                capsize=3.5,
                zorder=4,
            )
            label = (
                "carries a combination with parameters held at nominal, ± 1 std"
                if combination
                else "identified error ± 1 std (predicted)"
            )
            legend.setdefault(label, h)
        ax.axhline(0, color="#444", lw=0.8, zorder=1)
        ax.set_xticks(
            x,
            [row.get("label", row["name"]) for row in group],
            rotation=45,
            ha="right",
            rotation_mode="anchor",
            fontsize=8.5,
        )
        for tick, row in zip(ax.get_xticklabels(), group, strict=True):
            tick.set_color(MUTED if row["status"] in HELD else "#1f2328")
        unit = group[0]["unit"]
        ax.set(xlim=(-0.7, len(group) - 0.3), ylabel=f"error ({unit})")
        ax.set_title(title)
        ax.grid(False, axis="x")
        finish(ax)
        ax.grid(False, axis="x")
    first = ["identified error ± 1 std (predicted)"]
    labels = first + [k for k in legend if k not in first]
    labels = [k for k in labels if k in legend]
    fig.legend(
        [legend[k] for k in labels], labels, loc="outside upper center", ncols=2, fontsize=8.5
    )
    return fig
