"""One unit per quantity in every JSON document: the serializers that results.json, the verify and
history documents, compare and the fleet use for a transform, a point and a parameter value.

- A transform (hand-eye, instrument, world, tool): ``{"xyz_m": [x, y, z], "rpy_deg": [r, p, y]}``,
  translation in metres and the URDF's roll, pitch, yaw (fixed axes x, y, z) in degrees
  (:func:`transform_json`).
- A point (marker, tool point, group points): metres, under a key ending in ``_xyz_m``
  (:func:`point_json`).
- A kinematic parameter (an identified error, its standard deviation, a difference between two
  runs): in the unit a person reads, named beside it in ``unit``: mm for lengths, deg for angles,
  ppm for joint scales, urad/Nm or um/N for compliances (:func:`parameter_json`).
- Held-out errors: mm and deg, the unit in the key (``position_mm``, ``orientation_deg``).

Inside relcal every quantity is SI (m, rad); only these functions convert.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from relcal.geometry import to_xyz_rpy
from relcal.robot.kinematics import DISPLAY_UNITS

TRANSFORM_KEYS = ("xyz_m", "rpy_deg")


def transform_json(transform: np.ndarray) -> dict[str, list[float]]:
    """A rigid transform ``(4, 4)`` (m) as ``{"xyz_m": [...], "rpy_deg": [...]}``: the translation
    in metres and the URDF's roll, pitch and yaw about the fixed x, y and z axes in degrees.

    Parameters
    ----------
    transform : (4, 4) array_like of float
        The transform, translation in m.

    Returns
    -------
    dict
        ``xyz_m`` (3 floats, m) and ``rpy_deg`` (3 floats, deg).
    """
    xyz, rpy = to_xyz_rpy(np.asarray(transform, dtype=float))
    return {"xyz_m": [float(v) for v in xyz], "rpy_deg": [float(np.degrees(v)) for v in rpy]}


def point_json(point: Sequence[float] | np.ndarray) -> list:
    """A point ``(3,)`` or points ``(N, 3)`` (m) as nested lists of floats, in metres (the key it
    goes under ends in ``_xyz_m``)."""
    return np.asarray(point, dtype=float).tolist()


def parameter_json(value: float | None, si_unit: str) -> tuple[float | None, str]:
    """A parameter value in SI (``si_unit``: ``m``, ``rad``, ``1`` for a joint scale,
    ``rad/(N m)`` or ``m/N`` for a compliance) in the unit a person reads, and that unit: mm,
    deg, ppm, urad/Nm or um/N. None stays None.

    Parameters
    ----------
    value : float or None
        The value in ``si_unit``.
    si_unit : str
        Its SI unit (:meth:`relcal.robot.kinematics.Layout.units`).

    Returns
    -------
    value : float or None
        In the unit returned.
    unit : str
        The unit shown.
    """
    factor, shown = DISPLAY_UNITS.get(si_unit, (1.0, si_unit))
    return (None if value is None else float(value) * factor), shown
