"""The calibration report: one self-contained HTML file that opens offline.

Plots are drawn with Matplotlib (Agg, no pyplot state) into PNG bytes embedded as base64 ``data:``
URIs; the CSS is inline and there is no JavaScript. Every plot is an ``<img>`` with an ``id`` and
an ``alt`` text, every part of the page a ``<section>`` with an ``id`` (``summary``,
``parameters``, ``singular-values``, ``residuals``, ``per-pair``, ``rejected``, ``settings``), so
that tests and people can find them. All text from data is escaped.
"""

from __future__ import annotations

import base64
import html
import io
import json
from collections.abc import Iterable, Sequence
from dataclasses import replace

import matplotlib
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

from relcal import __version__
from relcal.calibration.identifiability import NUISANCE_KINDS, Identifiability
from relcal.calibration.measurement import pair_errors
from relcal.calibration.outcome import Calibration
from relcal.calibration.validate import PlacementValidation, Spread, stats
from relcal.reporting.text import pose_noise_parts
from relcal.robot.model import NONGEOMETRIC_KINDS
from relcal.sim.simulate import Simulation

BEFORE, AFTER, SPECIFIED, BAD = "#b0b8c1", "#1f6feb", "#e8833a", "#cf222e"
DPI = 110
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


# --- markup --------------------------------------------------------------------------------------


class Html(str):
    """Trusted markup, inserted as is; every other value is escaped."""


def _text(value: object) -> str:
    return value if isinstance(value, Html) else html.escape(str(value))


def _table(head: Sequence[object], rows: Iterable[Sequence[object]], cls: str = "") -> Html:
    """A table; ``cls="num"`` right-aligns every column but the first."""
    th = "".join(f"<th>{_text(h)}</th>" for h in head)
    body = "".join("<tr>" + "".join(f"<td>{_text(c)}</td>" for c in row) + "</tr>" for row in rows)
    return Html(f'<table class="{cls}"><thead><tr>{th}</tr></thead><tbody>{body}</tbody></table>')


def _badge(ok: bool, yes: str = "yes", no: str = "no") -> Html:
    return Html(f'<span class="badge {"ok" if ok else "bad"}">{_text(yes if ok else no)}</span>')


def _cards(items: Sequence[tuple[str, str, str]], cls: str = "") -> Html:
    """Summary cards of ``(label, value, note)``."""
    cells = "".join(
        f'<div class="card"><div class="label">{_text(label)}</div>'
        f'<div class="value">{_text(value)}</div><div class="note">{_text(note)}</div></div>'
        for label, value, note in items
    )
    return Html(f'<div class="cards {cls}">{cells}</div>')


def _list(items: Sequence[object], empty: str) -> Html:
    if not items:
        return Html(f'<p class="none">{_text(empty)}</p>')
    return Html("<ul>" + "".join(f"<li>{_text(i)}</li>" for i in items) + "</ul>")


