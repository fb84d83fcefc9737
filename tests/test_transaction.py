"""Everything a run writes is one transaction: the registry is opened and checked before any work
(a refusal names it, nothing is written), the record goes in with the set it describes (if one
fails, neither is there), an interrupt or a kill at any moment leaves the old outputs or the new
ones with their record, the message says which, and no file appears outside the output folder,
the registry and its lock."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest
from helpers_dataset import synthetic_dataset
from test_output_sets import whole_set

from relcal.cli import main
from relcal.fleet import registry as reg

HERE = Path(__file__).parent


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return synthetic_dataset(tmp_path_factory.mktemp("tx") / "d", n=16).root


def tree(root: Path) -> dict[str, str]:
    """Every file under ``root`` (hidden ones too) and its SHA-256, and every folder."""
    return {
        str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
        if p.is_file()
        else "folder"
        for p in sorted(root.rglob("*"))
    }


def records(path: Path) -> list[tuple[str, str]]:
    """``(uid, outputs_path)`` of every record in a SQLite registry (read without relcal)."""
    if not path.exists():
        return []
    conn = sqlite3.connect(path)
    try:
        return conn.execute("SELECT uid, outputs_path FROM calibrations ORDER BY id").fetchall()
    finally:
        conn.close()


def copy_dataset(dataset: Path, to: Path) -> Path:
    to.mkdir(parents=True)
    for p in dataset.iterdir():
        if p.is_file():
            (to / p.name).write_bytes(p.read_bytes())
    return to


# ------------------------------------------------------------- the registry, checked first


def _sqlite(path: Path, setup) -> None:
    conn = sqlite3.connect(path)
    try:
        with conn:
            setup(conn)
    finally:
        conn.close()


def _registry_of_relcal(path: Path) -> None:
    with reg.Registry(reg.registry_url(path)):
        pass


def _newer_schema(path: Path) -> None:
    _registry_of_relcal(path)
    _sqlite(path, lambda c: c.execute("UPDATE alembic_version SET version_num = '0099'"))


def _corrupt_pages(path: Path) -> None:
    _registry_of_relcal(path)
    data = bytearray(path.read_bytes())
    data[100:] = os.urandom(len(data) - 100)  # the header says SQLite, the pages are noise
    path.write_bytes(bytes(data))


def _truncated(path: Path) -> None:
    _registry_of_relcal(path)
    _sqlite(path, lambda c: c.execute("CREATE TABLE pad (x)"))
    _sqlite(path, lambda c: c.executemany("INSERT INTO pad VALUES (?)", [("x" * 500,)] * 200))
    path.write_bytes(path.read_bytes()[: 3 * 4096 + 17])


REFUSED = [
    # (id, registry path (relative to the case folder, {d} the dataset), setup, message parts)
    ("a-folder", "reg", lambda p: p.mkdir(), ("is a folder",)),
    ("the-samples-file", "{d}/samples.csv", None, ("this run reads", "input")),
    ("the-dataset-yaml", "{d}/dataset.yaml", None, ("this run reads",)),
    ("the-holdout-id-file", "ids.txt", None, ("this run reads",)),
    ("a-text-file", "notes.txt", lambda p: p.write_text("my notes\n"), ("not a SQLite database",)),
    ("random-bytes", "r.sqlite", lambda p: p.write_bytes(os.urandom(5000)), ("not a SQLite",)),
    ("corrupt-pages", "c.sqlite", _corrupt_pages, ("corrupt",)),
    ("truncated", "t.sqlite", _truncated, ("corrupt",)),
    (
        "another-programs-database",
        "places.sqlite",
        lambda p: _sqlite(p, lambda c: c.execute("CREATE TABLE moz_places (url TEXT)")),
        ("another program", "moz_places"),
    ),
    ("a-newer-schema", "n.sqlite", _newer_schema, ("newer than this relcal", "0099")),
    ("in-a-missing-folder", "nowhere/h.sqlite", None, ("does not exist",)),
    ("inside-the-output-folder", "out/h.sqlite", None, ("inside the output folder",)),
    ("the-json-output", "r.json", None, ("also given as", "--json")),
    ("a-device", "/dev/null", None, ("not a regular file",)),
]


@pytest.mark.parametrize(
    ("where", "setup", "expect"), [pytest.param(*c[1:], id=c[0]) for c in REFUSED]
)
def test_a_registry_that_cannot_be_one_is_refused_before_any_work(
    dataset, tmp_path, capsys, monkeypatch, where, setup, expect
):
    """Exit 2 naming the registry; no output, no record, no lock file, every file as it was."""
    copy_dataset(dataset, tmp_path / "d")
    (tmp_path / "ids.txt").write_text("s001\ns002\n")
    path = Path(where.replace("{d}", str(tmp_path / "d")))
    path = path if path.is_absolute() else tmp_path / path
    if setup is not None:
        setup(path)
    worked = []
    from relcal.calibration.kinds import poses

    monkeypatch.setattr(poses, "check_dataset", lambda *a: worked.append(1) or {})
    before = tree(tmp_path)
    argv = ["calibrate", str(tmp_path / "d"), "--out", str(tmp_path / "out"), "--quiet"]
    argv += ["--registry", str(path), "--json", str(tmp_path / "r.json")]
    argv += ["--holdout-ids", f"@{tmp_path / 'ids.txt'}"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "registry" in err and str(path) in err, err
    for part in expect:
        assert part in err, err
    assert "Traceback" not in err and "internal error" not in err and err.count("\n") == 1
    assert worked == []  # refused before the computation
    assert tree(tmp_path) == before  # nothing written, no lock beside an input


def test_a_read_only_registry_is_refused(dataset, tmp_path, capsys):
    """A registry file that cannot be written (immutable: even root cannot write it)."""
    path = tmp_path / "h.sqlite"
    _registry_of_relcal(path)
    if os.geteuid() == 0:
        if subprocess.run(["chattr", "+i", str(path)], capture_output=True).returncode:
            pytest.skip("chattr +i not available here")
    else:
        path.chmod(0o444)
    try:
        out = tmp_path / "out"
        argv = ["calibrate", str(dataset), "--out", str(out), "--quiet", "--registry", str(path)]
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert f"registry {path}" in err and "read-only" in err, err
        assert not out.exists()
    finally:
        if os.geteuid() == 0:
            subprocess.run(["chattr", "-i", str(path)])


def test_an_unreachable_server_is_refused_before_any_work(dataset, tmp_path, capsys):
    pytest.importorskip("psycopg")
    url = "postgresql+psycopg://relcal@127.0.0.1:1/relcal"
    out = tmp_path / "out"
    assert main(["calibrate", str(dataset), "--out", str(out), "--quiet", "--registry", url]) == 2
    err = capsys.readouterr().err
    assert "registry postgresql" in err and "cannot open" in err, err
    assert not out.exists()


def test_a_new_registry_is_created_with_its_first_record_only(dataset, tmp_path, capsys):
    """A refused run leaves no registry behind; a finished one creates it with its record, and
    the only files it adds are the output folder and the registry (its migration lock is
    removed once released: no lock file outlives the run)."""
    bad = copy_dataset(dataset, tmp_path / "bad")
    (bad / "dataset.yaml").write_text("robot: ur5e\njoint_unit: deg\n")  # another robot
    path = tmp_path / "h.sqlite"
    argv = ["calibrate", str(bad), "--out", str(tmp_path / "o"), "--quiet"]
    assert main([*argv, "--registry", str(path)]) == 2
    assert not path.exists() and not (tmp_path / "h.sqlite.lock").exists()
    capsys.readouterr()
    work = tmp_path / "work"
    copy_dataset(dataset, work / "d")
    before = set(tree(work))
    out = work / "cal"
    assert main(["calibrate", str(work / "d"), "--out", str(out), "--quiet", "--registry",
                 str(work / "h.sqlite")]) == 0  # fmt: skip
    added = {p.split("/")[0] for p in set(tree(work)) - before}
    assert added == {"cal", "h.sqlite"}, added
    (uid, outputs), = records(work / "h.sqlite")  # fmt: skip
    assert outputs == str(out.resolve())


# ------------------------------------------------------- the record and the set, together


def test_a_failed_commit_undoes_the_install(dataset, tmp_path, capsys, monkeypatch):
    out, path = tmp_path / "cal", tmp_path / "h.sqlite"
    argv = ["calibrate", str(dataset), "--out", str(out), "--quiet", "--registry", str(path)]
    assert main(argv) == 0
    old, first = whole_set(out), records(path)
    real = reg.PendingRecord.commit

    def failing(self):
        self._txn.rollback()  # the database refuses the commit (a full disk, a lost server)
        self._close()
        raise reg.RelcalError(f"registry {self.registry.name}: recording failed: disk I/O error")

    monkeypatch.setattr(reg.PendingRecord, "commit", failing)
    assert main([*argv, "--seed", "3"]) == 2
    err = capsys.readouterr().err
    assert "recording failed" in err and "nothing written" in err, err
    assert whole_set(out) == old and records(path) == first
    assert sorted(p.name for p in tmp_path.iterdir() if not p.name.startswith("h.")) == ["cal"]
    monkeypatch.setattr(reg.PendingRecord, "commit", real)
    assert main([*argv, "--seed", "4"]) == 0
    assert whole_set(out) != old and len(records(path)) == 2


def test_a_failed_install_rolls_the_record_back(dataset, tmp_path, capsys, monkeypatch):
    from relcal import outputset

    out, path = tmp_path / "cal", tmp_path / "h.sqlite"
    argv = ["calibrate", str(dataset), "--out", str(out), "--quiet", "--registry", str(path)]
    assert main(argv) == 0
    old, first = whole_set(out), records(path)

    def failing(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(outputset, "_commit_folder", failing)
    assert main([*argv, "--seed", "3"]) == 2
    assert "No space left" in capsys.readouterr().err
    assert whole_set(out) == old and records(path) == first


DRIVER = """
import os, signal, sys
sys.path.insert(0, sys.argv[1])
from relcal import outputset
from relcal.fleet import registry
from relcal.cli import main

