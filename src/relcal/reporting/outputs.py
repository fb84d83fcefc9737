"""The files of a calibration and of a measurement, written as one set.

The command line and the Python API write through these functions, so both give the same
guarantee (:mod:`relcal.outputset`): the set appears whole or not at all, the previous set is kept
as ``<folder>.prev/``, nothing the run read is written over.
"""

from __future__ import annotations

from pathlib import Path

from relcal.calibration.artifacts import RUN_ID_PREFIX  # first line of model.yaml
from relcal.calibration.outcome import Calibration
from relcal.checks import check_instance, check_path
from relcal.data.dataset import Dataset, joints_in_unit, write_samples
from relcal.data.imaging import Measurements
from relcal.io import json_text, yaml_text
from relcal.outputset import File, Folder, Journal, new_run_id, write_set
from relcal.reporting.documents import measurements_document, results_document
from relcal.reporting.ros2 import LAUNCH_FILE
from relcal.robot.export import parameter_csv


def calibration_files(cal: Calibration, doc: dict, run_id: str) -> dict[str, str | bytes]:
    """The content of every file of a calibration set: ``model.yaml`` (first line names the
    run), the robot's files (``robot.urdf``; for URDF robots also the origin corrections and the
    UR or Franka files, :func:`relcal.robot.export.robot_files`), beside ``robot.urdf`` the
    ROS 2 overlay ``ros2/calibrated.launch.py`` (:mod:`relcal.reporting.ros2`), ``parameters.csv``,
    ``results.json`` (with ``run_id``) and, when the intrinsics were calibrated from the images,
    ``camera.yaml`` (usable as a dataset's camera).

    The model files are the bytes that were read back and validated
    (:attr:`relcal.Calibration.artifacts`): ``model.yaml`` holds the chosen model, the robot's
    files the best geometry-only model (the chosen one when it has no non-geometric term); a
    file refused there (worse than the baseline, or unmeasured) is not written."""
    files: dict[str, str | bytes] = {}
    for artifact in cal.artifacts:
        if not artifact.written:
            continue
        if artifact.name == "model.yaml":  # the run's comment first: YAML ignores it
            files["model.yaml"] = (
                RUN_ID_PREFIX.encode() + run_id.encode() + b"\n" + artifact.content
            )
        else:
            files[artifact.name] = artifact.content
    if "robot.urdf" in files:
        files[LAUNCH_FILE] = ros2_overlay(cal, doc, files["robot.urdf"], run_id)
    files.update(
        {
            "parameters.csv": parameter_csv(doc["parameters"]),
            "results.json": json_text({**doc, "run_id": run_id}),
        }
    )
    camera = cal.measurements.camera
    if cal.dataset.camera == "calibrate" and camera is not None:
        files["camera.yaml"] = yaml_text(camera.to_dict())
    return files


def ros2_overlay(cal: Calibration, doc: dict, urdf: str | bytes, run_id: str) -> str:
    """The ROS 2 launch file beside ``robot.urdf`` (:mod:`relcal.reporting.ros2`): the URDF's
    chain, its SHA-256 and held-out error, and the calibration's hand-eye transform when it
    estimated one."""
    import numpy as np

    from relcal.geometry import from_xyz_rpy
    from relcal.reporting.ros2 import launch_file

    data = urdf.encode() if isinstance(urdf, str) else urdf
    chain = cal.dataset.model.urdf
    root, tip = (chain.root, chain.tip) if chain is not None else ("base_link", "tool0")
    found = doc.get("handeye")
    handeye = None
    if found:
        handeye = from_xyz_rpy(np.array(found["xyz_m"]), np.radians(found["rpy_deg"]))
    files = {f["file"]: f for f in (doc.get("artifacts") or {}).get("files", [])}
    held = (files.get("robot.urdf") or {}).get("held_out") or {}
    mode = (doc.get("settings") or {}).get("mode", "eye_in_hand")
    images = cal.dataset.measured == "image"
    held_mm = held.get("position_rms_mm")
    return launch_file(data, root, tip, handeye, mode, run_id, held_mm, images)


def calibration_outputs(
    cal: Calibration,
    out_dir: str | Path,
    doc: dict | None = None,
    json_path: str | Path | None = None,
    report_path: str | Path | None = None,
    run_id: str | None = None,
) -> list[Folder | File]:
    """The items :func:`write_calibration` writes (also to check destinations before a run)."""
    run_id = run_id or new_run_id()
    doc = results_document(cal) if doc is None else doc
    items: list[Folder | File] = [
        Folder(out_dir, calibration_files(cal, doc, run_id), what="--out", run_id=run_id)
    ]
    if json_path:
        items.append(File(json_path, json_text({**doc, "run_id": run_id}), "--json"))
    if report_path:
        from relcal.reporting.calibration_report import calibration_report

        items.append(File(report_path, calibration_report(cal, doc), "--report"))
    return items


