"""The command line starts light: building the parser and printing help imports no NumPy, SciPy,
OpenCV, Matplotlib, SQLAlchemy or Dask, and none of relcal's computing packages (the command
modules import those inside ``run``). Checked in fresh interpreters by what they loaded, not by
timing (the start-up time is a row of ``make bench``)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from relcal.cli import main

HEAVY = ("numpy", "scipy", "cv2", "matplotlib", "sqlalchemy", "dask", "distributed", "numba")
#: relcal's own packages that pull the heavy ones in.
COMPUTING = ("calibration", "robot", "vision", "data", "design", "sim", "reporting", "fleet")

# Every command and sub-command, as its --help is reached.
ALL_HELP = [
    [],
    *([c] for c in ("simulate", "measure", "calibrate", "import", "compensate", "board")),
    *([c] for c in ("observability", "study", "plan", "capture", "fleet", "history", "compare")),
    ["verify"],
    ["handeye"],
    ["fleet", "calibrate"],
]

PROBE = """
import json, sys
from relcal.cli import main
codes = [main([*argv, "--help"]) for argv in json.loads(sys.argv[1])]
top = {m.split(".")[0] for m in sys.modules}
# modules inside relcal's sub-packages (a package's own __init__ holds only constants)
relcal = {m.split(".")[1] for m in sys.modules if m.startswith("relcal.") and m.count(".") > 1}
print(json.dumps({"codes": codes, "top": sorted(top), "relcal": sorted(relcal)}))
"""


def _probe(commands: list[list[str]]) -> tuple[dict, str]:
    """Run ``relcal ... --help`` for each of ``commands`` in one fresh interpreter: exit codes,
    the top-level modules and the relcal sub-packages it loaded, and what it printed."""
    done = subprocess.run(
        [sys.executable, "-c", PROBE, json.dumps(commands)],
        capture_output=True,
        text=True,
        check=True,
    )
    *printed, last = done.stdout.rstrip("\n").split("\n")
    return json.loads(last), "\n".join(printed)


@pytest.mark.parametrize(
    "commands",
    [[[]], [["calibrate"]], ALL_HELP],
    ids=["relcal --help", "relcal calibrate --help", "every command's --help"],
)
def test_help_imports_nothing_heavy(commands):
    loaded, printed = _probe(commands)
    assert loaded["codes"] == [0] * len(commands)
    assert printed.count("usage: relcal") == len(commands)
    assert [m for m in HEAVY if m in loaded["top"]] == []
    assert [p for p in COMPUTING if p in loaded["relcal"]] == []


def test_every_command_is_probed():
    """ALL_HELP names every registered command (a new one is checked too)."""
    from relcal.cli import build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "command")
    assert set(sub.choices) == {c[0] for c in ALL_HELP if c}


@pytest.mark.parametrize("text", ["nan", "inf", "1e999"])
def test_number_options_still_refuse_non_finite(text, capsys):
    """The option types check finiteness without NumPy, as before."""
    assert main(["plan", "--margin", text]) == 2
    err = capsys.readouterr().err
    assert "argument --margin:" in err and text in err
    assert "expected a finite number" in err or "too large to be a number" in err
