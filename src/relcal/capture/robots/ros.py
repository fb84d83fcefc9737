"""Any ros2_control robot through rosbridge and ``roslibpy`` (``pip install 'relcal[ros]'``).

relcal needs no ROS installation: it speaks rosbridge's JSON protocol over a WebSocket to a
``rosbridge_server`` running beside the robot's ROS 2 stack. It subscribes to ``/joint_states``
(``sensor_msgs/msg/JointState``) and sends goals to the ``follow_joint_trajectory`` action of a
``joint_trajectory_controller`` (``control_msgs/action/FollowJointTrajectory``): one trajectory
point, the target, reached at a time set by ``max_velocity``. The action's result arrives when
the controller's goal tolerances are met (or the goal time tolerance expires): the arm may still
be moving within those tolerances, so the loop's settle check decides when it is still.

Joint states carry ``header.stamp`` on the ROS clock (the system clock, or ``/clock`` in a
simulation); stamps are mapped to the loop clock by
:class:`~relcal.capture.timesync.ClockMap` from the receipt times.

The flange pose comes from tf: the driver subscribes to ``/tf`` and ``/tf_static``
(``tf2_msgs/msg/TFMessage``, what robot_state_publisher and the controller's own broadcasters
publish), keeps the newest transform of each parent-child edge, and chains the edges from
``base_frame`` to ``flange_frame`` (``base_link`` and ``tool0`` by default, the ROS-Industrial
names) at each reading. When the two frames are not connected within ``tf_timeout`` seconds of
the connection, the readings carry no flange pose (a warning says why).
"""

from __future__ import annotations

import threading
from collections.abc import Sequence

import numpy as np

from relcal.capture.interfaces import CaptureError, Clock, JointReading, MoveFailed, RealClock
from relcal.capture.timesync import ClockMap, require
from relcal.errors import RelcalError

JOINT_STATE = "sensor_msgs/msg/JointState"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
FOLLOW = "control_msgs/action/FollowJointTrajectory"
ERROR_CODES = {  # control_msgs/action/FollowJointTrajectory result codes
    0: "SUCCESSFUL",
    -1: "INVALID_GOAL",
    -2: "INVALID_JOINTS",
    -3: "OLD_HEADER_TIMESTAMP",
    -4: "PATH_TOLERANCE_VIOLATED",
    -5: "GOAL_TOLERANCE_VIOLATED",
}


def ros_time(stamp: dict) -> float:
    """Seconds of a ``builtin_interfaces/Time`` (ROS 2 ``sec``/``nanosec``, ROS 1 ``secs``/
    ``nsecs``)."""
    if "sec" in stamp:
        return stamp["sec"] + 1e-9 * stamp.get("nanosec", 0)
    return stamp["secs"] + 1e-9 * stamp.get("nsecs", 0)


def transform_matrix(message: dict) -> np.ndarray:
    """A ``geometry_msgs/Transform`` as a ``(4, 4)`` (m)."""
    from scipy.spatial.transform import Rotation

    t, r = message["translation"], message["rotation"]
    out = np.eye(4)
    out[:3, :3] = Rotation.from_quat([r["x"], r["y"], r["z"], r["w"]]).as_matrix()
    out[:3, 3] = [t["x"], t["y"], t["z"]]
    return out


class TransformTree:
    """The newest transform of each parent-child edge of tf, and chains through them."""

    def __init__(self) -> None:
        self.edges: dict[str, tuple[str, np.ndarray]] = {}  # child: (parent, parent_T_child)

    def add(self, message: dict) -> None:
        """Take the transforms of a ``TFMessage``."""
        for item in message.get("transforms", []):
            parent = item["header"]["frame_id"].lstrip("/")
            child = item["child_frame_id"].lstrip("/")
            self.edges[child] = (parent, transform_matrix(item["transform"]))

    def _to_root(self, frame: str) -> tuple[str, np.ndarray]:
        out, seen = np.eye(4), {frame}
        while frame in self.edges:
            frame, step = self.edges[frame]
            out = step @ out
            if frame in seen:  # a loop in the tree: no answer
                break
            seen.add(frame)
        return frame, out

    def lookup(self, parent: str, child: str) -> np.ndarray | None:
        """``parent_T_child`` ``(4, 4)``, or None when the frames are not connected."""
        root_a, a = self._to_root(parent)
        root_b, b = self._to_root(child)
        if root_a != root_b:
            return None
        return np.linalg.solve(a, b)


def duration(seconds: float) -> dict:
    """A ``builtin_interfaces/Duration`` message of ``seconds`` (s >= 0)."""
    sec = int(np.floor(seconds))
    return {"sec": sec, "nanosec": int(round((seconds - sec) * 1e9))}


