"""Outputs as one set: whole or not at all, the previous set kept, nothing the run read written
over, devices written into, and a calibration interrupted at random moments leaves the old set or
the new one, whole."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import sys
from pathlib import Path

import pytest
from helpers_dataset import synthetic_dataset

from relcal import outputset
from relcal.calibration import pipeline
from relcal.cli import main
from relcal.errors import RelcalError
from relcal.io import File, Folder, write_set
from relcal.outputset import MARKER
from relcal.reporting.outputs import RUN_ID_PREFIX


def whole_set(folder: Path) -> str:
    """The run id of the calibration set in ``folder``; fails unless the set is whole: every file
    of its manifest present, nothing else, and results.json and model.yaml of the same run."""
    manifest = json.loads((folder / MARKER).read_text())
    present = sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())
    assert present == sorted([*manifest["files"], MARKER])
    assert {"model.yaml", "robot.urdf", "parameters.csv", "results.json"} <= set(present)
    run = manifest["run_id"]
    assert json.loads((folder / "results.json").read_text())["run_id"] == run
    assert (folder / "model.yaml").read_text().splitlines()[0] == RUN_ID_PREFIX + run
    return run


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return synthetic_dataset(tmp_path_factory.mktemp("ds") / "d", n=16).root


def calibrate(dataset, out, *extra):
    return main(["calibrate", str(dataset), "--out", str(out), "--quiet", *map(str, extra)])


def test_previous_set_kept_as_prev(dataset, tmp_path):
    out = tmp_path / "cal"
    assert calibrate(dataset, out) == 0
    first = whole_set(out)
    assert calibrate(dataset, out, "--seed", 1) == 0
    second = whole_set(out)
    assert whole_set(tmp_path / "cal.prev") == first != second
    assert calibrate(dataset, out, "--seed", 2) == 0  # one generation: the oldest is gone
    assert whole_set(tmp_path / "cal.prev") == second
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cal", "cal.prev"]  # no temporaries


def test_a_run_that_does_not_converge_writes_nothing(dataset, tmp_path, monkeypatch, capsys):
    out, doc = tmp_path / "cal", tmp_path / "r.json"
    assert calibrate(dataset, out) == 0
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    real = pipeline._fit

    def not_converged(*args, **kwargs):
        return dataclasses.replace(real(*args, **kwargs), stopped=False)

    monkeypatch.setattr(pipeline, "_fit", not_converged)
    assert calibrate(dataset, out, "--seed", 5, "--json", doc) == 1
    assert "did not converge; nothing written" in capsys.readouterr().err
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before


def test_internal_error_is_one_line_exit_3_and_a_traceback_on_request(
    dataset, tmp_path, monkeypatch, capsys
):
    def bug(*args, **kwargs):
        raise ZeroDivisionError("planted")

    monkeypatch.setattr(pipeline, "_fit", bug)
    assert calibrate(dataset, tmp_path / "o") == 3
    err = capsys.readouterr().err
    assert "internal error: ZeroDivisionError: planted; please report" in err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    monkeypatch.setenv("RELCAL_DEBUG", "1")
    with pytest.raises(ZeroDivisionError):
        calibrate(dataset, tmp_path / "o")
    assert not (tmp_path / "o").exists()


def test_interrupt_during_the_lazy_report_import(dataset, tmp_path, monkeypatch, capsys):
    import builtins

    real_import = builtins.__import__

    def interrupted(name, *args, **kwargs):
        if name in ("relcal.reporting.html", "matplotlib"):
            raise KeyboardInterrupt
        return real_import(name, *args, **kwargs)

    monkeypatch.delitem(__import__("sys").modules, "relcal.reporting.html", raising=False)
    monkeypatch.setattr(builtins, "__import__", interrupted)
    assert calibrate(dataset, tmp_path / "o", "--report", tmp_path / "r.html") == 130
    err = capsys.readouterr().err
    assert "interrupted" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(("sig", "code"), [("SIGINT", 130), ("SIGTERM", 143)])
@pytest.mark.parametrize("afterwards", ["fails", "goes_on"])
def test_an_interrupt_a_library_swallows_still_ends_the_run_as_interrupted(
    dataset, tmp_path, monkeypatch, capsys, sig, code, afterwards
):
    """Like trimesh's optional imports (``except BaseException``): the signal's exception never
    reaches relcal, and the library fails later with an unrelated error, or carries on."""
    real = pipeline._fit

    def swallowing(*args, **kwargs):
        try:
            signal.raise_signal(getattr(signal, sig))
        except BaseException:  # noqa: BLE001 - what such a library does
            pass
        if afterwards == "fails":
            raise TypeError("unsupported operand type(s) for |: 'ExceptionWrapper' and 'NoneType'")
        return real(*args, **kwargs)

    monkeypatch.setattr(pipeline, "_fit", swallowing)
    assert calibrate(dataset, tmp_path / "o") == code
    err = capsys.readouterr().err
    assert "internal error" not in err and "Traceback" not in err
    assert ("terminated" if sig == "SIGTERM" else "interrupted") in err
    if afterwards == "fails":
        assert "nothing written" in err and list(tmp_path.iterdir()) == []
    else:  # the run finished its outputs before it could stop: whole, and named
        assert "already written, each whole" in err and whole_set(tmp_path / "o")


def importable(tmp_path: Path, monkeypatch, name: str, body: str) -> None:
    """A module ``name`` with source ``body`` on the import path, for this test only."""
    (tmp_path / "lib").mkdir()
    (tmp_path / "lib" / f"{name}.py").write_text(body)
    monkeypatch.syspath_prepend(tmp_path / "lib")


@pytest.mark.parametrize(("sig", "code"), [("SIGINT", 130), ("SIGTERM", 143)])
def test_an_interrupt_during_an_import_arrives_once_the_import_is_done(
    dataset, tmp_path, monkeypatch, capsys, sig, code
):
    """A signal inside a module body (a nanobind extension aborts the process when its
    initialisation meets an exception) waits for the import to finish, then stops the run."""
    import importlib
    import time

    importable(
        tmp_path,
        monkeypatch,
        "fragile_module",
        "import signal\n"
        "intact = False\n"
        f"signal.raise_signal(signal.{sig})\n"
        "sum(range(100_000))  # the interpreter checks for signals while this runs\n"
        "intact = True\n",
    )
    seen: dict[str, object] = {}

    def importing(*args, **kwargs):
        module = importlib.import_module("fragile_module")
        seen["intact"] = module.intact
        start = time.perf_counter()
        try:
            time.sleep(30)  # the re-delivered signal ends this
        finally:
            seen["waited"] = time.perf_counter() - start

    monkeypatch.setattr(pipeline, "_fit", importing)
    assert calibrate(dataset, tmp_path / "o") == code
    assert seen["intact"] is True and seen["waited"] < 5, seen
    err = capsys.readouterr().err
    assert ("terminated" if sig == "SIGTERM" else "interrupted") in err and "Traceback" not in err
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    sys.modules.pop("fragile_module", None)


def test_an_import_that_hangs_is_still_interrupted(dataset, tmp_path, monkeypatch, capsys):
    """Deferred, not ignored: a signal inside an import that does not finish stops the run after
    a few seconds."""
    import importlib
    import time

    importable(
        tmp_path,
        monkeypatch,
        "hanging_module",
        "import signal, time\nsignal.raise_signal(signal.SIGINT)\ntime.sleep(60)\n",
    )
    monkeypatch.setattr(pipeline, "_fit", lambda *a, **k: importlib.import_module("hanging_module"))
    start = time.perf_counter()
    assert calibrate(dataset, tmp_path / "o") == 130
    assert time.perf_counter() - start < 30
    assert "interrupted" in capsys.readouterr().err and "hanging_module" not in sys.modules


def test_json_to_a_device_is_written_into_not_replaced(dataset, tmp_path, capfd):
    assert calibrate(dataset, tmp_path / "o", "--json", "/dev/stdout") == 0
    out = capfd.readouterr().out
    assert json.loads(out)["run_id"] == whole_set(tmp_path / "o")
    assert Path("/dev/null").is_char_device()
    assert calibrate(dataset, tmp_path / "o", "--json", "/dev/null") == 0
    assert Path("/dev/null").is_char_device()


def test_a_symbolic_link_keeps_pointing_at_the_replaced_file(tmp_path):
    target, link = tmp_path / "real.json", tmp_path / "link.json"
    target.write_text("old\n")
    link.symlink_to(target)
    write_set(File(link, "new\n"))
    assert link.is_symlink() and target.read_text() == "new\n"


def test_fifo_is_written_into(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    reader = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)
    try:
        write_set(File(fifo, "through the pipe\n"))
        assert os.read(reader, 100) == b"through the pipe\n"
    finally:
        os.close(reader)
    assert fifo.is_fifo()


def _set_files(run: str) -> dict[str, str]:
    return {
        "model.yaml": f"{RUN_ID_PREFIX}{run}\nname: x\n",
        "results.json": json.dumps({"run_id": run}),
        "robot.urdf": "<robot/>",
        "parameters.csv": "name\n",
    }


STEPS = ("_write_bytes", "_fsync_path", "_exchange", "_flock")


def _count_steps(monkeypatch, on_step, names=STEPS[:-1]) -> dict:
    """Route every file-system step of a write (file written, fsync, exchange, rename; not the
    locks, whose failures only mean no lock) through ``on_step(n)``, ``n`` counting from 1."""
    steps = {"n": 0}

    def counted(fn):
        def wrapped(*args, **kwargs):
            steps["n"] += 1
            on_step(steps["n"])
            return fn(*args, **kwargs)

        return wrapped

    for name in names:
        monkeypatch.setattr(outputset, name, counted(getattr(outputset, name)))
    monkeypatch.setattr(outputset.os, "rename", counted(os.rename))
    monkeypatch.setattr(outputset.os, "replace", counted(os.replace))
    return steps


def test_a_failure_at_any_step_of_the_write_leaves_the_old_sets(tmp_path, monkeypatch):
    """Each file-system step of a write (file written, fsync, exchange, rename) fails in turn:
    the folder and its .prev hold the old sets, whole, every time, and nothing is left over."""
    out = tmp_path / "cal"
    write_set(Folder(out, _set_files("older"), run_id="older"))
    write_set(Folder(out, _set_files("old"), run_id="old"))
    fail = {"at": -1}

    def on_step(n):
        if n == fail["at"]:
            raise OSError(5, "planted failure")

    steps = _count_steps(monkeypatch, on_step)
    write_set(Folder(out, _set_files("probe"), run_id="probe"))  # count the steps once
    total = steps["n"]
    write_set(Folder(out, _set_files("old"), run_id="old"))
    write_set(Folder(out, _set_files("old"), run_id="old"))  # .prev is "old" too now
    assert total >= 10
    for k in range(1, total + 1):
        steps["n"], fail["at"] = 0, k
        try:
            write_set(Folder(out, _set_files(f"r{k}"), run_id=f"r{k}"))
        except RelcalError as exc:
            assert "nothing written" in str(exc)
        else:  # a step after the commit point (the oldest set's removal): the new set
            assert whole_set(out) == f"r{k}"
            write_set(Folder(out, _set_files("old"), run_id="old"))
            write_set(Folder(out, _set_files("old"), run_id="old"))
            continue
        assert whole_set(out) == "old" and whole_set(tmp_path / "cal.prev") == "old", k
        assert sorted(p.name for p in tmp_path.iterdir()) == ["cal", "cal.prev"], k


KILLER = """
import json, os, signal, sys
sys.path.insert(0, sys.argv[1])
from pathlib import Path
from relcal import outputset
from relcal.outputset import Folder, write_set
from test_output_sets import STEPS, _set_files

