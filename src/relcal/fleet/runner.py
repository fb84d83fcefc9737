"""Many calibrations as tasks on a Dask cluster: one task per dataset folder (session).

A task loads, measures and calibrates one session and returns a small summary, the files of its
outputs (those of ``relcal calibrate``, a few kilobytes) and its registry record; it never
raises for a bad dataset (its entry says ``failed`` with the reason), so one bad folder cannot
stop the fleet. The client installs each session's outputs and records it in the registry in
one transaction (:func:`relcal.outputset.write_set` with the record as its journal), in session
order as the tasks finish: an interrupted fleet leaves every session either installed with its
record or untouched, and the workers write nothing (nor need access to the registry). A worker
that dies is replaced by its nanny, and the scheduler reruns its tasks elsewhere
(``distributed.scheduler.allowed-failures`` times, 3 by default).
"""

from __future__ import annotations

import time
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from relcal.errors import RelcalError


@dataclass(frozen=True)
class Session:
    """One dataset folder of a fleet: its path, its name (relative to the root) and robot id."""

    path: Path
    name: str
    robot_id: str


def _robot_id(folder: Path, root: Path) -> str:
    """``robot_id`` of ``dataset.yaml`` if it has one, else the robot's folder: in a fleet laid
    out ``ROOT/ROBOT/SESSION`` (a session two or more levels below the root) the session's
    parent, else the session folder itself (``ROOT/ROBOT``, one session per robot). Unreadable
    files give the same default; the task reports what is wrong with them."""
    from relcal.io import load_yaml

    default = folder.parent.name if folder.parent != root and folder != root else folder.name
    try:
        data, _ = load_yaml(folder / "dataset.yaml")  # the one YAML loader: bounded
    except RelcalError:
        return default
    value = data.get("robot_id") if isinstance(data, dict) else None
    return str(value) if value not in (None, "") else default


def discover(root: str | Path) -> list[Session]:
    """Every folder under ``root`` (``root`` itself included) holding a ``dataset.yaml``, in
    path order; the robot id is ``robot_id`` of ``dataset.yaml``, by default the robot's folder
    (the parent of a session in ``ROOT/ROBOT/SESSION``, the session folder in ``ROOT/ROBOT``)."""
    root = Path(root)
    if not root.is_dir():
        raise RelcalError(f"{root}: not a folder (expected a folder of dataset folders)")
    folders = sorted({p.parent for p in root.rglob("dataset.yaml")})
    if not folders:
        raise RelcalError(f"{root}: no dataset folder (a folder with dataset.yaml) under it")
    return [
        Session(f, f.relative_to(root).as_posix() if f != root else f.name, _robot_id(f, root))
        for f in folders
    ]


def outputs_folder(session: Session, out_root: str | Path | None) -> Path:
    """Where a session's outputs go: ``OUT/<session name>`` (never into the input tree)."""
    if out_root is None:
        from relcal.errors import ArgumentError

        raise ArgumentError(
            "out_root: the folder the sessions' calibrations go under (OUT/<session>); a fleet "
            "writes nothing into its input folders"
        )
    return Path(out_root) / session.name


def check_out_root(root: str | Path, out_root: str | Path) -> None:
    """``out_root`` must not lie inside the fleet's input folder ``root`` (its outputs would
    land in the input tree)."""
    from relcal.outputset import check_outside

    check_outside(out_root, "--out", root, "the fleet's input folder")


