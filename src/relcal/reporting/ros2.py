"""The ROS 2 overlay of a calibration: a launch file beside ``robot.urdf``.

``ros2/calibrated.launch.py`` starts ``robot_state_publisher`` with the calibrated URDF and, where
the calibration estimated a hand-eye transform, publishes it with tf2's
``static_transform_publisher`` (the camera's optical frame on the chain's tip link for a camera on
the flange; the board's frame for a board on the flange). The URDF's SHA-256, as validated, is
written into the launch file, which refuses to start with any other file.

The text is generated here and run only by ROS 2 (``ros2 launch``): relcal imports no ROS
package.
"""

from __future__ import annotations

import hashlib
import json

import numpy as np
from scipy.spatial.transform import Rotation

LAUNCH_FILE = "ros2/calibrated.launch.py"
CHILD_FRAME = {"eye_in_hand": "camera_optical_frame", "eye_to_hand": "calibration_board"}
MEASURED_FRAME = "measured_frame"  # poses measured otherwise (a marker, a tracker's probe)

TEMPLATE = '''\
"""ROS 2 launch file written by relcal calibrate (run {run_id}): the calibrated robot.

    ros2 launch CALIBRATION/{launch_file}

starts robot_state_publisher with ../robot.urdf, the calibrated URDF
({validated}){handeye_doc}
The URDF must be the file relcal validated (its SHA-256 below): a changed file is refused.
"""

import hashlib
from pathlib import Path

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

URDF = Path(__file__).resolve().parent.parent / "robot.urdf"
URDF_SHA256 = "{sha256}"
ROOT_LINK = "{root}"
TIP_LINK = "{tip}"
# The frame the hand-eye transform the calibration estimated is published to (TIP_LINK ->
# it: translation in m, rotation as a unit quaternion x, y, z, w, below).
HANDEYE_CHILD = "{child}"


def robot_description() -> str:
    """The calibrated URDF's text, refused when it is not the validated file."""
    data = URDF.read_bytes()
    if hashlib.sha256(data).hexdigest() != URDF_SHA256:
        raise RuntimeError(
            f"{{URDF}} is not the URDF relcal validated (SHA-256 {{URDF_SHA256}}): it was changed "
            "after the calibration; calibrate again or restore the file"
        )
    return data.decode("utf-8")


def generate_launch_description() -> LaunchDescription:
    actions = [
        DeclareLaunchArgument(
            "handeye_child_frame",
            default_value=HANDEYE_CHILD,
            description="frame the hand-eye transform is published to",
        ),
        Node(
            package="robot_state_publisher",
            executable="robot_state_publisher",
            parameters=[{{"robot_description": robot_description()}}],
            output="screen",
        ),
    ]
{handeye_action}    return LaunchDescription(actions)
'''


def static_transform_node(
    transform: np.ndarray, parent: str, child: str, name: str, indent: int = 0
) -> str:
    """The source text of a ROS 2 launch ``Node`` running tf2's ``static_transform_publisher``
    with ``transform`` ``(4, 4)`` (child in parent, m): ``--x --y --z`` (m) and ``--qx .. --qw``
    (unit quaternion) as exact decimal strings, ``--frame-id parent --child-frame-id child``.
    ``parent`` and ``child`` are Python expressions (a quoted name, ``json.dumps("tool0")``, or a
    constant or ``LaunchConfiguration`` of the launch file); ``indent`` spaces before each line.
    The one writer of a static transform for ``relcal calibrate``'s overlay and ``relcal
    handeye``'s launch file."""
    t = np.asarray(transform, dtype=float)
    quat = Rotation.from_matrix(t[:3, :3]).as_quat()
    keys = ("--x", "--y", "--z", "--qx", "--qy", "--qz", "--qw")
    pairs = [f'"{k}", "{float(v)!r}"' for k, v in zip(keys, (*t[:3, 3], *quat), strict=True)]
    pad = " " * indent
    lines = [
        "Node(",
        '    package="tf2_ros",',
        '    executable="static_transform_publisher",',
        f"    name={json.dumps(name)},",
        "    arguments=[",
        *(f"        {pair}," for pair in pairs),
        f'        "--frame-id", {parent},',
        f'        "--child-frame-id", {child},',
        "    ],",
        '    output="screen",',
        ")",
    ]
    return "\n".join(pad + line for line in lines)


def launch_file(
    urdf: bytes,
    root: str,
    tip: str,
    handeye: np.ndarray | None,
    mode: str,
    run_id: str,
    held_out_mm: float | None,
    images: bool = True,
) -> str:
    """The launch file's text for the calibrated ``urdf`` (its bytes as written), its chain
    ``root`` .. ``tip`` links, the hand-eye ``(4, 4)`` (tip -> camera for ``eye_in_hand``, tip
    -> board for ``eye_to_hand``; None: no static transform), the run's id and the URDF's own
    held-out position RMS (mm, None when not validated); ``images`` False for poses measured
    otherwise (the child frame is then :data:`MEASURED_FRAME`)."""
    child = CHILD_FRAME.get(mode, "camera_optical_frame") if images else MEASURED_FRAME
    if handeye is None:
        handeye_action = ""
        handeye_doc = "."
    else:
        node = static_transform_node(
            handeye, "TIP_LINK", 'LaunchConfiguration("handeye_child_frame")', "relcal_handeye", 8
        )
        handeye_action = f"    actions.append(\n{node}\n    )\n"
        handeye_doc = (
            f",\nand tf2's static_transform_publisher with the hand-eye transform {tip} -> {child}."
        )
    validated = (
        "not validated on held-out samples"
        if held_out_mm is None
        else f"held-out position RMS {held_out_mm:.4g} mm, measured on this file read back"
    )
    return TEMPLATE.format(
        run_id=run_id,
        launch_file=LAUNCH_FILE,
        validated=validated,
        handeye_doc=handeye_doc,
        sha256=hashlib.sha256(urdf).hexdigest(),
        root=root,
        tip=tip,
        child=child,
        handeye_action=handeye_action,
    )
