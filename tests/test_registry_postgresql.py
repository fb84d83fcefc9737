"""The registry against a real PostgreSQL server: a throw-away cluster (initdb, pg_ctl) started
for these tests from Debian's ``postgresql`` package (``make postgresql`` installs it; ``make
test`` does so first). Where the package is missing the tests are skipped, with that message."""

from __future__ import annotations

import glob
import os
import shutil
import socket
import subprocess
import tempfile
from pathlib import Path

import pytest
from helpers_fleet import make_robot, write_session
from helpers_registry import write_concurrently

from relcal.calibration.pipeline import calibrate
from relcal.data.dataset import load_dataset
from relcal.data.imaging import measure
from relcal.fleet import registry as reg
from relcal.fleet.records import calibration_record
from relcal.reporting.documents import results_document

pytest.importorskip("psycopg", reason="the PostgreSQL driver: pip install 'relcal[postgresql]'")


def _bin() -> Path | None:
    found = sorted(
        glob.glob("/usr/lib/postgresql/*/bin/initdb"), key=lambda p: int(p.split("/")[4])
    )
    if found:
        return Path(found[-1]).parent
    initdb = shutil.which("initdb")
    return Path(initdb).parent if initdb else None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def postgres_url():
    """A PostgreSQL server of its own on a free local port (trust authentication), stopped and
    removed after the tests; its SQLAlchemy URL."""
    bindir = _bin()
    if bindir is None:
        pytest.skip(
            "PostgreSQL is not installed: `make postgresql` installs Debian's postgresql package "
            "(as root) for these tests"
        )
    root = Path(tempfile.mkdtemp(prefix="relcal-pg-"))
    as_user: list[str] = []
    if os.geteuid() == 0:  # the server refuses to run as root: Debian's postgres user runs it
        if shutil.which("runuser") is None:
            pytest.skip("running as root without runuser: cannot start PostgreSQL")
        shutil.chown(root, "postgres")
        as_user = ["runuser", "-u", "postgres", "--"]
    os.chmod(root, 0o755)
    data, port = root / "data", _free_port()

    def run(*cmd: str) -> None:
        done = subprocess.run([*as_user, *cmd], capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, f"{cmd[0]} failed: {done.stdout[-800:]} {done.stderr[-800:]}"

    run(str(bindir / "initdb"), "-D", str(data), "-A", "trust", "-U", "relcal", "--no-sync")
    options = f"-p {port} -k {root} -c listen_addresses=127.0.0.1 -c fsync=off"
    run(
        str(bindir / "pg_ctl"),
        "-D",
        str(data),
        "-l",
        str(root / "log"),
        "-o",
        options,
        "-w",
        "start",
    )
    try:
        yield f"postgresql+psycopg://relcal@127.0.0.1:{port}/postgres"
    finally:
        run(str(bindir / "pg_ctl"), "-D", str(data), "-m", "immediate", "stop")
        shutil.rmtree(root, ignore_errors=True)


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    root = write_session(tmp_path_factory.mktemp("pg") / "cell", make_robot("ur5e", "pg-arm", 2), 3)
    dataset = load_dataset(root)
    cal = calibrate(dataset, measure(dataset, progress=False))
    return calibration_record(cal, results_document(cal))


def test_postgresql_registry_round_trip_and_concurrent_writers(postgres_url, record):
    n_proc, count = 3, 10
    results = write_concurrently(postgres_url, record, n_proc, count)  # racing to migrate too
    assert all(status == "ok" for status, _ in results), results
    with reg.Registry(postgres_url) as registry:
        assert reg.current_revision(registry.engine) == reg.head_revision()
        runs = registry.runs("pg-arm")
        assert len(runs) == n_proc * count == len({r.id for r in runs})
        run = registry.get(runs[0].uid[:10])
    assert run.covariance["names"] == record["covariance"]["names"]
    assert run.parameters == record["parameters"]
    assert run.errors == record["errors"]
    assert run.created_at.tzinfo is not None


def test_postgresql_keeps_verifications(postgres_url, record):
    """A verification record (relcal verify --registry) round-trips through PostgreSQL: its
    errors, intervals and details, under its calibration's run."""
    with reg.Registry(postgres_url) as registry:
        run_id = registry.add(record)
        verification = {
            "calibration_id": run_id,
            "calibration": f"run {run_id}",
            "robot_id": "pg-arm",
            "session": "next-week",
            "dataset_path": "/data/next-week",
            "relcal_version": "x",
            "kind": "pose",
            "n_samples": 30,
            "folds": 5,
            "baseline_position_rms_mm": 12.5,
            "calibrated_position_rms_mm": 0.21,
            "baseline_orientation_rms_deg": 0.8,
            "calibrated_orientation_rms_deg": 0.01,
            "ratio_position": 0.0168,
            "at_calibration_position_rms_mm": 0.19,
            "verdict": "holds",
            "intervals": {"ratio_position": [0.014, 0.02]},
            "details": {"reason": "better than the nominal model", "warnings": []},
        }
        vid = registry.add_verification(verification)
        (found,) = registry.verifications("pg-arm")
        assert registry.verifications(calibration_id=run_id)[0].id == vid == found.id
    assert found.intervals == verification["intervals"] and found.verdict == "holds"
    assert found.details == verification["details"] and found.created_at.tzinfo is not None
    assert found.calibrated_position_rms_mm == 0.21
