"""A recorded calibration run (ROS 1 bag, ROS 2 bag or MCAP) to a dataset folder.

The robot moves from pose to pose and stops at each; a stop is where every joint velocity stays
below a threshold for at least a settle time. Each stop becomes one sample: the mean joint
positions over the stop and the image (``sensor_msgs/Image`` or ``CompressedImage``, written as
PNG) or the pose (``geometry_msgs/PoseStamped`` or ``TransformStamped``) nearest the middle of the
stop, within it. Intrinsics come from a ``sensor_msgs/CameraInfo`` topic when present.

Bags are read with the ``rosbags`` library (pure Python, no ROS install): ``pip install
'relcal[ros]'``. Times are the messages' header stamps (the recording time when a stamp is zero).
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from relcal.checks import check_instance, check_number, check_path
from relcal.data.dataset import POSE_COLUMNS
from relcal.data.importers import Imported, embedded_robot
from relcal.errors import RelcalError, printable
from relcal.io import Folder, write_set, yaml_text

JOINT_TYPES = ("sensor_msgs/msg/JointState",)
IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
POSE_TYPES = ("geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/TransformStamped")
INFO_TYPES = ("sensor_msgs/msg/CameraInfo",)


@dataclass(frozen=True)
class StopOptions:
    """How stops are found: joint speed below ``velocity`` (rad/s, m/s for prismatic joints) for
    at least ``settle`` seconds."""

    velocity: float = 0.01
    settle: float = 0.5

    def __post_init__(self) -> None:
        """Arguments checked where the API is entered: ``velocity`` above 0 (no joint is ever
        slower than 0: no stop would be found), ``settle`` from 0, both finite."""
        check_number(self.velocity, "StopOptions.velocity", 0, low_open=True)
        check_number(self.settle, "StopOptions.settle", 0)


@dataclass(frozen=True)
class Stop:
    """One stop of the robot: its time span (s) and the mean joint positions ``(n,)``."""

    start: float
    end: float
    q: np.ndarray

    @property
    def middle(self) -> float:
        return 0.5 * (self.start + self.end)


@dataclass(frozen=True)
class JointTrack:
    """Joint states over time: names, times ``(T,)`` s, positions and velocities ``(T, n)``;
    ``measured_velocity`` tells whether the velocities were recorded or differenced."""

    names: tuple[str, ...]
    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    measured_velocity: bool


def find_stops(track: JointTrack, options: StopOptions = StopOptions()) -> list[Stop]:
    """The stops of a joint track: maximal runs of states with every joint speed below
    ``options.velocity`` lasting at least ``options.settle`` seconds."""
    still = np.all(np.abs(track.v) < options.velocity, axis=1)
    stops = []
    edges = np.flatnonzero(np.diff(np.r_[0, still.astype(int), 0]))
    for first, after in zip(edges[::2], edges[1::2], strict=True):
        start, end = track.t[first], track.t[after - 1]
        if end - start >= options.settle:
            stops.append(Stop(float(start), float(end), track.q[first:after].mean(axis=0)))
    return stops


def _stamp(msg, recorded_ns: int) -> float:
    """Header stamp in s, or the recording time when the message has no (or a zero) stamp."""
    header = getattr(msg, "header", None)
    stamp = getattr(header, "stamp", None)
    if stamp is not None:
        sec = getattr(stamp, "sec", None)
        nsec = getattr(stamp, "nanosec", None)
        if sec is None:  # ROS 1 time
            sec, nsec = getattr(stamp, "secs", 0), getattr(stamp, "nsecs", 0)
        if sec or nsec:
            return sec + nsec * 1e-9
    return recorded_ns * 1e-9


def _open(bag: Path):
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise RelcalError(
            "relcal import rosbag needs the rosbags package: pip install 'relcal[ros]'"
        ) from None
    if not bag.exists():
        raise RelcalError(
            f"{bag}: file or folder not found (expected a ROS 1 .bag, a ROS 2 bag "
            "folder, or an .mcap/.db3 file)"
        )
    return AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE))


@contextlib.contextmanager
def _reading(bag: Path):
    """Open ``bag`` for the block; what rosbags cannot read (a file that is not a bag, an empty
    or truncated one, a folder without ``metadata.yaml``) is a :class:`RelcalError` naming the
    bag and what was expected, never rosbags' own exception."""
    from rosbags.highlevel import AnyReaderError

    expected = "expected a ROS 1 .bag, a ROS 2 bag folder (with metadata.yaml), or an .mcap/.db3"
    try:
        with _open(bag) as reader:
            yield reader
    except AnyReaderError as exc:
        raise RelcalError(
            f"{bag}: not a bag rosbags can read ({printable(exc)}); {expected}"
        ) from None
    except FileNotFoundError as exc:  # a folder without metadata.yaml, a bag file gone
        if not bag.is_dir():
            raise
        raise RelcalError(
            f"{bag}: a folder without a ROS 2 bag's metadata.yaml ({printable(exc)}); {expected}"
        ) from None


