"""Plan files: the joint configurations ``relcal plan`` writes and ``relcal capture`` runs.

A plan is a CSV with a header ``id`` + one column per joint, named ``q1`` .. ``qn`` (as
``relcal plan`` has always written) or by the robot's joint names (``shoulder_pan_joint``, ...,
in any order), and one row per pose. Lines starting with ``#`` are comments; one of them may
state the unit of the angles::

    # unit: deg
    id,shoulder_pan_joint,shoulder_lift_joint,elbow_joint,wrist_1_joint,wrist_2_joint,wrist_3_joint
    p001,12.5,-80.1,95.0,-100.2,-90.0,3.0

``unit`` (or ``joint_unit``) is ``deg`` or ``rad``; without it angles are in degrees, as
``relcal plan`` writes by default. Prismatic joints are always in metres. Other columns and
other comment lines (``# robot: ur5e``, ``# longest move: ...``) are ignored.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from relcal.data.dataset import _joint_columns, _joint_values, parse_number
from relcal.errors import RelcalError
from relcal.io import note_input, read_table
from relcal.robot.model import RobotModel

_UNIT = re.compile(r"^\s*#\s*(?:joint_unit|unit|units)\s*[:=]\s*(\S+)\s*$", re.IGNORECASE)


@dataclass(frozen=True)
class Plan:
    """Planned poses in the order to visit them.

    Attributes
    ----------
    path : Path
        The plan file.
    ids : tuple of str
        Pose ids (the ``id`` column), unique; a captured sample keeps its pose's id.
    q : ndarray, shape (K, n)
        Joint targets in the model's joint order, rad (m for prismatic joints).
    unit : {"deg", "rad"}
        The unit the file states (or ``deg``, the default).
    """

    path: Path
    ids: tuple[str, ...]
    q: np.ndarray
    unit: str

    def __len__(self) -> int:
        return len(self.ids)


def read_plan(path: str | Path, model: RobotModel, unit: str | None = None) -> Plan:
    """Read a plan CSV for ``model``.

    Parameters
    ----------
    path : str or Path
    model : RobotModel
        The robot the plan was made for: its joint count and names select the columns.
    unit : {"deg", "rad"} or None
        The angle unit when the file states none (default ``deg``); a file's ``# unit:`` line
        that contradicts it is an error.

    Returns
    -------
    Plan

    Raises
    ------
    RelcalError
        Naming the file, the line and the column: missing joints, a wrong joint count, an
        unknown unit, a duplicate id, angles that look like the other unit.
    """
    path = Path(path)
    note_input(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise RelcalError(f"{path}: plan file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise RelcalError(f"{path}: cannot read the plan: {exc}") from None
    stated = None
    for number, line in enumerate(text.splitlines(), 1):
        match = _UNIT.match(line)
        if match:
            stated = match[1].lower()
            if stated not in ("deg", "rad"):
                raise RelcalError(
                    f"{path} line {number}: unit '{match[1]}': expected deg or rad (angles; "
                    "prismatic joints are always in m)"
                )
    if stated and unit and stated != unit:
        raise RelcalError(f"{path}: the file states unit {stated}, but {unit} was asked for")
    unit = stated or unit or "deg"
    header, rows = read_table(path, "pose", comments=True)
    if "id" not in header:
        raise RelcalError(
            f"{path} line 1: header: expected an 'id' column and the joint columns (as relcal "
            f"plan writes: id,q1..q{model.n_joints} or id and the joint names)"
        )
    joints = _joint_columns(path, header, model)
    col = {h: i for i, h in enumerate(header)}
    ids: list[str] = []
    seen: dict[str, int] = {}
    values = []
    for row in rows:
        if len(row) != len(header):
            raise RelcalError(
                f"{path} line {row.line}: {len(row)} fields, expected {len(header)} (the header)"
            )
        pid = row[col["id"]].strip()
        if not pid:
            raise RelcalError(f"{path} line {row.line}: id: empty")
        if not re.fullmatch(r"[A-Za-z0-9_.-]+", pid):
            raise RelcalError(
                f"{path} line {row.line}: id '{pid}': use letters, digits, '_', '-' and '.' only "
                "(it names the image file)"
            )
        if pid in seen:
            raise RelcalError(f"{path} line {row.line}: id '{pid}' duplicates line {seen[pid]}")
        seen[pid] = row.line
        ids.append(pid)
        values.append([parse_number(path, row.line, c, row[col[c]]) for c in joints])
    q = _joint_values(path, np.array(values, dtype=float), model, unit)
    return Plan(path, tuple(ids), q, unit)