def write_calibration(
    cal: Calibration,
    out_dir: str | Path,
    doc: dict | None = None,
    json_path: str | Path | None = None,
    report_path: str | Path | None = None,
    run_id: str | None = None,
    journal: Journal | None = None,
    registry=None,
) -> list[Path]:
    """Write a calibration's files into a folder, as one unit.

    The files read so far in this process count as inputs (never written over); wrap a
    session's runs in :func:`relcal.outputset.tracking` to start afresh.

    Parameters
    ----------
    cal : Calibration
        What :func:`relcal.calibrate` returned.
    out_dir : str or Path
        The output folder (``model.yaml``, ``robot.urdf``, ``results.json``,
        ``parameters.csv``, ...), replaced whole; the command line's ``--out``.
    doc : dict, optional
        The results document (default :func:`results_document`, to which the command adds
        cross-validation).
    json_path : str or Path, optional
        Also a copy of ``results.json`` here (the command line's ``--json``).
    report_path : str or Path, optional
        Also the HTML report here (the command line's ``--report``).
    run_id : str, optional
        The run id written into the files (default: a new one).
    journal : Journal, optional
        A registry record to commit in the same transaction as the set's install.
    registry : Registry, optional
        A :class:`relcal.fleet.registry.Registry`, opened with
        :func:`~relcal.fleet.registry.open_for_writing` before the work: the calibration is
        recorded in the same transaction as the set's install.

    Returns
    -------
    list of Path
        The files written: those in ``out_dir``, then ``json_path`` and ``report_path``.

    Raises
    ------
    ArgumentError
        ``cal`` not a :class:`~relcal.Calibration`, or ``out_dir`` (or ``json_path``,
        ``report_path``) not a path; nothing is written.
    RelcalError
        A destination is refused (an input of this process, a folder that is not a calibration
        set, unwritable); nothing is written.

    Examples
    --------
    >>> import tempfile, relcal
    >>> cal = relcal.calibrate(relcal.load_dataset("examples/tiago-pro-poses"), nongeometric="none")
    >>> files = relcal.write_calibration(cal, tempfile.mkdtemp() + "/cal")
    >>> sorted(path.name for path in files)[:3]
    ['calibrated.launch.py', 'model.yaml', 'origin_corrections.yaml']
    """
    check_instance(cal, Calibration, "cal", "a Calibration (what relcal.calibrate returned)")
    check_path(out_dir, "out_dir", "the output folder")
    for name, path in (("json_path", json_path), ("report_path", report_path)):
        if path is not None:
            check_path(path, name, "a file path")
    doc = results_document(cal) if doc is None else doc
    items = calibration_outputs(cal, out_dir, doc, json_path, report_path, run_id)
    if registry is not None and journal is None:
        from relcal.fleet.records import calibration_record

        journal = registry.pending(calibration_record(cal, doc, outputs=out_dir))
    write_set(*items, journal=journal)
    out = [Path(out_dir) / name for name in items[0].files]  # type: ignore[union-attr]
    return out + [Path(i.path) for i in items[1:]]


def measurement_outputs(
    dataset: Dataset, m: Measurements, out_dir: str | Path, json_path: str | Path | None = None
) -> list[Folder | File]:
    """``poses.csv`` (the posed samples, as a samples table), ``measurements.json`` and, when
    calibrated from the images, ``camera.yaml``; plus a copy of the JSON at ``json_path``."""
    ok = m.ok
    ids = [dataset.ids[i] for i in range(len(ok)) if ok[i]]
    q = joints_in_unit(dataset.model, dataset.q, "deg")
    doc = measurements_document(dataset, m)
    out_dir = Path(out_dir)
    files = {
        "poses.csv": write_samples(
            out_dir / "poses.csv",
            ids,
            q[ok],
            poses=m.poses[ok],
            positions_only=dataset.measured == "position",
        ),
        "measurements.json": json_text(doc),
    }
    if dataset.camera == "calibrate" and m.camera is not None:
        files["camera.yaml"] = yaml_text(m.camera.to_dict())
    items: list[Folder | File] = [Folder(out_dir, files, what="--out")]
    if json_path:
        items.append(File(json_path, json_text(doc), "--json"))
    return items


def write_measurements(
    dataset: Dataset, m: Measurements, out_dir: str | Path, json_path: str | Path | None = None
) -> list[Path]:
    """Write a measurement's set (see :func:`measurement_outputs`) as one unit."""
    items = measurement_outputs(dataset, m, out_dir, json_path)
    write_set(*items)
    return [Path(out_dir) / n for n in items[0].files] + [Path(i.path) for i in items[1:]]  # type: ignore[union-attr]
