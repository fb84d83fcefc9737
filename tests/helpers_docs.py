"""The documentation's fenced blocks: where they are, what they say, and how the tests run them.

A block's info string is its language and, optionally, ``norun`` (docs/contributing.md): `sh`
blocks are shell commands run as printed, `python` blocks are executed, `norun` blocks are only
checked (their ``relcal`` commands must name existing commands and options).
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
TAGS = {"norun"}


@dataclass(frozen=True)
class Block:
    page: Path
    line: int
    language: str
    tags: frozenset[str]
    body: str

    @property
    def where(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"

    @property
    def runs(self) -> bool:
        return "norun" not in self.tags

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
        out.append(Block(page, line, words[0], frozenset(words[1:]), body))
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
