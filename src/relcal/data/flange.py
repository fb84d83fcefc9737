"""Flange poses logged by a robot controller, with no robot model: a *pose chain* stands for the
robot.

A controller reports the flange (tool0) pose in its base frame. Hand-eye calibration needs nothing
else from the robot; the rest of relcal speaks of joint values and a model, so the poses become the
joint values of a six-joint chain (prismatic z, x, y in m, then revolute axes z, y, z in rad: the
chain of ``relcal import rct-images``, :data:`relcal.data.importers.POSE_CHAIN`) whose forward
kinematics reproduce each logged pose to round-off. The joint values are computed in closed form
(the ZYZ Euler angles of the rotation), not by a numerical inverse: every pose is reproduced, also
those at the chain's wrist singularity, where the split between the first and the last angle is
arbitrary but the pose is exact. The chain's tool is turned so that the mean orientation sits in
the middle of the wrist's range, far from that singularity.

Columns of a samples table: ``fx, fy, fz`` and one rotation (:data:`FLANGE_ROTATIONS`):
``fqx, fqy, fqz, fqw`` (unit quaternion, x first: what relcal writes, ``FLANGE_COLUMNS``), ``frx,
fry, frz`` (a rotation vector, as a UR controller logs its TCP pose) or ``froll, fpitch, fyaw``
(angles of a rotation sequence), in the units :class:`FlangeFormat` says.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from relcal import geometry as tf
from relcal.errors import RelcalError
from relcal.robot.model import RobotModel, model_from_dict

FLANGE_COLUMNS = ("fx", "fy", "fz", "fqx", "fqy", "fqz", "fqw")  # as relcal writes them
FLANGE_POSITION = FLANGE_COLUMNS[:3]
#: The rotations a controller's flange pose may come with: a unit quaternion (x first), a
#: rotation vector (a UR controller's rx, ry, rz) or three angles of a rotation sequence
FLANGE_ROTATIONS = {
    "quaternion": FLANGE_COLUMNS[3:],
    "rotation vector": ("frx", "fry", "frz"),
    "rpy": ("froll", "fpitch", "fyaw"),
}
FLANGE_NAMES = (*FLANGE_POSITION, *(c for cols in FLANGE_ROTATIONS.values() for c in cols))


@dataclass(frozen=True)
class FlangeFormat:
    """How a table's flange poses are written (``dataset.yaml``: ``flange_unit``,
    ``flange_angle_unit``, ``flange_euler``): the unit of ``fx, fy, fz`` (``m`` or ``mm``), the
    angle unit of a rotation vector or of ``froll, fpitch, fyaw`` (``rad`` or ``deg``), and the
    rotation sequence of the latter (SciPy's ``from_euler``)."""

    unit: str = "m"
    angle_unit: str = "rad"
    euler: str = "xyz"


REPRODUCED_TO = 1e-9  # m and rad: the chain's poses against the logged ones

_CHAIN = {
    "name": "flange poses",
    "source": (
        "Pose chain standing for a robot whose flange poses were logged by its controller: "
        "prismatic z, x, y (m) then revolute axes z, y, z (rad); its joint values reproduce each "
        "logged flange pose. Corrections of this chain describe errors of the logged poses, not "
        "of an arm."
    ),
    "convention": "dh",
    "angle_unit": "deg",
    "joints": [
        {"name": "z", "type": "prismatic", "theta_off": 90, "alpha": 90},
        {"name": "x", "type": "prismatic", "theta_off": 90, "alpha": 90},
        {"name": "y", "type": "prismatic", "theta_off": 90, "alpha": 90},
        {"name": "r1", "alpha": -90},
        {"name": "r2", "alpha": 90},
        {"name": "r3"},
    ],
}


def mean_rotation(rotations: np.ndarray) -> np.ndarray:
    """The chordal mean ``(3, 3)`` of rotations ``(N, 3, 3)``: their average projected on SO(3)."""
    u, _, vt = np.linalg.svd(np.mean(rotations, axis=0))
    return u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt


def flange_chain(flange: np.ndarray) -> tuple[RobotModel, np.ndarray]:
    """The pose chain and its joint values reproducing flange poses.

    Parameters
    ----------
    flange : (N, 4, 4) ndarray of float
        Flange poses in the robot's base frame, m.

    Returns
    -------
    model : RobotModel
        The six-joint pose chain (its tool turned so that the mean orientation is mid-range).
    q : (N, 6) ndarray of float
        Joint values (m, m, m, rad, rad, rad) with ``fk(model, q) == flange`` to round-off.

    Raises
    ------
    RelcalError
        A pose the chain does not reproduce (not a rigid transform).
    """
    from relcal.robot.kinematics import fk

    flange = np.asarray(flange, dtype=float)
    spec = {**_CHAIN, "joints": [dict(j) for j in _CHAIN["joints"]]}
    # The wrist is Rz(r1) Ry(r2) Rz(r3): mid-range (r2 = 90 deg) for the mean orientation.
    tool_rot = tf.rot_y(np.pi / 2).T @ mean_rotation(flange[:, :3, :3])
    spec["tool"] = {
        "rpy": [
            float(np.degrees(v)) for v in tf.to_xyz_rpy(tf.homogeneous(tool_rot, np.zeros(3)))[1]
        ]
    }
    model = model_from_dict(spec)
    # the prismatic joints translate along a permutation of the base axes: read it off the chain
    unit = np.zeros((3, 6))
    unit[:, :3] = np.eye(3)
    moves = fk(model, unit)[:, :3, 3].T  # column i: the flange shift of joint i per m
    q = np.zeros((len(flange), 6))
    q[:, :3] = np.linalg.solve(moves, flange[:, :3, 3].T).T
    wrist = flange[:, :3, :3] @ model.tool[:3, :3].T
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # gimbal lock: one angle set to 0, the pose still exact
        q[:, 3:] = Rotation.from_matrix(wrist).as_euler("ZYZ")
    miss = np.abs(fk(model, q) - flange).max(axis=(1, 2)) if len(q) else np.zeros(0)
    if np.any(miss > REPRODUCED_TO):
        bad = int(np.argmax(miss))
        raise RelcalError(
            f"flange pose {bad + 1}: not reproduced by the pose chain (miss {miss[bad]:.2g}): "
            "not a rigid transform?"
        )
    return model, q
