"""The Universal Robots driver with test doubles of ur_rtde's two interface classes.

A fake RTDE server would have to run the controller's side of RTDE and the URScript ur_rtde
uploads, so the doubles stand in for ``RTDEControlInterface`` and ``RTDEReceiveInterface``
themselves (installed into the real ``rtde_control``/``rtde_receive`` modules): a simulated arm
that moves linearly in joint space at moveJ's speed on a simulated clock, with the controller's
own time 5000 s ahead. The first test checks that every method the driver calls exists in the
installed ur_rtde with the signature the doubles assume."""

from __future__ import annotations

import numpy as np
import pytest

rtde_control = pytest.importorskip("rtde_control")
rtde_receive = pytest.importorskip("rtde_receive")

from relcal.capture.interfaces import CaptureError, MoveFailed, Robot  # noqa: E402
from relcal.capture.robots.ur import URRobot  # noqa: E402
from relcal.robot.loading import get_robot  # noqa: E402

UR5E = get_robot("ur5e")
CONTROL = ("moveJ", "stopJ", "getAsyncOperationProgressEx", "isJointsWithinSafetyLimits",
           "isConnected", "stopScript", "disconnect", "getTCPOffset")  # fmt: skip
RECEIVE = ("getActualQ", "getActualQd", "getTimestamp", "isProtectiveStopped", "isEmergencyStopped",
           "isConnected", "disconnect", "getActualTCPPose")  # fmt: skip
TCP = np.array([0.0, 0.01, 0.15, 0.0, 0.0, 0.3])  # the controller's active TCP offset (m, rotvec)


def ur_pose(t: np.ndarray) -> list[float]:
    """A ``(4, 4)`` as a UR pose (x, y, z, rx, ry, rz)."""
    from relcal import geometry as tf

    return [*t[:3, 3], *tf.log_rotation(t[:3, :3])]


