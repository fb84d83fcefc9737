"""The dataset folder: ``dataset.yaml`` plus one CSV table of samples.

``dataset.yaml``::

    robot: a465                # built-in name, a model YAML or URDF path (relative to the
                               # folder), an inline model mapping, or a URDF chain:
                               # {urdf: robot.urdf, root: base_link, tip: tool0}; may be left
                               # out when the samples give flange poses (fx .. fqw)
    hayati: auto               # auto | off: Hayati's beta for parallel consecutive axes
    mode: eye_in_hand          # eye_in_hand (camera on the flange) | eye_to_hand (board on it)
                               # | robot_world (camera or marker on the flange, measured in a
                               # fixed world frame; relcal handeye reports both transforms)
    board: board.yaml          # path or inline mapping (needed when samples have images)
    camera: camera.yaml        # path, inline mapping, or "calibrate" (from the same images)
    handeye:                   # guess of flange-from-camera (eye-in-hand) or flange-from-board
      xyz: [0.0, 0.04, 0.06]   # m   (optional: without it, a hand-eye solve on the data
      rpy: [0.0, 0.0, 0.0]     # deg  (OpenCV's calibrateHandEye) gives the starting guess)
    joint_unit: deg            # deg | rad (prismatic joints always in m)
    pose_angle_unit: rad       # rad | deg: unit of roll, pitch, yaw columns (default rad)
    euler: xyz                 # the roll, pitch, yaw columns' rotation sequence, as SciPy's
                               #   Rotation.from_euler: xyz (default, URDF: Rz(yaw) Ry(pitch)
                               #   Rx(roll)), XYZ intrinsic (R = Rx Ry Rz), ZYX, ...
    position_unit: m           # m | mm: unit of the x, y, z columns (default m)
    flange_unit: m             # m | mm: of logged flange poses fx, fy, fz (relcal handeye)
    flange_angle_unit: rad     # rad | deg: of their frx, fry, frz or froll, fpitch, fyaw
    flange_euler: xyz          # the sequence of froll, fpitch, fyaw (as euler)
    decimal: "."               # "." | ",": the decimal mark of the table's numbers (a decimal
                               #   comma needs semicolons or tabs between the columns)
    columns: {x: x1, roll: phix1}   # relcal column name: the file's header, for other layouts
    samples: samples.csv
    tolerances:                # optional plausibility thresholds (defaults shown)
      length_mm: 10            #   largest identified correction of a link length
      angle_deg: 5             #   of a joint offset or twist
      translation_mm: 100      #   median relative-translation misfit of the data (see plausibility)
    robot_id: cell4-arm2       # optional: which physical robot (history); default folder name
    measurement: coincidence   # optional: coincidence samples (inferred from a group column)
    tool: {xyz: [0, 0, 0.03]}  # coincidence: guess of the tool point in the tip frame (m)
    distances:                 # coincidence: known distances between groups' points (m)
      - {groups: [front/hole_0, front/hole_1], distance: 0.050, std: 0.0002}
    frames: {base: base_link, flange: tool0, camera: camera_optical}  # relcal handeye's
                               #   frame names in its exports (also world, marker)
    joint_limits:              # optional: the cell's limits, narrower than the robot's, in
      elbow: [-170, 170]       #   joint_unit (prismatic joints in m); plan and capture keep them

``samples.csv`` has a header: ``id`` (optional: without it the samples are numbered 1, 2, ... in
the order of their rows, blank lines not counted), one
column per joint, named ``q1`` .. ``qn`` or by the model's joint names (``torso_lift_joint``, ...,
matched by name in any order), then what was measured, one of:

- ``image``: a path relative to the folder;
- a pose ``x, y, z, qx, qy, qz, qw`` (``position_unit``, unit quaternion) or ``x, y, z, roll,
  pitch, yaw`` (by default the URDF convention ``R = Rz(yaw) Ry(pitch) Rx(roll)``, another
  sequence by ``euler``; angles in ``pose_angle_unit``): the camera in the
  board frame (eye-in-hand), the board in the camera frame (eye-to-hand), or a motion-capture
  rigid body in the instrument's frame; the instrument-to-base transform cancels;
- a position ``x, y, z`` alone: a laser tracker's reflector or a marker, in the instrument's
  frame (calibrated with the instrument transform and the marker position estimated);
- flange poses ``fx, fy, fz, fqx, fqy, fqz, fqw`` (the flange in the robot's base frame as the
  controller logs it, m, unit quaternion x first) beside the measured columns: with no
  ``robot:`` they stand for the robot (a pose chain, :mod:`relcal.data.flange`, reproduces
  them) and no joint columns are needed;
- nothing but a ``group`` (coincidence samples: the tool point seated at the same unknown point
  for every sample of a group, e.g. a ball in a socket), named ``PLACEMENT/NAME``
  (``front/hole_0``), or with a ``placement`` column that is prefixed to the group's name.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pydantic
from scipy.spatial.transform import Rotation

from relcal import geometry as tf
from relcal.checks import (
    check_choice,
    check_instance,
    check_number,
    check_path,
    describe,
    real_array,
)
from relcal.data.flange import FlangeFormat
from relcal.errors import ArgumentError, RelcalError, excerpt, printable
from relcal.io import csv_line, load_yaml, note_input, read_table, table_delimiter, validate
from relcal.limits import check_input_size
from relcal.numbers import NUMBER, NotANumber
from relcal.numbers import parse_number as _parse_number
from relcal.robot.loading import get_robot
from relcal.robot.model import (
    RobotModel,
    auto_hayati,
    library_names,
    model_from_dict,
    restrict_limits,
)

POSE_COLUMNS = ("x", "y", "z", "qx", "qy", "qz", "qw")
RPY_COLUMNS = ("x", "y", "z", "roll", "pitch", "yaw")
POSITION_COLUMNS = ("x", "y", "z")
Measured = Literal["image", "pose", "position", "coincidence"]
Mode = Literal["eye_in_hand", "eye_to_hand", "robot_world"]
MODES = ("eye_in_hand", "eye_to_hand", "robot_world")
COINCIDENCE_COLUMNS = ("group", "placement")


class _Frame(pydantic.BaseModel):
    model_config = pydantic.ConfigDict(extra="forbid")
    xyz: tuple[pydantic.FiniteFloat, pydantic.FiniteFloat, pydantic.FiniteFloat] = (0.0, 0.0, 0.0)
    rpy: tuple[pydantic.FiniteFloat, pydantic.FiniteFloat, pydantic.FiniteFloat] = (0.0, 0.0, 0.0)


class _Frames(pydantic.BaseModel):
    """``frames:``: the names ``relcal handeye`` writes into its exports (tf, URDF)."""

    model_config = pydantic.ConfigDict(extra="forbid")
    base: str | None = None  # the robot's base frame (base_link)
    flange: str | None = None  # the flange or tool frame the poses are of (tool0)
    camera: str | None = None  # the camera (or marker) frame
    world: str | None = None  # the fixed frame: board, tracker, world
    marker: str | None = None  # eye-to-hand: the board on the flange


class _Tolerances(pydantic.BaseModel):
    """Plausibility thresholds (relcal.calibration.plausibility.Tolerances), display units."""

    model_config = pydantic.ConfigDict(extra="forbid")
    length_mm: pydantic.PositiveFloat | None = None
    angle_deg: pydantic.PositiveFloat | None = None
    handeye_mm: pydantic.PositiveFloat | None = None
    handeye_deg: pydantic.PositiveFloat | None = None
    rotation_deg: pydantic.PositiveFloat | None = None
    scale_percent: pydantic.PositiveFloat | None = None
    joint_limit_deg: pydantic.PositiveFloat | None = None
    translation_mm: pydantic.PositiveFloat | None = None


class _Distance(pydantic.BaseModel):
    """A known distance between two groups' points: ``{groups: [A, B], distance: M, std: M}``."""

    model_config = pydantic.ConfigDict(extra="forbid")
    groups: tuple[str, str]
    distance: pydantic.PositiveFloat  # m
    std: pydantic.PositiveFloat = 1e-4  # m


class _ToolPoint(pydantic.BaseModel):
    model_config = pydantic.ConfigDict(extra="forbid")
    xyz: tuple[pydantic.FiniteFloat, pydantic.FiniteFloat, pydantic.FiniteFloat]


class _UrdfRobot(pydantic.BaseModel):
    """``robot: {urdf: PATH, root: LINK, tip: LINK}``; root and tip may be left out when the
    tree has one obvious serial chain."""

    model_config = pydantic.ConfigDict(extra="forbid")
    urdf: str
    root: str | None = None
    tip: str | None = None
    parametrisation: Literal["minimal", "origins"] = "minimal"


class _DatasetSpec(pydantic.BaseModel):
    model_config = pydantic.ConfigDict(extra="forbid")
    robot: str | dict[str, Any] | None = None  # None: the samples' flange poses stand for it
    hayati: Literal["auto", "off"] = "auto"
    mode: Mode = "eye_in_hand"
    board: str | dict[str, Any] | None = None
    camera: str | dict[str, Any] | None = None
    handeye: _Frame | None = None
    joint_unit: Literal["deg", "rad"] = "deg"
    pose_angle_unit: Literal["deg", "rad"] = "rad"
    euler: str = "xyz"
    position_unit: Literal["m", "mm"] = "m"
    flange_unit: Literal["m", "mm"] = "m"
    flange_angle_unit: Literal["deg", "rad"] = "rad"
    flange_euler: str = "xyz"
    decimal: Literal[".", ","] = "."
    columns: dict[str, str] = {}
    samples: str = "samples.csv"
    tolerances: _Tolerances | None = None
    robot_id: str | None = None  # which physical robot (fleet history); default the folder name
    measurement: Literal["coincidence"] | None = None  # default: from the samples' columns
    tool: _ToolPoint | None = None  # coincidence: tool point guess in the tip frame (m)
    distances: list[_Distance] = []  # coincidence: known distances between groups (m)
    # the cell's own limits, narrower than the robot's (joint name or qK -> [lower, upper] in
    # joint_unit, prismatic joints in m): what plan and capture keep to
    joint_limits: dict[str, tuple[float, float]] | None = None
    frames: _Frames | None = None  # relcal handeye: frame names of the exports

    @pydantic.field_validator("hayati", mode="before")
    @classmethod
    def _yaml_booleans(cls, value: object) -> object:
        """YAML 1.1 reads ``off``/``no`` as False and ``on``/``yes`` as True."""
        if value is False:
            return "off"
        if value is True:
            return "auto"
        return value

    @pydantic.field_validator("euler", "flange_euler")
    @classmethod
    def _euler_sequence(cls, value: str) -> str:
        """A sequence SciPy's ``Rotation.from_euler`` takes: three axes of x, y, z, all lower
        case (extrinsic, about the fixed frame) or all upper case (intrinsic, about the moving
        one), no axis twice in a row."""
        if not is_euler_sequence(value):
            raise ValueError(
                "expected three axes of x, y, z, all lower case (extrinsic: xyz is the URDF's "
                "roll, pitch, yaw) or all upper case (intrinsic: XYZ), no axis twice in a row"
            )
        return value