def _connections(reader, bag: Path, topic: str, types: tuple[str, ...], option: str):
    found = [c for c in reader.connections if c.topic == topic]
    if not found:
        listing = ", ".join(sorted({f"{c.topic} ({c.msgtype})" for c in reader.connections}))
        raise RelcalError(f"{bag}: {option} {topic}: no such topic; the bag has {listing}")
    bad = [c.msgtype for c in found if c.msgtype not in types]
    if bad:
        raise RelcalError(
            f"{bag}: {option} {topic}: message type {bad[0]}, expected {' or '.join(types)}"
        )
    return found


def _messages(reader, connections):
    for conn, recorded, raw in reader.messages(connections=connections):
        yield conn, recorded, reader.deserialize(raw, conn.msgtype)


def read_joint_track(reader, bag: Path, topic: str) -> JointTrack:
    """Joint states of ``topic``: the joints named in its first message, in that order (later
    messages reordered by name; messages lacking one of them are skipped). Velocities are the
    recorded ones when every message has them, otherwise central finite differences."""
    conns = _connections(reader, bag, topic, JOINT_TYPES, "--joints")
    names: tuple[str, ...] | None = None
    times, positions, velocities = [], [], []
    for _, recorded, msg in _messages(reader, conns):
        msg_names = tuple(msg.name)
        if names is None:
            if not msg_names:
                raise RelcalError(f"{bag}: --joints {topic}: the first message names no joints")
            names = msg_names
        where = {n: k for k, n in enumerate(msg_names)}
        if any(n not in where for n in names) or len(msg.position) != len(msg_names):
            continue
        order = [where[n] for n in names]
        times.append(_stamp(msg, recorded))
        positions.append(np.asarray(msg.position, dtype=float)[order])
        vel = np.asarray(msg.velocity, dtype=float)
        velocities.append(vel[order] if len(vel) == len(msg_names) else None)
    if names is None or len(times) < 2:
        raise RelcalError(f"{bag}: --joints {topic}: fewer than 2 joint state messages")
    t = np.array(times)
    order = np.argsort(t, kind="stable")
    t, q = t[order], np.array(positions)[order]
    measured = all(v is not None and np.all(np.isfinite(v)) for v in velocities)
    if measured:
        v = np.array(velocities)[order]
    else:
        unique = np.r_[True, np.diff(t) > 0]  # repeated stamps would divide by zero
        t, q = t[unique], q[unique]
        v = np.gradient(q, t, axis=0)
    return JointTrack(names, t, q, v, measured)


def _image_array(msg, msgtype: str, bag: Path, topic: str) -> np.ndarray:
    """The image as an OpenCV array (BGR or grey)."""
    import cv2

    data = np.frombuffer(bytes(msg.data), dtype=np.uint8)
    if msgtype.endswith("CompressedImage"):
        img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
        if img is None:
            raise RelcalError(f"{bag}: --image {topic}: cannot decode a '{msg.format}' image")
        return img
    enc = msg.encoding.lower()
    depth = {"8": np.uint8, "16": np.uint16}
    channels = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1, "mono16": 1, "8uc1": 1}
    if enc not in channels:
        raise RelcalError(
            f"{bag}: --image {topic}: encoding '{msg.encoding}' not supported (rgb8, bgr8, rgba8, "
            "bgra8, mono8, mono16)"
        )
    dtype = depth["16"] if enc == "mono16" else depth["8"]
    item = np.dtype(dtype).itemsize
    c = channels[enc]
    rows = np.frombuffer(bytes(msg.data), dtype=np.uint8).reshape(msg.height, msg.step)
    pixels = rows[:, : msg.width * c * item].copy().view(dtype)
    if item > 1 and msg.is_bigendian:
        pixels = pixels.byteswap()
    img = pixels.reshape(msg.height, msg.width, c) if c > 1 else pixels.reshape(msg.height, -1)
    conversions = {
        "rgb8": cv2.COLOR_RGB2BGR,
        "rgba8": cv2.COLOR_RGBA2BGR,
        "bgra8": cv2.COLOR_BGRA2BGR,
    }
    return cv2.cvtColor(img, conversions[enc]) if enc in conversions else img


