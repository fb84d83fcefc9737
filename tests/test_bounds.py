"""Bounded on any input, and nothing shown that the user did not mean to show: YAML alias
expansion and nesting capped in the one YAML loader (every YAML read goes through it), a file
named in the wrong place never read or shown (``robot:`` naming a secret file, in a single
calibration or a fleet, on the terminal, in fleet.json and fleet.html), and text from files
shown to a terminal stripped of control characters."""

from __future__ import annotations

import ast
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import pytest
from helpers_dataset import synthetic_dataset

from relcal.cli import main

SRC = Path(__file__).resolve().parent.parent / "src" / "relcal"
CANARY = "CANARY-7f3a9c-TOP-SECRET"


def laughs(levels: int = 9, width: int = 9, mapping: bool = False) -> str:
    """A 'billion laughs' YAML document: each level ``width`` aliases of the one below."""
    lines = ['a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for k in range(1, levels):
        if mapping:
            body = ", ".join(f"k{i}: *a{k - 1}" for i in range(width))
            lines.append(f"a{k}: &a{k} {{{body}}}")
        else:
            lines.append(f"a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * width) + "]")
    return "\n".join(lines) + "\n"


def merges(levels: int = 8, width: int = 9) -> str:
    """Merge keys (``<<: *a``) over nested aliases."""
    lines = ['m0: &m0 {x: ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]}']
    for k in range(1, levels):
        body = ", ".join([f"*m{k - 1}"] * width)
        lines.append(f"m{k}: &m{k} {{<<: *m{k - 1}, y{k}: [{body}]}}")
    return "\n".join(lines) + "\n"


BOMBS = {
    "nested-lists": laughs(),
    "nested-mappings": laughs(mapping=True),
    "merge-keys": merges(),
    "aliases-as-keys": "k: &k ["
    + ", ".join(['"x"'] * 300)
    + "]\nm: {"
    + ", ".join(f"? *k : {i}" for i in range(400))
    + "}\n",  # noqa: E501
    "recursive": "a: &a [1, *a]\nrobot: a465\n",
    "deeply-nested": "a: " + "[" * 2000 + "]" * 2000 + "\n",
}


def dataset_folder(tmp_path: Path, spec: str) -> Path:
    root = tmp_path / "d"
    root.mkdir()
    (root / "dataset.yaml").write_text(spec)
    (root / "samples.csv").write_text("id,q1,q2,q3,q4,q5,q6,x,y,z,qx,qy,qz,qw\n")
    return root


# each way a YAML file enters relcal: the command and where the document goes
READERS = {
    "dataset.yaml": lambda tmp, doc: ["calibrate", str(dataset_folder(tmp, doc)), "--quiet"],
    "robot model": lambda tmp, doc: (
        (tmp / "arm.yaml").write_text(doc),
        ["simulate", "--robot", str(tmp / "arm.yaml"), "--quiet"],
    )[1],
    "errors file": lambda tmp, doc: (
        (tmp / "e.yaml").write_text(doc),
        ["simulate", "--errors", str(tmp / "e.yaml"), "--quiet"],
    )[1],
    "board file": lambda tmp, doc: (
        (tmp / "b.yaml").write_text(doc),
        ["board", "--spec", str(tmp / "b.yaml"), "--out", str(tmp / "b.pdf")],
    )[1],
    "rct measurements": lambda tmp, doc: (
        (tmp / "m.yaml").write_text(doc),
        ["import", "rct-positioner", str(tmp / "m.yaml"), "--out", str(tmp / "new")],
    )[1],
}


@pytest.mark.parametrize("reader", list(READERS))
@pytest.mark.parametrize("bomb", list(BOMBS))
def test_yaml_bombs_are_refused_quickly_wherever_they_enter(reader, bomb, tmp_path, capsys):
    argv = READERS[reader](tmp_path, BOMBS[bomb])
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    started = time.perf_counter()
    assert main(argv) == 2
    seconds = time.perf_counter() - started
    err = capsys.readouterr().err
    assert "Traceback" not in err and "internal error" not in err, err
    assert any(w in err for w in ("aliases", "refers to itself", "nested", "nesting")), err
    assert seconds < 10, seconds
    grown_kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before
    assert grown_kb < 200_000, grown_kb  # the 471-byte file took 2.5 GB before


def test_the_471_byte_file_of_the_issue_in_its_own_process(tmp_path):
    """In a fresh process (its whole peak memory measured): refused in seconds, in megabytes."""
    root = dataset_folder(tmp_path, laughs() + "robot: a465\n")
    code = (  # VmHWM: this process's own peak (ru_maxrss would count the forking parent's)
        "import sys; from relcal.cli import main; code = main(sys.argv[1:]); "
        "print([l for l in open('/proc/self/status') if l.startswith('VmHWM')][0].split()[1]); "
        "sys.exit(code)"
    )
    started = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-c", code, "calibrate", str(root), "--quiet"],
        capture_output=True,
        text=True,
        timeout=120,
        env={"PYTHONPATH": ":".join(sys.path), "PATH": "/usr/bin:/bin"},
    )
    assert done.returncode == 2, done.stderr
    assert time.perf_counter() - started < 30
    assert int(done.stdout.split()[-1]) < 400_000, done.stdout  # kB: well under 0.4 GB
    assert "YAML aliases" in done.stderr


