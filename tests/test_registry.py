"""The calibration registry: records, schema migrations, concurrent writers, and the commands
that read it (history, compare) or write it (calibrate --registry)."""

from __future__ import annotations

import csv
import io
import json
import os

import numpy as np
import pytest
import sqlalchemy as sa
from helpers_fleet import make_robot, write_session
from helpers_registry import write_concurrently

from relcal.calibration.pipeline import calibrate
from relcal.cli import main
from relcal.data.dataset import load_dataset
from relcal.data.imaging import measure
from relcal.fleet import registry as reg
from relcal.fleet.records import calibration_record
from relcal.reporting.documents import results_document
from relcal.reporting.outputs import calibration_files


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """A calibration of a synthetic A465 session and its results document."""
    root = write_session(
        tmp_path_factory.mktemp("registry") / "cell1", make_robot("a465", "arm1", 1), 7
    )
    dataset = load_dataset(root)
    cal = calibrate(dataset, measure(dataset, progress=False))
    return cal, results_document(cal)


def test_a_record_holds_what_the_calibration_found(calibrated, tmp_path):
    cal, doc = calibrated
    with reg.open_registry(tmp_path / "h.sqlite") as registry:
        run_id = registry.add(calibration_record(cal, doc, outputs=tmp_path / "out"))
        run = registry.get(run_id)
        assert registry.get(run.uid[:8]).id == run_id
        assert registry.robots() == ["arm1"]
    assert run.robot_id == "arm1" and run.session == "cell1"
    assert run.model_name == cal.dataset.model.name
    chosen = cal.selection[cal.chosen].candidate
    settings = {**cal.settings, "chosen_model": chosen.name, "joint_ranges": doc["joint_ranges"]}
    settings["verdict"] = doc["verdict"]["code"]
    settings["held_out_metric"] = doc["held_out_metric"]
    settings["parameter_labels"] = {}  # a YAML robot: its joints are numbered
    settings["artifacts"] = [
        {
            "file": f["file"],
            "holds": f["holds"],
            "written": f["written"],
            "position_rms_mm": f["held_out"]["position_rms_mm"],
        }
        for f in doc["artifacts"]["files"]
    ]
    assert run.settings == json.loads(json.dumps(settings))
    assert set(run.input_hashes) == {"dataset.yaml", "samples.csv"}
    assert run.outputs_path == str((tmp_path / "out").resolve())
    # parameters, standard deviations and covariance in SI units, over the estimated subset
    names = [n for k, n in enumerate(cal.problem.full_layout.names) if np.isfinite(cal.std[k])]
    assert run.covariance["names"] == names and len(names) == len(chosen.columns)
    cov = run.covariance_of(names)
    np.testing.assert_allclose(cov, cov.T)
    assert np.linalg.eigvalsh(cov).min() > 0
    for k, name in enumerate(cal.problem.full_layout.names):
        p = run.parameter(name)
        assert p["estimated"] == (name in names)
        if p["estimated"]:
            assert p["value"] == pytest.approx(cal.result.params[k], rel=1e-12, abs=1e-300)
            assert p["calibration_std"] == pytest.approx(cal.std[k], rel=1e-12)
            assert p["std"] == pytest.approx(np.sqrt(cov[names.index(name)][names.index(name)]))
            assert p["std"] == pytest.approx(p["calibration_std"], rel=1e-9)  # one covariance
    # the held-out errors of the results document (baseline: the hand-eye-only fit)
    val = doc["validation"]
    assert run.errors["baseline_position_rms_mm"] == val["baseline"]["position_mm"]["rms"]
    assert (
        run.errors["calibrated_orientation_rms_deg"] == val["calibrated"]["orientation_deg"]["rms"]
    )
    with pytest.raises(reg.RelcalError, match="no run with id"):
        reg.Registry(reg.registry_url(tmp_path / "h.sqlite")).get(99)