def _pose_vector(msg, msgtype: str) -> np.ndarray:
    """``x, y, z, qx, qy, qz, qw`` of a PoseStamped or TransformStamped."""
    if msgtype.endswith("TransformStamped"):
        p, o = msg.transform.translation, msg.transform.rotation
    else:
        p, o = msg.pose.position, msg.pose.orientation
    return np.array([p.x, p.y, p.z, o.x, o.y, o.z, o.w], dtype=float)


def _camera_yaml(msg) -> dict | None:
    """relcal's camera YAML from a CameraInfo (ROS 1 or 2 field names); None for distortion
    models OpenCV's pinhole model does not cover."""
    k = list(getattr(msg, "k", None) if hasattr(msg, "k") else msg.K)
    d = [float(x) for x in (getattr(msg, "d", None) if hasattr(msg, "d") else msg.D)]
    model = msg.distortion_model
    if model not in ("plumb_bob", "rational_polynomial", "") or k[0] <= 0 or k[4] <= 0:
        return None
    if len(d) not in (0, 4, 5, 8, 12, 14):
        d = (d + [0.0] * 5)[:5] if len(d) < 5 else d[:8]
    return {
        "fx": float(k[0]),
        "fy": float(k[4]),
        "cx": float(k[2]),
        "cy": float(k[5]),
        "distortion": d,
        "width": int(msg.width),
        "height": int(msg.height),
    }


def _camera_info_topic(reader, image_topic: str) -> str | None:
    """The CameraInfo topic beside ``image_topic`` (``/cam/image_raw[/compressed]`` ->
    ``/cam/camera_info``), if the bag has it."""
    base = image_topic.removesuffix("/compressed").rsplit("/", 1)[0]
    wanted = f"{base}/camera_info"
    infos = {c.topic for c in reader.connections if c.msgtype in INFO_TYPES}
    return wanted if wanted in infos else None


@dataclass(frozen=True)
class RosbagImport(Imported):
    """What an import found: the stops, which of them got a sample, and why others did not."""

    stops: tuple[Stop, ...] = ()
    skipped: tuple[str, ...] = ()  # one reason per stop left out
    joint_names: tuple[str, ...] = ()
    measured_velocity: bool = False
    camera_info: str | None = None  # the CameraInfo topic used


def import_rosbag(
    bag: str | Path,
    out: str | Path,
    joints: str,
    image: str | None = None,
    pose: str | None = None,
    camera_info: str | None = None,
    robot: str | None = None,
    options: StopOptions = StopOptions(),
) -> RosbagImport:
    """Write a dataset folder from a bag: one sample per stop of the robot.

    Each stop gives one sample, with the image or pose nearest its middle (within the stop).
    Joints are written in rad (m for prismatic joints) under their names.

    Parameters
    ----------
    bag : str or Path
        The rosbag: a ROS 1 ``.bag``, a ROS 2 bag folder, or an ``.mcap``/``.db3`` file.
    out : str or Path
        The dataset folder to write.
    joints : str
        The ``sensor_msgs/JointState`` topic.
    image, pose : str, optional
        The image topic, or the pose topic (camera in the board frame); exactly one.
    camera_info : str, optional
        The ``CameraInfo`` topic of the intrinsics (default: found beside the image topic).
    robot : str, optional
        The robot, written into ``dataset.yaml`` as ``robot:``: a built-in name as is, a model
        file or a URDF copied into the folder (``robot.yaml``, ``robot.urdf``), so the dataset
        holds no path outside itself.
    options : StopOptions
        How stops are found: joint speed below ``velocity`` (rad/s, m/s) for at least
        ``settle`` s.

    Returns
    -------
    RosbagImport
        The stops, which of them got a sample, and why others did not.

    Raises
    ------
    ArgumentError
        ``bag`` or ``out`` not a path, a topic or ``robot`` not a string, ``options`` not
        :class:`StopOptions` (before the bag is opened).
    RelcalError
        Neither or both of ``image`` and ``pose``, a bag that is not found, the ``rosbags``
        package missing (the ``ros`` extra), a topic that is not in the bag, or a bag in which
        the robot never stops.
    """
    bag = check_path(bag, "bag", "a rosbag (a ROS 2 bag folder or a ROS 1 .bag file)")
    out = check_path(out, "out", "the dataset folder to write")
    check_instance(joints, str, "joints", "the JointState topic (e.g. '/joint_states')")
    for name, value in (
        ("image", image), ("pose", pose), ("camera_info", camera_info), ("robot", robot)
    ):  # fmt: skip
        if value is not None:
            check_instance(value, str, name, "a topic name (str) or None")
    check_instance(options, StopOptions, "options", "StopOptions(velocity=, settle=)")
    if (image is None) == (pose is None):
        raise RelcalError("relcal import rosbag: give exactly one of --image TOPIC or --pose TOPIC")
    if robot:
        embedded_robot(robot)  # a robot that cannot be copied in is refused before the work
    with _reading(bag) as reader:
        track = read_joint_track(reader, bag, joints)
        stops = find_stops(track, options)
        if not stops:
            peak = np.abs(track.v).max(axis=1)
            raise RelcalError(
                f"{bag}: --joints {joints}: the robot never stops (joint speed below "
                f"{options.velocity:g} for {options.settle:g} s); the slowest state moves at "
                f"{peak.min():.3g}; raise --velocity or lower --settle"
            )
        topic = image or pose
        types = IMAGE_TYPES if image else POSE_TYPES
        conns = _connections(reader, bag, topic, types, "--image" if image else "--pose")
        chosen = _nearest(reader, conns, stops)
        info_topic = camera_info or (_camera_info_topic(reader, image) if image else None)
        camera = None
        if info_topic is not None:
            info_conns = _connections(reader, bag, info_topic, INFO_TYPES, "--camera-info")
            for _, _, msg in _messages(reader, info_conns):
                camera = _camera_yaml(msg)
                break
        files, lines, skipped = {}, [], []
        header = ["id", *track.names, *(["image"] if image else POSE_COLUMNS)]
        lines.append(",".join(header))
        for k, stop in enumerate(stops):
            hit = chosen[k]
            if hit is None:
                skipped.append(
                    f"stop {k + 1} ({stop.start:.3f}..{stop.end:.3f} s): no {topic} message in it"
                )
                continue
            conn, msg = hit
            sid = f"stop{k + 1:03d}"
            cells = [sid, *(f"{v:.17g}" for v in stop.q)]
            if image:
                files[f"images/{sid}.png"] = _image_array(msg, conn.msgtype, bag, topic)
                cells.append(f"images/{sid}.png")
            else:
                cells += [f"{v:.17g}" for v in _pose_vector(msg, conn.msgtype)]
            lines.append(",".join(cells))
    if len(lines) == 1:
        raise RelcalError(f"{bag}: none of the {len(stops)} stops has a {topic} message")
    return _write(
        out, files, lines, camera, robot, image is not None, stops, skipped, track, info_topic
    )


