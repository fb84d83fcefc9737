"""easy_handeye2's saved samples as a relcal dataset folder, for ``relcal handeye``.

easy_handeye2 (ROS 2) saves a session's samples as YAML (``~/.ros2/easy_handeye2/samples/
NAME.samples``, a ``SampleList`` message): each sample holds two ``geometry_msgs/Transform``,
``robot`` and ``tracking``, each a ``translation`` (x, y, z, m) and a ``rotation`` (x, y, z, w).
What they are depends on the calibration type, which the file does not say (tf2's
``lookup_transform(target, source)``, the pose of ``source`` in ``target``):

- ``eye_in_hand``: ``robot`` is the effector in the robot base frame (relcal's flange pose
  ``F``), ``tracking`` the marker (board) in the camera frame; relcal's eye-in-hand pose is the
  camera in the board frame, its inverse.
- ``eye_on_base`` (relcal's ``eye_to_hand``): ``robot`` is the base in the effector frame
  (``F^-1``), ``tracking`` the marker on the flange in the camera frame, relcal's pose as is.

Read with the wrong type, the two transforms are both inverted, which fits the hand-eye equation
as well as the right reading (the roles of the hand-eye transform and the fixed frame swap): no
check of the data can tell, so the type must be given.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pydantic
from scipy.spatial.transform import Rotation

from relcal import geometry as tf
from relcal.data.dataset import POSE_COLUMNS
from relcal.data.flange import FLANGE_COLUMNS
from relcal.data.importers import Imported
from relcal.errors import RelcalError
from relcal.io import Folder, csv_line, load_validated, write_set, yaml_text

TYPES = {"eye_in_hand": "eye_in_hand", "eye_on_base": "eye_to_hand", "eye_to_hand": "eye_to_hand"}


class _Vector(pydantic.BaseModel):
    model_config = pydantic.ConfigDict(extra="forbid")
    x: pydantic.FiniteFloat
    y: pydantic.FiniteFloat
    z: pydantic.FiniteFloat


class _Quaternion(_Vector):
    w: pydantic.FiniteFloat


class _Transform(pydantic.BaseModel):
    model_config = pydantic.ConfigDict(extra="forbid")
    translation: _Vector
    rotation: _Quaternion


class _Sample(pydantic.BaseModel):
    model_config = pydantic.ConfigDict(extra="forbid")
    robot: _Transform
    tracking: _Transform


class _SampleList(pydantic.BaseModel):
    samples: list[_Sample] = pydantic.Field(min_length=1)


def _matrices(transforms: list[_Transform], where: str) -> np.ndarray:
    """``(N, 4, 4)`` from transforms whose rotations must be unit quaternions."""
    quat = np.array([[t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w] for t in transforms])
    norms = np.linalg.norm(quat, axis=1)
    bad = np.flatnonzero(np.abs(norms - 1) > 1e-3)
    if bad.size:
        raise RelcalError(
            f"{where} of sample {bad[0] + 1}: rotation: expected a unit quaternion, the norm is "
            f"{norms[bad[0]]:.4g}"
        )
    xyz = np.array([[t.translation.x, t.translation.y, t.translation.z] for t in transforms])
    return tf.homogeneous(Rotation.from_quat(quat / norms[:, None]).as_matrix(), xyz)


def import_easy_handeye2(source: str | Path, out: str | Path, calibration_type: str) -> Imported:
    """Write a dataset folder for ``relcal handeye`` from easy_handeye2's saved samples.

    Parameters
    ----------
    source : str or Path
        easy_handeye2's ``NAME.samples`` file (YAML).
    out : str or Path
        The dataset folder to write (new or empty: an existing dataset is never replaced).
    calibration_type : {"eye_in_hand", "eye_on_base", "eye_to_hand"}
        easy_handeye2's ``calibration_type`` of the session (``eye_to_hand`` is relcal's name
        of ``eye_on_base``).

    Returns
    -------
    Imported
        The dataset folder written: ``dataset.yaml`` (the mode, no robot: the logged flange
        poses stand for it) and ``samples.csv`` (``id``, the flange pose ``fx .. fqw`` in the
        robot's base frame, the measured pose ``x .. qw`` in relcal's convention for the mode;
        m).

    Raises
    ------
    RelcalError
        An unknown calibration type, a file that is not easy_handeye2's samples, a rotation that
        is not a unit quaternion.
    """
    if calibration_type not in TYPES:
        raise RelcalError(
            f"calibration type '{calibration_type}': expected eye_in_hand or eye_on_base "
            "(easy_handeye2's calibration_type of the session)"
        )
    mode = TYPES[calibration_type]
    samples = load_validated(_SampleList, source).samples
    where = str(source)
    robot = _matrices([s.robot for s in samples], f"{where}: robot")
    tracking = _matrices([s.tracking for s in samples], f"{where}: tracking")
    flange = robot if mode == "eye_in_hand" else tf.invert(robot)
    measured = tf.invert(tracking) if mode == "eye_in_hand" else tracking
    rows = [csv_line(["id", *FLANGE_COLUMNS, *POSE_COLUMNS])]
    for k, (f, c) in enumerate(zip(flange, measured, strict=True)):
        cells = []
        for pose in (f, c):
            quat = Rotation.from_matrix(pose[:3, :3]).as_quat()
            cells += [f"{v:.17g}" for v in (*pose[:3, 3], *quat)]
        rows.append(csv_line([str(k + 1), *cells]))
    spec = {"mode": mode, "samples": "samples.csv"}
    contents = {"samples.csv": "\n".join(rows) + "\n", "dataset.yaml": yaml_text(spec)}
    out = Path(out)
    write_set(Folder(out, contents, what="--out", replace="refuse"))
    return Imported(out, tuple(out / name for name in contents), len(samples))
