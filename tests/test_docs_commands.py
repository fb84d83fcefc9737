"""Every command of README.md and of the site's pages runs as printed.

The blocks are extracted by tests/helpers_docs.py (docs/contributing.md describes the
convention): ``sh`` blocks run with bash, ``python`` blocks are executed, ``norun`` blocks (a
robot, a cluster, an install) are checked for existing commands and options. Everything runs in
one scratch checkout (a copy of ``examples/`` beside a ``shared`` link to the real data), page
after page; a command printed on several pages runs once.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import DATA
from helpers_docs import ROOT, TAGS, blocks, check_relcal_command, pages

PAGES = pages()


class Checkout:
    """The scratch checkout the commands run in, and what already ran there."""

    def __init__(self, base: Path) -> None:
        (base / "shared").symlink_to(DATA.parent.resolve(), target_is_directory=True)
        self.root = base / "relcal"
        self.root.mkdir()
        shutil.copytree(ROOT / "examples", self.root / "examples")
        self.env = dict(os.environ, OPENBLAS_NUM_THREADS="1", MPLBACKEND="Agg")
        self.env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{self.env['PATH']}"
        self.done: dict[str, float] = {}  # command -> seconds it took

    def run(self, command: str, where: str) -> None:
        if command in self.done:
            return
        start = time.perf_counter()
        done = subprocess.run(
            ["bash", "-c", command],
            cwd=self.root,
            env=self.env,
            capture_output=True,
            text=True,
            timeout=600,
        )
        self.done[command] = time.perf_counter() - start
        assert done.returncode == 0, (
            f"{where}: `{command}` exited {done.returncode}\n"
            f"{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
        )


@pytest.fixture(scope="session")
def checkout(tmp_path_factory):
    box = Checkout(tmp_path_factory.mktemp("docs-commands"))
    yield box
    total = sum(box.done.values())
    slowest = sorted(box.done.items(), key=lambda kv: -kv[1])[:3]
    print(f"\ndocs commands: {len(box.done)} run in {total:.1f} s; slowest:")
    for command, seconds in slowest:
        print(f"  {seconds:6.1f} s  {command}")


@pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(ROOT)) for p in PAGES])
def test_page_commands_run_as_printed(page, checkout, monkeypatch):
    namespace: dict = {"__name__": "__docs__"}
    monkeypatch.chdir(checkout.root)
    for block in blocks(page):
        unknown = block.tags - TAGS
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
                exec(code, namespace)


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
