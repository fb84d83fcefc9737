"""One output discipline for every command and API function that writes (relcal.outputset):
every destination is declared and checked before any work (never a file the run reads, never a
registry, never the working folder, never given twice), a user's files inside an output folder
survive every re-run, concurrent writers of one dataset are refused, and no lock or temporary
file outlives its run. Each refusal is followed by doing what it suggests."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sqlite3
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from helpers_dataset import synthetic_dataset

import relcal
from relcal.cli import main
from relcal.errors import RelcalError
from relcal.outputset import MARKER, File, Folder, tracking, write_set

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return synthetic_dataset(tmp_path_factory.mktemp("discipline") / "d", n=14).root


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def tree(root: Path) -> dict[str, str]:
    return {
        str(p.relative_to(root)): digest(p) if p.is_file() else "folder"
        for p in sorted(root.rglob("*"))
    }


def refused(capsys, argv, *words) -> str:
    """Run ``argv``: exit 2 with a message (one line, after argparse's usage for an option
    refused while parsing) naming ``words``; the message."""
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err and "internal error" not in err, err
    err = err.strip().splitlines()[-1]
    for word in words:
        assert word in err, err
    return err


def records(path: Path) -> int:
    with sqlite3.connect(path) as conn:
        return conn.execute("SELECT count(*) FROM calibrations").fetchone()[0]


# ------------------------------------------------------------------ never over a registry


@pytest.fixture(scope="module")
def registry(dataset, tmp_path_factory):
    """A registry with one calibration of robot ``arm1``, and that calibration's folder."""
    where = tmp_path_factory.mktemp("reg")
    path, cal = where / "h.sqlite", where / "cal"
    argv = ["calibrate", dataset, "--out", cal, "--quiet", "--registry", path]
    assert main([str(a) for a in argv]) == 0
    return path, cal


@pytest.mark.parametrize("target", ["the-registry", "its-wal", "another-registry"])
def test_no_json_is_ever_written_over_a_registry(registry, tmp_path, capsys, target):
    """``history --json`` naming the registry it reads (or its -wal, or any other registry):
    refused before any work, every record kept; the suggestion (another file) works."""
    path, _ = registry
    other = tmp_path / "other.sqlite"
    shutil.copy(path, other)
    json_path = {"the-registry": path, "its-wal": Path(f"{path}-wal"), "another-registry": other}
    before = digest(path), digest(other)
    with sqlite3.connect(path) as conn:
        (robot,) = conn.execute("SELECT robot_id FROM calibrations").fetchone()
    argv = ["history", robot, "--registry", path, "--quiet", "--json", json_path[target]]
    refused(capsys, argv, "registry", str(json_path[target].name))
    assert (digest(path), digest(other)) == before and records(path) == 1
    assert not Path(f"{path}-wal").exists() or target != "its-wal" or records(path) == 1
    argv[-1] = tmp_path / "history.json"  # the suggestion: another file
    assert main([str(a) for a in argv]) == 0, capsys.readouterr().err
    assert json.loads((tmp_path / "history.json").read_text())["runs"]


@pytest.mark.parametrize("member", ["model.yaml", "ros2/calibrated.launch.py"])
def test_no_file_output_is_written_over_a_file_of_an_output_set(registry, tmp_path, capsys, member):
    """``history --json cal/model.yaml`` wrote the history over the calibrated model (exit 0):
    the set then held a file of another run (results.json's SHA-256 no longer its model).
    Refused before any work, naming the set; a file of the user's beside the set's files (as
    ``compensate --out cal/joints.csv`` writes) is still allowed."""
    path, cal = registry
    before = tree(cal)
    with sqlite3.connect(path) as conn:
        (robot,) = conn.execute("SELECT robot_id FROM calibrations").fetchone()
    argv = ["history", robot, "--registry", path, "--quiet", "--json", cal / member]
    refused(capsys, argv, f"is a file of the output set {cal.resolve()}", MARKER)
    assert tree(cal) == before
    with pytest.raises(RelcalError, match="is a file of the output set"):
        write_set(File(cal / member, "{}"))  # the API alike
    argv[-1] = cal / "history.json"  # not one of the set's files: the user's, kept with it
    assert main([str(a) for a in argv]) == 0, capsys.readouterr().err
    (cal / "history.json").unlink()
    assert tree(cal) == before


def test_verify_never_writes_over_its_registry_and_lists_the_record(
    registry, dataset, tmp_path, capsys
):
    path, cal = registry
    before = digest(path)
    argv = ["verify", cal, dataset, "--quiet", "--registry", path, "--json", path]
    refused(capsys, argv, "registry", "h.sqlite")
    assert digest(path) == before


def test_no_lock_file_outlives_a_recorded_run(registry):
    path, _ = registry
    assert sorted(p.name for p in path.parent.iterdir() if p.name.startswith("h.sqlite")) in (
        ["h.sqlite"],
        ["h.sqlite", "h.sqlite-shm", "h.sqlite-wal"],
    )
    assert not Path(f"{path}.lock").exists()


