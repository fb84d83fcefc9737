"""A simulated UR5e with first harmonics planted on its joints, as a poses dataset folder."""

import numpy as np
import pytest
from conftest import random_q
from helpers_sim import BOARD, HANDEYE

from relcal import geometry as tf
from relcal.data.dataset import write_samples
from relcal.robot.kinematics import apply_errors, fk, make_layout
from relcal.robot.loading import get_robot
from relcal.robot.model import dump_model, with_nongeometric


def ur5e_with_harmonics(root, n: int = 48, seed: int = 5, noise=(2e-5, 3.5e-5)):
    """``n`` camera poses of a UR5e whose joints carry first harmonics of 0.02..0.06 deg and
    whose links are off by 0.1..0.5 mm and 0.01..0.1 deg; pose noise ``(m, rad)``. The
    dataset's robot (``robot.yaml``) offers harmonics to model selection. Returns the true
    model."""
    rng = np.random.default_rng(seed)
    model = with_nongeometric(get_robot("ur5e"), ["harmonic"])
    layout = make_layout(model)
    kinds = np.array(layout.kinds)
    size = np.where(layout.is_angle(), np.radians(rng.uniform(0.01, 0.1, layout.size)), 0.0)
    size = np.where(layout.is_angle(), size, rng.uniform(1e-4, 5e-4, layout.size))
    harmonic = np.isin(kinds, ("harmonic_c", "harmonic_s"))
    size[harmonic] = np.radians(rng.uniform(0.02, 0.06, harmonic.sum()))
    truth = size * rng.choice([-1.0, 1.0], layout.size)
    true_model = apply_errors(model, layout, truth)
    q = random_q(model, n, rng, scale=0.8)
    poses = BOARD @ fk(true_model, q) @ HANDEYE
    delta = np.concatenate([rng.normal(0, noise[0], (n, 3)), rng.normal(0, noise[1], (n, 3))], 1)
    poses = poses @ tf.from_vector(delta)
    root.mkdir(parents=True, exist_ok=True)
    (root / "robot.yaml").write_text(dump_model(model))
    (root / "dataset.yaml").write_text(
        "robot: robot.yaml\njoint_unit: deg\nhandeye: {xyz: [0, 0.04, 0.06]}\n"
    )
    ids = [f"s{k:03d}" for k in range(n)]
    text = write_samples(root / "samples.csv", ids, np.degrees(q), poses=poses)
    (root / "samples.csv").write_text(text)
    return true_model


# --- each file's own held-out number (tests/test_artifact_numbers.py) ---------------------------


def model_file(cal):
    (model,) = [a for a in cal.artifacts if a.name == "model.yaml"]
    return model


def files_carry_the_validated_number(cal):
    """model.yaml always; every written file when nothing was refitted (they all hold the
    validated model then)."""
    val = cal.validation
    assert val is not None
    want = val.rms("calibrated")
    assert model_file(cal).rms() == pytest.approx(want, rel=1e-9, abs=1e-9)
    if cal.geometry is None:
        for art in cal.artifacts:
            assert art.written, (art.name, art.refused)
            assert art.rms() == pytest.approx(want, rel=1e-7), art.name
    assert want < val.rms("before")  # a real correction: the test could fail by doubling it


def relative_rms(cal, loaded, handeye, world=None) -> float:
    """Position RMS (mm) of ``model^-1 measured`` over the validation's pairs, recomputed from
    the file's forward kinematics and the hand-eye that accompanies it; for a validation of
    single poses (pairs ``(k, k)``), each pose predicted in the world frame, ``W F X`` with the
    world transform ``world`` (4, 4) that accompanies the file."""
    val = cal.validation
    poses = cal.measurements.poses
    tool = fk(loaded, cal.dataset.q) @ handeye
    i, j = val.pairs.T
    if np.array_equal(i, j):
        error = world @ tool[i]
        return float(np.sqrt(np.mean(np.sum((error - poses[i])[:, :3, 3] ** 2, axis=1)))) * 1e3
    model = np.linalg.inv(tool[i]) @ tool[j]
    measured = np.linalg.inv(poses[i]) @ poses[j]
    error = np.linalg.inv(model) @ measured
    return float(np.sqrt(np.mean(np.sum(error[:, :3, 3] ** 2, axis=1)))) * 1e3