def is_euler_sequence(value: str) -> bool:
    """Whether ``value`` is a rotation sequence of SciPy's ``Rotation.from_euler`` (``xyz``,
    ``ZYX``, ``zyz``, ...)."""
    return bool(
        len(value) == 3
        and (value.islower() or value.isupper())
        and set(value.lower()) <= set("xyz")
        and value[0].lower() != value[1].lower() != value[2].lower()
    )


@dataclass(frozen=True)
class Dataset:
    """A loaded dataset: the robot, the joint values of every sample and what was measured.

    Made by :func:`relcal.load_dataset` (a folder) or :meth:`Dataset.from_arrays` (arrays in
    memory); frozen.

    Parameters
    ----------
    root : Path
        The dataset folder (where relative paths of ``dataset.yaml`` start).
    model : RobotModel
        The nominal robot.
    mode : {"eye_in_hand", "eye_to_hand", "robot_world"}
        Camera on the flange looking at a fixed board, a fixed camera and the board on the
        flange, or a camera or marker on the flange measured in a fixed world frame (as
        eye-in-hand; ``relcal handeye`` reports the world frame too).
    handeye : (4, 4) ndarray of float or None
        Guess of the flange-from-camera (or flange-from-board) transform, m; None to estimate
        it from the data.
    ids : tuple of str
        ``N`` sample ids.
    q : (N, n_joints) ndarray of float
        Joint values in rad (m for prismatic joints).
    images : tuple of Path or None
        One image per sample, or None when poses are given.
    poses : (N, 4, 4) ndarray of float or None
        Measured camera poses ``C_k`` (or instrument poses, or points in the translation column
        for ``measured="position"``) when given directly, m.
    board : Board or None
        The calibration board seen in the images.
    camera : Camera, str or None
        The camera intrinsics, or ``"calibrate"`` to calibrate them from the same images.
    spec_path : Path or None
        The ``dataset.yaml`` read, for messages.
    tolerances : dict of str to float or None
        Plausibility thresholds (mm, deg, percent) overriding the defaults.
    measured : {"image", "pose", "position", "coincidence"}
        What each sample holds.
    robot_id : str or None
        Which physical robot (the registry's history); the folder name when absent.
    joint_unit, pose_angle_unit : str or None
        The units as declared in ``dataset.yaml`` (the diagnoses name them).
    euler : str or None
        The rotation sequence of roll, pitch, yaw columns as declared (SciPy's ``from_euler``),
        when the poses came so (the diagnoses try the others).
    groups : tuple of str or None
        Coincidence samples: each sample's group (a socket of a placement).
    tool_point : (3,) ndarray of float or None
        Coincidence samples: the tool point guess in the tip frame, m (None: solved).
    distances : tuple of (str, str, float, float)
        Coincidence samples: known distances between groups as
        ``(group_a, group_b, distance_m, std_m)``.
    flange : (N, 4, 4) ndarray of float or None
        Flange poses logged by the controller (columns ``fx`` .. ``fqw``), m; when the dataset
        names no robot, ``model`` is the pose chain that reproduces them
        (:func:`relcal.data.flange.flange_chain`).
    frames : dict of str to str or None
        ``frames:`` of dataset.yaml: the frame names ``relcal handeye`` exports with (``base``,
        ``flange``, ``camera``, ``world``, ``marker``).
    samples_path : Path or None
        The samples table as dataset.yaml names it (``samples:``), which messages about samples
        name; None for :meth:`from_arrays`.
    """

    root: Path
    model: RobotModel
    mode: str
    handeye: np.ndarray | None  # (4, 4) guess, or None to estimate it from the data
    ids: tuple[str, ...]
    q: np.ndarray
    images: tuple[Path, ...] | None  # one per sample, or None when poses are given
    poses: np.ndarray | None  # (N, 4, 4) measured C_k when given directly
    board: Any = None
    camera: Any = None  # a relcal.vision.camera.Camera, or "calibrate"
    spec_path: Path | None = None
    tolerances: dict[str, float] | None = None  # plausibility thresholds (mm, deg, percent)
    measured: Measured = "image"  # or "pose"; "position": poses hold points (rotation unused)
    robot_id: str | None = None  # ``robot_id`` of dataset.yaml (the folder name when absent)
    joint_unit: str | None = None  # as declared in dataset.yaml (the diagnoses name it)
    pose_angle_unit: str | None = None  # as declared, when the poses came as roll, pitch, yaw
    euler: str | None = None  # their rotation sequence as declared (SciPy's), likewise
    # Coincidence samples (``measured == "coincidence"``): each sample's group, the tool point
    # guess (tip frame, m; None: solved from the data) and the known distances between groups as
    # ``(group_a, group_b, distance_m, std_m)``.
    groups: tuple[str, ...] | None = None
    tool_point: np.ndarray | None = None
    distances: tuple[tuple[str, str, float, float], ...] = ()
    flange: np.ndarray | None = None  # (N, 4, 4) logged flange poses (fx .. fqw), when given
    frames: dict[str, str] | None = None  # relcal handeye: frame names of its exports
    samples_path: Path | None = None  # the samples table dataset.yaml names (messages name it)

    @classmethod
    def from_arrays(
        cls,
        model: RobotModel | str | None,
        q: np.ndarray | None,
        poses: np.ndarray | None = None,
        mode: Literal["eye_in_hand", "eye_to_hand"] = "eye_in_hand",
        handeye: np.ndarray | None = None,
        *,
        joint_unit: Literal["rad", "deg"] = "rad",
        hayati: Literal["auto", "off"] = "auto",
        ids: Sequence[str] | None = None,
        images: Sequence[str | Path] | None = None,
        board: Any = None,
        camera: Any = None,
        tolerances: dict[str, float] | None = None,
        robot_id: str | None = None,
        root: str | Path = ".",
        flange: np.ndarray | None = None,
    ) -> Dataset:
        """A dataset from arrays in memory: what :func:`load_dataset` reads from a folder.

        Parameters
        ----------
        model : RobotModel, str or None
            The nominal robot, or what :func:`relcal.get_robot` takes (a built-in name, a model
            YAML or a URDF path); None with ``flange`` (and ``q`` None): the flange poses stand
            for the robot (a pose chain, :func:`relcal.data.flange.flange_chain`), for
            :func:`relcal.handeye`.
        q : array_like, shape (N, n), or None
            Joint values, one row per sample, in ``joint_unit`` (prismatic joints in m); None
            when ``model`` is None.
        poses : array_like, shape (N, 4, 4), (N, 7) or (N, 3), optional
            What was measured at each configuration. ``(N, 4, 4)`` homogeneous transforms (m) or
            ``(N, 7)`` rows ``x, y, z, qx, qy, qz, qw``: the camera in the board frame
            (``eye_in_hand``), the board in the camera frame (``eye_to_hand``), or a
            motion-capture rigid body in the instrument's frame. ``(N, 3)``: positions alone
            (a laser tracker's reflector, a marker), calibrated with the instrument transform
            and the marker position estimated. Give ``images`` instead for images.
        mode : {"eye_in_hand", "eye_to_hand"}
            Camera on the flange looking at a fixed board, or a fixed camera and the board on
            the flange.
        handeye : array_like, shape (4, 4), optional
            Guess of the flange-from-camera (eye-in-hand) or flange-from-board transform, m.
            Without it a hand-eye solve on the data gives the starting guess.
        joint_unit : {"rad", "deg"}
            Unit of the revolute joints in ``q``.
        hayati : {"auto", "off"}
            Hayati's ``beta`` for parallel consecutive axes, as ``hayati:`` in dataset.yaml.
        ids : sequence of str, optional
            Sample ids (default ``"0"`` .. ``"N-1"``).
        images, board, camera : optional
            Image paths (one per sample) with the board (:func:`relcal.vision.boards.load_board`)
            and camera intrinsics (:func:`relcal.vision.camera.load_camera`, or ``"calibrate"``).
        tolerances : dict, optional
            Plausibility thresholds as ``tolerances:`` in dataset.yaml (mm, deg, percent).
        robot_id : str, optional
            Which physical robot, for the registry's history.
        root : str or Path
            Where the data came from (shown in results; default the working folder).
        flange : array_like, shape (N, 4, 4), optional
            The flange poses the controller logged (the flange in the robot's base frame, m),
            as the columns ``fx`` .. ``fqw`` of a samples table: :func:`relcal.handeye` uses
            them instead of the model's forward kinematics of ``q``.

        Returns
        -------
        Dataset
            Ready for :func:`relcal.calibrate`.

        Raises
        ------
        ArgumentError
            An argument of the wrong type or shape, not finite, not a rigid transform, or in a
            unit that looks wrong (degrees given as radians), naming the argument and the cause
            (a :class:`~relcal.RelcalError` and a ``ValueError``).

        Examples
        --------
        >>> import numpy as np, relcal
        >>> model = relcal.get_robot("a465")
        >>> q = np.radians([[10, 20, 30, 40, 50, 60]] * 8) + np.arange(8)[:, None] * 0.1
        >>> poses = relcal.fk(model, q)  # stand-ins for measured camera poses
        >>> relcal.Dataset.from_arrays(model, q, poses)
        <Dataset '.': 8 samples, poses given, eye_in_hand, robot 'Thermo CRS A465' (6 joints)>
        >>> relcal.Dataset.from_arrays(None, None, poses, flange=relcal.fk(model, q))
        <Dataset '.': 8 samples, poses given, eye_in_hand, robot 'flange poses' (6 joints)>
        """
        return _from_arrays(
            cls, model, q, poses, mode, handeye, joint_unit, hayati, ids, images, board, camera,
            tolerances, robot_id, root, flange,
        )  # fmt: skip

    def __repr__(self) -> str:
        from relcal._repr import plural, short

        given = {"image": "images", "pose": "poses given", "position": "positions given"}
        return short(
            "Dataset",
            repr(self.robot_id or self.root.name or str(self.root)),
            plural(len(self.ids), "sample"),
            given.get(self.measured, self.measured),
            self.mode if self.measured != "position" else "",
            f"robot {self.model.name!r} ({plural(self.model.n_joints, 'joint')})",
        )


