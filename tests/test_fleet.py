"""A synthetic fleet on a local Dask cluster of 2 worker processes: 10 robots of 2 models, two
sessions each, one corrupt dataset, one robot whose second session has a[2] 0.3 mm longer."""

from __future__ import annotations

import collections
import contextlib
import io
import json
import os
import signal
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import random_q
from helpers_fleet import make_robot, write_session

from relcal.cli import main
from relcal.fleet.registry import Registry, registry_url
from relcal.fleet.runner import discover, run_fleet

pytest.importorskip("distributed")

CHANGED, CORRUPT = "r04", "r09"


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    root = tmp_path_factory.mktemp("fleet") / "plant"
    for i in range(10):
        robot = make_robot(("a465", "ur5e")[i % 2], f"r{i:02d}", 40 + i)
        write_session(root / f"r{i:02d}" / "2026-01", robot, 100 + i)
        change = {"a[2]": 3e-4} if robot.robot_id == CHANGED else None
        write_session(root / f"r{i:02d}" / "2026-06", robot, 200 + i, change=change)
    samples = root / CORRUPT / "2026-06" / "samples.csv"
    lines = samples.read_text().splitlines()
    lines[5] = lines[5].replace(",", ",x", 1)  # a joint value that is not a number
    samples.write_text("\n".join(lines) + "\n")
    return root


@pytest.fixture(scope="module")
def fleet_run(fleet, tmp_path_factory):
    """``relcal fleet calibrate`` on the fleet (2 local worker processes), with a registry, the
    JSON and the report; its printed text."""
    tmp = tmp_path_factory.mktemp("fleet-run")
    db, out, report = tmp / "history.sqlite", tmp / "fleet.json", tmp / "fleet.html"
    argv = ["fleet", "calibrate", str(fleet), "--out", str(tmp / "cal"), "--workers", "2"]
    argv += ["--registry", str(db)]
    with contextlib.redirect_stdout(io.StringIO()) as text:
        assert main([*argv, "--json", str(out), "--report", str(report)]) == 1
    return json.loads(out.read_text()), text.getvalue(), db, report


def test_fleet_command_calibrates_every_session_and_flags_the_changed_robot(
    fleet, fleet_run, capsys
):
    doc, text, db, _ = fleet_run
    cal = db.parent / "cal"
    entries = {e["session"]: e for e in doc["sessions"]}
    assert doc["n_sessions"] == 20 and doc["n_ok"] == 19 and doc["workers"] == 2
    # the corrupt dataset fails alone, with its reason (file, line, field)
    failed = [e for e in doc["sessions"] if e["status"] != "ok"]
    assert [e["session"] for e in failed] == [f"{CORRUPT}/2026-06"]
    assert "samples.csv line 6: q1" in failed[0]["reason"] and "x" in failed[0]["reason"]
    assert f"failed {CORRUPT}/2026-06: " in text
    # every other session: the outputs of `relcal calibrate`, errors, a registry run
    for name, e in entries.items():
        if e["status"] != "ok":
            continue
        assert e["robot_id"] == name.split("/")[0]
        for file in ("model.yaml", "robot.urdf", "parameters.csv", "results.json"):
            assert (cal / name / file).is_file(), (name, file)
        assert e["outputs"] == str((cal / name).resolve())
        assert not (fleet / name / "calibration").exists()  # nothing into the input tree
        assert e["calibrated_position_rms_mm"] < 0.1 * e["baseline_position_rms_mm"]
        assert isinstance(e["run_id"], int)
    # drift: the planted change is flagged on its link, the unchanged robots agree
    for i in range(10):
        robot = f"r{i:02d}"
        if robot == CORRUPT:
            assert entries[f"{robot}/2026-06"]["drift"] is None
            continue
        drift = entries[f"{robot}/2026-06"]["drift"]
        assert drift["against"] == f"{robot}/2026-01"
        if robot == CHANGED:
            assert drift["verdict"] == "drift" and "a[2]" in drift["flagged"], drift
        else:
            assert drift["verdict"] == "agree", (robot, drift)
        assert entries[f"{robot}/2026-01"]["drift"] is None
    # summaries per robot model: robots of one model compare, of two do not
    models = {m["model"]: m for m in doc["models"]}
    assert sorted(m["n_sessions"] for m in models.values()) == [10, 10]
    changed = next(m for m in models.values() if CHANGED in m["robots"])
    assert changed["drift_robots"] == [CHANGED] and len(changed["robots"]) == 5
    corrupt = next(m for m in models.values() if CORRUPT in m["robots"])
    assert corrupt["n_failed"] == 1 and corrupt["n_ok"] == 9  # counted under its robot's model
    with Registry(registry_url(db)) as registry:
        assert len(registry.runs()) == 19
        assert [r.session for r in registry.runs(CHANGED)] == [
            f"{CHANGED}/2026-01",
            f"{CHANGED}/2026-06",
        ]
    assert main(["history", CHANGED, "--registry", str(db)]) == 0
    assert "DRIFT" in capsys.readouterr().out


