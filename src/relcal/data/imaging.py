"""Images of a dataset to camera poses ``C_k``: detection, intrinsics (given or calibrated from the
same images), pose with covariance, and rejected frames with their reasons."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from relcal import geometry as tf
from relcal.checks import check_instance
from relcal.data.dataset import Dataset, check_dataset
from relcal.errors import ArgumentError, RelcalError
from relcal.vision.camera import calibrate_intrinsics
from relcal.vision.detect import Rejected, estimate_pose, measure_images


@dataclass(frozen=True)
class Measurements:
    """Camera poses ``C_k`` per sample and which samples are usable (:func:`relcal.measure`).

    Parameters
    ----------
    poses : (N, 4, 4) ndarray of float
        Camera in the board frame per sample (m); NaN where rejected.
    ok : (N,) ndarray of bool
        Usable samples.
    reasons : tuple of str
        Why each sample was rejected; ``""`` for accepted ones.
    rms_px : (N,) ndarray of float
        Board reprojection RMS per image (px); NaN without images.
    covariance : (N, 6, 6) ndarray of float or None
        Covariance of each pose's (translation m, rotation vector rad), or None.
    camera : Camera or None
        The intrinsics used (given or calibrated).
    intrinsics_report : dict
        How the intrinsics were calibrated from the images, when they were.
    detections : tuple of Detection or None
        The board points found in each image (None where not found), images only: what a
        reprojection-error fit (``relcal handeye``) needs.
    """

    poses: np.ndarray  # (N, 4, 4); NaN where rejected
    ok: np.ndarray  # (N,) bool
    reasons: tuple[str, ...]  # "" for accepted samples
    rms_px: np.ndarray  # (N,) reprojection RMS, NaN without images
    covariance: np.ndarray | None = None  # (N, 6, 6) of (translation, rotation vector), or None
    camera: object = None  # the intrinsics used (given or calibrated)
    intrinsics_report: dict = field(default_factory=dict)
    detections: tuple | None = None  # (N,) board points found per image, images only


def check_measurements(measurements: Any, dataset: Dataset, name: str = "measurements") -> None:
    """``measurements`` are :class:`Measurements` of ``dataset`` (one entry per sample)."""
    check_instance(measurements, Measurements, name, "Measurements (relcal.measure(dataset))")
    if len(measurements.ok) != len(dataset.ids):
        raise ArgumentError(
            f"{name}: {len(measurements.ok)} samples, the dataset has "
            f"{len(dataset.ids)}: measured from another dataset?"
        )


def measure(
    dataset: Dataset, workers: int = 2, progress: bool = True, max_rms: float = 1.0
) -> Measurements:
    """Camera poses of every sample: given directly, or measured from the images.

    Parameters
    ----------
    dataset : Dataset
        The samples (:func:`relcal.load_dataset`).
    workers : int
        Processes that detect the board in images (1 or more).
    progress : bool
        Show a progress bar while images are measured.
    max_rms : float
        Frames whose board reprojection RMS is above this (px, > 0) are rejected.

    Returns
    -------
    Measurements
        One pose per sample, with which are usable and why others are not.

    Raises
    ------
    ArgumentError
        ``dataset`` not a :class:`Dataset`, ``workers`` below 1 or not whole, ``max_rms`` not
        positive.
    RelcalError
        No image shows the board (with the likely cause).
    """
    from relcal.checks import check_flag, check_number

    check_dataset(dataset)
    check_number(workers, "workers", 1, integer=True)
    check_number(max_rms, "max_rms", 0, low_open=True)
    check_flag(progress, "progress")
    n = len(dataset.ids)
    if dataset.poses is not None:
        return Measurements(
            poses=dataset.poses,
            ok=np.ones(n, dtype=bool),
            reasons=("",) * n,
            rms_px=np.full(n, np.nan),
        )
    return measure_dataset_images(dataset, workers=workers, progress=progress, max_rms=max_rms)


def measure_dataset_images(
    dataset: Dataset, workers: int = 2, progress: bool = True, max_rms: float = 1.0
) -> Measurements:
    """Camera poses of every image of ``dataset``.

    Eye-in-hand: ``C_k`` is the camera pose in the board frame. Eye-to-hand: the board moves with
    the flange, so ``C_k`` is the board pose in the camera frame (the inverse); both satisfy
    ``C_k = W F_k X``.
    """
    n = len(dataset.ids)
    calibrate = dataset.camera == "calibrate"
    camera = None if calibrate else dataset.camera
    results = measure_images(
        dataset.images, dataset.board, camera, workers=workers, progress=progress, max_rms=max_rms
    )
    reasons = [r.reason or "" for r in results]
    report: dict = {}
    if calibrate:
        found = [k for k in range(n) if results[k].detection is not None]
        if len(found) < 4:
            raise _never_found(dataset, reasons)
        intr = calibrate_intrinsics([results[k].detection for k in found])
        camera = intr.camera
        report = {
            "calibrated_from_images": True,
            "rms_px": intr.rms,
            "per_image_rms_px": {
                dataset.ids[found[i]]: float(v) for i, v in enumerate(intr.per_image_rms)
            },
            "rejected": {dataset.ids[found[i]]: why for i, why in intr.rejected.items()},
            "std_px": intr.std,
        }
        for i, why in intr.rejected.items():
            reasons[found[i]] = f"intrinsics: {why}"
    poses = np.full((n, 4, 4), np.nan)
    cov = np.full((n, 6, 6), np.nan)
    rms = np.full(n, np.nan)
    for k, res in enumerate(results):
        pose = res.pose
        if calibrate and not reasons[k] and res.detection is not None:
            pose = estimate_pose(res.detection, camera, max_rms=max_rms)
            if isinstance(pose, Rejected):
                reasons[k], pose = f"{res.path}: {pose.reason}", None
        if pose is None or reasons[k]:
            continue
        c = pose.T_board_camera
        poses[k] = tf.invert(c) if dataset.mode == "eye_to_hand" else c  # robot_world: on it
        cov[k], rms[k] = pose.covariance, pose.rms
    ok = np.all(np.isfinite(poses), axis=(1, 2))
    if not ok.any():
        raise _never_found(dataset, reasons)
    detections = tuple(r.detection for r in results)
    return Measurements(poses, ok, tuple(reasons), rms, cov, camera, report, detections)


def _never_found(dataset: Dataset, reasons: list[str]) -> RelcalError:
    first = next((r for r in reasons if r), "no reason recorded")
    return RelcalError(
        f"{dataset.spec_path or 'images'}: the board was not found (or not posed) in enough of the "
        f"{len(reasons)} images; first reason: {first}"
    )