# ------------------------------------------------------------ never a file the run reads


def test_an_input_named_as_json_is_refused_before_the_out_folder_is_written(tmp_path, capsys):
    """``import mukca DATA --json DATA/.../hole_0.csv``: the --json names a file the import
    reads; refused before --out is written (the output set checks every declared destination
    of the run at every write), the CSV untouched; another --json works."""
    source = SHARED / "mukca" / "data" / "panda_1"
    if not source.is_dir():
        pytest.skip("the shared MUKCa data are not here")
    data = tmp_path / "panda_1"
    shutil.copytree(source, data)
    csv = data / "front" / "hole_0.csv"
    before = digest(csv)
    argv = ["import", "mukca", data, "--urdf", SHARED / "mukca" / "urdf" / "panda.urdf"]
    argv += ["--tip", "ball_link", "--distance", "0.050", "--out", tmp_path / "out"]
    refused(capsys, [*argv, "--json", csv], "--json", "which this run reads")
    assert digest(csv) == before and not (tmp_path / "out").exists()
    assert main([str(a) for a in [*argv, "--json", tmp_path / "import.json"]]) == 0
    assert (tmp_path / "out" / "dataset.yaml").is_file() and digest(csv) == before


def test_two_options_naming_one_file_are_refused_before_any_work(dataset, tmp_path, capsys):
    argv = ["calibrate", dataset, "--out", tmp_path / "o", "--quiet"]
    refused(capsys, [*argv, "--json", tmp_path / "x", "--report", tmp_path / "x"], "also given as")
    assert sorted(tmp_path.iterdir()) == []


# --------------------------------------------------------------- never the working folder


def test_out_dot_and_an_empty_path_never_replace_the_working_folder(
    dataset, tmp_path, capsys, monkeypatch
):
    """``--out .`` (and a folder holding the working folder, and ``write_calibration(cal, "")``)
    are refused: an output folder is swapped as a whole, which would leave the shell in a
    deleted folder. The suggestion (a new folder name) works, and the working folder is the
    same folder (same inode) afterwards."""
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    inode = os.stat(".").st_ino
    refused(capsys, ["calibrate", dataset, "--out", ".", "--quiet"], "working folder", "results")
    refused(capsys, ["calibrate", dataset, "--out", "..", "--quiet"], "working folder")
    assert os.stat(".").st_ino == inode and os.path.samefile(".", work)
    with tracking():
        cal = relcal.calibrate(relcal.load_dataset(dataset))
        for bad in ("", ".", str(work)):
            with pytest.raises(RelcalError, match="working folder|empty path|out_dir: expected"):
                relcal.write_calibration(cal, bad)
        assert os.stat(".").st_ino == inode and list(work.iterdir()) == []
        relcal.write_calibration(cal, "results")  # the suggestion
    assert (work / "results" / "model.yaml").is_file() and os.stat(".").st_ino == inode


# ------------------------------------------------------- a user's files are never deleted


def test_a_users_file_inside_an_output_folder_survives_every_rerun(dataset, tmp_path, capsys):
    """A file of the user's inside ``cal/`` (say, the joints ``compensate --out cal/joints.csv``
    wrote) and a folder of notes are kept in ``cal/`` by every recalibration, never moved to
    ``cal.prev`` and deleted with it; one inside ``cal.prev`` moves with the set kept there."""
    cal = tmp_path / "cal"
    argv = ["calibrate", dataset, "--out", cal, "--quiet"]
    assert main([str(a) for a in argv]) == 0
    (cal / "joints.csv").write_text("id,q1\np1,0.5\n")
    (cal / "notes").mkdir()
    (cal / "notes" / "cell.txt").write_text("board moved on Tuesday\n")
    for seed in (1, 2, 3):
        assert main([str(a) for a in [*argv, "--seed", seed]]) == 0, capsys.readouterr().err
        assert (cal / "joints.csv").read_text() == "id,q1\np1,0.5\n"
        assert (cal / "notes" / "cell.txt").read_text() == "board moved on Tuesday\n"
        manifest = json.loads((cal / MARKER).read_text())["files"]
        assert "joints.csv" not in manifest and (cal / "model.yaml").is_file()
    (tmp_path / "cal.prev" / "mine.txt").write_text("kept\n")
    assert main([str(a) for a in [*argv, "--seed", 4]]) == 0
    assert (tmp_path / "cal.prev" / "mine.txt").read_text() == "kept\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cal", "cal.prev"]


def test_a_users_file_named_like_a_new_output_is_refused_then_the_suggestion_works(tmp_path):
    out = tmp_path / "set"
    write_set(Folder(out, {"a.txt": "1"}))
    (out / "b.txt").write_text("the user's\n")
    with pytest.raises(RelcalError, match="b.txt was not written by relcal") as info:
        write_set(Folder(out, {"a.txt": "2", "b.txt": "2"}))
    assert "move it out of the folder" in str(info.value)
    assert (out / "b.txt").read_text() == "the user's\n" and (out / "a.txt").read_text() == "1"
    (out / "b.txt").rename(tmp_path / "b.txt")  # the suggestion
    write_set(Folder(out, {"a.txt": "2", "b.txt": "2"}))
    assert (out / "b.txt").read_text() == "2" and (tmp_path / "b.txt").is_file()


