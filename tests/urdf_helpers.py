"""Real URDFs for the URDF tests, and Pinocchio as the independent forward kinematics."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, distribution
from pathlib import Path

import numpy as np
import pytest
from conftest import DATA
from lxml import etree

from relcal import geometry as tf

try:  # a dev dependency (about 400 MB of robots with meshes)
    ROBOTS = Path(str(distribution("example-robot-data").locate_file("cmeel.prefix"))) / (
        "share/example-robot-data/robots"
    )
except PackageNotFoundError:
    ROBOTS = Path("example-robot-data-not-installed")
TIAGO = DATA / "tiago_pro" / "tiago_pro.urdf"
TIAGO_CHAIN = ("base_footprint", "gripper_right_pal_atc_base_link")
TIAGO_JOINTS = ("torso_lift_joint", *[f"arm_right_{k}_joint" for k in range(1, 8)])

# (file, root, tip): root/tip None = found by the loader; tests skip the files that are missing
REAL = {
    "tiago_pro": (TIAGO, *TIAGO_CHAIN),
    "ur5": (ROBOTS / "ur_description/urdf/ur5_robot.urdf", None, None),
    "panda": (ROBOTS / "panda_description/urdf/panda.urdf", "panda_link0", "panda_link8"),
    "kinova": (ROBOTS / "kinova_description/robots/kinova.urdf", None, None),
    "z1": (ROBOTS / "z1_description/urdf/z1.urdf", None, None),
}


def pin_fk(path, root: str, tip: str, names, q: np.ndarray) -> np.ndarray:
    """Pose of ``tip`` in ``root`` ``(N, 4, 4)`` by Pinocchio, joints set by name to ``q``."""
    pin = pytest.importorskip("pinocchio")
    model = pin.buildModelFromUrdf(str(path))
    data = model.createData()
    root_id, tip_id = model.getFrameId(root), model.getFrameId(tip)
    out = []
    for row in np.atleast_2d(q):
        config = pin.neutral(model)
        for name, value in zip(names, row, strict=True):
            joint = model.joints[model.getJointId(name)]
            if joint.nq == 2:  # continuous joints are (cos, sin)
                config[joint.idx_q : joint.idx_q + 2] = [np.cos(value), np.sin(value)]
            else:
                config[joint.idx_q] = value
        pin.framesForwardKinematics(model, data, config)
        out.append((data.oMf[root_id].inverse() * data.oMf[tip_id]).homogeneous)
    return np.array(out)


# UR5e nominal kinematics in the layout of ur_description's default_kinematics.yaml (m, rad)
UR5E_KINEMATICS = {
    "shoulder": dict(x=0, y=0, z=0.1625, roll=0, pitch=0, yaw=0),
    "upper_arm": dict(x=0, y=0, z=0, roll=np.pi / 2, pitch=0, yaw=0),
    "forearm": dict(x=-0.425, y=0, z=0, roll=0, pitch=0, yaw=0),
    "wrist_1": dict(x=-0.3922, y=0, z=0.1333, roll=0, pitch=0, yaw=0),
    "wrist_2": dict(x=0, y=-0.0997, z=0, roll=np.pi / 2, pitch=0, yaw=0),
    "wrist_3": dict(x=0, y=0.0996, z=0, roll=np.pi / 2, pitch=np.pi, yaw=np.pi),
}
UR_JOINTS = (
    ("shoulder_pan_joint", "base_link_inertia", "shoulder_link", "shoulder"),
    ("shoulder_lift_joint", "shoulder_link", "upper_arm_link", "upper_arm"),
    ("elbow_joint", "upper_arm_link", "forearm_link", "forearm"),
    ("wrist_1_joint", "forearm_link", "wrist_1_link", "wrist_1"),
    ("wrist_2_joint", "wrist_1_link", "wrist_2_link", "wrist_2"),
    ("wrist_3_joint", "wrist_2_link", "wrist_3_link", "wrist_3"),
)


def ur_description_urdf(kinematics: dict) -> str:
    """The kinematic skeleton that ur_description's ur_macro.xacro builds from a
    ``kinematics:`` mapping: base_link, base_link_inertia turned by pi about z, the six joints
    with the mapping's origins (axis z), then flange and tool0."""

    def origin(k):
        return (
            f'<origin xyz="{k["x"]!r} {k["y"]!r} {k["z"]!r}" '
            f'rpy="{k["roll"]!r} {k["pitch"]!r} {k["yaw"]!r}"/>'
        )

    links = ["base_link", "base_link_inertia", *[j[2] for j in UR_JOINTS], "flange", "tool0"]
    out = ['<?xml version="1.0"?>', '<robot name="ur5e">']
    out += [f'  <link name="{name}"/>' for name in links]
    out.append(
        '  <joint name="base_link-base_link_inertia" type="fixed"><parent link="base_link"/>'
        '<child link="base_link_inertia"/><origin xyz="0 0 0" rpy="0 0 3.141592653589793"/>'
        "</joint>"
    )
    for name, parent, child, segment in UR_JOINTS:
        out.append(
            f'  <joint name="{name}" type="revolute"><parent link="{parent}"/>'
            f'<child link="{child}"/>{origin(kinematics[segment])}<axis xyz="0 0 1"/>'
            '<limit lower="-6.283185307179586" upper="6.283185307179586" effort="150" '
            'velocity="3.14"/></joint>'
        )
    out.append(
        '  <joint name="wrist_3-flange" type="fixed"><parent link="wrist_3_link"/>'
        '<child link="flange"/><origin xyz="0 0 0" rpy="0 -1.5707963267948966 '
        '-1.5707963267948966"/></joint>'
    )
    out.append(
        '  <joint name="flange-tool0" type="fixed"><parent link="flange"/>'
        '<child link="tool0"/><origin xyz="0 0 0" rpy="1.5707963267948966 0 '
        '1.5707963267948966"/></joint>'
    )
    out += ["</robot>", ""]
    return "\n".join(out)


def real(name: str) -> tuple:
    """``REAL[name]``, skipping the test when the file is not installed."""
    path = REAL[name][0]
    if not Path(path).is_file():
        pytest.skip(f"{path} is not available (pip install example-robot-data)")
    return REAL[name]


def substitute(data: bytes, origins: dict[str, np.ndarray]) -> bytes:
    """The URDF with these joints' origins replaced, as xacro would write them (via lxml)."""
    root = etree.fromstring(data)
    for name, origin in origins.items():
        (joint,) = root.xpath(f"/robot/joint[@name='{name}']")
        tag = joint.find("origin")
        if tag is None:
            tag = etree.SubElement(joint, "origin")
        xyz, rpy = tf.to_xyz_rpy(origin)
        tag.set("xyz", " ".join(repr(float(v)) for v in xyz))
        tag.set("rpy", " ".join(repr(float(v)) for v in rpy))
    return etree.tostring(root)
