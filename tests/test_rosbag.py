"""`relcal import rosbag`: bags written with rosbags' own writer (ROS 2 sqlite3 and MCAP), read
back through the command: the stops found, the images or poses chosen, the intrinsics."""

import json

import numpy as np
import pytest
import yaml

from relcal.cli import main

rosbags = pytest.importorskip("rosbags")
cv2 = pytest.importorskip("cv2")

from rosbags.rosbag2 import StoragePlugin, Writer  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

STORE = get_typestore(Stores.ROS2_HUMBLE)
T0 = 1000.0  # header stamps start here (s); the recording clock starts elsewhere
NAMES = [f"joint{i}" for i in range(1, 8)]  # the Franka FR3's joint names
# Four poses to stop at (rad), within the FR3's limits.
WAYPOINTS = np.array(
    [
        [0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.7],
        [0.5, 0.2, -0.4, -1.5, 0.3, 2.2, 0.0],
        [-0.6, -0.5, 0.3, -2.4, -0.5, 1.4, 1.1],
        [0.2, 0.4, 0.6, -1.0, 0.8, 2.6, -0.5],
    ]
)
HOLDS = [(0.0, 1.0), (2.0, 3.0), (4.0, 5.0), (6.0, 7.0)]  # s after T0; moves in between


def trajectory(t: np.ndarray) -> np.ndarray:
    """Joint positions ``(T, 7)``: hold each waypoint, move between them with a cosine profile."""
    q = np.empty((len(t), 7))
    for k, tk in enumerate(t):
        seg = min(int(tk // 2), len(WAYPOINTS) - 1)
        s = np.clip(tk - 2 * seg - 1.0, 0.0, 1.0)  # 0 during the hold, 0..1 during the move
        nxt = WAYPOINTS[min(seg + 1, len(WAYPOINTS) - 1)]
        blend = 0.5 - 0.5 * np.cos(np.pi * s)
        q[k] = WAYPOINTS[seg] + blend * (nxt - WAYPOINTS[seg])
    return q


def _header(t: float, frame: str = "base"):
    sec = int(np.floor(t))
    stamp = STORE.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((t - sec) * 1e9)))
    return STORE.types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)


def _joint_messages(writer, with_velocity: bool):
    JointState = STORE.types["sensor_msgs/msg/JointState"]
    conn = writer.add_connection("/joint_states", JointState.__msgtype__, typestore=STORE)
    t = np.arange(0.0, 7.0 + 1e-9, 0.01)  # 100 Hz
    q = trajectory(t)
    v = np.gradient(q, t, axis=0)
    for k, tk in enumerate(t):
        msg = JointState(
            header=_header(T0 + tk),
            name=NAMES,
            position=q[k],
            velocity=v[k] if with_velocity else np.zeros(0),
            effort=np.zeros(0),
        )
        writer.write(conn, int((5.0 + tk) * 1e9), STORE.serialize_cdr(msg, JointState.__msgtype__))


def _write_image_bag(path):
    Image = STORE.types["sensor_msgs/msg/Image"]
    CameraInfo = STORE.types["sensor_msgs/msg/CameraInfo"]
    with Writer(path, version=9, storage_plugin=StoragePlugin.SQLITE3) as writer:
        _joint_messages(writer, with_velocity=False)
        info = writer.add_connection("/cam/camera_info", CameraInfo.__msgtype__, typestore=STORE)
        image = writer.add_connection("/cam/image_raw", Image.__msgtype__, typestore=STORE)
        roi = STORE.types["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        )
        cam = CameraInfo(
            header=_header(T0),
            height=6,
            width=8,
            distortion_model="plumb_bob",
            d=np.array([0.1, -0.2, 0.001, 0.002, 0.05]),
            k=np.array([600.0, 0, 4.0, 0, 610.0, 3.0, 0, 0, 1]),
            r=np.eye(3).ravel(),
            p=np.zeros(12),
            binning_x=0,
            binning_y=0,
            roi=roi,
        )
        writer.write(info, int(5e9), STORE.serialize_cdr(cam, CameraInfo.__msgtype__))
        for frame in range(60):  # 10 Hz until 5.9 s: the last stop (6..7 s) has no image
            rgb = np.zeros((6, 8, 3), dtype=np.uint8)
            rgb[..., 0], rgb[..., 2] = frame, 200  # red = frame number, blue = 200
            msg = Image(
                header=_header(T0 + 0.1 * frame),
                height=6,
                width=8,
                encoding="rgb8",
                is_bigendian=0,
                step=24,
                data=rgb.ravel(),
            )
            ts = int((5.0 + 0.1 * frame) * 1e9)
            writer.write(image, ts, STORE.serialize_cdr(msg, Image.__msgtype__))


def _write_pose_bag(path):
    PoseStamped = STORE.types["geometry_msgs/msg/PoseStamped"]
    Point = STORE.types["geometry_msgs/msg/Point"]
    Quaternion = STORE.types["geometry_msgs/msg/Quaternion"]
    Pose = STORE.types["geometry_msgs/msg/Pose"]
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        _joint_messages(writer, with_velocity=True)
        conn = writer.add_connection("/mocap/tool", PoseStamped.__msgtype__, typestore=STORE)
        for frame in range(211):  # 30 Hz; the position encodes the time, the rotation is fixed
            t = frame / 30.0
            q = np.array([0.1, -0.2, 0.3, 0.9])
            q /= np.linalg.norm(q)
            pose = Pose(
                position=Point(x=t, y=2.0 * t, z=-1.0),
                orientation=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3]),
            )
            msg = PoseStamped(header=_header(T0 + t, "mocap"), pose=pose)
            ts = int((5.0 + t) * 1e9)
            writer.write(conn, ts, STORE.serialize_cdr(msg, PoseStamped.__msgtype__))