def calibrate_session(
    path: str,
    name: str,
    out: str,
    options: dict[str, Any] | None = None,
    robot_id: str | None = None,
) -> dict[str, Any]:
    """Calibrate one session (runs on a worker): its entry, with the registry record under
    ``record`` when it succeeded (recorded under ``robot_id``, default the dataset's). Bad input
    gives ``status: failed`` and the reason."""
    from threadpoolctl import threadpool_limits

    from relcal.cluster import prepare_worker

    prepare_worker()
    started = time.perf_counter()
    entry: dict[str, Any] = {"session": name, "path": str(Path(path).resolve())}
    try:
        from relcal.outputset import tracking

        with threadpool_limits(limits=1), tracking():  # this session's inputs only
            entry.update(_calibrate(Path(path), name, Path(out), dict(options or {}), robot_id))
    except RelcalError as exc:
        entry.update(status="failed", reason=str(exc))
    except Exception as exc:  # a bug or a broken file: still this session's failure alone
        last = traceback.extract_tb(exc.__traceback__)[-1]
        text = str(exc)
        text = text if len(text) <= 300 else text[:300] + "..."
        entry.update(
            status="failed",
            reason=f"internal error: {type(exc).__name__}: {text} "
            f"(at {Path(last.filename).name}:{last.lineno}; please report it)",
        )
    entry["seconds"] = time.perf_counter() - started
    return entry


def _calibrate(
    path: Path, name: str, out: Path, options: dict, robot_id: str | None = None
) -> dict[str, Any]:
    import numpy as np

    from relcal.calibration.kinds.dispatch import kind_of
    from relcal.calibration.pipeline import calibrate, cross_validate
    from relcal.data.dataset import load_dataset
    from relcal.data.imaging import measure
    from relcal.fleet.records import calibration_record, held_out_errors, held_out_metric
    from relcal.outputset import Folder, check, inputs, new_run_id
    from relcal.reporting.documents import cross_validation_document, results_document
    from relcal.reporting.outputs import calibration_files

    kfold = options.pop("kfold", None)  # as `relcal calibrate --kfold`: folds after the fit
    dataset = load_dataset(path)
    check([Folder(out, what="outputs")])  # refused before the work (an input, a foreign folder)
    with np.errstate(all="ignore"):
        m = measure(dataset, workers=1, progress=False)
        if kfold:
            kind_of(dataset, m).folds(kfold, options.get("seed", 0))  # too few: fail first
        cal = calibrate(dataset, m, **options)
        doc = results_document(cal)
    if cal.hurts:  # as `relcal calibrate`: a model worse than the baseline is not written
        val = cal.validation
        what = "spread" if dataset.measured == "coincidence" else "position"
        return {
            "robot_id": robot_id or dataset.robot_id,
            "model": dataset.model.name,
            "status": "rejected",
            "reason": f"the chosen model ({doc['model_selection']['chosen']}) is worse than the "
            f"baseline on the held-out samples ({what} RMS {val.rms('calibrated'):.3f} mm "
            f"against {val.rms('before'):.3f} mm); nothing written",
            **held_out_errors(doc),
            "held_out_metric": held_out_metric(doc),
        }
    cross: dict[str, Any] = {}
    if kfold:
        per_fold = {k: v for k, v in options.items() if k not in ("holdout", "seed")}
        with np.errstate(all="ignore"):
            folds = cross_validate(dataset, m, k=kfold, seed=options.get("seed", 0), **per_fold)
        doc["cross_validation"] = cross_validation_document(folds)
        pooled = held_out_errors({"validation": doc["cross_validation"]["pooled"]})
        cross = {
            "kfold": kfold,
            "kfold_baseline_position_rms_mm": pooled["baseline_position_rms_mm"],
            "kfold_calibrated_position_rms_mm": pooled["calibrated_position_rms_mm"],
        }
    run_id = new_run_id()
    record = calibration_record(cal, doc, outputs=out, session=name, robot_id=robot_id)
    return {
        "robot_id": record["robot_id"],
        "model": dataset.model.name,
        "status": "ok" if cal.result.converged else "not converged",
        "reason": None if cal.result.converged else "the identification did not converge",
        "outputs": str(out.resolve()),
        **held_out_errors(doc),
        "held_out_metric": held_out_metric(doc),
        **cross,
        "record": record,
        # installed by the client with the record (install_session): the files of `relcal
        # calibrate`, and what this session read (never written over)
        "files": calibration_files(cal, doc, run_id),
        "run": run_id,
        "inputs": sorted(str(p) for p in inputs()),
    }


