"""Converters from other tools' data to relcal dataset folders."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import pydantic

from relcal.data.dataset import POSE_COLUMNS
from relcal.errors import RelcalError, excerpt, printable
from relcal.io import Folder, csv_line, load_validated, note_input, write_set, yaml_text
from relcal.numbers import NotANumber, parse_number

POSITIONER_MODEL = """\
name: ROS-Industrial rct 2-axis positioner
source: >-
  Nominal chain of robot_cal_tools rct_examples positioner_kinematic_measurements (commit
  2089a06d): DH (d, theta, a, alpha) joint 1 (0, 0, 0, -90 deg), joint 2 (-0.475, -90 deg, 0, 0);
  base offset (2.2, 0, 1.6) m rotated 90 deg about x.
convention: dh
angle_unit: deg
joints:
  - {name: positioner_1, theta_off: 0, d: 0.0, a: 0.0, alpha: -90}
  - {name: positioner_2, theta_off: -90, d: -0.475, a: 0.0, alpha: 0}
base: {xyz: [2.2, 0.0, 1.6], rpy: [90, 0, 0]}
"""


MIN_IMPORTED = 4  # samples an importer needs to write a dataset (one pair per held-out sample)


class _Pose(pydantic.BaseModel):
    x: pydantic.FiniteFloat
    y: pydantic.FiniteFloat
    z: pydantic.FiniteFloat
    qx: pydantic.FiniteFloat
    qy: pydantic.FiniteFloat
    qz: pydantic.FiniteFloat
    qw: pydantic.FiniteFloat


def _unit_quaternion(p: _Pose, where: str) -> None:
    """A pose's quaternion must be a unit one (a zero or scaled one is a wrong file or field)."""
    norm = (p.qx**2 + p.qy**2 + p.qz**2 + p.qw**2) ** 0.5
    if abs(norm - 1) > 1e-3:
        raise RelcalError(
            f"{where}: qx, qy, qz, qw: expected a unit quaternion, the norm is {norm:.4g}"
        )


class _Observation(pydantic.BaseModel):
    camera_joints: list[pydantic.FiniteFloat] = []
    target_joints: list[pydantic.FiniteFloat]
    pose: _Pose


class _RctMeasurements(pydantic.RootModel[dict[str, _Observation]]):
    pass


def embedded_robot(
    robot: str | Path, root: str | None = None, tip: str | None = None
) -> tuple[str | dict, dict[str, bytes]]:
    """How a written dataset names its robot, and the files to copy into it: a built-in name as
    is; a model file copied as ``robot.yaml``, a URDF as ``robot.urdf`` (with its chain's
    ``root`` and ``tip``), so that the dataset folder holds no path outside itself and still
    loads when moved."""
    from relcal.io import note_input
    from relcal.robot.model import library_names

    name = str(robot)
    if name.lower() in library_names() and not Path(name).exists():
        return name.lower(), {}
    path = Path(name)
    if not path.is_file():
        raise RelcalError(
            f"robot {excerpt(name, 80)}: neither a built-in robot ({', '.join(library_names())}) "
            "nor a model file"
        )
    note_input(path)
    data = path.read_bytes()
    if path.suffix.lower() in (".urdf", ".xml", ".xacro"):
        entry: dict = {"urdf": "robot.urdf"}
        if root:
            entry["root"] = root
        if tip:
            entry["tip"] = tip
        return entry, {"robot.urdf": data}
    return "robot.yaml", {"robot.yaml": data}


def imported_id(where: str, name: str, seen: dict[str, str]) -> str:
    """``name`` (an observation key, a folder's name) as a sample id or group of the written
    ``samples.csv``: refused when it is empty, holds a line break (a CSV field never spans
    lines) or is another name's once its surrounding spaces are stripped (as the samples table
    reads ids: the two would be one id); ``seen`` maps the stripped names so far to the names
    given, updated here. Commas and quotes are kept (the writer quotes the cell)."""
    sid = name.strip()
    if not sid:
        raise RelcalError(
            f"{where}: an empty name ({excerpt(name)}); a sample id needs a character"
        )
    if len(sid.splitlines()) > 1:
        shown = printable(repr(name)[1:-1])
        raise RelcalError(
            f"{where}: a line break inside the name '{shown}': a sample id is one line of "
            "samples.csv; rename it"
        )
    if sid in seen:
        raise RelcalError(
            f"{where}: {excerpt(name)} and {excerpt(seen[sid])} are one id once their spaces "
            "are stripped; rename one"
        )
    seen[sid] = name
    return sid