class RosRobot:
    """A ros2_control arm behind rosbridge at ``host:port``.

    Parameters
    ----------
    host, port : str, int
        The rosbridge WebSocket server (``ros2 launch rosbridge_server
        rosbridge_websocket_launch.xml``, port 9090 by default).
    joint_names : sequence of str
        The robot model's joint names, in order (the order of ``q``).
    clock : Clock
        The capture loop's clock.
    controller : str
        The joint trajectory controller's namespace; its action is
        ``<controller>/follow_joint_trajectory``.
    joint_states : str
        The joint state topic.
    ros_joints : str
        The ROS joint names, comma-separated, in the model's order, where they differ from the
        model's (e.g. ``shoulder_pan_joint,...`` for UR's ROS driver); default: the model's.
    max_velocity : float
        Fastest joint speed of a move, rad/s (m/s for prismatic joints): the target's
        ``time_from_start`` is the largest joint travel over it, at least ``min_duration`` s.
    min_duration : float
        Shortest move, s.
    connect_timeout : float
        Seconds to wait for the connection and the first joint state.
    base_frame, flange_frame : str
        The tf frames of the robot's base and flange (``flange_frame`` empty: no flange pose).
    tf_timeout : float
        Seconds to wait after the first joint state for tf to connect the two frames.
    """

    def __init__(
        self,
        host: str = "localhost",
        port: int = 9090,
        *,
        joint_names: Sequence[str],
        clock: Clock | None = None,
        controller: str = "/joint_trajectory_controller",
        joint_states: str = "/joint_states",
        ros_joints: str | None = None,
        max_velocity: float = 0.3,
        min_duration: float = 1.0,
        connect_timeout: float = 10.0,
        base_frame: str = "base_link",
        flange_frame: str = "tool0",
        tf_timeout: float = 3.0,
    ) -> None:
        roslibpy = self._roslibpy = require("roslibpy", "ros", "the ROS 2 driver")
        self.joint_names = tuple(joint_names)
        names = [n.strip() for n in ros_joints.split(",")] if ros_joints else list(joint_names)
        if len(names) != len(self.joint_names):
            raise RelcalError(
                f"ros option ros_joints: {len(names)} names for the {len(self.joint_names)}-joint "
                "robot model; give one ROS joint name per model joint, in the model's order"
            )
        if max_velocity <= 0 or min_duration < 0:
            raise RelcalError(
                "ros options max_velocity and min_duration: expected positive numbers"
            )
        self.ros_joints = tuple(names)
        self.max_velocity, self.min_duration = float(max_velocity), float(min_duration)
        self._clock = clock or RealClock()
        self._map = ClockMap(self._clock)
        self._lock = threading.Lock()
        self._latest: JointReading | None = None
        self._missing: set[str] = set()
        self._first = threading.Event()
        self._goal: str | None = None
        self._tree = TransformTree()
        self._frames = (base_frame.strip().lstrip("/"), flange_frame.strip().lstrip("/"))
        self._tf_topics: list = []
        self.reports_flange = False
        try:
            self._ros = roslibpy.Ros(host=host, port=int(port), transport="asyncio")
            self._ros.run(timeout=connect_timeout)
        except Exception as exc:
            raise CaptureError(
                f"ros: cannot reach rosbridge at ws://{host}:{port}: {exc} (is rosbridge_server "
                "running there?)"
            ) from None
        self._topic = roslibpy.Topic(self._ros, joint_states, JOINT_STATE)
        self._topic.subscribe(self._on_joint_state)
        self._action = roslibpy.ActionClient(
            self._ros, f"{controller.rstrip('/')}/follow_joint_trajectory", FOLLOW
        )
        if not self._first.wait(connect_timeout):
            self._ros.close()
            extra = f" (they lack {', '.join(sorted(self._missing))})" if self._missing else ""
            raise CaptureError(
                f"ros: no joint state with joints {', '.join(self.ros_joints)} on {joint_states} "
                f"within {connect_timeout:g} s{extra}; check the topic and the ros_joints option"
            )
        if self._frames[1]:
            self._follow_tf(tf_timeout)

    def _on_tf(self, message: dict) -> None:
        with self._lock:
            self._tree.add(message)

    def _follow_tf(self, timeout: float) -> None:
        """Subscribe to tf; the readings carry the flange pose once the frames connect."""
        import warnings

        for topic in ("/tf", "/tf_static"):
            sub = self._roslibpy.Topic(self._ros, topic, TF_MESSAGE)
            sub.subscribe(self._on_tf)
            self._tf_topics.append(sub)
        begin = self._clock.now()
        while True:
            with self._lock:
                found = self._tree.lookup(*self._frames) is not None
            if found:
                self.reports_flange = True
                return
            if self._clock.now() - begin > timeout:
                warnings.warn(
                    f"ros: tf does not connect {self._frames[0]} to {self._frames[1]} within "
                    f"{timeout:g} s (frames seen: {', '.join(sorted(self._tree.edges)) or 'none'})"
                    "; the samples get no flange pose (options base_frame, flange_frame)",
                    stacklevel=3,
                )
                return
            self._clock.sleep(0.02)

    def _on_joint_state(self, message: dict) -> None:
        """Keep the newest state of the model's joints (a message may hold other joints, e.g. a
        gripper's, and joint state broadcasters may split joints over several messages)."""
        received = self._clock.now()
        index = {n: i for i, n in enumerate(message.get("name", []))}
        missing = [n for n in self.ros_joints if n not in index]
        if missing:
            self._missing = set(missing)
            return
        position = message["position"]
        q = np.array([position[index[n]] for n in self.ros_joints], dtype=float)
        stamp = message.get("header", {}).get("stamp")
        if stamp and ros_time(stamp) > 0:
            loop_stamp = self._map.observe(ros_time(stamp), received)
        else:  # an unstamped message: the time it arrived
            loop_stamp = received
        with self._lock:
            self._latest = JointReading(q, loop_stamp)
        self._first.set()

    def read(self) -> JointReading:
        """The newest joint state of the model's joints (rad, m), stamped, with the newest tf
        flange pose ``(4, 4)`` (m, in ``base_frame``) where tf gives one."""
        if not self._ros.is_connected:
            raise CaptureError("ros: the rosbridge connection is lost")
        with self._lock:
            latest = self._latest
            if not self.reports_flange:
                return latest
            flange = self._tree.lookup(*self._frames)
        return JointReading(latest.q, latest.stamp, latest.dq, flange)

    def goal(self, q: np.ndarray) -> dict:
        """The ``FollowJointTrajectory`` goal that moves from the current joints to ``q``."""
        travel = float(np.abs(np.asarray(q) - self.read().q).max())
        seconds = max(self.min_duration, travel / self.max_velocity)
        return {
            "trajectory": {
                "joint_names": list(self.ros_joints),
                "points": [
                    {
                        "positions": [float(v) for v in q],
                        "velocities": [0.0] * len(q),
                        "time_from_start": duration(seconds),
                    }
                ],
            },
            "goal_time_tolerance": duration(1.0),
        }

    def move(self, q: np.ndarray, timeout: float) -> None:
        """Send the trajectory to ``q`` and wait for the action's result.

        Raises
        ------
        MoveFailed
            The controller rejected or aborted the goal (its error code and string in the
            message), or no result came within ``timeout`` seconds (the goal is then cancelled).
        CaptureError
            The rosbridge connection is lost.
        """
        q = np.asarray(q, dtype=float)
        if q.shape != (len(self.ros_joints),):
            raise MoveFailed(f"ros: target has shape {q.shape}, expected ({len(self.ros_joints)},)")
        done = threading.Event()
        outcome: dict = {}

        def result(message) -> None:
            outcome["result"] = message
            done.set()

        def failure(message) -> None:
            outcome["error"] = message
            done.set()

        goal = self._roslibpy.Goal(self.goal(q))
        self._goal = self._action.send_goal(goal, result, lambda _feedback: None, failure)
        if not done.wait(timeout):
            self.stop()
            raise MoveFailed(f"ros: no result for the trajectory within {timeout:g} s")
        self._goal = None
        if not self._ros.is_connected:
            raise CaptureError("ros: the rosbridge connection is lost")
        if "error" in outcome:
            reason = _describe(outcome["error"])
            raise MoveFailed(f"ros: the controller rejected the goal: {reason}")
        values = outcome["result"]["values"]
        values = values.get("result", values)  # rosbridge versions nest the result or not
        code = int(values.get("error_code", 0))
        status = outcome["result"]["status"]
        if code != 0 or status.name not in ("SUCCEEDED", "UNKNOWN"):
            raise MoveFailed(
                f"ros: trajectory ended with {status.name}, error {ERROR_CODES.get(code, code)}"
                + (f": {values['error_string']}" if values.get("error_string") else "")
            )

    def stop(self) -> None:
        """Cancel the running goal (the controller then holds the current position)."""
        if self._goal is not None:
            self._action.cancel_goal(self._goal)
            self._goal = None

    def close(self) -> None:
        """Cancel any goal, unsubscribe and close the connection."""
        self.stop()
        try:
            self._topic.unsubscribe()
            for sub in self._tf_topics:
                sub.unsubscribe()
        finally:
            self._ros.close()  # roslibpy's event loop thread stays, shared by the process


def _describe(message) -> str:
    if isinstance(message, dict):
        values = message.get("values", message)
        return str(values)
    return str(message)
