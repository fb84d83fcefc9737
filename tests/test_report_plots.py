"""The calibration report's plots as Matplotlib draws them: tick labels that never collide on log
axes at any data range, histograms that bin both quantities alike and fit their data, the
calibrated series over the baseline, and the parameter plot showing the document's numbers."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import to_rgb

from relcal.reporting.htmlkit import compact_names
from relcal.reporting.plots import (
    AFTER,
    calibration_parameter_figure,
    histogram_figure,
    log_bins,
    per_pair_figure,
    singular_value_figure,
)

# (position mm, orientation deg) ranges of (before, after): a narrow one (less than a fifth of a
# decade), the TIAGo's real held-out errors (the old report wrote 0.50.60.70.80.91 there), four
# decades, an exact fit (13 decades), and a single value per series
RANGES = {
    "narrow": ((1.0, 1.6, 0.02, 0.03), (0.6, 1.2, 0.011, 0.025)),
    "real arm": ((5.0, 90.0, 0.9, 8.0), (4.0, 60.0, 0.5, 6.0)),
    "four decades": ((0.5, 60.0, 0.3, 5.0), (0.006, 0.13, 0.0005, 0.006)),
    "exact fit": ((0.5, 30.0, 0.05, 2.0), (1e-13, 1e-11, 1e-14, 1e-12)),
    "one value": ((2.0, 2.0, 0.1, 0.1), (0.5, 0.5, 0.01, 0.01)),
}


def pair_errors(mm: tuple[float, float], deg: tuple[float, float], n: int, seed: int) -> np.ndarray:
    """``(n, 6)`` errors whose norms are log-uniform in the ranges (m, rad)."""
    rng = np.random.default_rng(seed)
    e = np.zeros((n, 6))
    e[:, 0] = np.exp(rng.uniform(*np.log(mm), n)) * 1e-3
    e[:, 3] = np.radians(np.exp(rng.uniform(*np.log(deg), n)))
    return e


def errors(name: str, n: int = 60) -> tuple[np.ndarray, np.ndarray]:
    (b0, b1, b2, b3), (a0, a1, a2, a3) = RANGES[name]
    return pair_errors((b0, b1), (b2, b3), n, 1), pair_errors((a0, a1), (a2, a3), n, 2)


def drawn(fig):
    if not isinstance(fig.canvas, FigureCanvasAgg):
        FigureCanvasAgg(fig)
    fig.draw_without_rendering()
    return fig


def shown_labels(axis) -> list:
    """The tick labels the axis draws: visible, non-empty, at a tick inside the view."""
    lo, hi = sorted(axis.get_view_interval())
    out = []
    for tick in axis.get_major_ticks() + axis.get_minor_ticks():
        loc = tick.get_loc()
        inside = lo * (1 - 1e-9) <= loc <= hi * (1 + 1e-9)
        if inside and tick.label1.get_visible() and tick.label1.get_text():
            out.append((loc, tick.label1))
    return out


def log_axes(fig) -> list:
    return [
        axis
        for ax in fig.axes
        for axis in (ax.xaxis, ax.yaxis)
        if axis.get_scale() == "log" and ax.get_visible()
    ]


def value_of(text: str) -> float:
    """The number a label shows: ``0.02``, ``$10^{-6}$`` or ``$2\\times10^{-5}$``."""
    if not text.startswith("$"):
        return float(text)
    body = text.strip("$")
    mantissa, _, power = body.rpartition("10^")
    mantissa = float(mantissa.replace("\\times", "") or 1)
    return mantissa * 10.0 ** int(power.strip("{}"))


def check_log_labels(fig) -> None:
    """On every log axis: at least two labels, each naming its tick's value, none touching."""
    axes = log_axes(drawn(fig))
    assert axes, "no log axis"
    renderer = fig.canvas.get_renderer()
    for axis in axes:
        labels = shown_labels(axis)
        texts = [label.get_text() for _, label in labels]
        assert len(labels) >= 2, f"{axis.axes.get_title()}: only {texts}"
        for loc, label in labels:
            assert value_of(label.get_text()) == pytest.approx(loc, rel=1e-3), texts
        boxes = [label.get_window_extent(renderer) for _, label in labels]
        for i in range(len(boxes)):
            for j in range(i + 1, len(boxes)):
                assert not boxes[i].overlaps(boxes[j]), (
                    f"{axis.axes.get_title()}: tick labels {texts[i]!r} and {texts[j]!r} overlap"
                )


