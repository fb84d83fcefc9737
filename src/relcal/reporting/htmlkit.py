"""The HTML kit of relcal's reports: trusted markup (:class:`Html`) and everything else escaped,
tables, cards, badges, sections, embedded figures and the page around them, one stylesheet.

A page is self-contained: inline CSS, plots as PNG ``data:`` URIs, no script and nothing fetched,
so it opens offline and can be mailed or archived. Used by the calibration and simulation reports
(:mod:`relcal.reporting.calibration_report`, :mod:`relcal.reporting.simulation_report`) and the
fleet report (:mod:`relcal.fleet.report`).
"""

from __future__ import annotations

import base64
import html as _html
import io
import json
from collections.abc import Iterable, Sequence

import numpy as np
from matplotlib.figure import Figure

from relcal import __version__
from relcal.errors import printable

DPI = 110  # pixels per inch of every embedded plot

__all__ = [
    "CSS",
    "DPI",
    "Html",
    "badge",
    "bullet_list",
    "cards",
    "compact_names",
    "escape",
    "figure_html",
    "flatten",
    "fmt",
    "page",
    "paragraph",
    "section",
    "table",
]


class Html(str):
    """Trusted markup, inserted as is; every other value is escaped."""


def escape(value: object) -> str:
    """``value`` as HTML text: :class:`Html` as is, anything else escaped: ``<``, ``&`` and
    quotes as entities, and control characters and Unicode bidirectional controls (which would
    reorder the text a reader sees: a joint name that displays as another) as visible escapes
    (``\\u202e``), as the terminal shows them (:func:`relcal.errors.printable`)."""
    if isinstance(value, Html):
        return value
    return _html.escape(printable(str(value)))


def table(head: Sequence[object], rows: Iterable[Sequence[object]], cls: str = "") -> Html:
    """A table; ``cls="num"`` right-aligns every column but the first."""
    th = "".join(f"<th>{escape(h)}</th>" for h in head)
    body = "".join("<tr>" + "".join(f"<td>{escape(c)}</td>" for c in row) + "</tr>" for row in rows)
    return Html(f'<table class="{cls}"><thead><tr>{th}</tr></thead><tbody>{body}</tbody></table>')


def badge(ok: bool, yes: str = "yes", no: str = "no") -> Html:
    return Html(f'<span class="badge {"ok" if ok else "bad"}">{escape(yes if ok else no)}</span>')


def cards(items: Sequence[tuple[str, str, str]], cls: str = "") -> Html:
    """Summary cards of ``(label, value, note)``."""
    cells = "".join(
        f'<div class="card"><div class="label">{escape(label)}</div>'
        f'<div class="value">{escape(value)}</div><div class="note">{escape(note)}</div></div>'
        for label, value, note in items
    )
    return Html(f'<div class="cards {cls}">{cells}</div>')


def bullet_list(items: Sequence[object], empty: str) -> Html:
    if not items:
        return Html(f'<p class="none">{escape(empty)}</p>')
    return Html("<ul>" + "".join(f"<li>{escape(i)}</li>" for i in items) + "</ul>")


def figure_html(ident: str, alt: str, fig: Figure) -> Html:
    """The figure as an ``<img>`` with a PNG ``data:`` URI, and its caption."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI, facecolor="white")
    data = base64.b64encode(buffer.getvalue()).decode("ascii")
    return Html(
        f'<figure><img id="{escape(ident)}" alt="{escape(alt)}" '
        f'src="data:image/png;base64,{data}"><figcaption>{escape(alt)}</figcaption></figure>'
    )


def section(ident: str, title: str, *parts: object) -> tuple[str, str, Html]:
    body = "".join(escape(p) for p in parts)
    return (
        ident,
        title,
        Html(f'<section id="{escape(ident)}"><h2>{escape(title)}</h2>{body}</section>'),
    )


def paragraph(text: str) -> Html:
    return Html(f"<p>{escape(text)}</p>")


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


def page(title: str, meta: Sequence[tuple[str, str]], sections: Sequence[tuple]) -> str:
    """The whole document: header, navigation, sections, footer."""
    info = " &middot; ".join(f"{escape(k)} <b>{escape(v)}</b>" for k, v in meta)
    links = "".join(f'<a href="#{escape(i)}">{escape(t)}</a>' for i, t, _ in sections)
    body = "".join(s for _, _, s in sections)
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>{escape(title)}</title><style>{CSS}</style></head><body>"
        f'<header><div class="wrap"><h1>{escape(title)}</h1><div class="meta">{info}</div>'
        f'</div></header><nav><div class="wrap">{links}</div></nav><main>{body}</main>'
        f"<footer>Generated by relcal {escape(__version__)}. Lengths in mm, angles in degrees."
        "</footer></body></html>\n"
    )


def fmt(value: float | None, spec: str = ".4f") -> str:
    if value is None or not np.isfinite(value):
        return "–"
    return format(value, spec)


def flatten(value: object, prefix: str = "") -> list[tuple[str, str]]:
    """``(dotted key, text)`` rows of nested settings."""
    if isinstance(value, dict):
        rows = []
        for key, item in value.items():
            rows += flatten(item, f"{prefix}.{key}" if prefix else str(key))
        return rows
    if isinstance(value, float):
        return [(prefix, f"{value:g}")]
    if isinstance(value, list | tuple):
        return [(prefix, ", ".join(map(str, value)) or "none")]
    return [(prefix, json.dumps(value) if value is None or isinstance(value, bool) else str(value))]


def compact_names(names: Sequence[str]) -> str:
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