@dataclass(frozen=True)
class Imported:
    """A dataset folder written by an importer."""

    folder: Path
    files: tuple[Path, ...]  # every file written into it
    n_samples: int


def import_rct_positioner(source: str | Path, out: str | Path) -> Imported:
    """Write a dataset folder (eye-to-hand, poses given) from robot_cal_tools' positioner file.

    The folder is written as one set and must not exist yet (or be empty): an existing dataset
    is never replaced."""
    data = load_validated(_RctMeasurements, source).root
    if len(data) < MIN_IMPORTED:
        raise RelcalError(
            f"{source}: {len(data)} observations, at least {MIN_IMPORTED} needed (expected a "
            "mapping of observations, each with target_joints and pose)"
        )
    out = Path(out)
    lines = [",".join(["id", "q1", "q2", *POSE_COLUMNS])]
    seen: dict[str, str] = {}
    for key, obs in data.items():
        p = obs.pose
        where = f"{source}: observation {excerpt(key)}"
        sid = imported_id(where, key, seen)
        _unit_quaternion(p, where)
        if len(obs.target_joints) != 2:
            raise RelcalError(
                f"{where}: target_joints: {len(obs.target_joints)} values, the 2-axis positioner "
                "has 2 (a file of another robot_cal_tools problem?)"
            )
        values = [*obs.target_joints, p.x, p.y, p.z, p.qx, p.qy, p.qz, p.qw]
        lines.append(csv_line([sid, *(f"{v:.17g}" for v in values)]))
    spec = {
        "robot": "positioner.yaml",
        "hayati": "auto",
        "mode": "eye_to_hand",
        "joint_unit": "rad",
        "samples": "samples.csv",
    }
    contents = {
        "positioner.yaml": POSITIONER_MODEL,
        "samples.csv": "\n".join(lines) + "\n",
        "dataset.yaml": yaml_text(spec),
    }
    write_set(Folder(out, contents, what="--out", replace="refuse"))
    return Imported(out, tuple(out / name for name in contents), len(data))


POSE_CHAIN = {
    "name": "recorded tool poses",
    "source": (
        "Pose chain of relcal import rct-images: prismatic z, x, y (m) then three revolute "
        "axes (rad); its joint values reproduce each recorded tool pose exactly. It stands for "
        "the robot, whose joint angles robot_cal_tools' image sets do not record."
    ),
    "convention": "dh",
    "angle_unit": "deg",
    "joints": [
        {"name": "z", "type": "prismatic", "theta_off": 90, "alpha": 90, "limits": [-10, 10]},
        {"name": "x", "type": "prismatic", "theta_off": 90, "alpha": 90, "limits": [-10, 10]},
        {"name": "y", "type": "prismatic", "theta_off": 90, "alpha": 90, "limits": [-10, 10]},
        {"name": "r1", "alpha": -90},
        {"name": "r2", "alpha": 90},
        {"name": "r3"},
    ],
}


class _RctEntry(pydantic.BaseModel):
    image: str
    pose: str


class _RctCalData(pydantic.RootModel[list[_RctEntry]]):
    pass


def pose_chain_joints(poses, first):
    """The pose chain (``POSE_CHAIN`` with its tool turned so that the first pose sits mid-range)
    and its joint values ``(N, 6)`` reproducing ``poses`` ``(N, 4, 4)``."""
    import numpy as np

    from relcal import geometry as tf
    from relcal.errors import RelcalError
    from relcal.robot.ik import solve_numeric
    from relcal.robot.kinematics import fk
    from relcal.robot.model import model_from_dict

    home = np.zeros(6)
    home[4] = np.pi / 2  # the wrist far from its singularity
    spec = {**POSE_CHAIN, "joints": [dict(j) for j in POSE_CHAIN["joints"]]}
    f0 = fk(model_from_dict(spec), home[None])[0]
    tool = np.eye(4)
    tool[:3, :3] = f0[:3, :3].T @ first[:3, :3]
    spec["tool"] = {"rpy": [float(np.degrees(v)) for v in tf.to_xyz_rpy(tool)[1]]}
    model = model_from_dict(spec)
    sol = solve_numeric(model, poses, np.tile(home, (len(poses), 1)))
    miss = np.abs(fk(model, sol.q) - poses).max(axis=(1, 2))
    if not np.all(sol.converged) or np.any(miss > 1e-8):
        bad = int(np.argmax(miss))
        raise RelcalError(
            f"pose {bad + 1}: not reproduced by the pose chain (miss {miss[bad]:.2g}); a pose "
            "far outside the others (metres given in millimetres?)"
        )
    return spec, sol.q


