"""The documentation's fenced blocks: where they are, what they say, and how the tests run them.

A block's info string is its language and, optionally, tags (docs/contributing.md): `sh` blocks
are shell commands run as printed, `python` blocks are executed, `norun` blocks are only checked
(their ``relcal`` commands must name existing commands and options), ``label=NAME`` names an
`sh` block for figures quoted elsewhere. A ``text output`` block is the output of the `sh`
block before it, and a figure in prose followed by ``<!--out PATTERN-->`` (or
``<!--out:NAME PATTERN-->``) is a number of that output: both are compared with what the
commands print, to the digits shown (:func:`match_output`, :func:`quoted_figures`), and
rewritten from it by ``pytest tests/test_docs_commands.py --update-docs``
(:func:`updated_output`, :func:`rewritten`).
"""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
GENERATED = ("_build", "gallery", "generated", "_templates")  # written by the build, not pages
FENCE = re.compile(
    r"^(?P<indent>[ \t]*)```(?P<info>[^`\n]*)\n(?P<body>.*?)^(?P=indent)```[ \t]*$", re.M | re.S
)
TAGS = {"norun", "output"}
KEYS = {"label"}  # tags with a value: label=NAME


@dataclass(frozen=True)
class Block:
    page: Path
    line: int
    language: str
    tags: frozenset[str]
    body: str
    start: int = 0  # offsets of the body in the page's text
    end: int = 0
    indent: str = ""  # of the fence (a block inside a list item)

    @property
    def where(self) -> str:
        return f"{_shown(self.page)}:{self.line}"

    @property
    def runs(self) -> bool:
        return "norun" not in self.tags

    @property
    def is_output(self) -> bool:
        """A ``text output`` block: the output of the `sh` block before it."""
        return self.language == "text" and "output" in self.tags

    @property
    def label(self) -> str | None:
        """``NAME`` of a ``label=NAME`` tag."""
        return next((t.split("=", 1)[1] for t in self.tags if t.startswith("label=")), None)

    def unknown_tags(self) -> set[str]:
        return {t for t in self.tags if t not in TAGS and t.split("=", 1)[0] not in KEYS}

    def commands(self) -> list[str]:
        """The shell commands of an ``sh`` block: continuation lines joined, comments and blank
        lines left out."""
        out, current = [], ""
        for raw in self.body.splitlines():
            line = raw.rstrip()
            if not current and (not line.strip() or line.lstrip().startswith("#")):
                continue
            if line.endswith("\\"):
                current += line[:-1] + " "
                continue
            out.append((current + line).strip())
            current = ""
        if current.strip():
            out.append(current.strip())
        return out


def pages() -> list[Path]:
    """README.md, then every Markdown page of the site, by path."""
    found = [
        p
        for p in DOCS.rglob("*.md")
        if not any(part in GENERATED for part in p.relative_to(DOCS).parts)
    ]
    return [ROOT / "README.md", *sorted(found)]


def blocks(page: Path) -> list[Block]:
    text = page.read_text()
    out = []
    for m in FENCE.finditer(text):
        words = m["info"].split()
        if not words or words[0].startswith("{"):  # MyST directives: not code
            continue
        indent = len(m["indent"])
        body = "\n".join(line[indent:] for line in m["body"].splitlines())
        line = text.count("\n", 0, m.start()) + 1
        tags = frozenset(words[1:])
        out.append(
            Block(page, line, words[0], tags, body, m.start("body"), m.end("body"), m["indent"])
        )
    return out


def check_relcal_command(command: str) -> list[str]:
    """Problems with a ``relcal ...`` command line that is not run: an unknown command or an
    option its parser does not have."""
    import argparse

    from relcal.cli import build_parser

    words = shlex.split(command, comments=True)
    if not words or words[0] != "relcal":
        return []
    parser, problems = build_parser(), []
    rest = words[1:]
    while True:  # descend into subcommands
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs or not rest or rest[0].startswith("-"):
            break
        if rest[0] not in subs[0].choices:
            return [f"unknown command {rest[0]!r} in: {command}"]
        parser, rest = subs[0].choices[rest[0]], rest[1:]
    known = {s for a in parser._actions for s in a.option_strings}
    for word in rest:
        if word.startswith("--") and word.split("=")[0] not in known:
            problems.append(f"unknown option {word.split('=')[0]!r} in: {command}")
    return problems