def _nearest(reader, conns, stops: list[Stop]) -> list[tuple | None]:
    """Per stop, the (connection, message) nearest its middle among those stamped within it."""
    best: list[tuple[float, object, int] | None] = [None] * len(stops)
    starts = np.array([s.start for s in stops])
    for conn, recorded, raw in reader.messages(connections=conns):
        msg = reader.deserialize(raw, conn.msgtype)
        t = _stamp(msg, recorded)
        k = int(np.searchsorted(starts, t, side="right")) - 1
        if k < 0 or t > stops[k].end:
            continue
        gap = abs(t - stops[k].middle)
        if best[k] is None or gap < best[k][0]:
            best[k] = (gap, (conn, msg), k)
    return [None if b is None else b[1] for b in best]


def _write(out, images, lines, camera, robot, has_images, stops, skipped, track, info_topic):
    """The dataset folder, written as one set (never over an existing dataset)."""
    import cv2

    contents: dict = {}
    for name, img in images.items():
        ok, png = cv2.imencode(".png", img)
        if not ok:
            raise RelcalError(f"{out / name}: cannot encode the PNG image")
        contents[name] = png.tobytes()
    entry: str | dict = "REPLACE_ME (a built-in name or a model file)"
    if robot:
        entry, robot_files = embedded_robot(robot)
        contents.update(robot_files)
    spec: dict = {"robot": entry}
    spec.update(hayati="auto", mode="eye_in_hand", joint_unit="rad")
    if has_images:
        spec["board"] = "board.yaml"
        if camera is not None:
            contents["camera.yaml"] = yaml_text(camera)
            spec["camera"] = "camera.yaml"
        else:
            spec["camera"] = "calibrate"
    spec["samples"] = "samples.csv"
    contents["samples.csv"] = "\n".join(lines) + "\n"
    contents["dataset.yaml"] = yaml_text(spec)
    write_set(Folder(out, contents, what="--out", replace="refuse"))
    written = [out / name for name in contents]
    return RosbagImport(
        folder=out,
        files=tuple(written),
        n_samples=len(lines) - 1,
        stops=tuple(stops),
        skipped=tuple(skipped),
        joint_names=track.names,
        measured_velocity=track.measured_velocity,
        camera_info=info_topic,
    )
