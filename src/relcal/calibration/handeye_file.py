"""A finished hand-eye as the starting guess of a calibration: ``relcal calibrate --handeye``.

``relcal handeye`` writes ``handeye.yaml`` (:func:`relcal.reporting.handeye_report.handeye_yaml`):
the mode and each transform with its parent and child frames, ``xyz`` (m), ``quaternion`` (x, y,
z, w) and ``rpy`` (rad). A calibration starts from ``X``, the camera (or marker) on the flange
(eye-in-hand, robot-world: the ``handeye`` entry) or the board on the flange (eye-to-hand: the
``marker`` entry; the ``handeye`` entry there is the fixed camera in the base frame).
:func:`handeye_guess` reads it and checks that it belongs to the dataset: the same kind of mode
(eye-to-hand against the others: another transform altogether), and the frames the dataset's
exports name (``frames:`` of dataset.yaml, else relcal's defaults): a hand-eye of another flange
or camera frame is refused, with the likely cause.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from relcal import geometry as tf
from relcal.errors import RelcalError

FILE = "handeye.yaml"
MODES = ("eye_in_hand", "eye_to_hand", "robot_world")


@dataclass(frozen=True)
class HandEyeFile:
    """``handeye.yaml`` as read: ``path``, ``mode``, the ``estimate`` it holds (a method's name)
    and its entries ``{key: (parent, child, transform (4, 4) m)}``."""

    path: Path
    mode: str
    estimate: str
    entries: dict[str, tuple[str, str, np.ndarray]]


def read_handeye_file(path: str | Path) -> HandEyeFile:
    """Read ``handeye.yaml`` (or the folder holding it), checking every entry: frames named,
    ``xyz`` three numbers (m), ``quaternion`` a unit one, ``rpy`` the same rotation.

    Parameters
    ----------
    path : str or Path
        The file, or the folder ``relcal handeye`` wrote (``DATASET/handeye``).

    Returns
    -------
    HandEyeFile

    Raises
    ------
    RelcalError
        No such file, or a field missing or malformed (naming the file and the field).
    """
    from relcal.io import load_yaml

    path = Path(path)
    if path.is_dir():
        path = path / FILE
    if not path.is_file():
        raise RelcalError(
            f"{path}: not found; expected the {FILE} that relcal handeye writes (or its folder)"
        )
    data, _ = load_yaml(path)
    if not isinstance(data, dict) or data.get("mode") not in MODES:
        raise RelcalError(
            f"{path}: mode: expected one of {', '.join(MODES)} (the {FILE} of relcal handeye)"
        )
    entries = {}
    for key in ("handeye", "world", "marker"):
        if key in data:
            entries[key] = _entry(path, key, data[key])
    if "handeye" not in entries:
        raise RelcalError(f"{path}: handeye: missing (the {FILE} of relcal handeye has one)")
    return HandEyeFile(path, data["mode"], str(data.get("estimate", "")), entries)


def _entry(path: Path, key: str, value) -> tuple[str, str, np.ndarray]:
    where = f"{path}: {key}"
    if not isinstance(value, dict):
        raise RelcalError(f"{where}: expected parent, child, xyz, quaternion and rpy")
    for name in ("parent", "child"):
        if not isinstance(value.get(name), str) or not value[name]:
            raise RelcalError(f"{where}.{name}: expected a frame name")
    numbers = {}
    for name, size in (("xyz", 3), ("quaternion", 4), ("rpy", 3)):
        v = value.get(name)
        ok = isinstance(v, list) and len(v) == size
        ok = ok and all(isinstance(c, int | float) and np.isfinite(c) for c in v)
        if not ok:
            raise RelcalError(f"{where}.{name}: expected {size} finite numbers")
        numbers[name] = np.array(v, dtype=float)
    quat = numbers["quaternion"]
    if abs(np.linalg.norm(quat) - 1.0) > 1e-6:
        raise RelcalError(
            f"{where}.quaternion: norm {np.linalg.norm(quat):.6f}, expected a unit quaternion "
            "(x, y, z, w)"
        )
    if np.abs(numbers["xyz"]).max() > 20.0:
        raise RelcalError(f"{where}.xyz: {numbers['xyz']}: metres expected (millimetres given?)")
    transform = tf.homogeneous(Rotation.from_quat(quat).as_matrix(), numbers["xyz"])
    from_rpy = tf.from_xyz_rpy(numbers["xyz"], numbers["rpy"])
    if np.abs(from_rpy[:3, :3] - transform[:3, :3]).max() > 1e-6:
        raise RelcalError(
            f"{where}: rpy and quaternion are different rotations (rpy in rad, URDF's fixed "
            "axes; edited by hand?)"
        )
    return value["parent"], value["child"], transform


def handeye_guess(path: str | Path, dataset) -> np.ndarray:
    """``X`` ``(4, 4)`` (m) of a finished hand-eye for ``dataset``'s calibration: the camera (or
    marker) on the flange, or eye-to-hand the board on the flange.

    Parameters
    ----------
    path : str or Path
        ``handeye.yaml`` of ``relcal handeye``, or its folder.
    dataset : Dataset
        The dataset to calibrate.

    Returns
    -------
    (4, 4) ndarray of float
        Flange-from-camera (eye-in-hand, robot-world) or flange-from-board (eye-to-hand), m.

    Raises
    ------
    RelcalError
        The file is malformed, or of another mode or other frames than the dataset's (the
        message names both and the likely cause).
    """
    from relcal.calibration.handeye_job import frame_names

    found = read_handeye_file(path)
    where = str(found.path)
    ours = dataset.mode
    if (found.mode == "eye_to_hand") != (ours == "eye_to_hand"):
        raise RelcalError(
            f"{where}: mode {found.mode}, the dataset is {ours}: "
            + (
                "its transform is of a fixed camera, not one on the flange"
                if found.mode == "eye_to_hand"
                else "its transform is of a camera on the flange, not of the board on it"
            )
            + "; run relcal handeye on a dataset of this cell, or give the mode: of dataset.yaml"
        )
    key = "marker" if ours == "eye_to_hand" else "handeye"
    if key not in found.entries:
        raise RelcalError(
            f"{where}: no {key} entry (the board on the flange); written by an older relcal "
            "handeye? run it again"
        )
    parent, child, transform = found.entries[key]
    frames = frame_names(dataset, found.mode)
    want = (frames["flange"], frames["marker"] if key == "marker" else frames["camera"])
    if (parent, child) != want:
        raise RelcalError(
            f"{where}: {key} is {parent} -> {child}, the dataset's is {want[0]} -> {want[1]}: "
            "a hand-eye of another flange or camera frame (another cell, or other frames: in "
            "its dataset.yaml); name the same frames in frames: of dataset.yaml if they are the "
            "same"
        )
    return transform