def import_rct_images(
    source: str | Path,
    out: str | Path,
    mode: str | None = None,
    intrinsics: str = "calibrated",
) -> Imported:
    """Write a dataset folder from a robot_cal_tools image set (``cal_data.yaml`` listing image
    and pose files, ``target.yaml``, ``camera_intr[_calibrated].yaml``).

    The images are copied into the folder's ``images/`` (the dataset holds no path outside
    itself, and still loads when moved). The recorded tool
    poses become the joint values of a pose chain (:data:`POSE_CHAIN`), so that ``relcal
    measure`` and ``relcal calibrate`` (hand-eye, board poses, and a correction of the recorded
    poses) run on it. ``mode``: ``eye_in_hand`` or ``eye_to_hand`` (default: from the folder
    name). ``intrinsics``: ``calibrated`` (``camera_intr_calibrated.yaml``), ``guess``
    (``camera_intr.yaml``) or ``calibrate`` (from the images).
    """
    import cv2
    import numpy as np
    from scipy.spatial.transform import Rotation

    from relcal import geometry as tf
    from relcal.errors import RelcalError
    from relcal.io import note_input
    from relcal.vision.boards import board_to_spec, load_board
    from relcal.vision.camera import load_camera

    source = Path(source)
    if not (source / "cal_data.yaml").is_file():
        raise RelcalError(
            f"{source}: not a robot_cal_tools image set (expected cal_data.yaml listing image and "
            "pose files)"
        )
    if mode is None:
        name = source.resolve().name
        mode = next((m for m in ("eye_in_hand", "eye_to_hand") if m in name), None)
        if mode is None:
            raise RelcalError(f"{source}: give --mode eye_in_hand or eye_to_hand")
    entries = load_validated(_RctCalData, source / "cal_data.yaml").root
    if len(entries) < MIN_IMPORTED:
        raise RelcalError(
            f"{source / 'cal_data.yaml'}: {len(entries)} entries, at least {MIN_IMPORTED} needed"
        )
    images, poses = [], []
    listed: dict[Path, int] = {}
    for k, e in enumerate(entries):
        image = (source / e.image).resolve()
        if not image.is_file():
            raise RelcalError(f"{source / 'cal_data.yaml'} entry {k + 1}: image not found: {image}")
        if image in listed:
            raise RelcalError(
                f"{source / 'cal_data.yaml'} entry {k + 1}: image {excerpt(e.image)} is entry "
                f"{listed[image] + 1}'s too: an entry listed twice would weigh twice in the fit "
                "(and a held-out copy flatter the validation); remove the repeated entry"
            )
        listed[image] = k
        note_input(image)
        p = load_validated(_Pose, source / e.pose)
        _unit_quaternion(p, str(source / e.pose))
        rot = Rotation.from_quat([p.qx, p.qy, p.qz, p.qw]).as_matrix()
        poses.append(tf.homogeneous(rot, np.array([p.x, p.y, p.z])))
        images.append(image)
    poses = np.array(poses)
    spec, q = pose_chain_joints(poses, poses[0])
    from relcal.limits import check_input_size

    for k, image in enumerate(images):
        check_input_size(image, "image")
        if not cv2.haveImageReader(str(image)):  # (its header: every image, not the first only)
            raise RelcalError(
                f"{source / 'cal_data.yaml'} entry {k + 1}: {image}: not an image OpenCV can read"
            )
    first = cv2.imread(str(images[0]), cv2.IMREAD_UNCHANGED)
    if first is None:
        raise RelcalError(f"{images[0]}: not an image OpenCV can read")
    height, width = first.shape[:2]
    board = load_board(source / "target.yaml")
    contents = {
        "robot.yaml": yaml_text(spec),
        "board.yaml": yaml_text(board_to_spec(board)),
    }
    if intrinsics == "calibrate":
        camera_entry = "calibrate"
    else:
        name = "camera_intr_calibrated.yaml" if intrinsics == "calibrated" else "camera_intr.yaml"
        camera = load_camera(source / name, width, height)
        contents["camera.yaml"] = yaml_text(camera.to_dict())
        camera_entry = "camera.yaml"
    lines = ["id,q1,q2,q3,q4,q5,q6,image"]
    for k, image in enumerate(images):
        copied = f"images/{k:03d}_{image.name}"
        contents[copied] = image.read_bytes()
        lines.append(",".join([f"{k:03d}", *(f"{v:.17g}" for v in q[k]), copied]))
    contents["samples.csv"] = "\n".join(lines) + "\n"
    dataset = {
        "robot": "robot.yaml",
        "hayati": "off",
        "mode": mode,
        "board": "board.yaml",
        "camera": camera_entry,
        "joint_unit": "rad",
        "samples": "samples.csv",
    }
    contents["dataset.yaml"] = yaml_text(dataset)
    out = Path(out)
    write_set(Folder(out, contents, what="--out", replace="refuse"))
    return Imported(out, tuple(out / name for name in contents), len(entries))