def _array(name: str, value, what: str) -> np.ndarray:
    """``value`` as a float array, or a RelcalError naming the argument."""
    try:
        out = real_array(value, name)
    except ArgumentError:
        raise
    except (TypeError, ValueError) as exc:
        raise ArgumentError(
            f"{name}: expected {what}, got {type(value).__name__} ({exc})"
        ) from None
    if not np.all(np.isfinite(out)):
        bad = np.argwhere(~np.isfinite(out))[0]
        raise ArgumentError(f"{name}: {what}; entry {tuple(int(i) for i in bad)} is not finite")
    return out


def _rigid(name: str, transforms: np.ndarray) -> None:
    """Each ``(4, 4)`` must be a rigid transform: a rotation and ``0 0 0 1`` as last row."""
    last = np.abs(transforms[..., 3, :] - [0, 0, 0, 1]).max(axis=-1)
    rot = transforms[..., :3, :3]
    ortho = np.abs(np.swapaxes(rot, -1, -2) @ rot - np.eye(3)).max(axis=(-1, -2))
    bad = np.flatnonzero((last > 1e-9) | (ortho > 1e-6) | (np.linalg.det(rot) < 0))
    if bad.size:
        k = int(bad[0])
        where = f"{name}[{k}]" if transforms.ndim == 3 else name
        raise ArgumentError(
            f"{where}: not a rigid transform (rotation part orthonormal with determinant +1, last "
            f"row 0 0 0 1); {len(bad)} of them are not: transposed matrices, a scale, or rows "
            "in another layout?"
        )


def _flange_array(flange, n: int | None) -> np.ndarray:
    """The ``flange=`` argument of :meth:`Dataset.from_arrays`, checked: ``(N, 4, 4)`` rigid
    transforms in metres, one per sample."""
    out = _array("flange", flange, "flange poses (N, 4, 4) in the robot's base frame, m")
    if out.ndim != 3 or out.shape[1:] != (4, 4) or (n is not None and len(out) != n):
        want = "(N, 4, 4)" if n is None else f"({n}, 4, 4), one per row of q"
        raise ArgumentError(f"flange: shape {out.shape}, expected {want}")
    _rigid("flange", out)
    reach = np.abs(out[:, :3, 3]).max() if len(out) else 0.0
    if reach > 20.0:
        raise ArgumentError(
            f"flange: positions reach {reach:.1f} from the robot's base: flange positions are in "
            "metres (millimetres given?)"
        )
    return out


def _from_arrays(
    cls, model, q, poses, mode, handeye, joint_unit, hayati, ids, images, board, camera,
    tolerances, robot_id, root, flange=None,
) -> Dataset:  # fmt: skip
    """:meth:`Dataset.from_arrays`, with the checks at the boundary."""
    if model is None or q is None:
        if flange is None or model is not None or q is not None:
            raise ArgumentError(
                "model and q: give both (a robot and its joint values), or neither with flange= "
                "(the controller's flange poses stand for the robot)"
            )
        from relcal.data.flange import flange_chain

        logged = _flange_array(flange, None)
        if len(logged) < 4:
            raise ArgumentError(f"flange: {len(logged)} samples; at least 4 are needed")
        chain, q_chain = flange_chain(logged)
        out = _from_arrays(
            cls, chain, q_chain, poses, mode, handeye, "rad", "off", ids, images, board, camera,
            tolerances, robot_id, root,
        )  # fmt: skip
        return replace(out, flange=logged)
    if isinstance(model, str | Path):
        model = get_robot(check_path(model, "model", "a RobotModel or a robot name/file"))
    if not isinstance(model, RobotModel):
        raise ArgumentError(f"model: expected a RobotModel or a robot name/file, got {model!r}")
    check_choice(hayati, "hayati", ("auto", "off"))
    check_choice(mode, "mode", MODES)
    check_choice(joint_unit, "joint_unit", ("rad", "deg"))
    root = check_path(root, "root", "the folder the dataset stands for (relative paths)")
    if robot_id is not None and (not isinstance(robot_id, str) or not robot_id.strip()):
        raise ArgumentError(f"robot_id: expected a robot's name (a str), got {describe(robot_id)}")
    tolerances = _check_tolerances(tolerances)
    if ids is not None and (
        isinstance(ids, str | bytes)
        or not isinstance(ids, Sequence | np.ndarray)
        or not all(isinstance(i, str | int | np.integer) and not isinstance(i, bool) for i in ids)
    ):
        raise ArgumentError(
            f"ids: expected one id per sample (a list of str), got {describe(ids)}"
            + ("; a single id is ['s1'], not 's1'" if isinstance(ids, str) else "")
        )
    if hayati == "auto":
        model = auto_hayati(model)
    n = model.n_joints
    q = _array("q", q, f"joint values of shape (N, {n})")
    if q.ndim != 2 or q.shape[1] != n:
        raise ArgumentError(
            f"q: shape {q.shape}, expected (N, {n}) for the {n}-joint robot '{model.name}' (one "
            "row per sample, one column per joint" + ("; one sample needs q[None]" if q.ndim == 1
            else "; transposed?" if q.ndim == 2 and q.shape[0] == n else "") + ")"
        )  # fmt: skip
    if len(q) < 4:
        raise ArgumentError(f"q: {len(q)} samples; at least 4 are needed (many more to calibrate)")
    revolute = ~model.prismatic
    if revolute.any():
        peak = np.abs(q[:, revolute]).max()
        if joint_unit == "rad" and peak > 2 * np.pi + 0.1:
            raise ArgumentError(
                f"q: joint angles reach {peak:.1f}, which looks like degrees, but joint_unit is "
                "'rad' (pass joint_unit='deg', or np.radians(q))"
            )
        if joint_unit == "deg" and len(q) >= 5 and peak < np.pi + 0.05 and np.abs(q).mean() > 1e-3:
            raise ArgumentError(
                f"q: no joint angle exceeds {peak:.2f}, which looks like radians, but joint_unit "
                "is 'deg'"
            )
    q = joints_from_unit(model, q, joint_unit)
    if (poses is None) == (images is None):
        raise ArgumentError("give either poses (measured poses or positions) or images, not both")
    measured: Measured
    image_paths = None
    if images is not None:
        image_paths = tuple(Path(p) for p in images)
        if len(image_paths) != len(q):
            raise ArgumentError(f"images: {len(image_paths)} paths for {len(q)} samples in q")
        missing = [p for p in image_paths if not p.is_file()]
        if missing:
            raise ArgumentError(f"images: file not found: {missing[0]} ({len(missing)} missing)")
        if board is None or camera is None:
            raise ArgumentError(
                "images need board= (relcal.vision.boards.load_board) and camera= (intrinsics, "
                "relcal.vision.camera.load_camera, or 'calibrate')"
            )
        measured, pose_arr = "image", None
    else:
        pose_arr = _array("poses", poses, "measured poses (N, 4, 4), (N, 7) or positions (N, 3)")
        shape = pose_arr.shape
        if shape[:1] != (len(q),):
            raise ArgumentError(
                f"poses: {shape[0] if shape else 0} measurements for {len(q)} samples in q "
                f"(shape {shape}): one per row of q"
            )
        if shape[1:] == (4, 4):
            _rigid("poses", pose_arr)
            measured = "pose"
        elif shape[1:] == (7,):
            pose_arr = _poses(Path("poses"), pose_arr, list(range(len(q))))
            measured = "pose"
        elif shape[1:] == (3,):
            positions = pose_arr
            pose_arr = np.broadcast_to(np.eye(4), (len(q), 4, 4)).copy()
            pose_arr[:, :3, 3] = positions
            measured = "position"
        else:
            raise ArgumentError(
                f"poses: shape {shape}; expected (N, 4, 4) homogeneous transforms, (N, 7) rows "
                "x, y, z, qx, qy, qz, qw (m, unit quaternion, x-first), or (N, 3) positions (m)"
            )
    if handeye is not None:
        handeye = _array("handeye", handeye, "a (4, 4) transform")
        if handeye.shape != (4, 4):
            raise ArgumentError(f"handeye: shape {handeye.shape}, expected (4, 4) (metres)")
        _rigid("handeye", handeye)
    ids = tuple(str(k) for k in range(len(q))) if ids is None else tuple(str(i) for i in ids)
    if len(ids) != len(q) or len(set(ids)) != len(ids):
        raise ArgumentError(f"ids: {len(ids)} ids for {len(q)} samples; each sample one unique id")
    logged = None if flange is None else _flange_array(flange, len(q))
    return cls(
        root,
        model,
        mode,
        handeye,
        ids,
        q,
        image_paths,
        pose_arr,
        board,
        camera,
        None,
        tolerances,
        measured,
        robot_id=robot_id,
        flange=logged,
    )


def _check_tolerances(tolerances: Any) -> dict[str, float] | None:
    """``tolerances`` as ``tolerances:`` of dataset.yaml takes them (names in mm, deg and
    percent, each above 0): an unknown name or a value that is not a positive number is
    refused here, naming it, not blamed on the data later."""
    if tolerances is None:
        return None
    known = ", ".join(_Tolerances.model_fields)
    if not isinstance(tolerances, Mapping):
        raise ArgumentError(
            f"tolerances: expected a mapping of thresholds ({known}), got {describe(tolerances)}"
        )
    for key, value in tolerances.items():
        if key not in _Tolerances.model_fields:
            hint = difflib.get_close_matches(str(key), list(_Tolerances.model_fields), n=1)
            raise ArgumentError(
                f"tolerances: unknown {describe(key)}"
                + (f" (did you mean {hint[0]!r}?)" if hint else "")
                + f"; expected one of {known}"
            )
        check_number(value, f"tolerances[{key!r}]", 0, low_open=True)
    return {str(k): float(v) for k, v in tolerances.items()} or None