def test_every_yaml_read_goes_through_the_one_loader():
    """No module but relcal.io parses YAML itself (yaml.safe_load, yaml.load, yaml.compose...
    would bypass the size and alias bounds)."""
    parsers = {"load", "safe_load", "load_all", "safe_load_all", "full_load", "compose",
               "compose_all", "unsafe_load"}  # fmt: skip
    offenders = []
    for path in SRC.rglob("*.py"):
        if path.name == "io.py" and path.parent == SRC:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if (
                isinstance(node, ast.Attribute)
                and node.attr in parsers
                and isinstance(node.value, ast.Name)
                and node.value.id == "yaml"
            ):
                offenders.append(f"{path.relative_to(SRC)}:{node.lineno}")
    assert offenders == []


# ----------------------------------------------------- files named in the wrong place


@pytest.fixture(scope="module")
def secret(tmp_path_factory):
    """A readable file of someone's secrets, in several shapes."""
    folder = tmp_path_factory.mktemp("secret")
    (folder / "secret.txt").write_text(f"password: {CANARY}\n")
    (folder / "secret.yaml").write_text(f"password: {CANARY}\napi_key: {CANARY}\n")
    (folder / "secret.csv").write_text(f"user,{CANARY}\nroot,{CANARY}\n")
    (folder / "secret.urdf").write_text(f"<robot name='{CANARY}'><link name='{CANARY}'/></robot>")
    (folder / "secret.xml").write_text(f"{CANARY}\n")
    return folder


ROBOT_ENTRIES = [
    "{s}/secret.txt",
    "{s}/secret.yaml",
    "{s}/secret.csv",
    "{s}/secret.xml",
    "/etc/passwd",
    "/etc/hostname",
    "{{urdf: {s}/secret.txt}}",
    "{{urdf: {s}/secret.yaml}}",
    "{{urdf: /etc/passwd}}",
    "{{urdf: {s}/secret.xml}}",
]


@pytest.mark.parametrize("entry", ROBOT_ENTRIES)
def test_a_robot_entry_naming_another_file_shows_nothing_of_it(entry, secret, tmp_path, capsys):
    root = synthetic_dataset(tmp_path / "d", n=8).root
    value = entry.format(s=secret)
    (root / "dataset.yaml").write_text(f"robot: {value}\njoint_unit: deg\n")
    assert main(["calibrate", str(root), "--out", str(tmp_path / "o")]) == 2
    out = capsys.readouterr()
    assert CANARY not in out.out + out.err
    assert "root:" not in out.err  # /etc/passwd's content
    assert "Traceback" not in out.err and "internal error" not in out.err, out.err


def test_a_fleet_session_naming_a_secret_file_leaks_it_nowhere(secret, tmp_path, capsys):
    """One fleet session's robot: names a secret file (as a path, as a model, as a URDF): the
    session fails with a reason that shows nothing of the file, on the terminal, in fleet.json
    and in fleet.html; the other sessions calibrate."""
    pytest.importorskip("distributed")
    plant = tmp_path / "plant"
    synthetic_dataset(plant / "good", n=16)
    for k, entry in enumerate(["{s}/secret.txt", "{s}/secret.yaml", "{{urdf: {s}/secret.xml}}"]):
        root = synthetic_dataset(plant / f"bad{k}", n=8).root
        (root / "dataset.yaml").write_text(f"robot: {entry.format(s=secret)}\n")
    report, doc = tmp_path / "fleet.html", tmp_path / "fleet.json"
    argv = ["fleet", "calibrate", str(plant), "--out", str(tmp_path / "cal"), "--workers", "1"]
    argv += ["--report", str(report)]
    assert main([*argv, "--json", str(doc)]) == 1
    out = capsys.readouterr()
    shown = out.out + out.err + report.read_text() + doc.read_text()
    assert CANARY not in shown
    entries = {e["session"]: e for e in json.loads(doc.read_text())["sessions"]}
    assert entries["good"]["status"] == "ok"
    for k in range(3):
        assert entries[f"bad{k}"]["status"] == "failed"
        assert "secret" in entries[f"bad{k}"]["reason"]  # names the file, shows none of it


def test_text_from_files_cannot_drive_the_terminal(tmp_path, capsys):
    """Sample ids and a robot id holding terminal escape sequences are shown escaped."""
    root = synthetic_dataset(tmp_path / "d", n=12).root
    text = (root / "samples.csv").read_text().replace("s003,", "\x1b[2J\x1b]0;pwned\x07s003,", 1)
    text = text.replace("s005,", "s005\u202e,", 1)  # a bidirectional override
    (root / "samples.csv").write_text(text)
    spec = (root / "dataset.yaml").read_text() + 'robot_id: "arm\\e[31m7"\n'
    (root / "dataset.yaml").write_text(spec)
    main(["calibrate", str(root), "--out", str(tmp_path / "o")])
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "dataset.yaml").write_text("robot: a465\nsamples: s.csv\n")
    (bad / "s.csv").write_text(
        "id,q1,q2,q3,q4,q5,q6,x,y,z,qx,qy,qz,qw\nz,\x1b[31mred,1,1,1,1,1,0,0,0,0,0,0,1\n"
    )
    assert main(["calibrate", str(bad)]) == 2
    out = capsys.readouterr()
    for stream in (out.out, out.err):
        assert "\x1b" not in stream and "\x07" not in stream and "\u202e" not in stream
    assert "\\x1b[31mred" in out.err  # shown, escaped
