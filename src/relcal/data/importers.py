"""Converters from other tools' data to relcal dataset folders."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pydantic
import yaml

from relcal.data.dataset import POSE_COLUMNS
from relcal.io import load_validated, write_text

POSITIONER_MODEL = """\
name: ROS-Industrial rct 2-axis positioner
source: >-
  Nominal chain of robot_cal_tools rct_examples positioner_kinematic_measurements (commit
  2089a06d): DH (d, theta, a, alpha) joint 1 (0, 0, 0, -90 deg), joint 2 (-0.475, -90 deg, 0, 0);
  base offset (2.2, 0, 1.6) m rotated 90 deg about x.
convention: dh
angle_unit: deg
joints:
  - {name: positioner_1, theta_off: 0, d: 0.0, a: 0.0, alpha: -90}
  - {name: positioner_2, theta_off: -90, d: -0.475, a: 0.0, alpha: 0}
base: {xyz: [2.2, 0.0, 1.6], rpy: [90, 0, 0]}
"""


class _Pose(pydantic.BaseModel):
    x: pydantic.FiniteFloat
    y: pydantic.FiniteFloat
    z: pydantic.FiniteFloat
    qx: pydantic.FiniteFloat
    qy: pydantic.FiniteFloat
    qz: pydantic.FiniteFloat
    qw: pydantic.FiniteFloat


class _Observation(pydantic.BaseModel):
    camera_joints: list[pydantic.FiniteFloat] = []
    target_joints: list[pydantic.FiniteFloat]
    pose: _Pose


class _RctMeasurements(pydantic.RootModel[dict[str, _Observation]]):
    pass


@dataclass(frozen=True)
class Imported:
    """A dataset folder written by an importer."""

    folder: Path
    files: tuple[Path, ...]  # every file written into it
    n_samples: int


def import_rct_positioner(source: str | Path, out: str | Path) -> Imported:
    """Write a dataset folder (eye-to-hand, poses given) from robot_cal_tools' positioner file."""
    data = load_validated(_RctMeasurements, source).root
    out = Path(out)
    lines = [",".join(["id", "q1", "q2", *POSE_COLUMNS])]
    for key, obs in data.items():
        p = obs.pose
        values = [*obs.target_joints, p.x, p.y, p.z, p.qx, p.qy, p.qz, p.qw]
        lines.append(",".join([key, *(f"{v:.17g}" for v in values)]))
    spec = {
        "robot": "positioner.yaml",
        "hayati": "auto",
        "mode": "eye_to_hand",
        "joint_unit": "rad",
        "samples": "samples.csv",
    }
    contents = {  # in writing order: dataset.yaml last, once what it names is there
        "positioner.yaml": POSITIONER_MODEL,
        "samples.csv": "\n".join(lines) + "\n",
        "dataset.yaml": yaml.safe_dump(spec, sort_keys=False),
    }
    for name, text in contents.items():
        write_text(out / name, text)
    return Imported(out, tuple(out / name for name in contents), len(data))