@pytest.mark.parametrize("name", RANGES)
def test_log_tick_labels_never_overlap(name):
    before, after = errors(name)
    check_log_labels(histogram_figure(before, after, "held-out pairs"))
    check_log_labels(per_pair_figure(before, after, "held-out pairs"))


@pytest.mark.parametrize("floor", [1e-17, 1e-4, 0.3])
def test_singular_value_axis_labels_never_overlap(floor):
    s = np.geomspace(1.0, floor, 30)
    ident = SimpleNamespace(singular_values=s, rcond=1e-6, rank=int(np.sum(s > 1e-6)))
    check_log_labels(singular_value_figure(ident))


@pytest.mark.parametrize("name", RANGES)
def test_histograms_bin_alike_and_fit_their_data(name):
    before, after = errors(name)
    fig = drawn(histogram_figure(before, after, "held-out pairs"))
    position, orientation = fig.axes
    assert position.get_xlabel() == "relative position error (mm)"
    assert orientation.get_xlabel() == "relative orientation error (deg)"
    for ax, col, scale in ((position, 0, 1e3), (orientation, 3, np.degrees(1.0))):
        values = np.concatenate([before[:, col], after[:, col]]) * scale
        bins = log_bins(before[:, col] * scale, after[:, col] * scale)
        assert ax.get_xlim() == pytest.approx((bins[0], bins[-1]))
        assert bins[0] < values.min() and values.max() < bins[-1]
        steps = np.diff(np.log10(bins))
        assert steps == pytest.approx(np.full_like(steps, steps[0]))  # one bin width
        per = 1 / steps[0]  # bins per decade: 1-2-5 steps, edges on 10 ** (k / per)
        assert min(abs(per - m * 10.0**e) for e in range(-1, 4) for m in (1, 2, 5)) < 1e-6
        k = np.log10(bins) * per
        assert k == pytest.approx(np.round(k), abs=1e-6)
        spare = np.log10(values.min() / bins[0]), np.log10(bins[-1] / values.max())
        assert max(spare) <= 1.5 / per + 1e-9  # at most a bin and a half of empty axis
        assert 12 <= len(bins) - 1 <= 60
        counts, _ = np.histogram(values, bins)
        assert counts.sum() == len(values)  # nothing falls outside


def test_position_only_histogram_has_no_orientation_panel():
    before, after = errors("four decades")
    before[:, 3:], after[:, 3:] = np.nan, np.nan
    fig = histogram_figure(before, after, "held-out pairs")
    assert [ax.get_xlabel() for ax in fig.axes] == ["relative position error (mm)"]


def pixel(fig, x: float, y: float, ax) -> np.ndarray:
    """The RGB colour (0..1) the figure shows at data point ``(x, y)`` of ``ax``."""
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    image = np.asarray(canvas.buffer_rgba())[:, :, :3] / 255.0
    px, py = ax.transData.transform((x, y))
    return image[int(round(image.shape[0] - py)), int(round(px))]


def test_per_pair_calibrated_points_lie_on_top_and_lead_the_legend():
    before, after = errors("four decades", n=20)
    after[5] = before[5]  # the same error under both models: one point covers the other
    after[7] = before[7] * 3  # worse after calibration: the connector still joins the two
    fig = per_pair_figure(before, after, "held-out pairs")
    ax = fig.axes[0]
    value = np.linalg.norm(before[5, :3]) * 1e3
    assert pixel(fig, 6, value, ax) == pytest.approx(to_rgb(AFTER), abs=0.03)
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert labels[0] == "after (calibrated)" and labels[1].startswith("before: baseline")
    (connectors,) = ax.collections
    low, high = sorted(connectors.get_segments()[7][:, 1])
    b, a = (np.linalg.norm(e[7, :3]) * 1e3 for e in (before, after))
    assert (low, high) == pytest.approx((b, a))
    order = {line.get_label(): line.get_zorder() for line in ax.lines}
    assert order["after (calibrated)"] > order[labels[1]] > connectors.get_zorder()