def test_the_recorded_calibration_std_is_the_printed_one(calibrated, tmp_path):
    """``calibration_std`` of every parameter is the std that ``results.json`` and
    ``parameters.csv`` of the same run print (there in mm or deg), written and read back."""
    cal, doc = calibrated
    files = calibration_files(cal, doc, "r1")
    printed = {r["name"]: r for r in csv.DictReader(io.StringIO(files["parameters.csv"]))}
    in_json = {r["name"]: r for r in json.loads(files["results.json"])["parameters"]}
    with reg.open_registry(tmp_path / "h.sqlite") as registry:
        run = registry.get(registry.add(calibration_record(cal, doc)))
    shown = 0
    for p in run.parameters:
        row = printed[p["name"]]
        if row["unit"] not in ("mm", "deg"):
            continue
        if p["calibration_std"] is None:
            assert row["std"] == "" and in_json[p["name"]]["std"] is None
            continue
        value = p["calibration_std"] * (1e3 if row["unit"] == "mm" else np.degrees(1.0))
        assert float(row["std"]) == pytest.approx(value, rel=1e-12)
        assert in_json[p["name"]]["std"] == pytest.approx(value, rel=1e-12)
        shown += 1
    assert shown == int(np.isfinite(cal.std).sum())


def test_schema_is_migrated_on_open_and_keeps_old_rows(calibrated, tmp_path):
    cal, doc = calibrated
    path = tmp_path / "old.sqlite"
    engine = sa.create_engine(f"sqlite:///{path}")
    reg.migrate(engine, "0001")  # a registry written by the first schema
    record = calibration_record(cal, doc)
    row = {k: v for k, v in record.items() if k not in ("errors", "session")}
    row.update(record["errors"], uid="a" * 32, created_at=reg.datetime.now(reg.UTC))
    with engine.begin() as conn:
        conn.execute(sa.text("SELECT 1"))
        old = sa.Table("calibrations", sa.MetaData(), autoload_with=conn)
        assert "session" not in old.c
        conn.execute(old.insert().values(**row))
    assert reg.current_revision(engine) == "0001"
    engine.dispose()
    with reg.open_registry(path) as registry:
        assert reg.current_revision(registry.engine) == reg.head_revision() == "0003"
        (run,) = registry.runs("arm1")
        assert run.session is None and run.uid == "a" * 32
        with registry.engine.connect() as conn:
            mode = conn.execute(sa.text("PRAGMA journal_mode")).scalar()
        assert mode == "wal"


def test_concurrent_writers_lose_nothing(calibrated, tmp_path):
    """Four processes open a fresh SQLite registry at once (racing for the migration), then write
    25 records each at the same time: every record lands, with distinct ids."""
    cal, doc = calibrated
    record = calibration_record(cal, doc)
    url = reg.registry_url(tmp_path / "shared.sqlite")
    n_proc, count = 4, 25
    results = write_concurrently(url, record, n_proc, count)
    assert all(status == "ok" for status, _ in results), results
    ids = [i for _, got in results for i in got]
    assert len(set(ids)) == n_proc * count
    with reg.Registry(url) as registry:
        runs = registry.runs("arm1")
    assert len(runs) == n_proc * count
    assert {r.session for r in runs} == {f"w{w}-{k}" for w in range(n_proc) for k in range(count)}
    assert not (tmp_path / "shared.sqlite.lock").exists()  # the migration lock: removed


def test_opening_waits_for_a_migration_under_way(calibrated, tmp_path):
    """SQLite's driver commits each DDL statement of a migration on its own: a registry opened
    while another process migrates the file sees its tables before its revision. Opening waits
    for the migration lock, and then finds a registry, not "a database of another program"."""
    import threading
    import time

    path = tmp_path / "shared.sqlite"
    url = reg.registry_url(path)
    engine = sa.create_engine(url)
    with reg._file_lock(reg._lock_path(engine.url)):  # another process's migration, half done
        with engine.begin() as conn:
            conn.exec_driver_sql("CREATE TABLE calibrations (id INTEGER PRIMARY KEY)")
        outcome: list = []

        def open_it() -> None:
            try:
                with reg.Registry(url, write=True) as registry:
                    outcome.append(("ok", registry.runs()))
            except Exception as exc:  # reported below
                outcome.append(("error", repr(exc)))

        opener = threading.Thread(target=open_it)
        opener.start()
        time.sleep(0.5)  # room for an opener that does not wait to look at the half-made file
        with engine.begin() as conn:  # the migration goes on from scratch and completes
            conn.exec_driver_sql("DROP TABLE calibrations")
        reg.migrate(engine, locked=True)
    opener.join(timeout=120)
    engine.dispose()
    assert outcome == [("ok", [])]