def test_the_robot_of_a_session_is_its_robot_folder(tmp_path):
    """ROOT/ROBOT/SESSION: the robot id is the robot's folder, not the session's; a dataset
    directly under the root is a robot with one session; robot_id of dataset.yaml wins."""
    robot = make_robot("a465", "ignored", 1)
    layout = {"arm1/2026-01": None, "arm1/2026-06": None, "arm2": None, "arm3/s1": "cell-9"}
    for name, robot_id in layout.items():
        folder = write_session(tmp_path / name, robot, 1, n=6)
        spec = folder / "dataset.yaml"
        lines = [line for line in spec.read_text().splitlines() if not line.startswith("robot_")]
        lines += [f"robot_id: {robot_id}"] if robot_id else []
        spec.write_text("\n".join(lines) + "\n")
    found = {s.name: s.robot_id for s in discover(tmp_path)}
    assert found == {
        "arm1/2026-01": "arm1",
        "arm1/2026-06": "arm1",
        "arm2": "arm2",
        "arm3/s1": "cell-9",
    }


def test_fleet_summaries_are_per_robot_model():
    from relcal.fleet.runner import model_summaries

    def entry(model, robot, status, base=None, after=None, drift=None):
        return {
            "model": model,
            "robot_id": robot,
            "status": status,
            "baseline_position_rms_mm": base,
            "calibrated_position_rms_mm": after,
            "drift": None if drift is None else {"verdict": drift},
        }

    entries = [
        entry("A465", "r0", "ok", 10.0, 0.2),
        entry("A465", "r0", "ok", 12.0, 0.4, "drift"),
        entry("UR5e", "r1", "ok", 30.0, 0.3),
        entry("UR5e", "r3", "ok", 20.0, 0.1, "agree"),
        entry(None, "r2", "failed"),
    ]
    (a465, ur5e, unknown) = model_summaries(entries)
    assert a465["model"] == "A465" and a465["n_sessions"] == 2 and a465["robots"] == ["r0"]
    assert a465["drift_robots"] == ["r0"] and a465[
        "median_calibrated_position_rms_mm"
    ] == pytest.approx(0.3)
    assert ur5e["median_baseline_position_rms_mm"] == 25.0 and ur5e["drift_robots"] == []
    assert unknown["model"] is None and unknown["n_failed"] == 1