# --- figures: what a page quotes against what its commands print ------------------------------

NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")
ELLIPSIS = "..."  # a line of its own: output lines left out; inside a line: any text
MARKER = re.compile(r"<!--out(?::(?P<label>[\w.-]+))?\s+(?P<pattern>.*?)\s*-->", re.S)


def _digits(shown: str) -> float:
    """Half a unit of the last digit of the number as ``shown`` (``18.9``: 0.05; ``7.9e-6``:
    5e-8): how far what a page shows may be from what was printed."""
    mantissa, _, exponent = shown.lower().lstrip("+-").partition("e")
    decimals = len(mantissa.partition(".")[2])
    return 0.5 * 10.0 ** (int(exponent or 0) - decimals)


def same_figure(shown: str, printed: str) -> bool:
    """Whether ``printed`` is ``shown`` to the digits ``shown`` has (``18.86`` is ``18.9``, not
    ``18.8``; ``48`` is ``48``)."""
    return abs(float(shown) - float(printed)) <= _digits(shown) * (1 + 1e-9)


def _line_regex(line: str, search: bool = False) -> tuple[re.Pattern, list[str]]:
    """A regular expression for a page's ``line`` (numbers as groups, ``...`` as any text, runs
    of blanks as any blank) and the numbers it shows."""
    parts, shown = [], []
    for k, segment in enumerate(line.split(ELLIPSIS)):
        if k:
            parts.append(".+?")
        at = 0
        for m in NUMBER.finditer(segment):
            parts.append(_text_regex(segment[at : m.start()]))
            parts.append(f"({NUMBER.pattern})")
            shown.append(m.group())
            at = m.end()
        parts.append(_text_regex(segment[at:]))
    body = "".join(parts)
    return re.compile(body if search else rf"\s*{body}\s*"), shown


def _names(line: str) -> list[bool]:
    """For each number of a page's ``line``: whether it is part of a name (``joint3``,
    ``theta_off[3]``, ``p001``), which a new output keeps, unlike a measured figure."""
    out = []
    for segment in line.split(ELLIPSIS):
        for m in NUMBER.finditer(segment):
            before = segment[m.start() - 1] if m.start() else " "
            out.append((before.isalnum() or before in "_[") and "." not in m.group())
    return out


def _text_regex(text: str) -> str:
    """``text`` literally, each run of blanks as one or more blanks."""
    if not text.strip():
        return r"\s+" if text else ""
    return r"\s+".join(re.escape(w) for w in re.split(r"\s+", text))


def _lines(text: str) -> list[str]:
    """The non-blank lines of ``text``, stripped (indentation and blank lines do not count)."""
    return [line.strip() for line in text.splitlines() if line.strip()]


def _align(page: list[str], printed: list[str], numbers: str) -> list[int] | None:
    """For each of the ``page``'s lines the index of the ``printed`` line it shows (-1 for an
    ``...`` line), in order, covering the whole output; None if there is no such alignment.
    ``numbers``: ``"all"`` compared to the digits shown, ``"names"`` only the numbers that are
    part of a name (an index such as ``joint3`` stays what it is, measured figures may change)."""
    compiled = [None if p.strip() == ELLIPSIS else _line_regex(p) for p in page]
    names = [_names(p) for p in page]

    def fits(i: int, j: int) -> bool:
        regex, shown = compiled[i]
        m = regex.fullmatch(printed[j])
        if m is None:
            return False
        pairs = zip(shown, m.groups(), strict=True)
        if numbers == "names":
            pairs = [ab for ab, name in zip(pairs, names[i], strict=True) if name]
        return all(a == b if numbers == "names" else same_figure(a, b) for a, b in pairs)

    seen: dict[tuple[int, int], list[int] | None] = {}

    def solve(i: int, j: int) -> list[int] | None:
        if i == len(page):
            return [] if j == len(printed) else None
        if (i, j) in seen:
            return seen[(i, j)]
        out = None
        if compiled[i] is None:  # elided lines: none, or one more
            rest = solve(i + 1, j)
            if rest is not None:
                out = [-1, *rest]
            elif j < len(printed) and solve(i, j + 1) is not None:
                out = solve(i, j + 1)
        elif j < len(printed) and fits(i, j):
            rest = solve(i + 1, j + 1)
            out = None if rest is None else [j, *rest]
        seen[(i, j)] = out
        return out

    import sys

    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 4 * (len(page) + len(printed)) + 100))
    try:
        return solve(0, 0)
    finally:
        sys.setrecursionlimit(limit)