def test_user_files_survive_a_failed_install(tmp_path, monkeypatch):
    """A failure between the renames puts every file back where it was, the user's too."""
    from relcal import outputset

    out = tmp_path / "set"
    write_set(Folder(out, {"a.txt": "1"}))
    write_set(Folder(out, {"a.txt": "2"}))
    (out / "mine.txt").write_text("mine")
    (tmp_path / "set.prev" / "old.txt").write_text("old")
    real = outputset._carry
    calls = []

    def failing(src, dst, names, undo):
        real(src, dst, names, undo)
        calls.append(names)
        if len(calls) == 2:
            raise OSError("disk full")

    monkeypatch.setattr(outputset, "_carry", failing)
    with pytest.raises(RelcalError, match="disk full"):
        write_set(Folder(out, {"a.txt": "3"}))
    assert (out / "a.txt").read_text() == "2" and (out / "mine.txt").read_text() == "mine"
    assert (tmp_path / "set.prev" / "a.txt").read_text() == "1"
    assert (tmp_path / "set.prev" / "old.txt").read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["set", "set.prev"]


# --------------------------------------------------------- one writer of a dataset at a time

HOLDER = textwrap.dedent(
    """
    import sys, time
    from relcal.capture.record import claim
    with claim(sys.argv[1], True):
        print("held", flush=True)
        sys.stdin.readline()
    """
)


def test_a_second_writer_of_a_capture_folder_is_refused_and_no_lock_stays(tmp_path):
    """Two ``capture --resume`` of one dataset at once: the second is refused naming the
    folder and the first run's process (it would otherwise write over the first's log); once
    the first is done, doing what the message says (run again) works, and no lock file is
    left behind."""
    from relcal.capture.record import LOCK, LOG, claim

    root = tmp_path / "ds"
    root.mkdir()
    (root / LOG).write_text("{}")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    proc = subprocess.Popen(
        [sys.executable, "-c", HOLDER, str(root)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        assert proc.stdout.readline() == "held\n"
        with pytest.raises(RelcalError) as info:
            with claim(root, True):
                pass
        message = str(info.value)
        assert f"--out {root}" in message and f"process {proc.pid}" in message
        assert "wait until it has finished" in message
    finally:
        proc.communicate("done\n", timeout=60)
    assert not (root / LOCK).exists()
    with claim(root, True):  # the suggestion: run again once the other has finished
        assert (root / LOCK).is_file()
    assert sorted(p.name for p in root.iterdir()) == [LOG]


def test_a_killed_writers_lock_does_not_block_the_next_run(tmp_path):
    from relcal.capture.record import LOCK, LOG, claim

    root = tmp_path / "ds"
    root.mkdir()
    (root / LOG).write_text("{}")
    (root / LOCK).write_text("999999\n")  # left by a run killed with SIGKILL: nobody holds it
    with claim(root, True):
        pass
    assert not (root / LOCK).exists()


def test_a_file_output_is_never_written_into_an_existing_registry_by_the_api(tmp_path):
    path = tmp_path / "r.sqlite"
    with sqlite3.connect(path) as conn:
        conn.execute("CREATE TABLE t (x)")
    before = digest(path)
    with pytest.raises(RelcalError, match="registry"):
        write_set(File(path, "{}"))
    assert digest(path) == before


# ------------------------------------------- after an interrupt: every output committed, named


@pytest.mark.parametrize(
    ("point", "code"), [("term-during-install", 143), ("kill-after-insert", -9)]
)
def test_verify_writes_its_json_and_its_record_as_one_and_says_so(
    registry, tmp_path_factory, point, code
):
    """``verify --registry --json``: the JSON and the verification record are one transaction.
    SIGTERM during the install: both are in place and the message lists both (the registry
    record included); a kill after the insert: neither."""
    from test_transaction import run_driver

    path, cal = registry
    session = synthetic_dataset(tmp_path_factory.mktemp("session") / "s", n=14, seed=5).root
    out = session.parent / "v.json"
    with sqlite3.connect(path) as conn:
        before = conn.execute("SELECT count(*) FROM verifications").fetchone()[0]
    argv = ["verify", str(cal), str(session), "--quiet", "--registry", str(path)]
    done = run_driver(point, [*argv, "--json", str(out)])
    assert done.returncode == code, done.stderr
    with sqlite3.connect(path) as conn:
        after = conn.execute("SELECT count(*) FROM verifications").fetchone()[0]
    if code == 143:
        assert after == before + 1 and json.loads(out.read_text())["verification_id"] == after
        assert f"--json {out}" in done.stderr, done.stderr
        assert f"registry {path} verification {after}" in done.stderr, done.stderr
    else:
        assert after == before and not out.exists()