def test_fleet_summaries_never_pool_two_kinds_of_held_out_error():
    """One robot model, sessions of relative poses and of tracker points: their held-out errors
    measure different things (pairs of poses, absolute points), so each kind gets its own
    median and none is taken over both (the summary read 33.863 -> 12.537 mm, the median of
    the TIAGo Pro's poses and points sessions)."""
    from relcal.fleet.report import fleet_report
    from relcal.fleet.runner import model_summaries
    from relcal.fleet.text import fleet_text

    def entry(session, metric, base, after):
        return {
            "session": session,
            "model": "tiago",
            "robot_id": "arm",
            "status": "ok",
            "held_out_metric": metric,
            "baseline_position_rms_mm": base,
            "calibrated_position_rms_mm": after,
        }

    entries = [
        entry("poses-1", "pairs of poses", 37.0, 20.0),
        entry("poses-2", "pairs of poses", 41.0, 22.0),
        entry("points-1", "points", 30.0, 4.0),
        entry("points-2", "points", 34.0, 6.0),
    ]
    (summary,) = model_summaries(entries)
    by_metric = {h["metric"]: h for h in summary["held_out"]}
    assert set(by_metric) == {"pairs of poses", "points"}
    assert by_metric["pairs of poses"]["n_sessions"] == 2
    assert by_metric["pairs of poses"]["median_calibrated_position_rms_mm"] == 21.0
    assert by_metric["points"]["median_baseline_position_rms_mm"] == 32.0
    assert summary["median_calibrated_position_rms_mm"] is None  # no median over both kinds
    text = fleet_text(entries, [summary])
    assert "on pairs of poses 39.000 -> 21.000 mm (median of 2)" in text
    assert "on points 32.000 -> 5.000 mm (median of 2)" in text
    # what medians over both kinds would print: 35.5 -> 13.0 mm
    assert "35.500" not in text and "13.000" not in text
    doc = {"models": [summary], "seconds": 1.0, "alpha": 0.01}
    html = fleet_report(doc, entries)
    assert ">21.000<" in html and ">5.000<" in html
    assert "35.500" not in html and "13.000" not in html


def test_fleet_report_renders_in_chromium(fleet_run, tmp_path):
    from test_report_browser import check_page, check_rendering, check_section_drawn

    doc, _, _, report = fleet_run
    models = {"thermo-crs-a465", "universal-robots-ur5e"}
    sections = {"summary", "robots", "failed"} | {f"parameters-{m}" for m in models}
    plots = {f"plot-parameters-{m}" for m in models}
    page = check_page(report.read_text(), sections, plots)
    cells = page.cells
    # one row per session: status, errors as in the JSON, drift flags
    for e in doc["sessions"]:
        k = cells.index(e["session"])
        assert cells[k + 1] == e["robot_id"] and cells[k + 3] == e["status"]
        assert cells[k + 4] == (e.get("held_out_metric") or "–")  # what the numbers measure
        if e["status"] == "ok":
            assert float(cells[k + 5]) == pytest.approx(e["baseline_position_rms_mm"], abs=1e-3)
            assert float(cells[k + 6]) == pytest.approx(e["calibrated_position_rms_mm"], abs=1e-3)
        drift = e["drift"]
        if drift is None:
            assert cells[k + 9] == "–"
        elif drift["verdict"] == "drift":
            assert cells[k + 9].startswith("drift: a[2]")
        else:
            assert cells[k + 9].startswith("agree")
    failed = next(e for e in doc["sessions"] if e["status"] == "failed")
    assert failed["reason"] in cells
    found, shot = check_rendering(report, tmp_path, plots)
    for ident in sections:
        check_section_drawn(found, shot, ident)


@pytest.fixture(scope="module")
def cluster():
    """A local cluster of 2 single-threaded worker processes (as `--workers 2` makes)."""
    from relcal.cluster import local_cluster

    with local_cluster(2) as cluster:
        yield cluster


def test_study_on_the_cluster_gives_the_same_trials(cluster, tmp_path, capsys):
    """`relcal study --scheduler`: the trials run as Dask tasks, with the same estimates as in
    one process (each trial's noise is seeded by its index)."""
    from distributed import Client

    from relcal.calibration.noise import Noise
    from relcal.geometry import DEG, MM
    from relcal.robot.loading import get_robot
    from relcal.robot.model import auto_hayati
    from relcal.sim.scenario import make_scenario
    from relcal.sim.study import study

    model = auto_hayati(get_robot("a465"))
    q = random_q(model, 12, np.random.default_rng(11))
    scenario = make_scenario(model, q, Noise(0.05 * MM, 0.01 * DEG), seed=4)
    here = study(scenario, trials=30, workers=1, progress=False)
    with Client(cluster) as client:
        there = study(scenario, trials=30, progress=False, client=client)
    np.testing.assert_array_equal(there.estimates, here.estimates)
    out = tmp_path / "study.json"
    argv = ["study", "--robot", "a465", "--hayati", "auto", "--poses", "12", "--trials", "20"]
    assert main([*argv, "--scheduler", cluster.scheduler_address, "--json", str(out)]) == 0
    assert json.loads(out.read_text())["trials"] == 20
    assert "trials" in capsys.readouterr().out


