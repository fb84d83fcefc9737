"""Every command of README.md and of the site's pages runs as printed.

The blocks are extracted by tests/helpers_docs.py (docs/contributing.md describes the
convention): ``sh`` blocks run with bash, ``python`` blocks are executed, ``norun`` blocks (a
robot, a cluster, an install) are checked for existing commands and options. Everything runs in
one scratch checkout (a copy of ``examples/`` beside a ``shared`` link to the real data), shared
by the test processes, page after page; a command printed on several pages runs once in the run.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import io
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import DATA
from helpers_docs import (
    ROOT,
    TAGS,
    blocks,
    check_relcal_command,
    figure_in,
    match_output,
    pages,
    quoted_figures,
    rewritten,
    same_figure,
    untagged_outputs,
    updated_output,
)

PAGES = pages()
PROGRESS = re.compile(r"\d+%\|.*\|\s*\d+/\d+ \[|\r")  # a tqdm progress bar's line
LABELS = {b.label: b for page in PAGES for b in blocks(page) if b.label}


@contextlib.contextmanager
def _locked(path: Path):
    """An exclusive lock on ``path`` (a file), across processes: the test workers."""
    with open(path, "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


class Checkout:
    """The scratch checkout the commands run in, what already ran there and what it printed.

    One checkout for the whole run, shared by the test processes (pytest-xdist's workers): each
    command runs once, under a lock of its own, and its output is kept in ``outputs/`` for the
    others (a page quoting another page's run, a command printed on several pages)."""

    def __init__(self, base: Path) -> None:
        self.root = base / "relcal"
        self.outputs = base / "outputs"  # each command's record: output, status, times
        with _locked(base / "setup.lock"):
            if not self.root.exists():
                (base / "shared").symlink_to(DATA.parent.resolve(), target_is_directory=True)
                staging = base / "relcal.staging"
                shutil.copytree(ROOT / "examples", staging / "examples")
                staging.rename(self.root)
                self.outputs.mkdir()
        self.env = dict(os.environ, OPENBLAS_NUM_THREADS="1", MPLBACKEND="Agg")
        self.env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{self.env['PATH']}"
        self.done: dict[str, float] = {}  # command -> seconds it took (run by this process)
        self.cpu: dict[str, float] = {}  # command -> CPU seconds of its processes
        self.printed: dict[str, str] = {}  # command -> its output (stdout and stderr, in order)
        self.status: dict[str, tuple[int, str]] = {}  # command -> exit status, whole output

    def run(self, command: str, where: str) -> str:
        """Run ``command`` once in the whole test run (a command printed on several pages runs
        once) and return what it printed."""
        if command not in self.printed:
            key = hashlib.sha1(command.encode()).hexdigest()[:16]
            record = self.outputs / f"{key}.json"
            with _locked(self.outputs / f"{key}.lock"):
                if not record.exists():
                    staged = record.with_suffix(".staging")
                    staged.write_text(json.dumps(self._execute(command)))
                    staged.rename(record)
            done = json.loads(record.read_text())
            # What stays on a terminal: progress bars (tqdm, on standard error) left out.
            lines = [x for x in done["output"].splitlines() if not PROGRESS.search(x)]
            self.printed[command] = "\n".join(lines) + "\n" if lines else ""
            self.status[command] = (done["returncode"], done["output"])
        code, output = self.status[command]
        assert code == 0, f"{where}: `{command}` exited {code}\n{output[-6000:]}"
        return self.printed[command]

    def _execute(self, command: str) -> dict:
        start, before = time.perf_counter(), resource.getrusage(resource.RUSAGE_CHILDREN)
        done = subprocess.run(
            ["bash", "-c", command],
            cwd=self.root,
            env=self.env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            timeout=600,
        )
        self.done[command] = time.perf_counter() - start
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        self.cpu[command] = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        return {
            "command": command,
            "returncode": done.returncode,
            "output": done.stdout,
            "seconds": self.done[command],
            "cpu_seconds": self.cpu[command],
        }

    def run_block(self, block) -> str:
        """Run a runnable `sh` block; its commands' outputs, in order."""
        return "".join(self.run(command, block.where) for command in block.commands())

    def output(self, block) -> str:
        """What ``block`` printed, running first every runnable `sh` block of its page up to it
        (what the page's reader runs before it)."""
        for earlier in blocks(block.page):
            if earlier.language == "sh" and earlier.runs:
                printed = self.run_block(earlier)
                if earlier == block:
                    return printed
        raise AssertionError(f"{block.where}: not a runnable sh block")


@pytest.fixture(scope="session")
def checkout(tmp_path_factory):
    # The workers of one run share the parent of their own temporary folders.
    base = tmp_path_factory.getbasetemp()
    base = (base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base) / "docs-commands"
    base.mkdir(exist_ok=True)
    box = Checkout(base)
    yield box
    total, cpu = sum(box.done.values()), sum(box.cpu.values())
    slowest = sorted(box.done, key=lambda c: -box.cpu[c])[:8]
    print(f"\ndocs commands: {len(box.done)} run in {total:.1f} s ({cpu:.1f} s CPU); slowest:")
    for command in slowest:
        print(f"  {box.done[command]:6.1f} s  {box.cpu[command]:6.1f} s CPU  {command}")


def _source(figure, page_blocks):
    """The `sh` block whose output a quoted figure comes from."""
    if figure.label is not None:
        assert figure.label in LABELS, f"{figure.where}: no sh block has label={figure.label}"
        return LABELS[figure.label]
    earlier = [b for b in page_blocks if b.language == "sh" and b.runs and b.end < figure.start]
    assert earlier, f"{figure.where}: a quoted figure with no sh block before it"
    return earlier[-1]


@pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(ROOT)) for p in PAGES])
def test_page_commands_run_as_printed(page, checkout, monkeypatch, request):
    """Every command runs as printed, and every figure the page quotes (``text output``
    blocks, ``<!--out ...-->`` figures in prose) is what the commands print, to the digits
    shown; with ``--update-docs`` the page is rewritten from the output instead."""
    update = request.config.getoption("--update-docs")
    namespace: dict = {"__name__": "__docs__"}
    monkeypatch.chdir(checkout.root)
    page_blocks = blocks(page)
    problems, outputs, figures = [], {}, []
    previous, printed_by = None, {}  # the last sh or python block; what python blocks printed
    for block in page_blocks:
        unknown = block.unknown_tags()
        assert not unknown, f"{block.where}: unknown tag(s) {sorted(unknown)} (known: {TAGS})"
        if block.language == "sh":
            for command in block.commands():
                if block.runs:
                    checkout.run(command, block.where)
                else:
                    assert not check_relcal_command(command), block.where
        elif block.language == "python":
            code = compile(block.body, block.where, "exec")
            if block.runs:
                with contextlib.redirect_stdout(io.StringIO()) as printed:
                    exec(code, namespace)
                printed_by[block] = printed.getvalue()
        elif block.is_output:
            assert previous is not None, f"{block.where}: a text output block with no command"
            python = previous.language == "python"
            printed = printed_by.get(previous, "") if python else checkout.output(previous)
            problem = match_output(block.body, printed)
            if problem and update:
                outputs[block] = updated_output(block.body, printed)
            elif problem:
                problems.append(f"{block.where}: {problem}")
        if block.language in ("sh", "python"):
            previous = block
    problems += untagged_outputs(page)
    for figure in quoted_figures(page):
        printed = checkout.output(_source(figure, page_blocks))
        got = figure_in(figure, printed)
        if got is None:
            problems.append(
                f"{figure.where}: no output line fits {figure.pattern!r}; the output:\n"
                + printed[-4000:]
            )
        elif not same_figure(figure.shown, got) and update:
            figures.append((figure, got))
        elif not same_figure(figure.shown, got):
            problems.append(f"{figure.where}: {figure.shown} quoted, the output says {got}")
    if outputs or figures:
        page.write_text(rewritten(page, outputs, figures))
    assert not problems, "\n".join(problems)