def _resolve(root: Path, value: str | dict | None, loader, what: str, spec: Path):
    """A path (relative to the dataset) or an inline mapping, loaded by ``loader``."""
    if value is None or isinstance(value, str) and value == "calibrate":
        return value
    if isinstance(value, dict):
        return loader(value, spec)
    return loader(root / value, None)


def load_dataset(folder: str | Path) -> Dataset:
    """Read and check ``folder/dataset.yaml`` and its samples table.

    Parameters
    ----------
    folder : str or Path
        The dataset folder, holding ``dataset.yaml`` (see the file formats reference).

    Returns
    -------
    Dataset
        The samples, joint values in rad (m for prismatic joints), with the robot model.

    Raises
    ------
    ArgumentError
        ``folder`` is not a string or path.
    RelcalError
        Not a dataset folder, or a file that is malformed, too large, in the wrong units or
        inconsistent with the robot (naming the file, the line or field and the fix).

    Examples
    --------
    >>> import relcal
    >>> dataset = relcal.load_dataset("examples/tiago-pro-poses")  # from the repository root
    >>> dataset.robot_id, dataset.measured, dataset.q.shape
    ('tiago-pro-right-arm', 'pose', (48, 8))
    """
    root = check_path(folder, "folder", "a dataset folder path")
    spec_path = root / "dataset.yaml"
    if not root.is_dir():
        raise RelcalError(f"{root}: not a dataset folder (expected a folder with dataset.yaml)")
    data, node = load_yaml(spec_path)
    if data is None:
        raise RelcalError(
            f"{spec_path}: empty; expected at least 'robot: NAME' (a built-in robot or a model "
            "file) and, if the samples are not in samples.csv, 'samples: FILE'"
        )
    spec = validate(_DatasetSpec, data, spec_path, node)

    if spec.robot is None:
        return _flange_dataset(root, spec, spec_path)
    model = _robot(root, spec.robot, spec_path, node)
    if spec.hayati == "auto":
        model = auto_hayati(model)
    if spec.joint_limits:
        model = restrict_limits(
            model,
            limits_from_unit(model, spec.joint_limits, spec.joint_unit),
            f"{spec_path}: joint_limits",
        )

    handeye = None
    if spec.handeye is not None:
        handeye = tf.from_xyz_rpy(np.array(spec.handeye.xyz), np.radians(spec.handeye.rpy))
    table = read_sample_table(
        root / spec.samples,
        model,
        spec.joint_unit,
        spec.pose_angle_unit,
        spec.columns,
        euler=spec.euler,
        position_unit=spec.position_unit,
        decimal=spec.decimal,
        flange_format=_flange_format(spec),
    )
    ids, q, images, poses = table.ids, table.q, table.images, table.poses
    groups, distances = _coincidence_spec(spec, spec_path, table, model)
    board, camera = _board_and_camera(root, spec, spec_path, images is not None)
    tolerances = spec.tolerances.model_dump(exclude_none=True) if spec.tolerances else None
    return Dataset(
        root,
        model,
        spec.mode,
        handeye,
        ids,
        q,
        images,
        poses,
        board,
        camera,
        spec_path,
        tolerances,
        table.measured,
        robot_id=spec.robot_id or root.resolve().name,
        groups=groups,
        tool_point=None if spec.tool is None else np.array(spec.tool.xyz, dtype=float),
        distances=distances,
        joint_unit=spec.joint_unit,
        pose_angle_unit=spec.pose_angle_unit if table.rpy else None,
        euler=spec.euler if table.rpy else None,
        flange=table.flange,
        frames=_frame_names(spec),
        samples_path=root / spec.samples,
    )


def _frame_names(spec: _DatasetSpec) -> dict[str, str] | None:
    return None if spec.frames is None else spec.frames.model_dump(exclude_none=True)


def _flange_dataset(root: Path, spec: _DatasetSpec, spec_path: Path) -> Dataset:
    """A dataset with no ``robot:``: the samples' flange poses stand for the robot (a pose chain
    whose joint values reproduce them)."""
    from relcal.data.flange import flange_chain

    path = root / spec.samples
    table = read_sample_table(
        path,
        None,
        spec.joint_unit,
        spec.pose_angle_unit,
        spec.columns,
        euler=spec.euler,
        position_unit=spec.position_unit,
        decimal=spec.decimal,
        flange_format=_flange_format(spec),
    )
    extra = [k for k in ("joint_limits", "tool", "measurement") if getattr(spec, k)]
    if spec.distances:
        extra.append("distances")
    if extra:
        raise RelcalError(
            f"{spec_path}: {', '.join(extra)}: needs a robot (robot:); without one the flange "
            "poses stand for it"
        )
    model, q = flange_chain(table.flange)
    handeye = None
    if spec.handeye is not None:
        handeye = tf.from_xyz_rpy(np.array(spec.handeye.xyz), np.radians(spec.handeye.rpy))
    board, camera = _board_and_camera(root, spec, spec_path, table.images is not None)
    tolerances = spec.tolerances.model_dump(exclude_none=True) if spec.tolerances else None
    return Dataset(
        root,
        model,
        spec.mode,
        handeye,
        table.ids,
        q,
        table.images,
        table.poses,
        board,
        camera,
        spec_path,
        tolerances,
        table.measured,
        robot_id=spec.robot_id or root.resolve().name,
        joint_unit=None,
        pose_angle_unit=spec.pose_angle_unit if table.rpy else None,
        euler=spec.euler if table.rpy else None,
        flange=table.flange,
        frames=_frame_names(spec),
        samples_path=root / spec.samples,
    )


def _coincidence_spec(spec: _DatasetSpec, spec_path: Path, table: SampleTable, model):
    """The groups of coincidence samples and the known distances, checked against each other."""
    if table.measured != "coincidence":
        if spec.measurement == "coincidence":
            raise RelcalError(
                f"{spec_path}: measurement: coincidence, but {spec.samples} has no 'group' column "
                "(one group name per sample, e.g. front/hole_0)"
            )
        extra = [k for k in ("tool", "distances") if getattr(spec, k)]
        if extra:
            raise RelcalError(
                f"{spec_path}: {', '.join(extra)}: only for coincidence samples (a 'group' column "
                f"in {spec.samples})"
            )
        return None, ()
    known = list(dict.fromkeys(table.groups))
    distances = []
    for k, d in enumerate(spec.distances):
        for name in d.groups:
            if name not in known:
                import difflib

                hint = difflib.get_close_matches(name, known, n=1)
                raise RelcalError(
                    f"{spec_path}: distances entry {k + 1}: group '{name}' has no samples in "
                    f"{spec.samples}"
                    + (f" (did you mean '{hint[0]}'?)" if hint else "")
                    + f"; its groups are {', '.join(known[:6])}"
                    + (" ..." if len(known) > 6 else "")
                )
        if d.groups[0] == d.groups[1]:
            raise RelcalError(f"{spec_path}: distances entry {k + 1}: a group with itself")
        if d.distance > 10:
            raise RelcalError(
                f"{spec_path}: distances entry {k + 1}: distance {d.distance:g} m: distances "
                "are in metres (0.05 for 50 mm)"
            )
        distances.append((d.groups[0], d.groups[1], float(d.distance), float(d.std)))
    _check_single_samples(spec, spec_path, table, distances)
    _check_size(spec, spec_path, table, distances, model)
    return table.groups, tuple(distances)


def _check_size(spec, spec_path: Path, table: SampleTable, distances: list, model) -> None:
    """Refuse coincidence data too large to calibrate within the memory and time limits
    (:func:`relcal.limits.check_coincidence_size`), before anything is computed: the robot's
    largest candidate model counted (its geometry, a joint scale and a harmonic per joint)."""
    from relcal.limits import check_coincidence_size
    from relcal.robot.kinematics import make_layout

    n_params = make_layout(model).size + 3 * model.n_joints
    check_coincidence_size(
        len(table.ids),
        len(set(table.groups)),
        len(distances),
        n_params,
        str(spec_path.parent / spec.samples),
    )


def _check_single_samples(spec, spec_path: Path, table: SampleTable, distances: list) -> None:
    """Refuse a group with a single sample: its point is unknown, so the one sample is fitted
    to it exactly and tells nothing about the kinematics but, through a distance, one number
    (often a misspelt group name, or a socket visited once; with every group single, a group
    column that holds sample ids). Named, with the closest other group and what to do."""
    import difflib
    from collections import Counter

    counts = Counter(table.groups)
    in_distance = {name for a, b, _, _ in distances for name in (a, b)}
    single = [g for g, n in counts.items() if n == 1]
    if not single:
        return
    group = single[0]
    sid = table.ids[table.groups.index(group)]
    others = [g for g in counts if g != group and counts[g] > 1]
    names = {g.rpartition("/")[2] for g in others}
    plausible = "/" in group and group.rpartition("/")[2] in names  # hole_1 of another placement
    hint = [] if plausible else difflib.get_close_matches(group, others, n=1, cutoff=0.6)
    more = f" ({len(single)} groups have a single sample: {', '.join(single[:5])}" + (
        " ...)" if len(single) > 5 else ")"
    )
    raise RelcalError(
        f"{spec_path.parent / spec.samples}: group '{printable(group, 60)}' has a single sample "
        f"(id {printable(sid, 40)}){more if len(single) > 1 else ''}: its point is unknown, "
        "so one sample is fitted to it exactly and tells nothing about the kinematics"
        + (
            " (its distance to another group, one number, hardly more)"
            if group in in_distance
            else ""
        )
        + (f"; a misspelt '{printable(hint[0], 60)}'?" if hint else "")
        + "; record two or more samples in that group, or remove the row"
        + (" and the distances: entries that name the group" if group in in_distance else "")
    )


