"""A small rosbridge server on loopback for the ROS 2 driver's tests: it speaks the rosbridge v2
JSON protocol over a WebSocket (``subscribe``/``unsubscribe``, ``publish`` of
``sensor_msgs/msg/JointState`` at 200 Hz, ``send_action_goal``/``cancel_action_goal`` with
``action_result`` replies for ``control_msgs/action/FollowJointTrajectory``), with a simulated
arm behind it that follows a goal's trajectory linearly and then overshoots and rings down, as a
controller's tracking error does. Its ROS clock is the wall clock shifted by ``ros_offset``.
With ``tf`` (a function of the joints giving ``[(parent, child, (4, 4)), ...]``) it publishes
``tf2_msgs/msg/TFMessage`` on ``/tf`` with the joint states, and ``tf_static`` once to each
subscriber of ``/tf_static``, as robot_state_publisher does."""

from __future__ import annotations

import asyncio
import json
import threading
import time

import numpy as np
import websockets


class FakeRosbridge:
    """Serve on ``127.0.0.1:port`` (a free port) in a thread of its own; use as a context
    manager."""

    def __init__(
        self, joints, start, limits=None, ros_offset=1000.0, ring=0.004, tf=None, tf_static=()
    ):
        self.joints = list(joints)  # ROS names, the arm's order
        self.q = np.asarray(start, dtype=float).copy()
        self.limits = limits  # (lower, upper) arrays: goals outside are aborted
        self.ros_offset, self.ring = ros_offset, ring
        self.goals: list[dict] = []
        self.cancelled: list[str] = []
        self.reject = False  # answer the next goals with result false
        self._motion = None  # (t0, q0, q1, duration, goal id, action)
        self._subscribers: set = set()
        self.tf, self.tf_static = tf, list(tf_static)
        self._tf_subscribers: set = set()
        self._loop = asyncio.new_event_loop()
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    # -- the arm -------------------------------------------------------------------------
    def joints_now(self, t: float) -> np.ndarray:
        if self._motion is None:
            return self.q
        t0, q0, q1, dur, _, _ = self._motion
        s = (t - t0) / dur
        if s < 1:
            return q0 + (q1 - q0) * s
        after = t - t0 - dur  # damped ringing about the target after the trajectory ends
        return q1 + self.ring * np.exp(-after / 0.15) * np.cos(2 * np.pi * 3 * after)

    # -- the server ----------------------------------------------------------------------
    def _run(self) -> None:
        asyncio.set_event_loop(self._loop)

        async def main():
            async with websockets.serve(self._client, "127.0.0.1", 0) as server:
                self.port = server.sockets[0].getsockname()[1]
                self._ready.set()
                publisher = asyncio.ensure_future(self._publish())
                await self._stop_future
                publisher.cancel()

        self._stop_future = self._loop.create_future()
        self._loop.run_until_complete(main())

    async def _publish(self) -> None:
        while True:
            t = time.time()
            q = self.joints_now(t)
            stamp = t + self.ros_offset
            order = list(reversed(range(len(self.joints))))  # not the model's order
            msg = {
                "header": {
                    "stamp": {"sec": int(stamp), "nanosec": int((stamp % 1) * 1e9)},
                    "frame_id": "",
                },
                "name": [self.joints[i] for i in order] + ["gripper_finger_joint"],
                "position": [float(q[i]) for i in order] + [0.01],
                "velocity": [0.0] * (len(order) + 1),
                "effort": [0.0] * (len(order) + 1),
            }
            text = json.dumps({"op": "publish", "topic": "/joint_states", "msg": msg})
            for ws in list(self._subscribers):
                try:
                    await ws.send(text)
                except websockets.ConnectionClosed:
                    self._subscribers.discard(ws)
            if self.tf is not None:
                text = json.dumps(tf_message("/tf", self.tf(q), msg["header"]["stamp"]))
                for ws in list(self._tf_subscribers):
                    try:
                        await ws.send(text)
                    except websockets.ConnectionClosed:
                        self._tf_subscribers.discard(ws)
            await self._finish_motion(time.time())
            await asyncio.sleep(0.005)

    async def _finish_motion(self, t: float) -> None:
        if self._motion is None:
            return
        t0, q0, q1, dur, goal_id, ws = self._motion
        if t - t0 >= dur + 0.01 and goal_id is not None:  # result when the trajectory ends
            self._motion = (t0, q0, q1, dur, None, ws)
            await ws.send(json.dumps(_result(goal_id, 4, 0, "")))
        if t - t0 > dur + 2.0:
            self.q, self._motion = q1, None

    async def _client(self, ws) -> None:
        async for text in ws:
            message = json.loads(text)
            op = message["op"]
            if op == "subscribe" and message["topic"] == "/joint_states":
                self._subscribers.add(ws)
            elif op == "subscribe" and message["topic"] == "/tf":
                self._tf_subscribers.add(ws)
            elif op == "subscribe" and message["topic"] == "/tf_static" and self.tf_static:
                stamp = {"sec": 0, "nanosec": 0}
                await ws.send(json.dumps(tf_message("/tf_static", self.tf_static, stamp)))
            elif op == "unsubscribe":
                self._subscribers.discard(ws)
                self._tf_subscribers.discard(ws)
            elif op == "send_action_goal":
                await self._goal(ws, message)
            elif op == "cancel_action_goal":
                self.cancelled.append(message["id"])
                if self._motion is not None and self._motion[4] == message["id"]:
                    t = time.time()
                    self.q, self._motion = self.joints_now(t), None
                    await ws.send(json.dumps(_result(message["id"], 5, 0, "canceled")))

    async def _goal(self, ws, message) -> None:
        goal = message["args"]
        self.goals.append(goal)
        if self.reject:
            reply = {"op": "action_result", "id": message["id"], "action": message["action"],
                     "values": {}, "status": 6, "result": False}  # fmt: skip
            await ws.send(json.dumps(reply))
            return
        trajectory = goal["trajectory"]
        if sorted(trajectory["joint_names"]) != sorted(self.joints):
            await ws.send(json.dumps(_result(message["id"], 6, -2, "joints do not match")))
            return
        index = [trajectory["joint_names"].index(n) for n in self.joints]
        point = trajectory["points"][-1]
        target = np.array([point["positions"][i] for i in index])
        if self.limits is not None and (
            (target < self.limits[0]).any() or (target > self.limits[1]).any()
        ):
            await ws.send(json.dumps(_result(message["id"], 6, -1, "target out of limits")))
            return
        tfs = point["time_from_start"]
        t = time.time()
        start = self.joints_now(t)
        self._motion = (t, start, target, tfs["sec"] + 1e-9 * tfs["nanosec"], message["id"], ws)

    def __enter__(self) -> FakeRosbridge:
        self._thread.start()
        assert self._ready.wait(10), "the fake rosbridge did not start"
        return self

    def __exit__(self, *exc) -> None:
        self._loop.call_soon_threadsafe(self._stop_future.set_result, None)
        self._thread.join(10)


def _result(goal_id: str, status: int, code: int, text: str) -> dict:
    return {
        "op": "action_result",
        "id": goal_id,
        "action": "/arm_controller/follow_joint_trajectory",
        "values": {"error_code": code, "error_string": text},
        "status": status,
        "result": True,
    }


def tf_message(topic: str, transforms, stamp: dict) -> dict:
    """A rosbridge ``publish`` of a ``tf2_msgs/msg/TFMessage`` of ``(parent, child, (4, 4))``."""
    from scipy.spatial.transform import Rotation

    out = []
    for parent, child, t in transforms:
        q = Rotation.from_matrix(np.asarray(t)[:3, :3]).as_quat()
        out.append(
            {
                "header": {"stamp": stamp, "frame_id": parent},
                "child_frame_id": child,
                "transform": {
                    "translation": dict(zip("xyz", map(float, np.asarray(t)[:3, 3]), strict=True)),
                    "rotation": dict(zip("xyzw", map(float, q), strict=True)),
                },
            }
        )
    return {"op": "publish", "topic": topic, "msg": {"transforms": out}}