def _figure_html(ident: str, alt: str, fig: Figure) -> Html:
    """The figure as an ``<img>`` with a PNG ``data:`` URI, and its caption."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI, facecolor="white")
    data = base64.b64encode(buffer.getvalue()).decode("ascii")
    return Html(
        f'<figure><img id="{_text(ident)}" alt="{_text(alt)}" '
        f'src="data:image/png;base64,{data}"><figcaption>{_text(alt)}</figcaption></figure>'
    )


def _section(ident: str, title: str, *parts: object) -> tuple[str, str, Html]:
    body = "".join(_text(p) for p in parts)
    return (
        ident,
        title,
        Html(f'<section id="{_text(ident)}"><h2>{_text(title)}</h2>{body}</section>'),
    )


def _p(text: str) -> Html:
    return Html(f"<p>{_text(text)}</p>")


CSS = """
:root { --ink:#1f2328; --muted:#59636e; --line:#d1d9e0; --accent:#1f6feb; --bg:#f6f8fa; }
* { box-sizing: border-box; }
body { margin:0; background:var(--bg); color:var(--ink);
  font: 15px/1.5 system-ui, -apple-system, "Segoe UI", "DejaVu Sans", "Liberation Sans",
  sans-serif; }
header { background:#0d1b2a; color:#fff; padding:28px 0 22px; }
header .wrap, main, nav .wrap, footer { max-width:1120px; margin:0 auto; padding:0 28px; }
header h1 { margin:0 0 4px; font-size:26px; font-weight:650; letter-spacing:.2px; }
header .meta { color:#b6c2cf; font-size:14px; }
header .meta b { color:#fff; font-weight:600; }
nav { background:#fff; border-bottom:1px solid var(--line); }
nav .wrap { display:flex; flex-wrap:wrap; gap:4px 18px; padding-top:10px; padding-bottom:10px; }
nav a { color:var(--accent); text-decoration:none; font-size:14px; }
main { padding-top:22px; padding-bottom:10px; }
section { background:#fff; border:1px solid var(--line); border-radius:8px;
  padding:18px 24px 20px; margin:0 0 20px; }
h2 { margin:0 0 12px; font-size:19px; font-weight:650; padding-bottom:8px;
  border-bottom:1px solid var(--line); }
h3 { margin:18px 0 8px; font-size:15.5px; }
p { margin:8px 0; }
p.hint, figcaption, .note { color:var(--muted); font-size:13.5px; }
p.none { color:var(--muted); font-style:italic; }
.cards { display:grid; grid-template-columns:repeat(auto-fit, minmax(190px, 1fr)); gap:12px;
  margin:4px 0 16px; }
.card { border:1px solid var(--line); border-radius:8px; padding:12px 14px; background:#fbfcfd; }
.card .label { color:var(--muted); font-size:12.5px; text-transform:uppercase;
  letter-spacing:.4px; }
.cards.wide .card .value { font-size:24px; }
.card .value { font-size:19px; font-weight:650; margin:2px 0; font-variant-numeric:tabular-nums; }
table { border-collapse:collapse; width:100%; margin:8px 0 4px; font-size:14px; }
th, td { padding:5px 10px; border-bottom:1px solid #e6eaef; text-align:left; vertical-align:top; }
thead th { background:#f0f3f6; border-bottom:1px solid var(--line); font-weight:600; }
tbody tr:nth-child(even) { background:#fafbfc; }
table.num td:not(:first-child), table.num th:not(:first-child) { text-align:right;
  font-variant-numeric:tabular-nums; }
table.ids td:first-child { width:200px; }
td code, p code, li code { font-size:13px; }
.badge { display:inline-block; padding:0 8px; border-radius:10px; font-size:12.5px;
  font-weight:600; }
.badge.ok { background:#dafbe1; color:#116329; }
.badge.bad { background:#ffebe9; color:#a40e26; }
figure { margin:10px 0 6px; text-align:center; }
figure img { max-width:100%; height:auto; border:1px solid #eef1f4; border-radius:4px; }
figcaption { margin-top:4px; }
ul { margin:6px 0; padding-left:22px; }
footer { color:var(--muted); font-size:13px; padding-bottom:28px; }
@media print { body { background:#fff; } nav { display:none; }
  section { break-inside:avoid; border:none; } }
"""


def _page(title: str, meta: Sequence[tuple[str, str]], sections: Sequence[tuple]) -> str:
    """The whole document: header, navigation, sections, footer."""
    info = " &middot; ".join(f"{_text(k)} <b>{_text(v)}</b>" for k, v in meta)
    links = "".join(f'<a href="#{_text(i)}">{_text(t)}</a>' for i, t, _ in sections)
    body = "".join(s for _, _, s in sections)
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>{_text(title)}</title><style>{CSS}</style></head><body>"
        f'<header><div class="wrap"><h1>{_text(title)}</h1><div class="meta">{info}</div>'
        f'</div></header><nav><div class="wrap">{links}</div></nav><main>{body}</main>'
        f"<footer>Generated by relcal {_text(__version__)}. Lengths in mm, angles in degrees."
        "</footer></body></html>\n"
    )


# --- numbers -------------------------------------------------------------------------------------


def _fmt(value: float | None, spec: str = ".4f") -> str:
    if value is None or not np.isfinite(value):
        return "–"
    return format(value, spec)


def _norms(errors: np.ndarray) -> dict[str, np.ndarray]:
    """Per-pair error norms: position (mm) and orientation (deg, absent when not measured)."""
    out = {"position": np.linalg.norm(errors[:, :3], axis=1) * 1e3}
    rotation = np.degrees(np.linalg.norm(errors[:, 3:], axis=1))
    if len(rotation) and not np.all(np.isnan(rotation)):
        out["orientation"] = rotation
    return out


def _flatten(value: object, prefix: str = "") -> list[tuple[str, str]]:
    """``(dotted key, text)`` rows of nested settings."""
    if isinstance(value, dict):
        rows = []
        for key, item in value.items():
            rows += _flatten(item, f"{prefix}.{key}" if prefix else str(key))
        return rows
    if isinstance(value, float):
        return [(prefix, f"{value:g}")]
    if isinstance(value, list | tuple):
        return [(prefix, ", ".join(map(str, value)) or "none")]
    return [(prefix, json.dumps(value) if value is None or isinstance(value, bool) else str(value))]


# --- plots ---------------------------------------------------------------------------------------


def _finish(ax) -> None:
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
    _finish(ax)
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


def _log_bins(*arrays: np.ndarray, n: int = 30) -> np.ndarray:
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
    if where.startswith("measured pairs"):  # a simulation: the nominal model, nothing fitted
        return "after (identified)", "before (nominal model)"
    return "after (calibrated)", "before: baseline (nominal, hand-eye fitted)"


def histogram_figure(before: np.ndarray, after: np.ndarray, where: str) -> Figure:
    """Histograms of per-pair error norms before and after, one panel per measured quantity
    (position mm, orientation deg), logarithmic bins from :func:`_log_bins` shared by the two
    series of a panel; the calibrated series is drawn over the baseline and listed first."""
    b, a = _norms(before), _norms(after)
    fig = Figure(figsize=(FIG_WIDTH, 3.4), dpi=DPI, layout="constrained")
    axes = fig.subplots(1, len(b), squeeze=False)[0]
    after_label, before_label = _series(where)
    absolute = where.startswith("held-out points")
    for ax, key in zip(axes, b, strict=True):
        label, unit, _ = QUANTITIES[key]
        label = label.replace("relative ", "") if absolute else label
        bins = _log_bins(b[key], a[key])
        ax.hist(b[key], bins=bins, histtype="stepfilled", color=BEFORE, zorder=2)
        ax.hist(b[key], bins=bins, histtype="step", color="#7d8793", lw=1, zorder=2)
        ax.hist(a[key], bins=bins, histtype="stepfilled", color=AFTER, alpha=0.7, zorder=3)
        ax.hist(a[key], bins=bins, histtype="step", color=AFTER, lw=1.2, zorder=3)
        ax.set(xscale="log", xlim=(bins[0], bins[-1]), xlabel=f"{label} ({unit})")
        ax.set_ylabel("points" if absolute else "pairs")
        ax.yaxis.set_major_locator(MaxNLocator(integer=True, steps=[1, 2, 2.5, 5, 10]))
        ax.set_title(f"{label.capitalize()}, {where}")
        _finish(ax)
    handles = [Patch(fc=AFTER, ec=AFTER, alpha=0.7), Patch(fc=BEFORE, ec="#7d8793")]
    fig.legend(handles, [after_label, before_label], loc="outside upper center", ncols=2)
    _log_ticks(fig, [ax.xaxis for ax in axes])
    return fig


def per_pair_figure(before: np.ndarray, after: np.ndarray, where: str) -> Figure:
    """Error norm of every pair before and after (log scale), one panel per quantity; a thin
    line joins the two values of a pair, the calibrated points lie on top and come first in the
    legend."""
    b, a = _norms(before), _norms(after)
    fig = Figure(figsize=(FIG_WIDTH, 2.5 + 2.1 * len(b)), dpi=DPI, layout="constrained")
    axes = fig.subplots(len(b), 1, squeeze=False, sharex=True)[:, 0]
    after_label, before_label = _series(where)
    item = "point" if where.startswith("held-out points") else "pair"
    x = np.arange(1, len(before) + 1)
    for ax, key in zip(axes, b, strict=True):
        label, unit, _ = QUANTITIES[key]
        label = label.replace("relative ", "") if item == "point" else label
        low, high = np.fmin(a[key], b[key]), np.fmax(a[key], b[key])
        ax.vlines(x, low, high, color="#d5dae0", lw=1, zorder=1)
        ax.plot(x, b[key], "o", ms=3.5, color="#7d8793", zorder=2, label=before_label)
        ax.plot(x, a[key], "o", ms=3.5, color=AFTER, zorder=3, label=after_label)
        ax.set(yscale="log", ylabel=f"{key} ({unit})")
        ax.set_title(f"{label.capitalize()} per {item}, {where}")
        _finish(ax)
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
        _finish(ax)
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
            [row["name"] for row in group],
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
        _finish(ax)
        ax.grid(False, axis="x")
    first = ["identified error ± 1 std (predicted)"]
    labels = first + [k for k in legend if k not in first]
    labels = [k for k in labels if k in legend]
    fig.legend(
        [legend[k] for k in labels], labels, loc="outside upper center", ncols=2, fontsize=8.5
    )
    return fig


def _compact_names(names: Sequence[str]) -> str:
    """``scale[1]``, ``scale[2]``, ``scale[3]`` -> ``scale[1–3]``; other names as they are."""
    out: list[str] = []
    groups: dict[str, list[int]] = {}
    for name in names:
        kind, _, rest = name.partition("[")
        if rest.endswith("]") and rest[:-1].isdigit():
            if kind not in groups:
                groups[kind] = []
                out.append(kind)
            groups[kind].append(int(rest[:-1]))
        else:
            out.append(name)
    text = []
    for item in out:
        if item not in groups:
            text.append(item)
            continue
        runs, idx = [], sorted(groups[item])
        start = prev = idx[0]
        for i in idx[1:] + [None]:
            if i is not None and i == prev + 1:
                prev = i
                continue
            runs.append(f"{start}" if start == prev else f"{start}–{prev}")
            if i is not None:
                start = prev = i
        text.append(f"{item}[{', '.join(runs)}]")
    return ", ".join(text)


# --- the calibration report ----------------------------------------------------------------------


def _error_sets(cal: Calibration) -> tuple[np.ndarray, np.ndarray, str, str]:
    """Per-pair errors before and after, a short label and a sentence saying where from."""
    if isinstance(cal.validation, PlacementValidation):
        v = cal.validation

        def errors(spread: Spread) -> np.ndarray:  # the spread as a position error
            out = np.full((len(spread.spread), 6), np.nan)
            out[:, :3] = 0.0
            out[:, 0] = spread.spread
            return out

        return (
            errors(v.baseline),
            errors(v.calibrated),
            "held-out samples",
            f"Held-out validation: {len(v.samples)} samples of {len(v.placements)} placement(s) "
            f"({', '.join(v.placements)}) that the identification did not use, each sample's "
            "predicted tool point against its group's point refitted there (kinematics and tool "
            "point frozen: a new plate position); before = nominal kinematics with the tool "
            "point and the group points fitted to the training samples, after = the exported "
            "model.",
        )
    if cal.validation is not None and cal.problem.formulation == "tracker":
        v = cal.validation
        return (
            v.before,
            v.after,
            "held-out points",
            f"Held-out validation: absolute position errors of {len(v.pairs)} points that the "
            "identification did not use; before = nominal model with the instrument transform and "
            "marker fitted to the training points, after = calibrated model.",
        )
    if cal.validation is not None:
        v = cal.validation
        return (
            v.before,
            v.after,
            "held-out pairs",
            f"Held-out validation: {len(v.pairs)} pairs among {len(cal.test)} samples that the "
            "identification did not use; before = the baseline (nominal kinematics with the "
            "hand-eye transform fitted on the training samples, the best a user gets without "
            "kinematic calibration), after = the exported model.",
        )
    problem = replace(cal.problem, weights=None, pair_weights=None)
    return (
        pair_errors(problem, cal.baseline.params),
        pair_errors(problem, cal.result.params),
        "training pairs",
        f"No held-out samples: training residuals of {len(problem.pair_indices())} pairs "
        "(optimistic: the fit saw them).",
    )


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
    return [
        (
            "identification",
            "converged" if r.converged else "NOT converged",
            f"{r.method}, {r.iterations} iterations; weighted residual "
            f"{r.initial_residual_norm:.3g} → {r.residual_norm:.3g}",
        ),
        (
            "identifiable",
            f"{r.rank} of {len(r.params)}",
            f"parameters; {len(r.unidentifiable)} unidentifiable combination(s)",
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
        rows.append([label] + [_fmt(s[k][stat]) for _, _, k in keys for s in (before, after)])
    ratio = ["RMS after / before"]
    for _, _, k in keys:
        ratio += ["", _fmt(after[k]["rms"] / max(before[k]["rms"], 1e-300), ".3f")]
    rows.append(ratio)
    if interval:
        row = ["95 % interval of after / before (bootstrap over held-out samples)"]
        for _, _, k in keys:
            lo, hi = interval[k]["ci95"]
            row += ["", f"{_fmt(lo, '.3f')} – {_fmt(hi, '.3f')}"]
        rows.append(row)
    if guess:
        row = ["RMS of the nominal model with the hand-eye guess"]
        for _, _, k in keys:
            row += [_fmt(guess[k]["rms"]), ""]
        rows.append(row)
    return _table(head, rows, "num")


def _summary(cal: Calibration, doc: dict, errors: tuple) -> tuple[str, str, Html]:
    before, after, label, sentence = errors
    b, a = stats(before), stats(after)
    converged = cal.result.converged
    interval = (doc.get("validation") or {}).get("ratio_to_baseline")
    if interval and "spread_mm" in interval:  # held-out placements: the spread is the position
        interval = {"position_mm": interval["spread_mm"]}
    return _section(
        "summary",
        "Summary",
        _cards(_accuracy_cards(b, a, label), "wide"),
        _cards(_fit_cards(cal, doc)),
        _p(sentence),
        _stats_table(b, a, interval, (doc.get("validation") or {}).get("baseline_handeye_guess")),
        _selection(doc),
        Html(
            "<p>Convergence: "
            + _badge(converged, "converged", "not converged")
            + _text(
                f" after {cal.result.iterations} iterations of {cal.result.method}; "
                f"stacked residual norm {cal.result.initial_residual_norm:.4g} → "
                f"{cal.result.residual_norm:.4g} (weighted rows)."
            )
            + "</p>"
        ),
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
            Html(f"<code>{_text(row['name'])}</code>"),
            row["unit"],
            _fmt(row["nominal"], ".3f"),
            _fmt(row["error"], "+.4f"),
            _fmt(s, ".2g"),
            _fmt(row.get("bootstrap_std"), ".2g"),
            _fmt(row.get("significance"), ".1f"),
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
    return _table(head, body, "num"), source


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
            _fmt(c["cv_position_rms_mm"], ".4f"),
            _fmt(c["cv_orientation_rms_deg"], ".4f"),
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
        note += (
            " The data support no kinematic correction: the exported model is the nominal "
            "kinematics with the fitted hand-eye transform."
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
        + _table(head, rows, "num")
        + f'<p class="hint">{_text(note)}</p>'
    )


def _handeye_table(doc: dict) -> Html:
    he = doc.get("handeye")
    if not he:
        return Html("")
    xyz = [_fmt(v * 1e3, ".3f") for v in he["xyz_m"]]
    rpy = [_fmt(v, ".4f") for v in he["rpy_deg"]]
    return _table(
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
        names = [r["name"] for r in doc["parameters"] if r["status"] == status]
        if names:
            parts.append(f"{why}, nominal kept: {_compact_names(names)}.")
    if not parts:
        return Html("")
    return Html(f'<p class="hint">{_text(" ".join(parts))}</p>')


def _parameter_plot(cal: Calibration, doc: dict) -> Html:
    kinds = cal.problem.full_layout.kinds
    names = [r["name"] for r in doc["parameters"]]
    if tuple(names) != tuple(cal.problem.full_layout.names):
        return Html("")  # a document of another calibration: no plot rather than a wrong one
    return _figure_html(
        "plot-parameters",
        "Identified error of each parameter with ± 1 standard deviation (blue: predicted, "
        "orange: bootstrap over the training samples; often smaller than the dot), lengths and "
        "angles of the geometry and the non-geometric terms of the chosen model on separate "
        "axes; grey marks at zero: held at nominal",
        calibration_parameter_figure(doc["parameters"], kinds),
    )


def _parameters(cal: Calibration, doc: dict) -> tuple[str, str, Html]:
    table, source = _parameter_table(cal, doc)
    return _section(
        "parameters",
        "Parameters",
        _p(
            "Identified errors are corrections to the nominal model (lengths in mm, angles in "
            "degrees); handeye.* are corrections to the hand-eye guess (in the table, not the "
            "plot). Unidentifiable parameters keep their nominal value."
        ),
        _parameter_plot(cal, doc),
        _held_at_nominal(doc),
        table,
        Html(f'<p class="hint">{_text(source)}</p>'),
        Html("<h3>Unidentifiable combinations, with the reason</h3>"),
        _list(doc["identification"]["unidentifiable"], "none: every parameter is identifiable"),
        Html("<h3>Hand-eye transform</h3>"),
        _handeye_table(doc),
    )


def _singular_values(ident: Identifiability, ident_id: str = "plot-singular-values"):
    s = ident.singular_values
    cond = ident.condition_number
    return (
        _figure_html(
            ident_id,
            f"Singular values of the scaled identification Jacobian (log scale): rank "
            f"{ident.rank} of {len(s)}, tolerance {ident.rcond:g} × the largest",
            singular_value_figure(ident),
        ),
        _p(
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
        parts.append(_table(["sample", "reason"], rows, "ids"))
    else:
        parts.append(Html('<p class="none">none: every sample gave a camera pose</p>'))
    parts.append(Html("<h3>Outliers</h3>"))
    if outliers:
        why = "kept in the fit (--keep-outliers)" if kept else "left out of the final fit"
        rows = [[o, f"its pairs fit badly after a robust fit; {why}"] for o in outliers]
        parts.append(_table(["sample", "reason"], rows, "ids"))
    else:
        parts.append(Html('<p class="none">none</p>'))
    return _section("rejected", "Rejected images", *parts)


def _settings(cal: Calibration, doc: dict) -> tuple[str, str, Html]:
    rows = [
        ("robot", doc["robot"]),
        ("dataset", doc["dataset"]),
        ("identification method", cal.result.method),
        (
            "rank tolerance (relative to the largest singular value)",
            f"{cal.result.identifiability.rcond:g}",
        ),
        ("training pairs", str(len(cal.problem.pair_indices()))),
    ]
    rows += _flatten(doc["settings"])
    return _section("settings", "Settings", _table(["setting", "value"], rows))


def calibration_report(cal: Calibration, doc: dict) -> str:
    """The HTML report of a calibration; ``doc`` is :func:`documents.results_document`."""
    errors = _error_sets(cal)
    before, after, label, sentence = errors
    with matplotlib.rc_context(PLOT_STYLE):
        sections = [
            _summary(cal, doc, errors),
            _parameters(cal, doc),
            _section(
                "singular-values",
                "Singular value spectrum",
                *_singular_values(cal.result.identifiability),
            ),
            _section(
                "residuals",
                "Residual histograms",
                _p(sentence),
                _figure_html(
                    "plot-residuals",
                    f"Histograms of the relative pose errors of {label} before and after "
                    "calibration (logarithmic bins)",
                    histogram_figure(before, after, label),
                ),
            ),
            _section(
                "per-pair",
                "Errors per pair, before and after",
                _figure_html(
                    "plot-per-pair",
                    f"Relative pose error of each of the {len(before)} {label} before (grey) and "
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
    return _page("Calibration report", meta, sections)


# --- the simulation report -----------------------------------------------------------------------


def _sim_errors(sim: Simulation) -> tuple[np.ndarray, np.ndarray]:
    zero = np.zeros_like(sim.result.params)
    return pair_errors(sim.problem, zero), pair_errors(sim.problem, sim.result.params)


def _sim_title(sim: Simulation) -> str:
    what = "position only" if sim.measure == "position" else "position and orientation"
    return f"relative {what}, {sim.formulation} formulation, {sim.result.method} solver"


def _kind_rms(sim: Simulation) -> tuple[float, float]:
    """RMS of identified minus specified over identifiable parameters: lengths mm, angles deg."""
    ok, units = sim.result.identifiable, np.array(sim.layout.units())
    diff = sim.result.params - sim.specified
    out = []
    for mask, scale in ((units == "m", 1e3), (units == "rad", np.degrees(1.0))):
        d = diff[ok & mask] * scale
        out.append(float(np.sqrt(np.mean(d**2))) if d.size else float("nan"))
    return out[0], out[1]


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
        b, a = (stats(e) for e in _sim_errors(sim))
        lengths, angles = _kind_rms(sim)
        col = [
            f"{sim.formulation} / {r.method}",
            f"{len(sim.problem.q)} / {r.n_residuals}",
            f"{r.rank} / {r.identifiability.rank} of {len(r.params)}",
            _badge(r.converged, f"converged ({r.iterations} it.)", "NOT converged"),
            f"{r.initial_residual_norm:.3g} → {r.residual_norm:.3g}",
        ]
        for key in ("position_mm", "orientation_deg"):
            col.append(f"{b[key]['rms']:.4g} → {a[key]['rms']:.4g}" if key in b else "–")
        col += [_fmt(lengths, ".2e"), _fmt(angles, ".2e")]
        for row, cell in zip(rows, col, strict=True):
            row.append(cell)
    return _section(
        "summary",
        "Summary",
        _p(
            "Known geometric errors, simulated relative measurements, identification. Residual "
            "errors are training residuals (before = nominal model, after = identified)."
        ),
        _table(head, rows, "num"),
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
                Html(f"<code>{_text(name)}</code>"),
                unit,
                _fmt(spec * scale, "+.4f"),
                _fmt(value * scale, "+.4f") if ok else "n/i",
                _fmt((value - spec) * scale, "+.2e") if ok else "–",
                _badge(bool(ok)),
            ]
        )
    head = ["parameter", "unit", "specified", "identified", "difference", "identifiable"]
    return _table(head, rows, "num")


def _sim_sections(sim: Simulation, k: int) -> list[tuple[str, str, Html]]:
    before, after = _sim_errors(sim)
    title = _sim_title(sim)
    return [
        _section(
            f"run{k}-parameters",
            f"Run {k}: specified vs identified",
            _p(title[0].upper() + title[1:] + "."),
            _figure_html(
                f"plot-run{k}-parameters",
                f"Run {k}: specified and identified error of every parameter (n/i: not "
                "identifiable)",
                parameter_figure(sim),
            ),
            _sim_parameter_table(sim),
            Html("<h3>Unidentifiable combinations, with the reason</h3>"),
            _list(sim.result.unidentifiable, "none: every parameter is identifiable"),
        ),
        _section(
            f"run{k}-singular-values",
            f"Run {k}: singular value spectrum",
            *_singular_values(sim.result.identifiability, f"plot-run{k}-singular-values"),
        ),
        _section(
            f"run{k}-residuals",
            f"Run {k}: residuals",
            _figure_html(
                f"plot-run{k}-residuals",
                f"Run {k}: histograms of the relative errors of the {len(before)} measured pairs "
                "before and after identification (logarithmic bins)",
                histogram_figure(before, after, "measured pairs"),
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
        ["pairs", *[str(len(s.problem.pair_indices())) for s in runs]],
        ["noise position (mm)", *[f"{s.noise.position * 1e3:g}" for s in runs]],
        ["noise orientation (deg)", *[f"{np.degrees(s.noise.orientation):g}" for s in runs]],
        ["noise joints (deg)", *[f"{np.degrees(s.noise.joints):g}" for s in runs]],
        ["rank tolerance (relative)", *[f"{s.result.identifiability.rcond:g}" for s in runs]],
        ["hayati joints", *[_hayati(s) for s in runs]],
    ]
    return _section("settings", "Settings", _table(head, rows))


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
    return _page("Simulation report", meta, sections)
