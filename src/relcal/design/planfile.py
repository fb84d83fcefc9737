"""The plan file: the joint configurations ``relcal plan`` writes and ``relcal capture`` runs.

A CSV whose first line is a comment stating the robot and the unit, a second comment saying how
to load that robot (a built-in name, a model file, or a URDF with its chain; files relative to
the plan's folder), then a header naming the joints as the robot model does, one row per pose in
travel order::

    # relcal plan: robot Universal Robots UR5e, joint unit deg
    # relcal robot: ur5e
    id,shoulder_pan,shoulder_lift,elbow,wrist1,wrist2,wrist3
    p001,12.5,-95.1,101.7,-96.3,-88.0,30.2
    ...

A plan for a fixed camera and the board on the flange has a third comment,
``# relcal mode: eye_to_hand``, which ``relcal capture`` writes into the dataset's ``mode``
(:func:`plan_mode`; without it a plan is for a camera on the flange, ``eye_in_hand``).

Angles are in the stated unit (``deg`` or ``rad``), prismatic joints always in m. The files of
older versions (``id,q1..qn`` in degrees, no comment line; no ``relcal robot`` line) are read
too. :func:`read_plan` is the
one reader; :func:`plan_text` the one writer.
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from relcal.data.dataset import PLAN_COMMENT, _row_id, _unique_columns, unit_mixup
from relcal.errors import RelcalError, printable
from relcal.numbers import NotANumber, parse_number
from relcal.robot.model import RobotModel, library_names

COMMENT = PLAN_COMMENT
MODE_LINE = re.compile(r"#\s*relcal mode:\s*(?P<mode>\S+)\s*$")
PLAN_MODES = ("eye_in_hand", "eye_to_hand")
ROBOT_LINE = re.compile(
    r"#\s*relcal robot:\s*(?P<robot>.+?)"
    r"(?:,\s*root\s+(?P<root>\S+))?(?:,\s*tip\s+(?P<tip>\S+))?\s*$"
)


@dataclass(frozen=True)
class PlanRobot:
    """How to load the robot a plan was made for: ``robot`` a built-in name or a file path
    (relative to the plan's folder as written; resolved when read), ``root`` and ``tip`` the
    URDF chain's links."""

    robot: str
    root: str | None = None
    tip: str | None = None

    def line(self) -> str:
        """The plan file's ``# relcal robot:`` line."""
        parts = [self.robot]
        if self.root:
            parts.append(f"root {self.root}")
        if self.tip:
            parts.append(f"tip {self.tip}")
        return "# relcal robot: " + ", ".join(parts)


@dataclass(frozen=True)
class PlanFile:
    """A read plan: ``ids`` (K,), ``q`` ``(K, n)`` in rad (m for prismatic joints) in the model's
    joint order, the ``unit`` the file was in and the ``robot`` it names (``None`` for an old
    file)."""

    ids: tuple[str, ...]
    q: np.ndarray
    unit: str
    robot: str | None
    source: PlanRobot | None = None  # how to load the robot (None: an older file)


def plan_robot(model: RobotModel, named: str, plan_folder: str | Path | None) -> PlanRobot:
    """How a plan names its robot for ``relcal capture``: a built-in name as is, a file by its
    path relative to ``plan_folder`` (the folder the plan is written into; None: as given), a
    URDF with the chain's root and tip."""
    import os

    if named.lower() in library_names():
        return PlanRobot(named.lower())
    path = Path(named)
    if plan_folder is not None:
        path = Path(os.path.relpath(path.resolve(), Path(plan_folder).resolve()))
    if model.urdf is not None:
        return PlanRobot(path.as_posix(), model.urdf.root, model.urdf.tip)
    return PlanRobot(path.as_posix())


def plan_text(
    model: RobotModel,
    q: np.ndarray,
    ids=None,
    unit: str = "deg",
    source: PlanRobot | None = None,
    mode: str = "eye_in_hand",
) -> str:
    """The plan file's text for configurations ``q`` ``(K, n)`` (rad, m) of ``model``, angles
    written in ``unit`` (``deg`` or ``rad``); ``ids`` default ``p001``, ``p002``, ...;
    ``source`` how to load the robot (:func:`plan_robot`), written as the second comment;
    ``mode`` ``eye_to_hand`` (a fixed camera, the board on the flange) written as the
    ``# relcal mode:`` comment (``eye_in_hand``, the default, writes none)."""
    if unit not in ("deg", "rad"):
        raise ValueError(f"unit '{unit}': use deg or rad")
    if mode not in PLAN_MODES:
        raise ValueError(f"mode '{mode}': use one of {', '.join(PLAN_MODES)}")
    q = np.atleast_2d(q)
    ids = [f"p{k + 1:03d}" for k in range(len(q))] if ids is None else list(ids)
    values = np.where(model.prismatic, q, np.degrees(q)) if unit == "deg" else q
    lines = [f"# relcal plan: robot {model.name}, joint unit {unit}"]
    if source is not None:
        lines.append(source.line())
    if mode != "eye_in_hand":
        lines.append(f"# relcal mode: {mode}")
    lines.append(",".join(["id", *model.joint_names]))
    for sid, row in zip(ids, values, strict=True):
        lines.append(",".join([str(sid), *(f"{v:.12g}" for v in row)]))
    return "\n".join(lines) + "\n"


def read_plan(path: str | Path, model: RobotModel, joint_unit: str | None = None) -> PlanFile:
    """Read a plan file for ``model``.

    Parameters
    ----------
    path : str or Path
        The plan CSV.
    model : RobotModel
        The robot the plan is for: its joint names (or ``q1`` .. ``qn``) must head the columns.
    joint_unit : {"deg", "rad"}, optional
        The unit of an old file without the comment line (default ``deg``, what older versions
        wrote); a file that states its unit is read in it, and a different ``joint_unit`` is an
        error.

    Returns
    -------
    PlanFile
        Ids and joint values ``(K, n)`` in rad (m for prismatic joints).

    Raises
    ------
    RelcalError
        The file is missing or malformed, names another robot or other joints, or its values
        are not numbers; the message names the file and line.
    """
    path = Path(path)
    robot, unit, source = plan_header(path)
    if unit is not None and joint_unit is not None and joint_unit != unit:
        raise RelcalError(f"{path}: the file states joint unit {unit}, but {joint_unit} was asked")
    if robot is not None and robot != model.name:
        raise RelcalError(
            f"{path} line 1: the plan is for robot '{robot}', not '{model.name}'; plan again "
            "for this robot or load the robot the plan was made for"
        )
    rows = _rows(path)
    unit = unit or joint_unit or "deg"
    data = [(no, line) for no, line in rows if not line.lstrip().startswith("#")]
    if len(data) < 2:
        raise RelcalError(f"{path}: expected a header line and one line per pose")
    header = [h.strip() for h in next(csv.reader([data[0][1]]))]
    _unique_columns(path, header, line=data[0][0])
    named, numbered = list(model.joint_names), [f"q{i + 1}" for i in range(model.n_joints)]
    columns = named if set(named) <= set(header) else numbered
    missing = [c for c in columns if c not in header]
    if "id" not in header or missing:
        raise RelcalError(
            f"{path} line {data[0][0]}: header: expected id and the joints of '{model.name}' "
            f"({', '.join(named)}, or {numbered[0]}..{numbered[-1]})"
            + (f"; missing {', '.join(missing)}" if missing else "")
        )
    extra = [h for h in header if h != "id" and h not in columns]
    if extra:
        raise RelcalError(
            f"{path} line {data[0][0]}: header: column(s) {', '.join(extra)} are not joints of "
            f"'{model.name}' ({model.n_joints} joints: {', '.join(named)}); a plan for another "
            "robot?"
        )
    col = [header.index(c) for c in columns]
    ids, values, seen = [], [], {}
    for no, line in data[1:]:
        cells = next(csv.reader([line]))
        if len(cells) != len(header):
            tabs = "\t" in line or ";" in line
            raise RelcalError(
                f"{path} line {no}: {len(cells)} fields, expected {len(header)}"
                + ("; separated by tabs or semicolons? a plan is comma-separated" if tabs else "")
            )
        row = []
        for name, i in zip(columns, col, strict=True):
            try:
                row.append(parse_number(cells[i]))
            except NotANumber as exc:
                raise RelcalError(f"{path} line {no}: {name}: {printable(exc)}") from None
        ids.append(_row_id(path, no, cells[header.index("id")], seen, "pose"))
        values.append(row)
    q = np.array(values)
    if not np.isfinite(q).all():
        raise RelcalError(f"{path}: joint values must be finite numbers")
    mixup = unit_mixup(q, model, unit) if unit == "deg" else None  # (rad: up to 4 pi below)
    if mixup:
        raise RelcalError(
            f"{path}: {mixup}, but the plan is read in degrees"
            + (
                " (its '# relcal plan:' line states joint unit deg); fix: joint unit rad there"
                if robot is not None
                else " (an older plan without the '# relcal plan:' line); fix: --joint-unit rad"
            )
        )
    if unit == "deg":
        q = np.where(model.prismatic, q, np.radians(q))
    elif (~model.prismatic).any() and np.abs(q[:, ~model.prismatic]).max() > 4 * np.pi + 0.1:
        raise RelcalError(f"{path}: joint angles exceed 4 pi, which looks like degrees, not rad")
    return PlanFile(tuple(ids), q, unit, robot, source)


def _rows(path: Path) -> list[tuple[int, str]]:
    """The non-blank lines of a plan file with their numbers."""
    from relcal.limits import read_input

    try:
        text = read_input(path, "csv").decode("utf-8-sig")
    except FileNotFoundError:
        raise RelcalError(f"{path}: plan file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise RelcalError(f"{path}: cannot read the plan file: {exc}") from None
    return [(no, line) for no, line in enumerate(text.splitlines(), 1) if line.strip()]


def plan_header(path: str | Path) -> tuple[str | None, str | None, PlanRobot | None]:
    """``(robot name, joint unit, how to load the robot)`` a plan file's comment lines state
    (None for what an older file does not say); a robot file is resolved against the plan's
    folder."""
    path = Path(path)
    robot = unit = source = None
    for no, line in _rows(path):
        if not line.lstrip().startswith("#"):
            break
        found = COMMENT.match(line.strip())
        if found:
            robot, unit = found["robot"], found["unit"]
            if unit not in ("deg", "rad"):
                raise RelcalError(f"{path} line {no}: joint unit '{unit}': expected deg or rad")
        named = ROBOT_LINE.match(line.strip())
        if named:
            spec = named["robot"].strip()
            if spec.lower() not in library_names():
                spec = str(path.parent / spec)
            source = PlanRobot(spec, named["root"], named["tip"])
    return robot, unit, source


def plan_mode(path: str | Path) -> str:
    """Where the plan's camera is: ``eye_to_hand`` when its comment lines say ``# relcal mode:
    eye_to_hand`` (a fixed camera, the board on the flange), else ``eye_in_hand``.

    Raises
    ------
    RelcalError
        The file is missing, or names a mode relcal does not plan for (the message names the
        file and line).
    """
    path = Path(path)
    for no, line in _rows(path):
        if not line.lstrip().startswith("#"):
            break
        found = MODE_LINE.match(line.strip())
        if found:
            if found["mode"] not in PLAN_MODES:
                raise RelcalError(
                    f"{path} line {no}: mode '{found['mode']}': expected one of "
                    f"{', '.join(PLAN_MODES)}"
                )
            return found["mode"]
    return "eye_in_hand"
