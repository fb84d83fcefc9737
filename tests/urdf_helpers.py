"""Real URDFs for the URDF tests, and Pinocchio as the independent forward kinematics."""

from __future__ import annotations

from importlib.metadata import distribution
from pathlib import Path

import numpy as np
from conftest import DATA

ROBOTS = Path(str(distribution("example-robot-data").locate_file("cmeel.prefix"))) / (
    "share/example-robot-data/robots"
)
TIAGO = DATA / "tiago_pro" / "tiago_pro.urdf"
TIAGO_CHAIN = ("base_footprint", "gripper_right_pal_atc_base_link")
TIAGO_JOINTS = ("torso_lift_joint", *[f"arm_right_{k}_joint" for k in range(1, 8)])

# (file, root, tip): root/tip None = found by the loader
REAL = {
    "tiago_pro": (TIAGO, *TIAGO_CHAIN),
    "ur5": (ROBOTS / "ur_description/urdf/ur5_robot.urdf", None, None),
    "panda": (ROBOTS / "panda_description/urdf/panda.urdf", "panda_link0", "panda_link8"),
    "kinova": (ROBOTS / "kinova_description/robots/kinova.urdf", None, None),
    "z1": (ROBOTS / "z1_description/urdf/z1.urdf", None, None),
}


def pin_fk(path, root: str, tip: str, names, q: np.ndarray) -> np.ndarray:
    """Pose of ``tip`` in ``root`` ``(N, 4, 4)`` by Pinocchio, joints set by name to ``q``."""
    import pinocchio as pin

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
