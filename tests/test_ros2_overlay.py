"""The ROS 2 overlay beside a calibration's robot.urdf: ``ros2/calibrated.launch.py``.

No ROS here: the launch file is parsed (Python AST) for what it points at, then run with small
stand-ins for ``launch`` and ``launch_ros`` that record what it would start; the URDF it
points at is the one results.json validated (SHA-256), and it loads (relcal's URDF loader and
Pinocchio, the same kinematics as model.yaml)."""

import ast
import hashlib
import json
import shutil
import sys
import types
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from urdf_helpers import pin_fk

from relcal.cli import main
from relcal.robot.kinematics import fk
from relcal.robot.loading import get_robot
from relcal.robot.model import load_model

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def calibration(tmp_path_factory):
    out = tmp_path_factory.mktemp("tiago") / "cal"
    assert main(["calibrate", str(ROOT / "examples/tiago-pro-poses"), "--out", str(out),
                 "--quiet"]) == 0  # fmt: skip
    return out


def constants(path):
    """The module-level constants of the launch file, from its AST."""
    tree = ast.parse(path.read_text())
    found = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and isinstance(node.targets[0], ast.Name):
            try:
                found[node.targets[0].id] = ast.literal_eval(node.value)
            except ValueError:
                found[node.targets[0].id] = ast.unparse(node.value)
    return found


class Recorded:
    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs


def run_launch_file(path):
    """``generate_launch_description()`` of the file, ``launch`` and ``launch_ros`` replaced
    by recorders."""
    fake = {}
    for name in ("launch", "launch.actions", "launch.substitutions", "launch_ros",
                 "launch_ros.actions"):  # fmt: skip
        fake[name] = types.ModuleType(name)
    fake["launch"].LaunchDescription = Recorded
    fake["launch.actions"].DeclareLaunchArgument = Recorded
    fake["launch.substitutions"].LaunchConfiguration = Recorded
    fake["launch_ros.actions"].Node = Recorded
    saved = {name: sys.modules.get(name) for name in fake}
    sys.modules.update(fake)
    try:
        namespace = {"__file__": str(path), "__name__": "calibrated_launch"}
        exec(compile(path.read_text(), str(path), "exec"), namespace)
        return namespace["generate_launch_description"]()
    finally:
        for name, module in saved.items():
            if module is None:
                sys.modules.pop(name, None)
            else:
                sys.modules[name] = module


def test_the_launch_file_points_at_the_validated_urdf(calibration):
    launch = calibration / "ros2" / "calibrated.launch.py"
    urdf = calibration / "robot.urdf"
    results = json.loads((calibration / "results.json").read_text())
    found = constants(launch)
    assert "parent.parent" in found["URDF"] and "'robot.urdf'" in found["URDF"]
    validated = {f["file"]: f for f in results["artifacts"]["files"]}["robot.urdf"]
    assert validated["written"]
    assert (
        found["URDF_SHA256"] == validated["sha256"] == hashlib.sha256(urdf.read_bytes()).hexdigest()
    )
    chain = results["nominal_robot"]["chain"]
    assert (found["ROOT_LINK"], found["TIP_LINK"]) == (chain["root"], chain["tip"])

    # what ROS 2 would start: robot_state_publisher with that URDF, the hand-eye on the tip
    description = run_launch_file(launch)
    nodes = [a for a in description.args[0] if "package" in a.kwargs]
    publisher = next(n for n in nodes if n.kwargs["package"] == "robot_state_publisher")
    assert publisher.kwargs["parameters"] == [{"robot_description": urdf.read_text()}]
    static = next(n for n in nodes if n.kwargs["executable"] == "static_transform_publisher")
    args = static.kwargs["arguments"]
    value = {args[i]: args[i + 1] for i in range(0, len(args) - 1, 2)}
    assert value["--frame-id"] == chain["tip"]
    he = results["handeye"]
    np.testing.assert_allclose([float(value[k]) for k in ("--x", "--y", "--z")], he["xyz_m"])
    quat = [float(value[k]) for k in ("--qx", "--qy", "--qz", "--qw")]
    expected = Rotation.from_euler("xyz", he["rpy_deg"], degrees=True)
    assert (Rotation.from_quat(quat) * expected.inv()).magnitude() < 1e-9

    # the URDF loads, with the kinematics of model.yaml (the validated geometry)
    assert results["artifacts"]["geometry_is_validated_model"]
    loaded = get_robot(urdf, chain["root"], chain["tip"])
    model = load_model(calibration / "model.yaml")
    q = np.random.default_rng(0).uniform(model.lower, model.upper, (20, model.n_joints))
    np.testing.assert_allclose(fk(loaded, q), fk(model, q), atol=1e-9)
    np.testing.assert_allclose(
        pin_fk(urdf, chain["root"], chain["tip"], loaded.joint_names, q), fk(model, q), atol=1e-9
    )


def test_a_changed_urdf_is_refused_at_launch(calibration, tmp_path):
    copy = tmp_path / "cal"
    shutil.copytree(calibration, copy)
    urdf = copy / "robot.urdf"
    urdf.write_text(urdf.read_text().replace("<robot", "<!-- edited -->\n<robot", 1))
    with pytest.raises(RuntimeError, match="is not the URDF relcal validated"):
        run_launch_file(copy / "ros2" / "calibrated.launch.py")