MUKCA_SOCKET = "hole_*.csv"


def _mukca_joints(path: Path, n_joints: int):
    """Joint angles ``(N, n)`` (rad) of one MUKCa socket file: no header, one configuration per
    row, separated by commas (or semicolons, tabs or vertical bars: one of them throughout the
    file, as :func:`relcal.io.read_table` reads tables); errors name the file and the line.

    A UTF-8 byte-order mark is skipped; an empty field is refused (it would shift the joints
    after it), as is a row that repeats an earlier one (a configuration recorded or copied
    twice weighs twice in the fit) and a file of fewer than two configurations (its socket's
    point would be fitted to one sample exactly: it tells nothing about the kinematics)."""
    import numpy as np

    from relcal.errors import RelcalError
    from relcal.io import DELIMITERS, other_separator
    from relcal.limits import read_input

    note_input(path)
    try:
        text = read_input(path, "csv").decode("utf-8-sig")
    except UnicodeDecodeError:
        raise RelcalError(f"{path}: not a text file (not UTF-8); expected joint values") from None
    except OSError as exc:
        raise RelcalError(f"{path}: cannot read: {exc.strerror or exc}") from None
    lines = [(no, line) for no, line in enumerate(text.splitlines(), start=1) if line.strip()]
    if not lines:
        raise RelcalError(f"{path}: empty; expected one configuration per line (rad, no header)")
    first = lines[0][1]
    counts = {d: first.count(d) for d in DELIMITERS}
    fits = sorted(  # n fields, else n and a trailing separator (0,5;1,2: ';')
        (d for d in DELIMITERS if counts[d] in (n_joints - 1, n_joints)),
        key=lambda d: counts[d] != n_joints - 1,
    )
    delimiter = fits[0] if fits else max(counts, key=lambda d: (counts[d], d == ","))
    rows, first_seen = [], {}
    for line_no, line in lines:
        cells = line.split(delimiter)
        other = other_separator(line, delimiter, n_joints)
        if other is not None:
            raise RelcalError(
                f"{path} line {line_no}: fields separated by {DELIMITERS[other]}, but line "
                f"{lines[0][0]} by {DELIMITERS[delimiter]}; use one separator throughout the file"
            )
        if len(cells) == n_joints + 1 and not cells[-1].strip():
            cells = cells[:-1]  # a trailing separator
        values = []
        for k, cell in enumerate(cells):
            try:
                values.append(parse_number(cell))
            except NotANumber as exc:
                raise RelcalError(
                    f"{path} line {line_no}: joint {k + 1}: {exc} (joint angles in rad, "
                    f"separated by {DELIMITERS[delimiter]}, no header)"
                ) from None
        if len(values) != n_joints:
            raise RelcalError(
                f"{path} line {line_no}: {len(values)} values, expected {n_joints} joint angles "
                "(rad) for the robot of --urdf"
            )
        key = tuple(values)
        if key in first_seen:
            raise RelcalError(
                f"{path} line {line_no}: repeats line {first_seen[key]}: the same configuration "
                "twice (a configuration recorded or copied twice counts twice in the fit; fix: "
                "remove the repeated line)"
            )
        first_seen[key] = line_no
        rows.append(values)
    q = np.array(rows)
    peak = np.abs(q).max(axis=1)
    worst = int(np.argmax(peak))
    if peak[worst] > 2 * np.pi + 0.1:
        line_no = lines[worst][0]
        many = int((peak > 2 * np.pi + 0.1).sum())
        raise RelcalError(
            f"{path} line {line_no}: a joint angle of {peak[worst]:.4g}, beyond 2 pi; "
            + (
                "degrees? MUKCa files hold radians"
                if many > 1 and peak[worst] < 400
                else f"{many} of {len(q)} lines: a mistyped value? fix or remove the line"
            )
        )
    if len(q) < 2:
        raise RelcalError(
            f"{path}: one configuration; a socket needs two or more (its point is unknown: one "
            "sample is fitted to it exactly and tells nothing about the kinematics); record more "
            "or leave the file out of the placement folder"
        )
    return q