def written(out: Path) -> bool:
    """Whether a session's results.json is in ``out`` yet (staged or in place). The workers
    rename and remove folders while the walk runs: ``os.walk`` skips a folder that vanished
    between its listing and its scan (``rglob`` raised, and under load kept raising until the
    fleet was done)."""
    return any("results.json" in files for _, _, files in os.walk(out))


def test_a_killed_worker_does_not_stop_the_fleet(fleet, cluster, tmp_path):
    """SIGKILL one of the two worker processes while sessions run: its tasks run again
    elsewhere (the nanny starts a new worker), and the fleet completes."""
    from distributed import Client

    sessions = discover(fleet)
    out = tmp_path / "out"
    with Client(cluster) as client:
        pids = client.run(os.getpid)  # by worker address
        killed = threading.Event()
        seen: collections.Counter[str] = collections.Counter()  # what the killer saw, if it failed
        victim = None

        def busy() -> int | None:
            """The pid of a worker the scheduler has given a session to, if any. (The
            scheduler's state changes under this thread: a read that races it tries again.)"""
            try:
                workers = list(cluster.scheduler.workers.items())
                return next((pids[a] for a, w in workers if w.processing and a in pids), None)
            except RuntimeError:
                return None

        def killer() -> None:
            # A worker busy with a session, not a fixed one: as sessions got faster, the first
            # worker could be between tasks when the first result appeared, and its killing
            # then sent no task elsewhere (the test's own assertion failed, not the fleet).
            nonlocal victim
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline:
                running = written(out)  # sessions are running
                victim = busy() if running else None
                seen[f"result written {running}, busy worker {victim is not None}"] += 1
                if victim is not None:
                    os.kill(victim, signal.SIGKILL)
                    killed.set()
                    return
                time.sleep(0.01)

        thread = threading.Thread(target=killer, daemon=True)
        thread.start()
        entries = run_fleet(sessions, out_root=out, client=client)
        thread.join(timeout=5)
        assert killed.is_set(), seen
        assert victim not in client.run(os.getpid).values()
        rerun = {
            key
            for key, start, finish, *_ in cluster.scheduler.transition_log
            if start == "processing" and finish in ("released", "waiting")
        }
    assert rerun, "no task was running on the killed worker"
    status = {e["session"]: e["status"] for e in entries}
    assert len(status) == 20
    assert [s for s, v in status.items() if v != "ok"] == [f"{CORRUPT}/2026-06"]
    # a task rerun after the kill may find its set already written (kept as .prev/), and a
    # worker killed while staging leaves a hidden temporary: neither is a session's output
    sets = [
        p
        for p in out.rglob("results.json")
        if not any(x.startswith(".") or x.endswith(".prev") for x in p.relative_to(out).parts)
    ]
    assert len(sets) == 19


# --------------------------------------------- per-session options as `relcal calibrate` has them