def _robot(root: Path, value: str | dict, spec_path: Path, node) -> RobotModel:
    """The ``robot:`` entry: a name, a path (relative to the dataset), a URDF chain mapping, or
    an inline model mapping."""
    if isinstance(value, dict) and "urdf" in value:
        from relcal.robot.urdf import load_urdf

        sub = node.value if node is not None else None
        robot_node = next((v for k, v in sub or [] if getattr(k, "value", None) == "robot"), None)
        spec = validate(_UrdfRobot, value, f"{spec_path}: robot", robot_node)
        if Path(spec.urdf).suffix.lower() not in (".urdf", ".xml"):
            raise RelcalError(
                f"{spec_path}: robot: urdf: {excerpt(spec.urdf, 80)}: not a URDF file name "
                "(.urdf or .xml); relcal reads no other file as a robot"
            )
        return load_urdf(root / spec.urdf, spec.root, spec.tip, spec.parametrisation)
    if isinstance(value, dict):
        return model_from_dict(value, f"{spec_path}: robot")
    suffix = Path(value).suffix.lower()
    if suffix in (".yaml", ".yml", ".urdf", ".xacro"):
        return get_robot(root / value)  # a model file, relative to the dataset folder
    if value.lower() in library_names():
        return get_robot(value.lower())
    raise RelcalError(
        f"{spec_path}: robot: {excerpt(value, 80)}: neither a built-in robot "
        f"({', '.join(library_names())}) nor a model file (.yaml, .yml or .urdf, relative to "
        "the dataset folder); relcal reads no other file as a robot"
    )


def robot_from_file(
    path: str | Path, root: str | None = None, tip: str | None = None
) -> RobotModel:
    """A robot from a file as a user names it: a model YAML, a URDF (``root``, ``tip``), a
    URDF chain mapping (``urdf: FILE``, ``root:``, ``tip:``, the file relative to the YAML), or
    a ``dataset.yaml`` (its ``robot:`` entry). ``root``/``tip`` fill in what a mapping leaves
    out; a mapping that names other links is refused."""
    path = Path(path)
    if path.suffix.lower() not in (".yaml", ".yml"):
        return get_robot(path, root, tip)
    data, node = load_yaml(path)
    if isinstance(data, dict) and "robot" in data and "joints" not in data:
        data = data["robot"]
        if not isinstance(data, dict):
            if root is not None or tip is not None:
                raise RelcalError(
                    f"{path}: robot: {excerpt(str(data), 60)} is not a URDF chain: --root and "
                    "--tip apply to URDF robots only"
                )
            return _robot(path.parent, data, path, None)
    if isinstance(data, dict) and "urdf" in data:
        data = dict(data)
        for key, value in (("root", root), ("tip", tip)):
            if value is None:
                continue
            if data.get(key) not in (None, value):
                raise RelcalError(
                    f"{path}: {key}: {data[key]}, but --{key} {value} was given: which chain?"
                )
            data[key] = value
        return _robot(path.parent, data, path, None)
    if root is not None or tip is not None:
        raise RelcalError(f"{path}: a robot model file: --root and --tip apply to URDF robots only")
    return get_robot(path)


def _board_and_camera(root: Path, spec: _DatasetSpec, spec_path: Path, images: bool):
    """The board and the camera of ``dataset.yaml`` when the samples have ``images`` (both
    required then), else ``(None, None)``."""
    if not images:
        return None, None
    from relcal.vision.boards import load_board
    from relcal.vision.camera import load_camera

    if spec.board is None:
        raise RelcalError(f"{spec_path}: board: required when the samples have images")
    board = _board(root, spec.board, spec_path, load_board)
    if spec.camera is None:
        raise RelcalError(
            f"{spec_path}: camera: required when the samples have images (a file, a mapping "
            "or 'calibrate')"
        )
    return board, _camera(root, spec.camera, spec_path, load_camera)


def _board(root: Path, value, spec_path: Path, load_board):
    if isinstance(value, dict):
        from relcal.vision.boards import BoardSpec

        return validate(BoardSpec, value, f"{spec_path}: board").to_board()
    return load_board(root / value)


def _camera(root: Path, value, spec_path: Path, load_camera):
    if value == "calibrate":
        return "calibrate"
    if isinstance(value, dict):
        from relcal.vision.camera import CameraSpec

        return validate(CameraSpec, value, f"{spec_path}: camera").to_camera()
    return load_camera(root / value)


@dataclass(frozen=True)
class SampleTable:
    """A parsed samples table. ``q`` ``(N, n)`` in rad (m for prismatic joints), in the model's
    joint order; ``poses`` ``(N, 4, 4)`` measured poses (for positions, identity rotations)."""

    ids: tuple[str, ...]
    q: np.ndarray
    images: tuple[Path, ...] | None
    poses: np.ndarray | None
    measured: Measured
    groups: tuple[str, ...] | None = None  # coincidence: each sample's group (PLACEMENT/NAME)
    rpy: bool = False  # the poses came as roll, pitch, yaw
    flange: np.ndarray | None = None  # (N, 4, 4) flange poses (fx .. fqw), when given


def read_samples(
    path: Path, model: RobotModel, joint_unit: str
) -> tuple[tuple[str, ...], np.ndarray, tuple[Path, ...] | None, np.ndarray | None]:
    """Parse the samples table; errors name the file, the line and the column."""
    t = read_sample_table(path, model, joint_unit)
    return t.ids, t.q, t.images, t.poses


def _rename(
    path: Path, header: list[str], columns: dict[str, str], model: RobotModel | None
) -> list[str]:
    """The header with the file's names replaced by relcal's (``columns``: relcal name -> the
    file's name), each mapped name required."""
    from relcal.data.flange import FLANGE_NAMES

    known = ["id", "image", *POSE_COLUMNS, *RPY_COLUMNS[3:], *COINCIDENCE_COLUMNS, *FLANGE_NAMES]
    if model is not None:
        known += [f"q{i + 1}" for i in range(model.n_joints)] + list(model.joint_names)
    unknown = [ours for ours in columns if ours not in known]
    if unknown:
        joints = "" if model is None else f", q1..q{model.n_joints} or the joint names"
        raise RelcalError(
            f"{path}: dataset.yaml columns: unknown column name(s) {', '.join(unknown)}; relcal's "
            "names are id, image, x, y, z, qx, qy, qz, qw, roll, pitch, yaw, fx, fy, fz, fqx, "
            f"fqy, fqz, fqw, frx, fry, frz, froll, fpitch, fyaw{joints}"
        )
    inverse = {theirs.strip(): ours for ours, theirs in columns.items()}
    missing = [theirs for theirs in inverse if theirs not in header]
    if missing:
        raise RelcalError(
            f"{path} line 1: header: dataset.yaml columns: maps to "
            f"{', '.join(repr(m) for m in missing)}, which the header lacks (it has "
            f"{_header_text(header)})"
        )
    return [inverse.get(h, h) for h in header]


def _header_text(header: list[str]) -> str:
    """A header's names for a message: escaped, and not more than a line of them."""
    return printable(", ".join(header), 200)


def _joint_columns(path: Path, header: list[str], model: RobotModel) -> list[str]:
    """The header names of the model's joints, in the model's order: ``q1`` .. ``qn`` or the
    joint names."""
    n = model.n_joints
    numbered = [f"q{i + 1}" for i in range(n)]
    named = list(model.joint_names)
    extra_q = [h for h in header if h.startswith("q") and h[1:].isdigit() and h not in numbered]
    by_name = [h for h in named if h in header]
    if by_name and len(set(named)) == n:
        missing = [h for h in named if h not in header]
        if missing:
            raise RelcalError(
                f"{path} line 1: header: joint columns by name for the {n}-joint robot "
                f"'{model.name}' ({', '.join(named)}); missing {', '.join(missing)}"
            )
        return named
    missing = [c for c in numbered if c not in header]
    if missing or extra_q:
        raise RelcalError(
            f"{path} line 1: header: expected joint columns {', '.join(numbered)} (or the joint "
            f"names {', '.join(named)}) for the {n}-joint robot '{model.name}'"
            + (f"; missing {', '.join(missing)}" if missing else "")
            + (f"; unexpected {', '.join(extra_q)} (wrong joint count?)" if extra_q else "")
        )
    return numbered


def _measured_columns(path: Path, header: list[str]) -> tuple[Measured, tuple[str, ...]]:
    """What the table measures and its columns: an image, a pose (quaternion or roll-pitch-yaw),
    or a position alone."""
    has = set(header)
    orientation = [c for c in (*POSE_COLUMNS[3:], *RPY_COLUMNS[3:]) if c in has]
    found: list[tuple[Measured, tuple[str, ...]]] = []
    if "image" in has:
        found.append(("image", ("image",)))
    for cols in (POSE_COLUMNS, RPY_COLUMNS):
        if has.issuperset(cols):
            found.append(("pose", cols))
    if has.issuperset(POSITION_COLUMNS) and not any(k == "pose" for k, _ in found):
        found.append(("position", POSITION_COLUMNS))
    complete = {c for _, cols in found for c in cols}
    if len(found) != 1 or any(c not in complete for c in orientation):
        raise RelcalError(
            f"{path} line 1: header: expected an 'image' column, or a pose "
            f"{', '.join(POSE_COLUMNS)} or {', '.join(RPY_COLUMNS)}, or a position x, y, z "
            f"(exactly one of these; the header has {_header_text(header)}); map other names in "
            "dataset.yaml, e.g. columns: {x: x1, y: y1, z: z1}"
        )
    return found[0]


def _flange_format(spec: _DatasetSpec) -> FlangeFormat:
    return FlangeFormat(spec.flange_unit, spec.flange_angle_unit, spec.flange_euler)