def import_mukca(
    source: str | Path,
    out: str | Path,
    urdf: str | Path,
    tip: str = "ball_link",
    root: str | None = None,
    distance: float | None = None,
    distance_std: float = 1e-4,
    placements: Sequence[str] | None = None,
) -> Imported:
    """Write a coincidence dataset folder from one robot's folder of the MUKCa layout
    (``ROBOT/PLACEMENT/hole_0.csv``, ``hole_1.csv``: joint angles in rad, no header).

    Each placement folder is a placement, each ``hole_*.csv`` a group (``PLACEMENT/hole_0``);
    ``hole_*_pose.csv`` (the controller's own FK of another frame) are not read: they may hold
    more rows than the joint files, and nothing here pairs rows across files. The robot is the
    URDF's chain ``root`` .. ``tip``, whose origin is the ball centre guess; the URDF is copied
    into the folder as ``robot.urdf`` (the dataset holds no path outside itself, and still loads
    when moved). ``distance`` (m) between the two sockets of every placement, with
    ``distance_std``, goes into ``distances:``. ``placements``: the placement folders to import
    (default all), e.g. some to calibrate with and the others, as a later session, to verify on.
    The folder ``out`` must be new or empty.
    """
    from relcal.errors import RelcalError
    from relcal.robot.urdf import load_urdf

    source, urdf = Path(source), Path(urdf)
    if not source.is_dir():
        raise RelcalError(f"{source}: not a folder (expected ROBOT/PLACEMENT/hole_*.csv)")
    model = load_urdf(urdf, root, tip)
    found = []
    for folder in sorted(p for p in source.iterdir() if p.is_dir()):
        files = sorted(f for f in folder.glob(MUKCA_SOCKET) if not f.stem.endswith("_pose"))
        if files:
            found.append((folder.name, files))
    if not found:
        raise RelcalError(
            f"{source}: no placement folders with hole_*.csv (expected the MUKCa layout "
            "ROBOT/PLACEMENT/hole_0.csv; give the robot's folder, e.g. data/panda_1)"
        )
    if placements is not None:
        names = [name for name, _ in found]
        unknown = [p for p in placements if p not in names]
        if unknown or not placements:
            raise RelcalError(
                f"{source}: placements {', '.join(unknown) or '(none given)'}: not among its "
                f"placement folders ({', '.join(names)})"
            )
        found = [(name, files) for name, files in found if name in set(placements)]
    ids, groups, blocks = [], [], []
    distances = []
    seen: dict[str, str] = {}
    for place, files in found:
        imported_id(f"{source}: placement folder", place, {})
        for f in files:
            q = _mukca_joints(f, model.n_joints)
            group = imported_id(f"{f}: its group", f"{place}/{f.stem}", seen)
            ids += [f"{group}/{k:03d}" for k in range(len(q))]
            groups += [group] * len(q)
            blocks.append(q)
        if distance is not None:
            if len(files) != 2:
                raise RelcalError(
                    f"{source / place}: {len(files)} socket files; --distance needs exactly two "
                    "per placement"
                )
            distances.append(
                {
                    "groups": [f"{place}/{files[0].stem}", f"{place}/{files[1].stem}"],
                    "distance": float(distance),
                    "std": float(distance_std),
                }
            )
    import numpy as np

    from relcal.data.dataset import write_coincidence_samples

    robot, robot_files = embedded_robot(urdf, root, tip)
    spec: dict = {
        "robot": robot,
        "measurement": "coincidence",
        "joint_unit": "rad",
        "samples": "samples.csv",
        "tool": {"xyz": [0.0, 0.0, 0.0]},
        "robot_id": source.resolve().name,
    }
    if distances:
        spec["distances"] = distances
    contents = {
        **robot_files,
        "samples.csv": write_coincidence_samples(ids, groups, np.concatenate(blocks)),
        "dataset.yaml": yaml_text(spec),
    }
    out = Path(out)
    write_set(Folder(out, contents, what="--out", replace="refuse"))
    return Imported(out, tuple(out / name for name in contents), len(ids))