def _structure(page: list[str], printed: list[str]) -> list[int] | None:
    """The alignment of the page's lines with the output's whatever the measured figures (a
    row ``d[panda_joint3]`` stays that row)."""
    return _align(page, printed, "names")


def match_output(shown: str, printed: str) -> str | None:
    """None when the ``text output`` block ``shown`` is what ``printed`` says, line by line
    (blank lines aside; ``...`` lines for lines left out, ``...`` in a line for any text) with
    every figure to the digits shown; else what differs, for the test's message."""
    page, out = _lines(shown), _lines(printed)
    if _align(page, out, "all") is not None:
        return None
    structure = _structure(page, out)
    if structure is None:
        return (
            "the block's lines are not the output's (a line changed, was added or removed: "
            "elide with '...')\n--- page\n" + "\n".join(page) + "\n--- output\n" + "\n".join(out)
        )
    stale = []
    for i, j in enumerate(structure):
        if j < 0:
            continue
        regex, numbers = _line_regex(page[i])
        got = regex.fullmatch(out[j]).groups()
        pairs = zip(numbers, got, strict=True)
        bad = [f"{a} (prints {b})" for a, b in pairs if not same_figure(a, b)]
        if bad:
            stale.append(f"  {page[i].strip()}\n    stale: {', '.join(bad)}")
    return "figures differ from the output:\n" + "\n".join(stale)


def updated_output(shown: str, printed: str) -> str:
    """The ``text output`` block ``shown`` rewritten from ``printed``: its lines, elisions and
    wildcards kept, each figure the printed one to the digits shown; the whole output when the
    lines no longer correspond (a person elides again)."""
    page, out = _lines(shown), _lines(printed)
    structure = _structure(page, out)
    if structure is None:
        return "\n".join(line.rstrip() for line in printed.strip("\n").splitlines())
    lines = shown.splitlines()
    index = [k for k, line in enumerate(lines) if line.strip()]
    for i, j in enumerate(structure):
        if j >= 0:
            lines[index[i]] = _refigured(lines[index[i]], out[j])
    return "\n".join(lines)


def _refigured(line: str, printed: str) -> str:
    """``line`` with each of its numbers replaced by the one ``printed`` at its place, written
    with the digits ``line`` shows."""
    regex, shown = _line_regex(line.strip())
    got = regex.fullmatch(printed).groups()
    new = iter([_formatted(a, b) for a, b in zip(shown, got, strict=True)])
    return NUMBER.sub(lambda m: next(new), line)


def _formatted(shown: str, printed: str) -> str:
    """``printed`` written as ``shown`` is (decimals, exponent, an explicit sign)."""
    if same_figure(shown, printed) and len(shown) == len(printed):
        return printed
    mantissa, e, exponent = shown.lower().partition("e")
    decimals = len(mantissa.partition(".")[2])
    value = float(printed)
    if e:
        text = f"{value:.{decimals}e}"
        m, _, x = text.partition("e")
        text = f"{m}e{int(x)}" if not exponent.startswith(("+", "-0", "0")) else text
    else:
        text = f"{value:.{decimals}f}"
    if (shown.startswith("+") or printed.startswith("+")) and value >= 0:
        text = "+" + text
    return text


@dataclass(frozen=True)
class Figure:
    """A figure quoted in prose: ``shown`` before the marker at ``start`` (page offsets),
    ``pattern`` locating it in the output of the block labelled ``label`` (None: the `sh` block
    before it on its page)."""

    page: Path
    line: int
    shown: str
    start: int  # offset of the figure in the page
    label: str | None
    pattern: str

    @property
    def where(self) -> str:
        return f"{_shown(self.page)}:{self.line}"