point, argv = sys.argv[2], sys.argv[3:]
real_prepare, real_commit = registry.PendingRecord.prepare, registry.PendingRecord.commit
real_write = outputset.write_set


def prepare(self):
    real_prepare(self)
    if point == "kill-after-insert":
        os.kill(os.getpid(), signal.SIGKILL)


def commit(self):
    if point == "term-during-install":
        os.kill(os.getpid(), signal.SIGTERM)  # held back until the install is complete
    real_commit(self)
    if point == "kill-after-commit":
        os.kill(os.getpid(), signal.SIGKILL)


def write_set(*items, **kwargs):
    paths = real_write(*items, **kwargs)
    if point in ("int-after-install", "term-after-install"):
        sig = signal.SIGINT if point.startswith("int") else signal.SIGTERM
        os.kill(os.getpid(), sig)
    return paths


registry.PendingRecord.prepare, registry.PendingRecord.commit = prepare, commit
import relcal.reporting.outputs as outputs  # noqa: E402

outputs.write_set = write_set
sys.exit(main(argv))
"""


def run_driver(point: str, argv: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", DRIVER, str(HERE), point, *argv],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
    )


@pytest.mark.parametrize(
    ("point", "code", "installed", "says"),
    [
        ("term-during-install", 143, True, "already written"),
        ("int-after-install", 130, True, "already written"),
        ("term-after-install", 143, True, "already written"),
        ("kill-after-insert", -9, False, None),
        ("kill-after-commit", -9, True, None),
    ],
)
def test_signals_around_the_install(dataset, tmp_path, point, code, installed, says):
    """A real signal at a chosen moment of a recorded calibration (run in its own process):
    the set and its record are both there or both not, the old set otherwise, and the message
    says which; a killed run's temporaries are removed by the next run."""
    out, path = tmp_path / "cal", tmp_path / "h.sqlite"
    argv = ["calibrate", str(dataset), "--out", str(out), "--quiet", "--registry", str(path)]
    assert main(argv) == 0
    old, first = whole_set(out), records(path)
    done = run_driver(point, [*argv, "--seed", "7"])
    assert done.returncode == code, done.stderr
    now = whole_set(out)
    rows = records(path)
    if installed:
        assert now != old and len(rows) == len(first) + 1
        run = json.loads((out / "results.json").read_text())["run_id"]
        assert rows[-1][1] == str(out.resolve()) and run == now
        assert whole_set(tmp_path / "cal.prev") == old
    else:
        assert now == old and rows == first
    if says is not None:
        assert says in done.stderr and f"--out {out}" in done.stderr, done.stderr
        assert f"registry {path} run" in done.stderr, done.stderr
    assert main([*argv, "--seed", "8"]) == 0  # the next run: whole, and it cleans up
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names[:3] == ["cal", "cal.prev", "h.sqlite"], names
    assert set(names[3:]) <= {"h.sqlite.lock"}, names  # only after a SIGKILL during a migration


