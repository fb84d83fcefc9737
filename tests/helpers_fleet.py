"""Synthetic fleets: robots with their own known geometric errors, sessions of them as dataset
folders (poses given directly), a planted change of one link, a corrupt dataset."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from conftest import random_q
from helpers_sim import BOARD, HANDEYE, true_errors

from relcal import geometry as tf
from relcal.data.dataset import write_samples
from relcal.robot.kinematics import apply_errors, fk, make_layout
from relcal.robot.loading import get_robot
from relcal.robot.model import auto_hayati

NOISE = (5e-5, 1e-4)  # pose noise per axis: 0.05 mm, 0.0057 deg


@dataclass(frozen=True)
class Robot:
    """One physical arm: model name, robot id, its true errors and hand-eye transform."""

    model: str
    robot_id: str
    truth: np.ndarray
    handeye: np.ndarray


def make_robot(model: str, robot_id: str, seed: int) -> Robot:
    nominal = auto_hayati(get_robot(model))
    rng = np.random.default_rng(seed)
    truth = true_errors(make_layout(nominal), rng)
    handeye = HANDEYE @ tf.from_vector(
        np.concatenate([rng.normal(0, 1e-3, 3), rng.normal(0, 5e-3, 3)])
    )
    return Robot(model, robot_id, truth, handeye)


def write_session(
    root: Path,
    robot: Robot,
    seed: int,
    n: int = 30,
    noise: tuple[float, float] = NOISE,
    change: dict[str, float] | None = None,
    scale: dict[int, float] | None = None,
) -> Path:
    """A dataset folder of ``n`` samples of ``robot`` (new poses and noise for each ``seed``);
    ``change`` adds to named true errors (SI), e.g. ``{"a[2]": 3e-4}`` for 0.3 mm; ``scale``
    gives joints (1-based) a true joint scale (gear ratio error), e.g. ``{2: 5e-4}``."""
    nominal = auto_hayati(get_robot(robot.model))
    layout = make_layout(nominal)
    truth = robot.truth.copy()
    for name, delta in (change or {}).items():
        truth[layout.names.index(name)] += delta
    true_model = apply_errors(nominal, layout, truth)
    if scale:
        factors = np.zeros(nominal.n_joints)
        for joint, value in scale.items():
            factors[joint - 1] = value
        true_model = true_model.with_values(scale=factors)
    rng = np.random.default_rng(seed)
    q = random_q(nominal, n, rng, scale=0.8)
    poses = BOARD @ fk(true_model, q) @ robot.handeye
    delta = np.concatenate([rng.normal(0, noise[0], (n, 3)), rng.normal(0, noise[1], (n, 3))], 1)
    poses = poses @ tf.from_vector(delta)
    root.mkdir(parents=True, exist_ok=True)
    ids = [f"s{k:03d}" for k in range(n)]
    xyz, rpy = tf.to_xyz_rpy(HANDEYE)
    (root / "dataset.yaml").write_text(
        f"robot: {robot.model}\nhayati: auto\njoint_unit: deg\nrobot_id: {robot.robot_id}\n"
        f"handeye: {{xyz: {xyz.tolist()}, rpy: {np.degrees(rpy).tolist()}}}\n"
    )
    (root / "samples.csv").write_text(
        write_samples(root / "samples.csv", ids, np.degrees(q), poses=poses)
    )
    return root