def install_session(entry: dict[str, Any], registry=None) -> None:
    """Install a finished session's outputs (``entry["files"]``) into ``entry["outputs"]`` and
    record it in ``registry`` in one transaction; ``entry`` gets ``run_id``, or becomes
    ``failed`` with the reason when the outputs or the record cannot be written (then neither
    is). The files are dropped from the entry either way."""
    from relcal.outputset import Folder, note_input, tracking, write_set

    files = entry.pop("files", None)
    inputs = entry.pop("inputs", ())
    run = entry.pop("run", None)
    if files is None:
        return
    journal = None
    if registry is not None and entry.get("record") is not None:
        journal = registry.pending(entry["record"])
    try:
        with tracking():  # the session's own inputs, never written over
            for p in inputs:
                note_input(p)
            write_set(Folder(entry["outputs"], files, what="outputs", run_id=run), journal=journal)
    except RelcalError as exc:
        entry.update(status="failed", reason=str(exc), record=None)
        return
    if journal is not None:
        entry["run_id"] = journal.run_id


def iterate_fleet(
    sessions: list[Session],
    out_root: str | Path | None = None,
    options: dict[str, Any] | None = None,
    workers: int = 2,
    scheduler: str | None = None,
    client=None,
) -> Iterator[dict[str, Any]]:
    """Entries of :func:`calibrate_session` as the tasks finish (in any order). ``client``: an
    existing Dask client (else one is made from ``workers`` / ``scheduler`` and closed at the
    end). A task whose workers kept dying gives a failed entry naming that."""
    from relcal.cluster import connect

    own = None
    if client is None:
        own = connect(scheduler, workers)
        client = own[0]
    from distributed import as_completed

    try:
        futures, submitted = {}, []
        for s in sessions:
            future = client.submit(
                calibrate_session,
                str(s.path),
                s.name,
                str(outputs_folder(s, out_root)),
                options,
                s.robot_id,
                key=f"relcal-session-{s.name}-{time.time_ns()}",
                pure=False,
            )
            futures[future.key] = s
            submitted.append(future)
        for future in as_completed(submitted):
            s = futures[future.key]
            try:
                entry = future.result()
            except Exception as exc:  # KilledWorker, a lost scheduler, ...
                entry = {
                    "session": s.name,
                    "path": str(s.path.resolve()),
                    "status": "failed",
                    "reason": f"task lost: {type(exc).__name__}: {exc}",
                }
            entry.setdefault("robot_id", s.robot_id)
            yield entry
    finally:
        if own is not None:
            own[0].close()
            if own[1] is not None:
                own[1].close()


def run_fleet(
    sessions: list[Session],
    out_root: str | Path | None = None,
    options: dict[str, Any] | None = None,
    workers: int = 2,
    scheduler: str | None = None,
    registry=None,
    on_entry: Callable[[dict], None] | None = None,
    client=None,
) -> list[dict[str, Any]]:
    """Calibrate every session on the cluster, install the outputs of the successful ones and
    record them in ``registry`` (a :class:`relcal.fleet.registry.Registry`, or None), each in
    one transaction, and return the entries in session order, each with its run id
    (``run_id``) when recorded; ``on_entry`` is called as each is installed.

    Sessions are installed and recorded in session order (each as soon as it and every session
    before it have finished), so that a robot's sessions enter its history in the order of
    their folders."""
    by_name: dict[str, dict] = {}
    next_up = 0
    for entry in iterate_fleet(sessions, out_root, options, workers, scheduler, client):
        by_name[entry["session"]] = entry
        while next_up < len(sessions) and sessions[next_up].name in by_name:
            done = by_name[sessions[next_up].name]
            install_session(done, registry)  # outputs and record: one transaction
            if on_entry is not None:
                on_entry(done)
            next_up += 1
    return [by_name[s.name] for s in sessions]