out, kill_at = Path(sys.argv[2]), int(sys.argv[3])
steps = {"n": 0}


def counted(fn):
    def wrapped(*args, **kwargs):
        steps["n"] += 1
        if steps["n"] == kill_at:
            os.kill(os.getpid(), signal.SIGKILL)  # a crash right here
        return fn(*args, **kwargs)

    return wrapped


for name in STEPS:
    setattr(outputset, name, counted(getattr(outputset, name)))
os.rename, os.replace = counted(os.rename), counted(os.replace)
write_set(Folder(out, _set_files("new"), run_id="new"))
print(steps["n"])
"""


def test_a_sigkill_at_any_step_leaves_whole_sets_and_the_next_run_cleans_up(tmp_path):
    """A run killed with SIGKILL at each file-system step of its write in turn: the folder holds
    the old set or the new one, whole, ``.prev`` a whole set (the previous one, or the one before
    when the kill came between the two exchanges), and the next run removes what the killed one
    left (and nothing else, not even a file named like a temporary)."""
    import subprocess

    def run_killer(out, at):
        return subprocess.run(
            [sys.executable, "-c", KILLER, str(Path(__file__).parent), str(out), str(at)],
            capture_output=True,
            text=True,
            timeout=60,
            env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
        )

    probe = tmp_path / "probe" / "cal"
    write_set(Folder(probe, _set_files("older"), run_id="older"))
    write_set(Folder(probe, _set_files("old"), run_id="old"))
    done = run_killer(probe, 0)
    assert done.returncode == 0, done.stderr
    total = int(done.stdout)
    assert total >= 10
    outcomes = set()
    for k in range(1, total + 1):
        base = tmp_path / f"k{k}"
        out = base / "cal"
        write_set(Folder(out, _set_files("older"), run_id="older"))
        write_set(Folder(out, _set_files("old"), run_id="old"))
        done = run_killer(out, k)
        assert done.returncode == -signal.SIGKILL, (k, done.stderr)
        now, prev = whole_set(out), whole_set(base / "cal.prev")
        # ("new", "older"): killed between the two exchanges, the old set in a temporary
        assert (now, prev) in (("old", "older"), ("new", "old"), ("new", "older")), (k, now)
        outcomes.add(now)
        foreign = base / ".cal.tmp-notes.txt"  # a user's file that only looks like ours
        foreign.write_text("mine\n")
        write_set(Folder(out, _set_files("next"), run_id="next"))
        assert whole_set(out) == "next" and whole_set(base / "cal.prev") == now
        left = sorted(p.name for p in base.iterdir())
        assert left == [".cal.tmp-notes.txt", "cal", "cal.prev"], (k, left)
    assert outcomes == {"old", "new"}


def test_a_live_runs_temporaries_are_never_removed(tmp_path):
    """The staging folder of a run still writing (its lock held) survives another run's
    cleanup; once its process is gone, the next run removes it."""
    import subprocess

    out = tmp_path / "cal"
    write_set(Folder(out, _set_files("old"), run_id="old"))
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import fcntl, os, sys, tempfile, time\n"
            f"d = tempfile.mkdtemp(dir={str(tmp_path)!r}, prefix='.cal.tmp-')\n"
            "fd = os.open(d, os.O_RDONLY); fcntl.flock(fd, fcntl.LOCK_EX)\n"
            "print(d, flush=True); time.sleep(60)\n",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        staging = Path(holder.stdout.readline().strip())
        write_set(Folder(out, _set_files("new"), run_id="new"))
        assert staging.is_dir()  # held by a live process: not stale
    finally:
        holder.kill()
        holder.wait()
    write_set(Folder(out, _set_files("newer"), run_id="newer"))
    assert not staging.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cal", "cal.prev"]


CALIBRATION = """
import os, sys