def read_sample_table(
    path: Path,
    model: RobotModel | None,
    joint_unit: str,
    pose_angle_unit: str = "rad",
    columns: dict[str, str] | None = None,
    *,
    euler: str = "xyz",
    position_unit: str = "m",
    decimal: str = ".",
    flange_format: FlangeFormat | None = None,
) -> SampleTable:
    """Parse the samples table; errors name the file, the line and the column.

    ``euler``: the rotation sequence of roll, pitch, yaw columns (SciPy's ``from_euler``);
    ``position_unit``: ``"m"`` or ``"mm"`` for x, y, z; ``decimal``: the numbers' decimal mark.
    ``model`` None: no robot, the flange poses (``fx, fy, fz`` and one rotation:
    :data:`~relcal.data.flange.FLANGE_ROTATIONS`, written as ``flange_format`` says) are
    required instead of joint columns (``q`` of the table is then ``(N, 0)``).
    """
    header, data = read_table(path, "sample")
    if decimal == "," and table_delimiter(path) == ",":
        raise RelcalError(
            f"{path} line 1: header: columns separated by commas, but dataset.yaml declares "
            "decimal: ','; a table with decimal commas separates its columns by semicolons or "
            "tabs (fix: decimal: '.', or export the table with semicolons)"
        )
    header = _rename(path, header, columns or {}, model)
    joints = [] if model is None else _joint_columns(path, header, model)
    flange_cols = _flange_columns(path, header, model is None)
    if "group" in header:
        return _coincidence_table(path, header, data, joints, model, joint_unit, decimal)
    measured, meas_cols = _measured_columns(path, header)
    _unique_columns(path, header, data)
    col = {h: i for i, h in enumerate(header)}
    has_id = "id" in col
    ids, q, images, values, seen = [], [], [], [], {}
    lines = []
    for number, row in enumerate(data, start=1):
        line_no = row.line
        lines.append(line_no)
        if len(row) != len(header):
            raise RelcalError(
                f"{path} line {line_no}: {len(row)} fields, expected {len(header)} as in the header"
            )
        sid = row[col["id"]] if has_id else str(number)  # no id column: rows 1..N
        ids.append(_row_id(path, line_no, sid, seen, "sample"))
        q.append(
            [parse_number(path, line_no, c, row[col[c]], decimal) for c in (*joints, *flange_cols)]
        )
        if measured == "image":
            name = row[col["image"]].strip()
            if not name:
                raise RelcalError(f"{path} line {line_no}: image: empty; expected an image path")
            images.append(path.parent / name)
        else:
            values.append([parse_number(path, line_no, c, row[col[c]], decimal) for c in meas_cols])
    _no_repeated_samples(path, ids, lines, q, images if measured == "image" else values)
    q_arr, flange = np.array(q, dtype=float).reshape(len(q), -1), None
    if flange_cols:
        logged = q_arr[:, len(joints) :]
        flange = _flange(path, logged, lines, flange_format or FlangeFormat(), flange_cols)
        q_arr = q_arr[:, : len(joints)]
    if model is not None:
        q_arr = _joint_values(path, q_arr, model, joint_unit)
    pose_arr = None
    if measured == "image":
        for line_no, image in zip(lines, images, strict=True):
            if image.is_dir():
                raise RelcalError(
                    f"{path} line {line_no}: image: {image} is a directory, expected an image file"
                )
            if not image.is_file():
                raise RelcalError(f"{path} line {line_no}: image: file not found: {image}")
            note_input(image)
            check_input_size(image, "image")
    elif meas_cols == POSE_COLUMNS:
        pose_arr = _poses(path, np.array(values), lines)
    elif meas_cols == RPY_COLUMNS:
        pose_arr = _rpy_poses(path, np.array(values), pose_angle_unit, euler)
    else:
        pose_arr = np.broadcast_to(np.eye(4), (len(values), 4, 4)).copy()
        pose_arr[:, :3, 3] = values
    if pose_arr is not None and position_unit == "mm":
        pose_arr[:, :3, 3] /= 1000.0
    return SampleTable(
        tuple(ids),
        q_arr,
        tuple(images) if measured == "image" else None,
        pose_arr,
        measured,
        rpy=meas_cols == RPY_COLUMNS,
        flange=flange,
    )


def _flange_columns(path: Path, header: list[str], required: bool) -> tuple[str, ...]:
    """The flange-pose columns when the header has them: ``fx, fy, fz`` and one rotation of
    :data:`~relcal.data.flange.FLANGE_ROTATIONS` (all of one, none of another); ``required``:
    the dataset names no robot, so they stand for it."""
    from relcal.data.flange import FLANGE_NAMES, FLANGE_POSITION, FLANGE_ROTATIONS

    if required and "group" in header:
        raise RelcalError(
            f"{path} line 1: header: coincidence samples (a 'group' column) need a robot: give "
            "robot: in dataset.yaml"
        )
    present = [c for c in FLANGE_NAMES if c in header]
    if not present and not required:
        return ()
    rotations = [cols for cols in FLANGE_ROTATIONS.values() if set(cols) <= set(header)]
    columns = (*FLANGE_POSITION, *rotations[0]) if len(rotations) == 1 else ()
    if (
        not columns
        or any(c not in columns for c in present)
        or not set(FLANGE_POSITION) <= set(header)
    ):
        why = (
            "dataset.yaml names no robot, so the samples must give the flange poses"
            if required and not present
            else f"flange pose columns {', '.join(present)} are not one complete pose"
        )
        raise RelcalError(
            f"{path} line 1: header: {why}: fx, fy, fz (the flange in the robot's base frame) and "
            "one rotation, fqx, fqy, fqz, fqw (unit quaternion, x first), frx, fry, frz "
            "(rotation vector) or froll, fpitch, fyaw (flange_euler, flange_angle_unit in "
            "dataset.yaml); or give robot: and joint columns in dataset.yaml"
        )
    return columns


def _flange(
    path: Path, values: np.ndarray, lines: list[int], fmt: FlangeFormat, columns: tuple[str, ...]
) -> np.ndarray:
    """Flange poses ``(N, 4, 4)`` (m) from the rows ``(N, 6 or 7)`` of the ``columns`` of
    :func:`_flange_columns`, written as ``fmt`` says: unit quaternions, rotation vectors within
    a turn, angles in their unit, positions within 20 m of the base."""
    from relcal.data.flange import FLANGE_ROTATIONS

    positions = values[:, :3] * (1e-3 if fmt.unit == "mm" else 1.0)
    rows = np.c_[positions, values[:, 3:]]
    if columns[3:] == FLANGE_ROTATIONS["quaternion"]:
        poses = _poses(path, rows, lines, "fqx, fqy, fqz, fqw")
    elif columns[3:] == FLANGE_ROTATIONS["rpy"]:
        names = ", ".join(FLANGE_ROTATIONS["rpy"])
        poses = _rpy_poses(path, rows, fmt.angle_unit, fmt.euler, names, "flange_angle_unit")
    else:
        if fmt.angle_unit == "deg":
            rows[:, 3:] = np.radians(rows[:, 3:])
        fix = "fix: flange_angle_unit: deg in dataset.yaml"
        poses = _rotvec_poses(path, rows, lines, "frx, fry, frz", fix)
    reach = np.abs(positions).max() if len(positions) else 0.0
    if reach > 20.0:
        k = int(np.argmax(np.abs(positions).max(axis=1)))
        raise RelcalError(
            f"{path} line {lines[k]}: fx, fy, fz: {reach:.1f} m from the robot's base: "
            "millimetres given as metres? (fix: flange_unit: mm in dataset.yaml)"
        )
    return poses


def _coincidence_table(
    path: Path,
    header: list[str],
    data: list,
    joints: list[str],
    model: RobotModel,
    unit: str,
    decimal: str = ".",
) -> SampleTable:
    """A table of coincidence samples: ``id`` (optional), ``group``, optional ``placement``
    (prefixed to the group as ``PLACEMENT/GROUP``), and the joints."""
    measured = [c for c in ("image", *POSE_COLUMNS, *RPY_COLUMNS[3:]) if c in header]
    if measured:
        raise RelcalError(
            f"{path} line 1: header: a 'group' column (coincidence samples) with measured "
            f"column(s) {', '.join(measured)}: a table is either one or the other"
        )
    _unique_columns(path, header, data)
    col = {h: i for i, h in enumerate(header)}
    ids, q, groups, seen = [], [], [], {}
    for row in data:
        line_no = row.line
        if len(row) != len(header):
            raise RelcalError(
                f"{path} line {line_no}: {len(row)} fields, expected {len(header)} as in the header"
            )
        sid = _row_id(path, line_no, row[col["id"]] if "id" in col else str(line_no), seen)
        group = row[col["group"]].strip()
        if not group:
            raise RelcalError(f"{path} line {line_no}: group: empty; expected a group name")
        if "placement" in col:
            place = row[col["placement"]].strip()
            group = f"{place}/{group}" if place else group
        ids.append(sid)
        groups.append(group)
        q.append([parse_number(path, line_no, c, row[col[c]], decimal) for c in joints])
    lines = [row.line for row in data]
    _no_repeated_samples(path, ids, lines, q, [(g,) for g in groups])  # (the group: its measure)
    q_arr = _joint_values(path, np.array(q, dtype=float), model, unit)
    poses = np.broadcast_to(np.eye(4), (len(ids), 4, 4)).copy()
    return SampleTable(tuple(ids), q_arr, None, poses, "coincidence", tuple(groups))


def _no_repeated_samples(path: Path, ids, lines, q, measured) -> None:
    """Refuse rows that repeat another row's joints and measurement exactly: a sample recorded
    (or copied) twice, which weighs twice in the fit, and whose held-out copy of a training
    sample would flatter the validation."""
    first: dict[tuple, int] = {}
    repeats = []
    for k, (joints, meas) in enumerate(zip(q, measured, strict=True)):
        key = (tuple(joints), str(meas) if isinstance(meas, Path) else tuple(meas))
        if key in first:
            repeats.append((k, first[key]))
        else:
            first[key] = k
    if repeats:
        k, j = repeats[0]
        raise RelcalError(
            f"{path} line {lines[k]}: sample {excerpt(ids[k])} repeats line {lines[j]} (sample "
            f"{excerpt(ids[j])}): the same joints and measurement; {len(repeats)} of {len(ids)} "
            "rows repeat an earlier one (a sample recorded or copied twice counts twice, and a "
            "held-out copy of a training sample would flatter the validation; fix: remove the "
            "repeated rows)"
        )


DECLARE_DECIMAL = "declare decimal: ',' in dataset.yaml, with semicolons between the columns"
POINTS_ONLY = "this table takes decimal points only: export it with points"