def test_calibrate_records_and_history_compare_read(tmp_path, capsys, monkeypatch):
    robot = make_robot("a465", "cell7-arm2", 3)
    first = write_session(tmp_path / "monday", robot, 11)
    second = write_session(tmp_path / "friday", robot, 12, change={"d[4]": 3e-4})
    path = tmp_path / "history.sqlite"
    assert main(["calibrate", str(first), "--quiet", "--registry", str(path)]) == 0
    monkeypatch.setenv(reg.ENV, str(path))  # the variable works as --registry does
    assert main(["calibrate", str(second), "--quiet"]) == 0
    capsys.readouterr()

    assert main(["history", "cell7-arm2", "--json", str(tmp_path / "h.json")]) == 0
    text = capsys.readouterr().out
    assert "2 calibration(s)" in text and "monday" in text and "friday" in text
    assert "DRIFT" in text and "d[4]" in text
    # terms left out by model selection are not called unidentifiable
    unidentifiable = next(line for line in text.splitlines() if line.startswith("not identif"))
    left_out = next(line for line in text.splitlines() if line.startswith("not in any run"))
    assert "theta_off[1]" in unidentifiable and "scale[2]" not in unidentifiable
    assert "scale[2]" in left_out and "theta_off[1]" not in left_out
    history = json.loads((tmp_path / "h.json").read_text())
    assert [r["session"] for r in history["runs"]] == ["monday", "friday"]
    assert history["runs"][1]["drift"]["verdict"] == "drift"
    assert history["runs"][1]["drift"]["flagged"] == ["d[4]"]

    a, b = (r["id"] for r in history["runs"])
    assert main(["compare", str(a), str(b), "--json", str(tmp_path / "c.json")]) == 0
    text = capsys.readouterr().out
    assert "DRIFT" in text and "chi-square" in text
    doc = json.loads((tmp_path / "c.json").read_text())
    change = next(p for p in doc["parameters"] if p["name"] == "d[4]")
    assert change["unit"] == "mm"  # as results.json gives it
    assert change["difference"] == pytest.approx(0.3, abs=4 * change["std"])
    assert change["flagged"] and doc["flagged"] == ["d[4]"]


@pytest.mark.parametrize(
    "argv, message",
    [
        (["history", "arm1"], "no registry: give --registry"),
        (["history", "arm1", "--registry", "{tmp}/none.sqlite"], "no such file"),
        (["history", "ghost", "--registry", "{tmp}/h.sqlite"], "no calibration of robot 'ghost'"),
        (["compare", "1", "7", "--registry", "{tmp}/h.sqlite"], "no run with id or uid '7'"),
        (["history", "arm1", "--registry", "nosuchdb://x"], "registry"),
    ],
)
def test_registry_errors_are_one_line(argv, message, calibrated, tmp_path, capsys, monkeypatch):
    monkeypatch.delenv(reg.ENV, raising=False)
    cal, doc = calibrated
    with reg.open_registry(tmp_path / "h.sqlite") as registry:
        registry.add(calibration_record(cal, doc))
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and err.count("\n") == 1


def test_registry_url_rules(tmp_path, monkeypatch):
    monkeypatch.delenv(reg.ENV, raising=False)
    assert reg.registry_url(None) is None
    assert reg.registry_url("postgresql+psycopg://u@h/db") == "postgresql+psycopg://u@h/db"
    assert reg.registry_url(tmp_path / "x.db") == f"sqlite:///{(tmp_path / 'x.db').resolve()}"
    monkeypatch.setenv(reg.ENV, str(tmp_path / "env.db"))
    assert reg.registry_url(None).endswith("env.db")
    assert os.environ[reg.ENV]