class SimClock:
    """A clock that advances only when slept on."""

    def __init__(self) -> None:
        self.t = 100.0

    def now(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.t += max(seconds, 0.0)


class Arm:
    """The controller: joints moving linearly at the leading axis' speed (no acceleration
    phase), operations numbered as ur_rtde's AsyncOperationStatus numbers them."""

    def __init__(self, clock: SimClock, q) -> None:
        self.clock, self.q0, self.q1 = clock, np.array(q, float), np.array(q, float)
        self.t0, self.duration, self.operation = clock.t, 0.0, 0
        self.protective = False
        self.calls: list[tuple] = []

    def q(self) -> np.ndarray:
        s = 1.0 if self.duration == 0 else min((self.clock.t - self.t0) / self.duration, 1.0)
        return self.q0 + (self.q1 - self.q0) * s

    def running(self) -> bool:
        return self.clock.t - self.t0 < self.duration

    def dq(self) -> np.ndarray:
        if not self.running():
            return np.zeros_like(self.q0)
        return (self.q1 - self.q0) / self.duration


class Status:
    def __init__(self, arm: Arm) -> None:
        self._running, self._id = arm.running(), arm.operation

    def isAsyncOperationRunning(self) -> bool:  # noqa: N802 (ur_rtde's names)
        return self._running

    def operationId(self) -> int:  # noqa: N802
        return self._id


def doubles(arm: Arm):
    class Control:
        def __init__(self, host, frequency=-1.0) -> None:
            arm.calls.append(("connect", host, frequency))

        def moveJ(self, q, speed=1.05, acceleration=1.4, asynchronous=False):  # noqa: N802
            assert asynchronous is True  # the driver must be able to stop it
            arm.calls.append(("moveJ", list(q), speed, acceleration))
            if arm.protective:
                return False
            arm.q0, arm.q1, arm.t0 = arm.q(), np.array(q), arm.clock.t
            arm.duration = float(np.abs(arm.q1 - arm.q0).max() / speed)
            arm.operation += 1
            return True

        def stopJ(self, a=2.0, asynchronous=False):  # noqa: N802
            arm.calls.append(("stopJ", a))
            arm.q0 = arm.q1 = arm.q()
            arm.duration = 0.0

        def getAsyncOperationProgressEx(self):  # noqa: N802
            return Status(arm)

        def isJointsWithinSafetyLimits(self, q):  # noqa: N802
            return bool(np.all(np.abs(q) <= np.radians(363)))

        def isConnected(self):  # noqa: N802
            return True

        def stopScript(self):  # noqa: N802
            arm.calls.append(("stopScript",))

        def getTCPOffset(self):  # noqa: N802
            return TCP.tolist()

        def disconnect(self):
            arm.calls.append(("disconnect control",))

    class Receive:
        def __init__(self, host, frequency=-1.0) -> None:
            pass

        def getActualQ(self):  # noqa: N802
            return arm.q().tolist()

        def getActualQd(self):  # noqa: N802
            return arm.dq().tolist()

        def getActualTCPPose(self):  # noqa: N802
            # the tool centre point by the controller's kinematics (here relcal's UR5e model)
            from relcal import geometry as tf
            from relcal.robot.kinematics import fk

            offset = tf.homogeneous(tf.exp_rotation(TCP[3:]), TCP[:3])
            return ur_pose(fk(UR5E, arm.q()) @ offset)

        def getTimestamp(self):  # noqa: N802
            # the newest RTDE packet of the 500 Hz stream, on the controller's clock
            return np.floor(arm.clock.t / 0.002) * 0.002 + 5000.0

        def isProtectiveStopped(self):  # noqa: N802
            return arm.protective

        def isEmergencyStopped(self):  # noqa: N802
            return False

        def isConnected(self):  # noqa: N802
            return True

        def disconnect(self):
            arm.calls.append(("disconnect receive",))

    return Control, Receive


@pytest.fixture
def ur(monkeypatch):
    clock = SimClock()
    arm = Arm(clock, np.zeros(6))
    control, receive = doubles(arm)
    monkeypatch.setattr(rtde_control, "RTDEControlInterface", control)
    monkeypatch.setattr(rtde_receive, "RTDEReceiveInterface", receive)
    robot = URRobot("192.0.2.10", joint_names=UR5E.joint_names, clock=clock, speed=0.5)
    yield robot, arm, clock
    robot.close()


def test_the_doubles_match_the_installed_ur_rtde():
    for name in CONTROL:
        assert hasattr(rtde_control.RTDEControlInterface, name), name
    for name in RECEIVE:
        assert hasattr(rtde_receive.RTDEReceiveInterface, name), name
    assert "asynchronous" in rtde_control.RTDEControlInterface.moveJ.__doc__
    status = rtde_control.AsyncOperationStatus
    assert hasattr(status, "isAsyncOperationRunning") and hasattr(status, "operationId")


def test_move_and_read(ur):
    robot, arm, clock = ur
    assert isinstance(robot, Robot)
    target = np.array([0.5, -1.0, 1.0, -0.5, 0.2, 0.0])
    start = clock.now()
    robot.move(target, timeout=10)
    # moveJ asynchronous at speed 0.5 rad/s: 1 rad takes 2 s, polled every 10 ms
    assert clock.now() - start == pytest.approx(2.0, abs=0.02)
    assert arm.calls[1] == ("moveJ", target.tolist(), 0.5, 0.8)
    reading = robot.read()
    np.testing.assert_allclose(reading.q, target)
    # the flange pose: the controller's TCP pose with the TCP offset taken off
    from relcal.robot.kinematics import fk

    assert robot.reports_flange
    np.testing.assert_allclose(reading.flange, fk(UR5E, target), atol=1e-12)
    # the controller's time (5000 s ahead) on the loop clock: the packet's time, which is up to
    # one 2 ms period before now
    assert clock.now() - 0.002 - 1e-9 <= reading.stamp <= clock.now() + 1e-9


def test_timeout_stops_the_arm(ur):
    robot, arm, clock = ur
    with pytest.raises(MoveFailed, match="did not finish within 1 s"):
        robot.move(np.full(6, 1.0), timeout=1.0)
    assert ("stopJ", 2.0) in arm.calls
    np.testing.assert_allclose(robot.read().q, np.full(6, 0.5), atol=0.01)  # halfway


def test_refusals(ur):
    robot, arm, _ = ur
    with pytest.raises(MoveFailed, match="outside the controller's safety joint limits"):
        robot.move(np.array([0, 0, 7.0, 0, 0, 0]), timeout=10)
    with pytest.raises(MoveFailed, match=r"shape \(5,\)"):
        robot.move(np.zeros(5), timeout=10)
    arm.protective = True
    with pytest.raises(CaptureError, match="protective or emergency stop"):
        robot.move(np.zeros(6), timeout=10)


def test_wrong_model():
    from relcal.errors import RelcalError

    with pytest.raises(RelcalError, match="a UR arm has 6"):
        URRobot("192.0.2.10", joint_names=get_robot("franka_fr3").joint_names)


def test_clock_map_keeps_the_smallest_latency_and_follows_restarts():
    from relcal.capture.timesync import ClockMap

    clock = SimClock()
    sync = ClockMap(clock, window=1.0)
    rng = np.random.default_rng(0)
    errors = []
    for k in range(300):  # 100 Hz, device 50 s behind, latency 1 to 20 ms
        clock.sleep(0.01)
        exposed = clock.now() - rng.uniform(0.001, 0.02)
        errors.append(sync.observe(exposed - 50.0) - exposed)
        assert errors[-1] >= 0 or k == 0  # never earlier than the truth
    assert max(errors[50:]) < 0.02 and np.median(errors[50:]) < 0.003
    sync.observe(0.5)  # the device clock restarted: the old offset is forgotten
    assert sync.offset == pytest.approx(clock.now() - 0.5)


@pytest.mark.parametrize("rate", [1.0, 1.25, 3.0, 12.0])
def test_clock_map_follows_a_device_clock_slower_than_the_loop(rate):
    """A simulator running ``rate`` times slower than real time (franky-sim on a loaded
    machine): stamps stay never earlier than the truth and late by about the smallest latency;
    taking the window's smallest offset at face value would make them ``0.25 * (rate - 1)`` s
    early (2.75 s at 12)."""
    from relcal.capture.timesync import ClockMap, clock_rate

    clock = SimClock()
    clock.sleep(100.0)
    sync = ClockMap(clock)
    rng = np.random.default_rng(1)
    errors, device = [], 7.0
    for _ in range(1500):  # 100 readings a loop second, latency 1 to 30 ms
        clock.sleep(0.01 * rng.uniform(0.5, 1.5))
        exposed = clock.now() - rng.uniform(0.001, 0.03)
        device_stamp = device + (exposed - 100.0) / rate
        errors.append(sync.observe(device_stamp) - exposed)
    errors = np.array(errors[300:])
    assert errors.min() >= -1e-3, errors.min()  # never earlier than the exposure
    assert np.median(errors) < 0.01 and errors.max() < 0.04, (np.median(errors), errors.max())
    assert sync.rate == pytest.approx(rate, rel=0.02)
    # the estimator on its own: a straight line through the least delayed samples
    d = np.linspace(0.0, 2.0, 200)
    late = rng.uniform(0.0, 0.02, d.size)
    late[[3, 190]] = 0.0
    assert clock_rate(d, 5.0 + rate * d + late) == pytest.approx(rate, abs=0.02 / 1.9)
    assert clock_rate(d[:20], 5.0 + rate * d[:20]) is None  # 0.2 s: too short to tell