def parse_number(
    path: Path,
    line_no: int,
    column: str,
    text: str,
    decimal: str = ".",
    comma_fix: str = DECLARE_DECIMAL,
) -> float:
    """A finite float from a CSV cell, with ``decimal`` its decimal mark (``"."`` or ``","``),
    read strictly (:mod:`relcal.numbers`: ``4_1.67`` is no number); errors name the file, the
    line, the column and the likely cause. ``comma_fix``: the fix named for a decimal comma in a
    table read with points (a dataset's samples table declares its mark in dataset.yaml; a
    table with no dataset.yaml, ``POINTS_ONLY``)."""
    cell = text.strip()
    if decimal == "," and "." in cell:
        raise RelcalError(
            f"{path} line {line_no}: {column}: expected a number with a decimal comma "
            f"(dataset.yaml declares decimal: ','), got {excerpt(cell)}: a decimal point, or a "
            "thousands separator (fix: export the table without thousands separators, or "
            "decimal: '.' if the whole table uses points)"
        )
    try:
        return _parse_number(cell.replace(",", ".") if decimal == "," else cell)
    except NotANumber as exc:
        if decimal == "." and "," in cell and NUMBER.fullmatch(cell.replace(",", ".", 1)):
            raise RelcalError(
                f"{path} line {line_no}: {column}: expected a number, got {excerpt(cell)} (a "
                f"decimal comma? {comma_fix})"
            ) from None
        raise RelcalError(f"{path} line {line_no}: {column}: {printable(exc)}") from None


def unit_mixup(q: np.ndarray, model: RobotModel, unit: str) -> str | None:
    """The classic unit mistakes of joint values ``q`` ``(N, n)`` read in ``unit``: a message
    part naming the unit they look like (``"joint angles reach 57.3, which looks like
    degrees"``), or None when they fit ``unit``. Angles above 2 pi are not radians; five or more
    configurations none of whose angles exceeds pi are not degrees."""
    revolute = ~model.prismatic
    if q.size and revolute.any():
        peak = np.abs(q[:, revolute]).max()
        if unit == "rad" and peak > 2 * np.pi + 0.1:
            return f"joint angles reach {peak:.1f}, which looks like degrees"
        if unit == "deg" and len(q) >= 5 and peak < np.pi + 0.05 and np.abs(q).mean() > 1e-3:
            return f"no joint angle exceeds {peak:.2f}, which looks like radians"
    return None


def _joint_values(path: Path, q: np.ndarray, model: RobotModel, unit: str) -> np.ndarray:
    """Convert to radians and catch the two classic unit mistakes."""
    mixup = unit_mixup(q, model, unit)
    if mixup:
        other = "deg" if unit == "rad" else "rad"
        raise RelcalError(
            f"{path}: {mixup}, but dataset.yaml declares joint_unit: {unit} (fix: joint_unit: "
            f"{other})"
        )
    return joints_from_unit(model, q, unit)


def limits_from_unit(
    model: RobotModel, limits: dict[str, tuple[float, float]], unit: str
) -> dict[str, tuple[float, float]]:
    """Joint limits by joint name (or ``qK``) from ``unit`` (deg or rad; prismatic joints in m)
    to rad and m (unknown names are left for :func:`restrict_limits` to report)."""
    index = {name: i for i, name in enumerate(model.joint_names)}
    index.update({f"q{i + 1}": i for i in range(model.n_joints)})
    out = {}
    for name, (lo, hi) in limits.items():
        i = index.get(name)
        angle = unit == "deg" and (i is None or not model.prismatic[i])
        out[name] = (np.radians(lo), np.radians(hi)) if angle else (float(lo), float(hi))
    return out


def read_joints(
    path: str | Path, model: RobotModel, joint_unit: str | None = "deg", option: str = "joint_unit"
) -> np.ndarray:
    """Joint values ``(N, n)`` (rad, m) from any CSV whose header names the joints (``q1..qn``
    or the joint names; other columns are ignored, so a plan or a dataset's samples.csv both
    work); prismatic joints in m, angles in the unit a relcal plan's first line states, else in
    ``joint_unit`` (None: degrees). A ``joint_unit`` other than the one the plan states, or
    angles that look like the other unit, are refused (``option`` names where the unit was
    given, as ``--joint-unit``)."""
    path = Path(path)
    header, data = read_table(path, "pose")
    joints = _joint_columns(path, header, model)
    q = _read_columns(path, header, data, joints)
    stated = _stated_unit(path)
    if stated is not None and joint_unit is not None and joint_unit != stated:
        raise RelcalError(
            f"{path} line 1: the file states joint unit {stated}, but {option} {joint_unit} was "
            f"given; drop {option} (the file's own unit is used) or fix the file's first line"
        )
    unit = stated or joint_unit or "deg"
    mixup = unit_mixup(q, model, unit)
    if mixup:
        if stated:
            given, fix = f"the file's first line states {unit}", "fix the file's first line"
        else:
            given = (
                f"{option} is {unit}" if joint_unit else f"they are read in {unit} (the default)"
            )
            fix = f"{option} {'rad' if unit == 'deg' else 'deg'}"
        raise RelcalError(f"{path}: {mixup}, but {given}; give the angles in {unit}, or {fix}")
    return joints_from_unit(model, q, unit)


def _stated_unit(path: Path) -> str | None:
    """The joint unit a relcal plan's first line states (``# relcal plan: robot ..., joint unit
    deg``), or None."""
    with open(path, encoding="utf-8-sig", errors="replace") as handle:
        for line in handle:
            if line.strip():
                found = PLAN_COMMENT.match(line.strip())
                unit = found["unit"] if found else None
                return unit if unit in ("deg", "rad") else None
    return None


PLAN_COMMENT = re.compile(
    r"#\s*relcal plan:\s*robot\s+(?P<robot>.*?),\s*joint unit\s+(?P<unit>\w+)\s*$"
)  # the first line of relcal's plan files (relcal.design.planfile)
ROTATIONS = {
    "quaternion": ("qx", "qy", "qz", "qw"),
    "rpy": ("roll", "pitch", "yaw"),
    "rotation vector": ("rx", "ry", "rz"),
}


@dataclass(frozen=True)
class Targets:
    """What a target file holds: ``ids`` and ``lines`` (its line numbers), and either tool
    ``poses`` ``(N, 4, 4)`` in the base frame (m) or joint values ``q`` ``(N, n)`` (rad, m); a
    relcal plan file's ``plan_robot`` and ``unit`` when its first line states them."""

    ids: list[str]
    lines: list[int]
    poses: np.ndarray | None
    q: np.ndarray | None
    plan_robot: str | None = None
    unit: str | None = None


def _plan_comment(path: Path) -> tuple[str | None, str | None]:
    """``(robot, unit)`` of a relcal plan's comment line, or ``(None, None)``."""
    try:
        with open(path, encoding="utf-8-sig") as handle:
            for raw in handle:
                if not raw.strip():
                    continue
                if not raw.lstrip().startswith("#"):
                    break
                found = PLAN_COMMENT.match(raw.strip())
                if found:
                    return found["robot"], found["unit"]
    except (OSError, UnicodeDecodeError):
        pass  # read_table names what is wrong with the file
    return None, None


def read_target_file(
    path: str | Path,
    model: RobotModel,
    joint_unit: str | None = None,
    pose_angle_unit: str = "deg",
    robot_name: str | None = None,
) -> Targets:
    """Targets from a CSV: ``id`` and either tool poses or joint values, nothing else.

    Poses: ``x, y, z`` (m, base frame) and one rotation: ``qx, qy, qz, qw`` (unit quaternion),
    ``roll, pitch, yaw`` (``R = Rz(yaw) Ry(pitch) Rx(roll)``, in ``pose_angle_unit``) or ``rx,
    ry, rz`` (rotation vector, rad, as a UR controller writes poses). Joints: one column per
    joint of ``model``, named as the model names them or ``q1 .. qn`` (angles in ``joint_unit``,
    prismatic joints in m); relcal's plan file (``# relcal plan: robot NAME, joint unit UNIT``)
    is read in its unit, and refused when it names another robot than ``robot_name`` (default
    the model's). A file whose columns do not fit the robot (another number of joints, unknown
    names, extra columns) is refused, never truncated; errors name the file, line and column.
    """
    path = Path(path)
    plan_robot, plan_unit = _plan_comment(path)
    if plan_unit is not None and plan_unit not in ("deg", "rad"):
        raise RelcalError(f"{path} line 1: joint unit '{plan_unit}': expected deg or rad")
    if plan_unit is not None and joint_unit is not None and joint_unit != plan_unit:
        raise RelcalError(
            f"{path} line 1: the plan states joint unit {plan_unit}, but --joint-unit "
            f"{joint_unit} was given; leave --joint-unit out (the file says its unit)"
        )
    expected_robot = robot_name or model.name
    if plan_robot is not None and plan_robot != expected_robot:
        raise RelcalError(
            f"{path} line 1: the plan is for robot '{plan_robot}', the calibration is of "
            f"'{expected_robot}': targets of another robot"
        )
    header, data = read_table(path, "target")
    if "id" not in header:
        raise RelcalError(f"{path} line {data[0].line - 1 if data else 1}: header: no id column")
    _unique_columns(path, header, data)
    seen: dict[str, int] = {}
    ids = []
    for row in data:
        if len(row) != len(header):
            raise RelcalError(f"{path} line {row.line}: {len(row)} fields, expected {len(header)}")
        ids.append(_row_id(path, row.line, row[header.index("id")], seen, "target"))
    fields = [h for h in header if h != "id"]
    lines = [row.line for row in data]
    named, numbered = list(model.joint_names), [f"q{i + 1}" for i in range(model.n_joints)]
    unit = plan_unit or joint_unit or "deg"
    header_line = (data[0].line - 1) if data else 1
    if set(POSITION_COLUMNS) <= set(fields):
        rotation = [k for k, cols in ROTATIONS.items() if set(cols) <= set(fields)]
        if len(rotation) != 1:
            raise RelcalError(
                f"{path} line {header_line}: header: x, y, z and "
                + (
                    f"two rotations ({' and '.join(rotation)}): keep one"
                    if rotation
                    else "no rotation: expected qx, qy, qz, qw or roll, pitch, yaw or rx, ry, rz"
                )
            )
        columns = [*POSITION_COLUMNS, *ROTATIONS[rotation[0]]]
        extra = [h for h in fields if h not in columns]
        if extra:
            raise RelcalError(
                f"{path} line {header_line}: header: unexpected column(s) {', '.join(extra)}; "
                f"a pose target is id, {', '.join(columns)}"
            )
        values = _read_columns(path, header, data, columns)
        if rotation[0] == "quaternion":
            poses = _poses(path, values, lines)
        elif rotation[0] == "rpy":
            rpy = values[:, 3:]
            if pose_angle_unit == "rad" and np.abs(rpy).max() > 2 * np.pi + 0.1:
                raise RelcalError(
                    f"{path}: roll, pitch, yaw reach {np.abs(rpy).max():.1f}, which looks like "
                    "degrees, but --pose-angle-unit is rad"
                )
            if pose_angle_unit == "deg":
                rpy = np.radians(rpy)
            poses = tf.homogeneous(Rotation.from_euler("xyz", rpy).as_matrix(), values[:, :3])
        else:
            poses = _rotvec_poses(path, values, lines, "rx, ry, rz", "give radians")
        _check_reach(path, values[:, :3], lines)
        return Targets(ids, lines, poses, None, plan_robot, plan_unit)
    columns = named if set(named) <= set(fields) else numbered
    if sorted(fields) != sorted(columns):
        joints_like = [h for h in fields if h in named or re.fullmatch(r"q\d+", h)]
        if len(joints_like) == len(fields) and len(fields) != model.n_joints:
            why = (
                f"{len(fields)} joint columns ({', '.join(fields)}), but '{expected_robot}' has "
                f"{model.n_joints} joints ({', '.join(named)}): targets of another robot?"
            )
        else:
            unknown = [h for h in fields if h not in columns]
            missing = [c for c in columns if c not in fields]
            why = (
                f"expected id and either x, y, z with a rotation (qx, qy, qz, qw; roll, pitch, "
                f"yaw; rx, ry, rz) or the joints of '{expected_robot}' ({', '.join(named)}, or "
                f"{numbered[0]}..{numbered[-1]})"
                + (f"; unknown column(s) {', '.join(unknown)}" if unknown else "")
                + (f"; missing {', '.join(missing)}" if missing and not unknown else "")
            )
        raise RelcalError(f"{path} line {header_line}: header: {why}")
    values = _read_columns(path, header, data, columns)
    q = joints_from_unit(model, values, unit)  # (the caller checks the joint limits)
    return Targets(ids, lines, None, q, plan_robot, plan_unit)