def _shown(page: Path) -> str:
    """A page's path from the repository's root (as given when outside it)."""
    return str(page.relative_to(ROOT)) if page.is_relative_to(ROOT) else str(page)


def quoted_figures(page: Path) -> list[Figure]:
    """The figures of ``page``'s prose tied to an output by a ``<!--out ...-->`` marker right
    after them (outside code blocks and inline code)."""
    text = page.read_text()
    fenced = [(m.start(), m.end()) for m in FENCE.finditer(text)]
    masked = text
    for a, b in fenced:  # inline code is looked for outside the fenced blocks
        masked = masked[:a] + " " * (b - a) + masked[b:]
    inline = re.finditer(r"``[^\n]*?``|`[^`\n]*`", masked)
    spans = fenced + [(m.start(), m.end()) for m in inline]
    out = []
    for m in MARKER.finditer(text):
        if any(a <= m.start() < b for a, b in spans):
            continue
        window = max(0, m.start() - 40)
        found = list(NUMBER.finditer(text[window : m.start()]))
        line = text.count("\n", 0, m.start()) + 1
        if not found or window + found[-1].end() != m.start():
            raise ValueError(
                f"{_shown(page)}:{line}: an <!--out ...--> marker must follow a "
                "number directly (e.g. 18.9<!--out calibrated {} mm-->)"
            )
        figure = found[-1]
        start = window + figure.start()
        if "{}" not in m["pattern"]:
            raise ValueError(f"{_shown(page)}:{line}: the marker's pattern has no {{}}")
        out.append(Figure(page, line, figure.group(), start, m["label"], m["pattern"]))
    return out


ANCHOR = " >> "  # in a prose pattern: the lines after the first one that fits what precedes


def figure_in(figure: Figure, printed: str) -> str | None:
    """The number that ``figure``'s pattern locates in ``printed`` (the first line it fits,
    after the lines that fit its anchors, ``A >> B >> pattern``), or None."""
    *anchors, pattern = figure.pattern.split(ANCHOR)
    lines = _lines(printed)
    for anchor in anchors:
        regex = _line_regex(anchor, search=True)[0]
        at = next((k for k, line in enumerate(lines) if regex.search(line)), None)
        if at is None:
            return None
        lines = lines[at + 1 :]
    before, _, after = pattern.partition("{}")
    regex, shown = _line_regex(f"{before}\0{after}", search=True)
    regex = re.compile(regex.pattern.replace(re.escape("\0"), f"({NUMBER.pattern})", 1))
    k = len(_line_regex(before, search=True)[1])  # numbers of the pattern before {}
    for line in lines:
        for m in regex.finditer(line):
            context = m.groups()[:k] + m.groups()[k + 1 :]  # the pattern's own numbers
            if all(map(same_figure, shown, context)):  # (theta_off[4] is not theta_off[3])
                return m.group(k + 1)
    return None


def rewritten(page: Path, outputs: dict[Block, str], figures: list[tuple[Figure, str]]) -> str:
    """The text of ``page`` with the bodies of the ``outputs`` blocks replaced (indented as their
    fences) and the quoted ``figures`` replaced by the printed ones."""
    text = page.read_text()
    edits = [(f.start, f.start + len(f.shown), _formatted(f.shown, new)) for f, new in figures]
    for block, body in outputs.items():
        lines = [f"{block.indent}{line}" if line.strip() else "" for line in body.splitlines()]
        edits.append((block.start, block.end, "\n".join(lines) + "\n"))
    for start, end, new in sorted(edits, reverse=True):
        text = text[:start] + new + text[end:]
    return text


def untagged_outputs(page: Path) -> list[str]:
    """Problems: ``text`` blocks right after a runnable command (nothing but blank lines
    between) that are not tagged ``output``: what follows a command is its output, compared."""
    text, out, previous = page.read_text(), [], None
    for block in blocks(page):
        if block.language == "text" and not block.is_output and previous is not None:
            between = text[previous.end : block.start].split("\n")[1:-2]  # the fences aside
            if not any(line.strip() for line in between):
                out.append(
                    f"{block.where}: a text block right after a command is its output: tag it "
                    "```text output``` (compared with what the command prints)"
                )
        previous = block if block.language in ("sh", "python") and block.runs else None
    return out