def test_an_interrupt_before_the_install_says_nothing_was_written(dataset, tmp_path):
    out = tmp_path / "cal"
    argv = ["calibrate", str(dataset), "--out", str(out), "--quiet"]
    assert main(argv) == 0
    old = whole_set(out)
    driver = (
        "import os, signal, sys\n"
        f"sys.path.insert(0, {str(HERE)!r})\n"
        "from relcal.calibration import pipeline\n"
        "from relcal.cli import main\n"
        "real = pipeline.bootstrap_std\n"
        "def interrupted(*a, **k):\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "    return real(*a, **k)\n"
        "pipeline.bootstrap_std = interrupted\n"
        "sys.exit(main(sys.argv[1:]))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", driver, *argv, "--seed", "2"],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
    )
    assert done.returncode == 130, done.stderr
    assert "interrupted; nothing written (earlier outputs left as they were)" in done.stderr
    assert whole_set(out) == old


# ------------------------------------------------------------------------------- the fleet


def test_a_fleet_interrupted_after_its_first_session_is_consistent(tmp_path):
    """``relcal fleet calibrate`` interrupted (SIGINT) once its first session is recorded: every
    session's outputs are there, whole, exactly when its record is."""
    pytest.importorskip("distributed")
    from helpers_fleet import make_robot, write_session

    root = tmp_path / "plant"
    for i in range(4):
        write_session(root / f"r{i}" / "s1", make_robot("a465", f"r{i}", 60 + i), 300 + i, n=20)
    path = tmp_path / "h.sqlite"
    cli = "import sys; from relcal.cli import main; sys.exit(main(sys.argv[1:]))"
    cal = tmp_path / "cal"
    argv = [sys.executable, "-c", cli, "fleet", "calibrate", str(root), "--out", str(cal)]
    argv += ["--workers", "1", "--registry", str(path), "--quiet"]
    proc = subprocess.Popen(
        argv,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
    )
    deadline = time.time() + 240
    while time.time() < deadline and proc.poll() is None:
        try:
            if records(path):
                break
        except sqlite3.Error:
            pass
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    rows = records(path)
    assert rows, err
    recorded = {outputs for _, outputs in rows}
    for session in sorted(root.glob("r*/s1")):
        out = cal / session.relative_to(root)
        if str(out.resolve()) in recorded:
            whole_set(out)
        else:
            assert not out.exists(), (session, err)
    leftovers = [p for p in tmp_path.rglob("*.tmp-*")]
    assert sorted(p.name for p in root.rglob("*") if p.is_dir() and p.name != "images") == [
        "r0",
        "r1",
        "r2",
        "r3",
        "s1",
        "s1",
        "s1",
        "s1",
    ]  # nothing written into the input tree
    assert leftovers == [], leftovers
    if proc.returncode == 130:
        assert "already written" in err, err


def test_a_set_written_while_another_is_staged_does_not_wait_on_itself(tmp_path):
    """A set written inside the staging folder of another set of the same run (the synthetic
    images of ``relcal simulate --images`` go into the output set as they are rendered): the
    folder locks and the lock of the run's own temporary are taken again, not waited for. In a
    child process, so that a deadlock fails the test instead of hanging the suite."""
    code = (
        "import sys\n"
        "from pathlib import Path\n"
        "from relcal.io import write_text\n"
        "from relcal.outputset import Folder, write_set\n"
        "def fill(folder):\n"
        "    write_text(folder / 'inner.txt', 'inner')\n"
        "    write_text(folder / 'sub' / 'deeper.txt', 'deeper')\n"
        "write_set(Folder(Path(sys.argv[1]), {'outer.txt': 'outer'}, fill=fill))\n"
    )
    out = tmp_path / "set"
    done = subprocess.run(
        [sys.executable, "-c", code, str(out)], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr
    assert (out / "outer.txt").read_text() == "outer"
    assert (out / "inner.txt").read_text() == "inner"
    assert (out / "sub" / "deeper.txt").read_text() == "deeper"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["set"]  # no temporaries left