def attach_drift(
    entries: list[dict[str, Any]], registry=None, since=None, alpha: float | None = None
) -> None:
    """Add ``drift`` to each successful entry: the comparison with the robot's previous
    calibration, the previous session of the same robot in this fleet (session order) or, for
    its first one, the latest run of the registry made before ``since`` (a datetime)."""
    from relcal.fleet.drift import ALPHA, consecutive
    from relcal.fleet.registry import run_from_record
    from relcal.fleet.text import drift_summary

    by_robot: dict[str, list[dict]] = {}
    for e in entries:
        if e.get("record") is not None and e["status"] == "ok":
            by_robot.setdefault(e["robot_id"], []).append(e)
    for robot_id, group in by_robot.items():
        runs = [run_from_record(e["record"], e.get("run_id") or 0) for e in group]
        labels = [e["session"] for e in group]
        if registry is not None and since is not None:
            earlier = [r for r in registry.runs(robot_id) if r.created_at < since]
            if earlier:
                runs.insert(0, earlier[-1])
                labels.insert(0, f"run {earlier[-1].id}")
        comparisons = consecutive(runs, ALPHA if alpha is None else alpha)
        offset = len(runs) - len(group)
        for k, e in enumerate(group):
            i = k + offset
            e["drift"] = drift_summary(comparisons[i], labels[i - 1] if i else None)


def model_summaries(entries: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per robot model (the fleet's robots of one model are comparable, those of two are not):
    sessions, robots, calibrated and failed sessions, robots flagged for drift, and, per kind of
    held-out metric (``held_out``: relative poses, points and placements measure different
    things, so they are never pooled), the number of calibrated sessions and the median over
    them of the baseline and calibrated held-out errors (mm, deg). The ``median_*`` keys of the
    summary itself are those of the one metric when all its sessions share it, else None. A
    session that failed before its model was known counts under its robot's model (from the
    robot's other sessions), else under ``model: None``."""
    import numpy as np

    known = {e.get("robot_id"): e["model"] for e in entries if e.get("model")}
    entries = [
        e if e.get("model") else {**e, "model": known.get(e.get("robot_id"))} for e in entries
    ]

    def median(values: list) -> float | None:
        values = [v for v in values if v is not None]
        return float(np.median(values)) if values else None

    keys = (
        "baseline_position_rms_mm",
        "calibrated_position_rms_mm",
        "baseline_orientation_rms_deg",
        "calibrated_orientation_rms_deg",
    )
    out = []
    models = list(dict.fromkeys(e.get("model") for e in entries))
    for model in sorted(models, key=lambda m: (m is None, m or "")):
        group = [e for e in entries if e.get("model") == model]
        ok = [e for e in group if e["status"] == "ok"]
        drifted = sorted(
            {e["robot_id"] for e in group if (e.get("drift") or {}).get("verdict") == "drift"}
        )
        held_out = []
        metrics = dict.fromkeys(e.get("held_out_metric") for e in ok)
        for metric in sorted(metrics, key=lambda m: (m is None, m or "")):
            mine = [e for e in ok if e.get("held_out_metric") == metric]
            row: dict[str, Any] = {"metric": metric, "n_sessions": len(mine)}
            row |= {f"median_{key}": median([e.get(key) for e in mine]) for key in keys}
            held_out.append(row)
        summary = {
            "model": model,
            "n_sessions": len(group),
            "robots": sorted({str(e.get("robot_id")) for e in group}),
            "n_ok": len(ok),
            "n_failed": len(group) - len(ok),
            "drift_robots": drifted,
            "held_out": held_out,
        }
        one = held_out[0] if len(held_out) == 1 else {}
        for key in keys:
            summary[f"median_{key}"] = one.get(f"median_{key}")
        out.append(summary)
    return out
