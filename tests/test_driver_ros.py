"""The ROS 2 driver through roslibpy against a rosbridge server on loopback
(:mod:`fake_rosbridge`: the rosbridge v2 JSON protocol, a JointState publisher whose ROS clock
is 1000 s ahead of the wall, a FollowJointTrajectory action server over a simulated arm)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("roslibpy")
pytest.importorskip("websockets")

from fake_rosbridge import FakeRosbridge  # noqa: E402

from relcal import geometry as tf  # noqa: E402
from relcal.capture.interfaces import CaptureError, MoveFailed, RealClock, Robot  # noqa: E402
from relcal.capture.robots.ros import RosRobot  # noqa: E402
from relcal.errors import RelcalError  # noqa: E402
from relcal.robot.kinematics import fk  # noqa: E402
from relcal.robot.loading import get_robot  # noqa: E402

UR5E = get_robot("ur5e")
ROS_NAMES = [f"{n}_joint" for n in UR5E.joint_names]
START = np.array([0.0, -1.57, 1.57, -1.57, -1.57, 0.0])


def connect(server, clock, **options):
    return RosRobot(
        "127.0.0.1",
        server.port,
        joint_names=UR5E.joint_names,
        clock=clock,
        controller="/arm_controller",
        ros_joints=",".join(ROS_NAMES),
        **options,
    )


FLIP = tf.homogeneous(tf.rot_z(np.pi), np.zeros(3))  # base_link -> base, as UR's description
TOOL = tf.from_xyz_rpy(np.array([0.0, 0.0, 0.02]), np.radians([0.0, 0.0, 30.0]))


def ur5e_tf(q):
    """The dynamic edge base -> wrist_3_link of tf at joints ``q`` (the static ones: base_link ->
    base and wrist_3_link -> tool0)."""
    return [("base", "wrist_3_link", tf.invert(FLIP) @ fk(UR5E, q) @ tf.invert(TOOL))]


@pytest.fixture
def server():
    statics = [("base_link", "base", FLIP), ("wrist_3_link", "tool0", TOOL)]
    with FakeRosbridge(ROS_NAMES, START, limits=(UR5E.lower, UR5E.upper), tf=ur5e_tf,
                       tf_static=statics) as fake:  # fmt: skip
        yield fake


def test_joint_states_in_model_order_on_the_loop_clock(server):
    clock = RealClock()
    robot = connect(server, clock)
    try:
        assert isinstance(robot, Robot)
        reading = robot.read()
        np.testing.assert_allclose(reading.q, START)  # reordered, gripper joint left out
        # the flange pose: tf chained base_link -> base -> wrist_3_link -> tool0 (static and
        # dynamic edges), the forward kinematics of the same joints
        assert robot.reports_flange
        np.testing.assert_allclose(reading.flange, fk(UR5E, START), atol=1e-6)
        # header stamps 1000 s ahead of the wall: mapped onto the loop's monotonic clock
        assert 0 <= clock.now() - reading.stamp < 0.05
    finally:
        robot.close()


def test_moves_follow_the_trajectory_and_report_done_before_still(server):
    clock = RealClock()
    robot = connect(server, clock, max_velocity=2.0, min_duration=0.3)
    try:
        target = START + np.array([0.3, -0.2, 0.1, 0.2, -0.1, 0.5])
        robot.move(target, timeout=5)
        goal = server.goals[-1]["trajectory"]
        assert goal["joint_names"] == ROS_NAMES
        np.testing.assert_allclose(goal["points"][0]["positions"], target)
        tfs = goal["points"][0]["time_from_start"]
        assert tfs["sec"] + 1e-9 * tfs["nanosec"] == pytest.approx(0.3)  # max(0.5 / 2.0, 0.3)
        # the result came with the trajectory's end; the arm still rings about the target
        a = robot.read()
        clock.sleep(0.03)
        b = robot.read()
        assert np.abs(b.q - a.q).max() > 1e-4
        clock.sleep(1.5)
        np.testing.assert_allclose(robot.read().q, target, atol=1e-5)
    finally:
        robot.close()


def test_refused_aborted_and_timed_out_goals(server):
    robot = connect(server, RealClock(), max_velocity=1.0, min_duration=0.2)
    try:
        beyond = START.copy()
        beyond[2] = 7.0  # past the elbow's limit
        with pytest.raises(MoveFailed, match="ABORTED, error INVALID_GOAL: target out of limits"):
            robot.move(beyond, timeout=5)
        server.reject = True
        with pytest.raises(MoveFailed, match="rejected the goal"):
            robot.move(START, timeout=5)
        server.reject = False
        far = START + 1.0  # 1 s at 1 rad/s
        with pytest.raises(MoveFailed, match="no result for the trajectory within 0.3 s"):
            robot.move(far, timeout=0.3)
        for _ in range(100):  # the cancel reaches the server
            if server.cancelled:
                break
            RealClock().sleep(0.02)
        assert server.cancelled, "the timed-out goal was not cancelled"
    finally:
        robot.close()


def test_wrong_names_and_no_server(server):
    with pytest.raises(CaptureError, match="lack .*shoulder_pan"):
        RosRobot("127.0.0.1", server.port, joint_names=UR5E.joint_names, connect_timeout=1.0)
    with pytest.raises(RelcalError, match="5 names for the 6-joint"):
        RosRobot("127.0.0.1", server.port, joint_names=UR5E.joint_names, ros_joints="a,b,c,d,e")


def test_no_tf_no_flange_pose_with_a_warning():
    with FakeRosbridge(ROS_NAMES, START) as bare:
        with pytest.warns(UserWarning, match="tf does not connect base_link to tool0"):
            robot = connect(bare, RealClock(), tf_timeout=0.3)
        try:
            assert not robot.reports_flange and robot.read().flange is None
        finally:
            robot.close()


def test_transform_tree_chains_and_refuses_unconnected_frames():
    from fake_rosbridge import tf_message

    from relcal.capture.robots.ros import TransformTree

    a = tf.from_xyz_rpy(np.array([0.1, 0.2, 0.3]), np.radians([10, 20, 30]))
    b = tf.from_xyz_rpy(np.array([-0.3, 0.0, 0.5]), np.radians([-40, 5, 90]))
    tree = TransformTree()
    tree.add(tf_message("/tf", [("world", "base", a), ("/world", "/camera", b)], {})["msg"])
    np.testing.assert_allclose(tree.lookup("base", "camera"), tf.invert(a) @ b, atol=1e-12)
    np.testing.assert_allclose(tree.lookup("world", "world"), np.eye(4))
    assert tree.lookup("base", "elsewhere") is None