def test_a_session_with_kfold_and_both_weightings_is_relcal_calibrates(tmp_path):
    """``--kfold`` and ``--weighting both`` per session: the same Python API calls as
    ``relcal calibrate`` (calibrate, then cross_validate), the same numbers, in the session's
    results.json and its fleet entry; without them neither is there."""
    from relcal.calibration.pipeline import calibrate, cross_validate
    from relcal.data.dataset import load_dataset
    from relcal.data.imaging import measure
    from relcal.fleet.records import held_out_errors
    from relcal.fleet.runner import calibrate_session
    from relcal.reporting.documents import cross_validation_document

    path = write_session(tmp_path / "arm1" / "s1", make_robot("a465", "arm1", 41), 7, n=16)
    options = {"seed": 0, "nongeometric": "none", "weightings": ("plain", "noise model")}
    entry = calibrate_session(str(path), "arm1/s1", str(tmp_path / "out"), {**options, "kfold": 2})
    assert entry["status"] == "ok", entry.get("reason")
    doc = json.loads(entry["files"]["results.json"])
    tried = {c["weighting"] for c in doc["model_selection"]["candidates"]}
    assert tried == {"plain", "noise model"}
    dataset = load_dataset(path)
    m = measure(dataset, progress=False)
    direct = calibrate(dataset, m, **options)
    assert doc["model_selection"]["chosen"] == direct.selection[direct.chosen].candidate.name
    folds = cross_validate(dataset, m, k=2, **options)
    want = cross_validation_document(folds)
    assert doc["cross_validation"]["k"] == 2 and doc["cross_validation"]["chosen"] == want["chosen"]
    pooled = held_out_errors({"validation": want["pooled"]})
    assert entry["kfold"] == 2
    assert entry["kfold_calibrated_position_rms_mm"] == pytest.approx(
        pooled["calibrated_position_rms_mm"], rel=1e-9
    )
    assert entry["kfold_baseline_position_rms_mm"] == pytest.approx(
        pooled["baseline_position_rms_mm"], rel=1e-9
    )
    assert entry["kfold_calibrated_position_rms_mm"] < entry["kfold_baseline_position_rms_mm"]
    plain = calibrate_session(str(path), "arm1/s1", str(tmp_path / "out2"), {"seed": 0})
    assert "kfold" not in plain
    assert "cross_validation" not in json.loads(plain["files"]["results.json"])


def test_a_session_too_small_for_its_folds_fails_alone(tmp_path):
    """K above half the usable samples: that session fails with the reason, before any fit."""
    from relcal.fleet.runner import calibrate_session

    path = write_session(tmp_path / "arm1" / "s1", make_robot("a465", "arm1", 41), 7, n=10)
    entry = calibrate_session(str(path), "s1", str(tmp_path / "out"), {"kfold": 6})
    assert entry["status"] == "failed"
    assert "--kfold 6" in entry["reason"] and "K is 2 to 5" in entry["reason"], entry["reason"]


def test_fleet_command_passes_kfold_and_weighting_to_every_session(tmp_path, monkeypatch):
    """The options reach each session's call as relcal calibrate maps them; bad values are
    refused by argparse (exit 2 naming the option)."""
    from relcal.fleet import runner

    root = tmp_path / "plant"
    write_session(root / "arm1" / "s1", make_robot("a465", "arm1", 41), 7, n=10)
    seen = []

    def fake_run_fleet(sessions, out, options, *args, **kwargs):
        seen.append(options)
        return []

    monkeypatch.setattr(runner, "run_fleet", fake_run_fleet)
    argv = ["fleet", "calibrate", str(root), "--out", str(tmp_path / "cal"), "--quiet"]
    assert main([*argv, "--kfold", "3", "--weighting", "both", "--priors", "none"]) == 0
    assert main(argv) == 0
    assert seen[0]["kfold"] == 3 and seen[0]["weightings"] == ("plain", "noise model")
    assert seen[1]["kfold"] is None and seen[1]["weightings"] == ("plain",)
    assert seen[0]["priors"] == "none" and seen[1]["priors"] == "model"
    assert main([*argv, "--kfold", "1"]) == 2 and main([*argv, "--weighting", "robust"]) == 2
    assert main([*argv, "--priors", "flat"]) == 2


def test_fleet_outputs_go_under_out_never_into_the_input_tree(tmp_path, capsys):
    """Without --out, or with --out inside the input folder, the fleet is refused before any
    work, and nothing appears anywhere."""
    root = tmp_path / "plant"
    write_session(root / "arm1" / "s1", make_robot("a465", "arm1", 41), 7, n=10)
    before = sorted(tmp_path.rglob("*"))
    assert main(["fleet", "calibrate", str(root), "--quiet"]) == 2
    assert "--out OUT is required" in capsys.readouterr().err
    assert main(["fleet", "calibrate", str(root), "--out", str(root / "cal"), "--quiet"]) == 2
    assert "inside the fleet's input folder" in capsys.readouterr().err
    assert sorted(tmp_path.rglob("*")) == before