def parameter_rows() -> tuple[list[dict], list[str]]:
    """Hand-made ``parameters`` rows of a results document and the layout kind of each."""

    def row(name, unit, status, error=None, std=None, boot=None):
        return {
            "name": name,
            "unit": unit,
            "status": status,
            "error": error,
            "std": std,
            "bootstrap_std": boot,
        }

    rows = [
        (row("theta_off[1]", "deg", "unidentifiable"), "theta_off"),
        (row("theta_off[2]", "deg", "estimated", 0.4, 0.05, 0.08), "theta_off"),
        (row("a[1]", "mm", "estimated", -0.7, 0.1, 0.12), "a"),
        (row("a[2]", "mm", "combination", 0.3, 0.2, None), "a"),
        (row("d[1]", "mm", "not supported"), "d"),
        (row("alpha[1]", "deg", "estimated", -0.2, 0.01, 0.02), "alpha"),
        (row("scale[1]", "ppm", "estimated", 120.0, 15.0, 20.0), "scale"),
        (row("scale[2]", "ppm", "not supported"), "scale"),
        (row("compliance[2]", "urad/Nm", "estimated", 3.0, 0.5, 0.4), "compliance"),
        (row("harmonic_s[2]", "deg", "not supported"), "harmonic_s"),
        (row("handeye.tx", "mm", "combination", 25.0, 0.01, 0.01), "handeye"),
    ]
    return [r for r, _ in rows], [k for _, k in rows]


def test_parameter_plot_shows_the_documents_numbers_by_kind():
    rows, kinds = parameter_rows()
    fig = drawn(calibration_parameter_figure(rows, kinds))
    titles = [ax.get_title() for ax in fig.axes]
    assert titles == [
        "Lengths (mm)",
        "Angles (deg)",
        "Non-geometric terms (ppm)",
        "Non-geometric terms (urad/Nm)",
    ]
    panels = {
        "Lengths (mm)": ["a[1]", "a[2]", "d[1]"],  # the hand-eye is not a robot parameter
        "Angles (deg)": ["theta_off[1]", "theta_off[2]", "alpha[1]"],
        "Non-geometric terms (ppm)": ["scale[1]"],  # terms left out of the model: listed only
        "Non-geometric terms (urad/Nm)": ["compliance[2]"],
    }
    by_name = {r["name"]: r for r in rows}
    for ax in fig.axes:
        names = [t.get_text() for t in ax.get_xticklabels()]
        assert names == panels[ax.get_title()]
        assert ax.get_ylabel() == f"error ({by_name[names[0]]['unit']})"
        for k, name in enumerate(names):
            r = by_name[name]
            if r["error"] is None:  # held at nominal: a grey mark at zero, a grey name
                marks = [ln for ln in ax.lines if list(ln.get_xdata()) == [k]]
                assert [ln.get_ydata()[0] for ln in marks] == [0]
                assert ax.get_xticklabels()[k].get_color() != "#1f2328"
                continue
            bars = [
                c
                for c in ax.containers
                if c.lines[0] is not None and c.lines[0].get_xdata()[0] == k
            ]
            assert len(bars) == 1
            assert bars[0].lines[0].get_ydata()[0] == pytest.approx(r["error"])
            ((_, low), (_, high)) = bars[0].lines[2][0].get_segments()[0]
            assert (low, high) == pytest.approx((r["error"] - r["std"], r["error"] + r["std"]))
            beside = [  # the bootstrap's bar, just right of the predicted one
                c.lines[2][0].get_segments()[0]
                for c in ax.containers
                if c.lines[0] is None and k < c.lines[2][0].get_segments()[0][0, 0] < k + 0.5
            ]
            if r["bootstrap_std"] is None:
                assert beside == []
            else:
                ((_, low), (_, high)) = beside[0]
                b, e = r["bootstrap_std"], r["error"]
                assert len(beside) == 1 and (low, high) == pytest.approx((e - b, e + b))
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert labels[0] == "identified error ± 1 std (predicted)"
    assert {
        "unidentifiable: nominal kept",
        "not supported by model selection: nominal kept",
    } <= set(labels)


def test_compact_names():
    names = ["scale[1]", "scale[2]", "scale[3]", "harmonic_c[2]", "harmonic_c[4]", "base.tx"]
    assert compact_names(names) == "scale[1–3], harmonic_c[2, 4], base.tx"