def test_images_one_sample_per_stop(tmp_path, capsys):
    bag = tmp_path / "run"
    _write_image_bag(bag)
    out, doc = tmp_path / "ds", tmp_path / "import.json"
    argv = ["import", "rosbag", str(bag), "--joints", "/joint_states", "--image", "/cam/image_raw"]
    assert main([*argv, "--out", str(out), "--robot", "franka_fr3", "--json", str(doc)]) == 0
    text = capsys.readouterr().out
    assert "4 stops of the robot found (finite differences" in text
    assert "skipped stop 4" in text
    report = json.loads(doc.read_text())
    assert report["n_samples"] == 3 and report["camera_info"] == "/cam/camera_info"
    for stop, (a, b) in zip(report["stops"], HOLDS, strict=True):
        assert abs(stop["start_s"] - (T0 + a)) < 0.02 and abs(stop["end_s"] - (T0 + b)) < 0.02
    lines = (out / "samples.csv").read_text().splitlines()
    assert lines[0] == ",".join(["id", *NAMES, "image"])
    for k, line in enumerate(lines[1:]):
        cells = line.split(",")
        np.testing.assert_allclose([float(c) for c in cells[1:8]], WAYPOINTS[k], atol=1e-12)
        img = cv2.imread(str(out / cells[8]), cv2.IMREAD_UNCHANGED)
        assert img.shape == (6, 8, 3)
        # The frame nearest the middle of hold k (T0 + 2 k + 0.5 s) is frame 20 k + 5.
        assert np.all(img[..., 2] == 20 * k + 5) and np.all(img[..., 0] == 200)  # BGR on disk
    camera = (out / "camera.yaml").read_text()
    assert "fx: 600.0" in camera and "cy: 3.0" in camera and "0.05" in camera
    assert "camera: camera.yaml" in (out / "dataset.yaml").read_text()


def test_poses_from_mcap_load_as_a_dataset(tmp_path):
    from relcal.data.dataset import load_dataset

    bag = tmp_path / "run"
    _write_pose_bag(bag)
    mcap = next(bag.glob("*.mcap"))  # a bare MCAP file reads too
    out = tmp_path / "ds"
    argv = ["import", "rosbag", str(mcap), "--joints", "/joint_states", "--pose", "/mocap/tool"]
    assert main([*argv, "--out", str(out), "--robot", "franka_fr3", "--quiet"]) == 0
    ds = load_dataset(out)
    assert ds.measured == "pose" and len(ds.ids) == 4
    np.testing.assert_allclose(ds.q, WAYPOINTS, atol=1e-12)
    for k, (a, b) in enumerate(HOLDS):
        t = ds.poses[k, 0, 3]  # the chosen pose's time, encoded in x
        assert abs(t - 0.5 * (a + b)) <= 1 / 60 + 1e-9  # the 30 Hz frame nearest the middle
        np.testing.assert_allclose(ds.poses[k, :3, 3], [t, 2 * t, -1.0], atol=1e-12)


def test_bad_topics_are_named(tmp_path, capsys):
    bag = tmp_path / "run"
    _write_pose_bag(bag)
    base = ["import", "rosbag", str(bag), "--out", str(tmp_path / "ds")]
    assert main([*base, "--joints", "/joints", "--pose", "/mocap/tool"]) == 2
    assert "--joints /joints: no such topic; the bag has /joint_states" in capsys.readouterr().err
    assert main([*base, "--joints", "/mocap/tool", "--pose", "/mocap/tool"]) == 2
    assert "expected sensor_msgs/msg/JointState" in capsys.readouterr().err
    assert main([*base, "--joints", "/joint_states", "--pose", "/mocap/tool", "--settle", "5"]) == 2
    assert "the robot never stops" in capsys.readouterr().err