def _unique_columns(
    path: Path, header: list[str], data: list = (), line: int | None = None
) -> None:
    """Refuse a header that names a column twice: one of the two would be read, the other
    silently ignored. The header's ``line``, else the line before the first row of ``data``."""
    dupes = sorted({h for h in header if header.count(h) > 1})
    if dupes:
        if line is None:
            line = data[0].line - 1 if data else 1
        raise RelcalError(
            f"{path} line {line}: header: column(s) {', '.join(map(printable, dupes))} appear "
            "twice; keep one"
        )


def _row_id(path: Path, line: int, sid: str, seen: dict[str, int], what: str = "sample") -> str:
    """The stripped id of a row, refused when empty or when an earlier row (``seen``: id to
    line, updated here) has it: two rows under one id cannot be told apart in the outputs."""
    sid = sid.strip()
    if not sid:
        raise RelcalError(f"{path} line {line}: id: empty; give every {what} an id")
    if sid in seen:
        raise RelcalError(f"{path} line {line}: id {excerpt(sid)} duplicates line {seen[sid]}")
    seen[sid] = line
    return sid


def _check_reach(path: Path, xyz: np.ndarray, lines: list[int]) -> None:
    """Positions beyond any arm's reach look like millimetres."""
    far = np.flatnonzero(np.linalg.norm(xyz, axis=1) > 20.0)
    if far.size:
        raise RelcalError(
            f"{path} line {lines[far[0]]}: x, y, z is {np.linalg.norm(xyz[far[0]]):.4g} m from "
            "the base: positions are in metres (millimetres given?)"
        )


def read_targets(
    path: str | Path, model: RobotModel, joint_unit: str = "deg"
) -> tuple[list[str], np.ndarray | None, np.ndarray | None]:
    """``(ids, poses (N, 4, 4) or None, q (N, n) or None)`` of :func:`read_target_file`."""
    found = read_target_file(path, model, joint_unit)
    return found.ids, found.poses, found.q


def _read_columns(path: Path, header: list[str], data: list, columns) -> np.ndarray:
    """The numbers of ``columns`` ``(N, len(columns))``; errors name the file, line and column."""
    idx = [header.index(c) for c in columns]
    values = []
    for row in data:
        if len(row) != len(header):
            raise RelcalError(f"{path} line {row.line}: {len(row)} fields, expected {len(header)}")
        values.append(
            [
                parse_number(path, row.line, c, row[i], comma_fix=POINTS_ONLY)
                for c, i in zip(columns, idx, strict=True)
            ]
        )
    return np.array(values, dtype=float).reshape(-1, len(idx))


def joints_from_unit(model: RobotModel, q: np.ndarray, unit: str) -> np.ndarray:
    """Joint values ``(N, n)`` in ``unit`` (deg or rad; prismatic joints in m) to rad and m."""
    return np.where(model.prismatic, q, np.radians(q)) if unit == "deg" else q


def joints_in_unit(model: RobotModel, q: np.ndarray, unit: str) -> np.ndarray:
    """Joint values ``(N, n)`` in rad and m to ``unit`` (deg or rad; prismatic joints in m)."""
    return np.where(model.prismatic, q, np.degrees(q)) if unit == "deg" else q


def _poses(
    path: Path, values: np.ndarray, lines: list[int], names: str = "qx, qy, qz, qw"
) -> np.ndarray:
    """Poses from rows ``x, y, z`` and a quaternion (x first, the columns ``names``), which
    must be a unit one."""
    norms = np.linalg.norm(values[:, 3:], axis=1)
    bad = np.flatnonzero(np.abs(norms - 1) > 1e-3)
    if bad.size:
        raise RelcalError(
            f"{path} line {lines[bad[0]]}: {names}: expected a unit quaternion (x first), the "
            f"norm is {norms[bad[0]]:.4f}"
        )
    rot = Rotation.from_quat(values[:, 3:] / norms[:, None]).as_matrix()
    return tf.homogeneous(rot, values[:, :3])


def _rotvec_poses(
    path: Path, values: np.ndarray, lines: list[int], names: str, fix: str
) -> np.ndarray:
    """Poses from rows ``x, y, z`` and a rotation vector (rad, the columns ``names``), which
    turns at most a turn: a controller writes at most pi, degrees read as radians reach 180
    (``fix``: what to declare then)."""
    angle = np.linalg.norm(values[:, 3:], axis=1)
    far = np.flatnonzero(angle > 2 * np.pi + 0.1)
    if far.size:
        raise RelcalError(
            f"{path} line {lines[far[0]]}: {names} is a rotation of {angle[far[0]]:.4g} rad "
            f"({np.degrees(angle[far[0]]):.4g} deg): a rotation vector is in radians (degrees "
            f"given? {fix})"
        )
    return tf.homogeneous(Rotation.from_rotvec(values[:, 3:]).as_matrix(), values[:, :3])


def _rpy_poses(
    path: Path,
    values: np.ndarray,
    unit: str,
    euler: str = "xyz",
    names: str = "roll, pitch, yaw",
    field: str = "pose_angle_unit",
) -> np.ndarray:
    """Poses from ``x, y, z, roll, pitch, yaw``: the three angles of the rotation sequence
    ``euler`` (SciPy's ``from_euler``; ``xyz``: ``R = Rz(yaw) Ry(pitch) Rx(roll)``); messages
    name the columns ``names`` and the dataset.yaml ``field`` of their unit."""
    rpy = values[:, 3:]
    if unit == "rad" and len(rpy) and np.abs(rpy).max() > 2 * np.pi + 0.1:
        raise RelcalError(
            f"{path}: {names} reach {np.abs(rpy).max():.1f}, which looks like degrees, "
            f"but dataset.yaml declares {field}: rad (the default; fix: {field}: deg)"
        )
    if unit == "deg" and len(rpy) >= 5 and np.abs(rpy).max() < np.pi + 0.05:
        raise RelcalError(
            f"{path}: {names} never exceed {np.abs(rpy).max():.2f}, which looks like "
            f"radians, but dataset.yaml declares {field}: deg (fix: {field}: rad)"
        )
    if unit == "deg":
        rpy = np.radians(rpy)
    return tf.homogeneous(Rotation.from_euler(euler, rpy).as_matrix(), values[:, :3])


def write_samples(
    path: Path, ids, q_deg: np.ndarray, images=None, poses=None, positions_only: bool = False
) -> str:
    """CSV text of a samples table (joint values as given, then an image path, a pose as x..qw,
    with ``positions_only`` the translations of ``poses`` as x, y, z, or none of them: a table of
    joint configurations)."""
    n = q_deg.shape[1]
    header = ["id", *[f"q{i + 1}" for i in range(n)]]
    if images is not None:
        header.append("image")
    elif poses is not None:
        header += list(POSITION_COLUMNS if positions_only else POSE_COLUMNS)
    lines = [csv_line(header)]
    for k, sid in enumerate(ids):
        cells = [str(sid), *[f"{v:.12g}" for v in q_deg[k]]]
        if images is not None:
            cells.append(str(images[k]))
        elif poses is not None and positions_only:
            cells += [f"{v:.12g}" for v in poses[k][:3, 3]]
        elif poses is not None:
            quat = Rotation.from_matrix(poses[k][:3, :3]).as_quat()
            cells += [f"{v:.12g}" for v in (*poses[k][:3, 3], *quat)]
        lines.append(csv_line(cells))
    return "\n".join(lines) + "\n"


def write_coincidence_samples(ids, groups, q: np.ndarray, digits: int = 17) -> str:
    """CSV text of a coincidence samples table: ``id, group, q1 .. qn`` (joint values as
    given)."""
    n = q.shape[1]
    lines = [",".join(["id", "group", *[f"q{i + 1}" for i in range(n)]])]
    for sid, group, row in zip(ids, groups, q, strict=True):
        lines.append(csv_line([str(sid), str(group), *[f"{v:.{digits}g}" for v in row]]))
    return "\n".join(lines) + "\n"


def check_dataset(dataset: Any, name: str = "dataset") -> Any:
    """A loaded :class:`relcal.data.dataset.Dataset` (a folder path is loaded first)."""
    if isinstance(dataset, str | Path):
        raise ArgumentError(
            f"{name}: expected a Dataset, got {describe(dataset)}: load the folder first, "
            f"relcal.load_dataset({str(dataset)!r})"
        )
    return check_instance(dataset, Dataset, name, "a Dataset (relcal.load_dataset(folder))")