# relcal.cli first, as the command has it: BLAS on one thread, set before NumPy loads
from relcal.cli import main
import relcal.calibration.pipeline, relcal.io, relcal.reporting.outputs

code = 99  # interrupted outside main's own handling
try:
    print("ready", flush=True)  # imports done: the moments drawn fall in the run itself
    code = main(sys.argv[1:])
finally:
    sys.stderr.flush()
    os._exit(code)
"""


def test_calibrate_interrupted_at_20_random_moments(dataset, tmp_path):
    """``relcal calibrate`` interrupted (SIGINT or SIGTERM) at 20 seeded random moments of its
    run: every time the output folder holds one whole set, the old or the new.

    Each run is a fresh interpreter (it says when its imports are done; the moment is drawn
    from then on), as the command line runs: not a child forked from a process that has
    loaded NumPy, whose BLAS threads a fork leaves to OpenBLAS's after-fork handling (and, in
    such a child, a signal can land in CPython's own after-fork hooks)."""
    import subprocess
    import time

    import numpy as np

    out, log = tmp_path / "cal", tmp_path.parent / f"{tmp_path.name}.stderr"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}

    def start(seed: int) -> tuple[subprocess.Popen, float]:
        argv = ["calibrate", str(dataset), "--out", str(out), "--quiet", "--seed", str(seed)]
        with open(log, "w") as err:
            proc = subprocess.Popen(
                [sys.executable, "-c", CALIBRATION, *argv],
                stdout=subprocess.PIPE,
                stderr=err,
                text=True,
                env=env,
            )
        assert proc.stdout.readline() == "ready\n", log.read_text()
        return proc, time.perf_counter()

    def finish(proc: subprocess.Popen) -> int:
        try:
            proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
            raise AssertionError(f"a calibration hung; its stderr: {log.read_text()}") from None
        return proc.returncode

    proc, started = start(0)
    assert finish(proc) == 0, log.read_text()
    duration = time.perf_counter() - started
    previous = whole_set(out)
    rng = np.random.default_rng(12)
    outcomes = []
    for trial in range(20):
        delay = rng.uniform(0.0, 1.2 * duration)
        sig = (signal.SIGINT, signal.SIGTERM)[trial % 2]
        proc, started = start(trial + 1)
        time.sleep(max(0.0, started + delay - time.perf_counter()))
        proc.send_signal(sig)  # a no-op once the run has ended
        code = finish(proc)
        t = {"trial": trial, "code": code, "previous": previous, "stderr": log.read_text()}
        try:
            run = whole_set(out)
        except Exception as exc:  # noqa: BLE001 - whatever the check met, reported with the trial
            raise AssertionError(f"not a whole set: {exc!r}; {t}") from None
        # 130/143: the handlers ran; -15: SIGTERM before main installed its handler
        assert code in (0, 130, 143, 99, -15), t
        if code == 0:
            assert run != previous, t
        outcomes.append("new" if run != previous else "old")
        previous = run
    assert set(outcomes) == {"old", "new"}
    leftovers = [p.name for p in tmp_path.iterdir() if p.name not in ("cal", "cal.prev")]
    assert leftovers == []


