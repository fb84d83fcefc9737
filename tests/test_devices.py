"""The device registry (names, text options, missing extras) and the manual driver with the
operator's answers injected."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from relcal.capture import devices
from relcal.capture.interfaces import CaptureError, JointReading, MoveFailed, Robot
from relcal.capture.robots.manual import ManualRobot
from relcal.errors import RelcalError

NAMES = ("j1", "j2", "j3")


class Operator:
    """Scripted answers; records what relcal showed."""

    def __init__(self, *answers: str) -> None:
        self.answers, self.shown, self.asked = list(answers), [], []

    def ask(self, prompt: str) -> str:
        self.asked.append(prompt)
        return self.answers.pop(0)

    def tell(self, text: str) -> None:
        self.shown.append(text)


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def now(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.t += seconds


def test_manual_typed_joints():
    op = Operator("10, 20, 30", "", "1,2", "x", "-5;0;5", "s")
    robot = ManualRobot(joint_names=NAMES, clock=Clock(), ask=op.ask, tell=op.tell)
    assert isinstance(robot, Robot)
    assert not robot.reports_flange
    with pytest.raises(CaptureError, match="no joint values yet"):
        robot.read()
    robot.move(np.radians([11.0, 21.0, 31.0]), timeout=1)
    assert op.shown[0] == "jog to (deg): j1 11.000, j2 21.000, j3 31.000"
    np.testing.assert_allclose(robot.read().q, np.radians([10, 20, 30]))
    target = np.radians([1.0, 2.0, 3.0])
    robot.move(target, timeout=1)  # Enter: the target itself
    np.testing.assert_allclose(robot.read().q, target)
    robot.move(target, timeout=1)  # "1,2" and "x" are asked again, then -5;0;5
    assert op.shown.count("expected 3 numbers separated by commas, got '1,2'") == 1
    np.testing.assert_allclose(robot.read().q, np.radians([-5, 0, 5]))
    with pytest.raises(MoveFailed, match="skipped"):
        robot.move(target, timeout=1)


def test_manual_reads_joints_from_a_source_driver():
    class Source:
        joint_names = NAMES
        reports_flange = True

        def __init__(self) -> None:
            self.stopped = False

        def read(self):
            return JointReading(np.array([0.1, 0.2, 0.3]), 12.5, flange=np.eye(4) * 2)

        def move(self, q, timeout):
            raise AssertionError("the manual driver never moves its source")

        def stop(self):
            self.stopped = True

        def close(self):
            pass

    source = Source()
    op = Operator("", "s")
    robot = ManualRobot(
        joint_names=NAMES, source=source, unit="rad", prismatic=[False, False, True],
        ask=op.ask, tell=op.tell,
    )  # fmt: skip
    robot.move(np.zeros(3), timeout=1)
    reading = robot.read()
    assert reading.stamp == 12.5 and reading.q.tolist() == [0.1, 0.2, 0.3]
    assert robot.reports_flange and (reading.flange == np.eye(4) * 2).all()  # the source's
    assert op.shown[-1] == "read: j1 0.100, j2 0.200, j3 0.300"
    robot.stop()
    assert source.stopped


def test_registry_lists_importable_drivers_without_their_libraries():
    for table in (devices.ROBOTS, devices.CAMERAS):
        for name, entry in table.items():
            cls = entry.load()  # imports the module, not its optional library
            assert cls.__doc__, name
    assert "franka" in devices.describe() and "[extra realsense]" in devices.describe()


def test_registry_options_from_text(tmp_path):
    assert devices.parse_options(["host=10.0.0.2,ros_joints=a,b,c", "port=9091"], "-o") == {
        "host": "10.0.0.2",
        "ros_joints": "a,b,c",
        "port": "9091",
    }
    with pytest.raises(RelcalError, match="-o 'speed': expected KEY=VALUE"):
        devices.parse_options(["speed"], "-o")
    camera = devices.open_camera("folder", {"path": str(tmp_path), "settle": "0.5"})
    assert camera.settle == 0.5
    with pytest.raises(RelcalError, match="folder option settle: 'slow': expected a number"):
        devices.open_camera("folder", {"path": str(tmp_path), "settle": "slow"})
    with pytest.raises(RelcalError, match="unknown option 'speed'; its options are path, "):
        devices.open_camera("folder", {"path": str(tmp_path), "speed": "1"})
    with pytest.raises(RelcalError, match="option path=... is required"):
        devices.open_camera("folder", {})
    with pytest.raises(RelcalError, match="--camera 'kinect': expected one of folder, genicam"):
        devices.open_camera("kinect", {})
    manual = devices.open_robot("manual", {"unit": "rad"}, joint_names=NAMES)
    assert manual.joint_names == NAMES


def test_a_missing_library_names_its_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "rtde_control", None)  # as if ur_rtde were not installed
    with pytest.raises(RelcalError, match=r"pip install 'relcal\[ur\]'"):
        devices.open_robot("ur", {"host": "192.0.2.1"}, joint_names=NAMES * 2)
    monkeypatch.setitem(sys.modules, "franky", None)
    with pytest.raises(RelcalError, match=r"pip install 'relcal\[franka\]'"):
        devices.open_robot("manual", {"source": "franka", "host": "x"}, joint_names=NAMES)


def test_context_reaches_drivers_that_take_it(tmp_path, monkeypatch):
    """A driver may take shared objects (the virtual cell's world) that are never options."""

    class Paired:
        def __init__(self, path: str, *, clock=None, robot=None) -> None:
            self.path, self.robot = path, robot

    monkeypatch.setitem(devices.CAMERAS, "paired", devices.Device(f"{__name__}:Paired", None, "x"))
    monkeypatch.setattr(sys.modules[__name__], "Paired", Paired, raising=False)
    camera = devices.open_camera("paired", {"path": "p"}, robot="the robot")
    assert camera.robot == "the robot" and camera.path == "p"
    with pytest.raises(RelcalError, match="unknown option 'speed'; its options are path$"):
        devices.open_camera("paired", {"path": "p", "speed": "1"}, robot="the robot")