def test_ros1_bag_with_compressed_images_and_transforms(tmp_path):
    """A ROS 1 bag: CompressedImage (PNG inside) and TransformStamped, header stamps from
    ROS 1 headers (with seq)."""
    from rosbags.rosbag1 import Writer as Writer1

    store = get_typestore(Stores.ROS1_NOETIC)
    types = store.types
    Time, Header = types["builtin_interfaces/msg/Time"], types["std_msgs/msg/Header"]

    def header(t):
        sec = int(np.floor(t))
        return Header(seq=0, stamp=Time(sec=sec, nanosec=int(round((t - sec) * 1e9))), frame_id="")

    bag = tmp_path / "run.bag"
    with Writer1(bag) as writer:
        js_type = "sensor_msgs/msg/JointState"
        joints = writer.add_connection("/joint_states", js_type, typestore=store)
        t = np.arange(0.0, 7.0 + 1e-9, 0.01)
        q = trajectory(t)
        v = np.gradient(q, t, axis=0)
        for k, tk in enumerate(t):
            msg = types[js_type](
                header=header(T0 + tk), name=NAMES, position=q[k], velocity=v[k], effort=v[k] * 0
            )
            writer.write(joints, int((T0 + tk) * 1e9), store.serialize_ros1(msg, js_type))
        img_type, tf_type = "sensor_msgs/msg/CompressedImage", "geometry_msgs/msg/TransformStamped"
        images = writer.add_connection("/cam/image/compressed", img_type, typestore=store)
        poses = writer.add_connection("/tool_tf", tf_type, typestore=store)
        info_type = "sensor_msgs/msg/CameraInfo"
        info = writer.add_connection("/other/camera_info", info_type, typestore=store)
        roi = types["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        )
        cam = types[info_type](
            header=header(T0),
            height=4,
            width=5,
            distortion_model="rational_polynomial",
            D=np.arange(1.0, 9.0) * 1e-3,
            K=np.array([300.0, 0, 2.0, 0, 301.0, 1.5, 0, 0, 1]),
            R=np.eye(3).ravel(),
            P=np.zeros(12),
            binning_x=0,
            binning_y=0,
            roi=roi,
        )
        writer.write(info, int(T0 * 1e9), store.serialize_ros1(cam, info_type))
        for frame in range(71):
            tk = 0.1 * frame
            grey = np.full((4, 5), frame, dtype=np.uint8)
            png = np.frombuffer(cv2.imencode(".png", grey)[1].tobytes(), dtype=np.uint8)
            msg = types[img_type](header=header(T0 + tk), format="png", data=png)
            writer.write(images, int((T0 + tk) * 1e9), store.serialize_ros1(msg, img_type))
            transform = types["geometry_msgs/msg/Transform"](
                translation=types["geometry_msgs/msg/Vector3"](x=tk, y=0.0, z=0.5),
                rotation=types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            )
            msg = types[tf_type](header=header(T0 + tk), child_frame_id="tool", transform=transform)
            writer.write(poses, int((T0 + tk) * 1e9), store.serialize_ros1(msg, tf_type))
    base = ["import", "rosbag", str(bag), "--joints", "/joint_states", "--quiet"]
    out = tmp_path / "img"
    assert main([*base, "--image", "/cam/image/compressed", "--out", str(out)]) == 0
    rows = [line.split(",") for line in (out / "samples.csv").read_text().splitlines()[1:]]
    assert len(rows) == 4
    for k, row in enumerate(rows):
        img = cv2.imread(str(out / row[-1]), cv2.IMREAD_UNCHANGED)
        assert img.shape == (4, 5) and np.all(img == 20 * k + 5)
    # The CameraInfo is not beside the image topic: intrinsics to calibrate, unless named.
    assert "camera: calibrate" in (out / "dataset.yaml").read_text()
    out = tmp_path / "img2"
    named = ["--image", "/cam/image/compressed", "--camera-info", "/other/camera_info"]
    assert main([*base, *named, "--out", str(out)]) == 0
    camera = yaml.safe_load((out / "camera.yaml").read_text())
    assert camera["fx"] == 300.0 and camera["cy"] == 1.5 and camera["width"] == 5
    np.testing.assert_allclose(camera["distortion"], np.arange(1.0, 9.0) * 1e-3)
    out = tmp_path / "pose"
    assert main([*base, "--pose", "/tool_tf", "--out", str(out)]) == 0
    rows = [line.split(",") for line in (out / "samples.csv").read_text().splitlines()[1:]]
    x = np.array([float(r[8]) for r in rows])
    np.testing.assert_allclose(x, [0.5, 2.5, 4.5, 6.5], atol=1e-9)
    np.testing.assert_allclose([float(c) for c in rows[1][1:8]], WAYPOINTS[1], atol=1e-12)