def test_readme_is_short_and_links_resolve():
    """About 150 lines, no link into a file the repository lacks (e.g. a DESIGN.md it does not
    hold)."""
    import re

    readme = (ROOT / "README.md").read_text()
    assert len(readme.splitlines()) < 200
    for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", readme):
        if "://" not in target:
            assert (ROOT / target).exists(), target
    assert "DESIGN.md" not in readme


def test_fences_are_found_and_norun_commands_are_checked():
    """The extraction sees the README's commands, and the check catches a wrong option."""
    readme = blocks(ROOT / "README.md")
    commands = [c for b in readme if b.language == "sh" and b.runs for c in b.commands()]
    assert any(c.startswith("relcal calibrate positioner") for c in commands)
    assert any(b.language == "python" and b.runs for b in readme)
    assert check_relcal_command("relcal calibrate DS --kfold 5") == []
    assert check_relcal_command("relcal import rosbag B --joints /j --out d") == []
    assert check_relcal_command("relcal calibrate DS --k-fold 5")
    assert check_relcal_command("relcal calibrat DS")


PRINTED = (
    "calibration: tiago-positions (geometric + compliance)\n"
    "  position     baseline (nominal) 29.151 (26.726..31.563) mm  calibrated 18.461 "
    "(17.291..20.526) mm  ratio x0.633 (0.594..0.708)\n"
    "identification: converged in 6 iterations, 106.8 ms\n"
    "verdict: HOLDS\n"
)