def test_a_signal_during_the_renames_is_delivered_after_them(tmp_path, monkeypatch):
    """SIGINT sent while the set is being renamed into place: the set is whole, then the
    interrupt arrives."""
    out = tmp_path / "cal"
    write_set(Folder(out, _set_files("old"), run_id="old"))
    real = outputset._commit_folder

    def interrupted_commit(tmp, item, undo, trash):
        signal.raise_signal(signal.SIGINT)  # arrives in the middle of the commit
        real(tmp, item, undo, trash)

    monkeypatch.setattr(outputset, "_commit_folder", interrupted_commit)
    with pytest.raises(KeyboardInterrupt):
        write_set(Folder(out, _set_files("new"), run_id="new"))
    assert whole_set(out) == "new" and whole_set(tmp_path / "cal.prev") == "old"
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


@pytest.mark.parametrize("when", ["after the commit", "after a failure"])
def test_a_signal_during_the_clean_up_leaves_no_temporaries(tmp_path, monkeypatch, when):
    """SIGINT sent while the write removes its temporaries (the replaced set once the new one is
    in place; the staged set once a step failed): the clean-up ends, then the interrupt arrives;
    nothing is left beside the outputs."""
    out = tmp_path / "cal"
    write_set(Folder(out, _set_files("old"), run_id="old"))
    write_set(Folder(out, _set_files("older"), run_id="older"))  # a .prev to replace
    real_rmtree = outputset.shutil.rmtree

    def interrupted_rmtree(path, *args, **kwargs):
        signal.raise_signal(signal.SIGINT)
        real_rmtree(path, *args, **kwargs)

    monkeypatch.setattr(outputset.shutil, "rmtree", interrupted_rmtree)
    if when == "after a failure":
        monkeypatch.setattr(outputset, "_exchange", lambda a, b: _raise(OSError("disk gone")))
    with pytest.raises((KeyboardInterrupt, RelcalError)):
        write_set(Folder(out, _set_files("new"), run_id="new"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cal", "cal.prev"]
    assert whole_set(out) == ("new" if when == "after the commit" else "older")


def _raise(exc: Exception):
    raise exc


def test_a_reentrant_lock_released_late_by_the_garbage_collector_does_not_fail(tmp_path):
    """A block re-entering a lock this thread holds, left open (a generator dropped mid-way) and
    closed only after the outer block released the lock: it ends quietly, and the lock is free."""

    def holder():
        with outputset.exclusive(tmp_path / "x.lock", "--out x", wait=False):
            yield

    with outputset.exclusive(tmp_path / "x.lock", "--out x", wait=False):
        inner = holder()
        next(inner)
    inner.close()  # GeneratorExit in the inner block, after the outer one ended
    with outputset.exclusive(tmp_path / "x.lock", "--out x", wait=False):
        pass