def test_output_blocks_compare_every_figure_to_the_digits_shown():
    """The issue-28 case: a page that says 18.860 and x0.647 where the output is 18.461 and
    x0.633 fails, naming both; rounding to the digits shown, elided lines and wildcards pass."""
    stale = PRINTED.replace("18.461", "18.860").replace("x0.633", "x0.647")
    problem = match_output(stale, PRINTED)
    assert "18.860 (prints 18.461)" in problem and "0.647 (prints 0.633)" in problem
    assert match_output(PRINTED, PRINTED) is None
    shown = "...\n  position  baseline (nominal) 29.2 (26.7..31.6) mm  calibrated 18.5 ...\n..."
    assert match_output(shown, PRINTED) is None  # fewer digits, a wildcard, elided lines
    assert match_output(shown.replace("18.5", "18.4"), PRINTED)  # 18.461 is not 18.4
    assert match_output(shown.replace("29.2", "29"), PRINTED) is None  # 29.151 is 29
    assert match_output(shown.replace("29.2", "30"), PRINTED)  # ... and not 30
    assert match_output(PRINTED.replace("verdict: HOLDS\n", ""), PRINTED)  # a line left out
    assert match_output(PRINTED.replace("HOLDS", "DEGRADED"), PRINTED)  # a word changed
    assert match_output("...\nverdict: HOLDS", PRINTED) is None
    assert match_output("verdict: HOLDS", PRINTED)  # no '...': the block is the whole output
    # Rewritten from the output: the stale figures fixed, digits, elisions and wildcards kept.
    assert updated_output(stale, PRINTED).strip() == PRINTED.strip()
    assert updated_output(shown.replace("18.5", "18.4"), PRINTED) == shown
    assert updated_output("a line the output lacks", PRINTED).strip() == PRINTED.strip()


def test_prose_figures_are_tied_to_their_output_line(tmp_path):
    """A figure followed by <!--out PATTERN--> is the number the pattern finds in the output;
    --update-docs rewrites it with the digits shown."""
    page = tmp_path / "figures.md"
    text = (
        "the reverse (29.2<!--out baseline (nominal) {} (--> -> 18.9<!--out:x calibrated {} (-->"
        " mm, x0.65<!--out ratio x{} (-->) holds\n\n```text\nnot prose: 1.0<!--out a {} b-->\n```\n"
    )
    page.write_text(text)
    figures = quoted_figures(page)
    shown = [(f.shown, f.label) for f in figures]
    assert shown == [("29.2", None), ("18.9", "x"), ("0.65", None)]
    got = [figure_in(f, PRINTED) for f in figures]
    assert got == ["29.151", "18.461", "0.633"]
    assert [same_figure(f.shown, g) for f, g in zip(figures, got, strict=True)] == [
        True,
        False,  # stale: the test fails on it
        False,
    ]
    new = rewritten(page, {}, list(zip(figures, got, strict=True)))
    assert "(29.2<!--" in new and "-> 18.5<!--" in new and "x0.63<!--" in new
    page.write_text("a figure 18.9 <!--out calibrated {} (-->\n")
    with pytest.raises(ValueError, match="must follow a number directly"):
        quoted_figures(page)


def test_text_right_after_a_command_must_be_its_checked_output(tmp_path):
    page = tmp_path / "untagged.md"
    fence = "```"
    page.write_text(
        f"{fence}sh\necho 1\n{fence}\n\n{fence}text\n1\n{fence}\n\n"  # flagged
        f"{fence}sh\necho 2\n{fence}\n\nsaid:\n\n{fence}text\nx\n{fence}\n"  # prose between
    )
    problems = untagged_outputs(page)
    assert len(problems) == 1 and "untagged.md:5" in problems[0]
