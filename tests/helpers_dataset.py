"""Synthetic dataset folders with poses given directly: a perturbed A465 with known truth,
optionally with non-geometric errors (joint scale, compliance under gravity, harmonics)."""

from dataclasses import dataclass

import numpy as np
from conftest import random_q
from helpers_sim import BOARD, HANDEYE, true_errors, with_plausible_loads

from relcal import geometry as tf
from relcal.data.dataset import write_samples
from relcal.robot.kinematics import apply_errors, fk, make_layout
from relcal.robot.loading import get_robot
from relcal.robot.model import auto_hayati, dump_model, with_nongeometric


@dataclass
class Synthetic:
    root: object
    truth: np.ndarray
    true_model: object
    true_handeye: np.ndarray
    ids: list
    layout: object = None  # of ``truth``


def synthetic_dataset(
    root, n=60, noise=(2e-5, 2e-5), outliers=0, seed=0, errors=1.0, nongeometric=()
) -> Synthetic:
    """``n`` samples of a perturbed A465 (Hayati on; geometric errors of 0.1..0.9 mm and
    0.01..0.9 deg times ``errors``), pose noise ``(m, rad)``, and ``outliers`` samples whose
    pose is off by 5 mm and 1 deg (a wrongly detected board).

    ``nongeometric`` terms (``scale``, ``compliance``, ``harmonic``) are planted on every joint
    (100..900 ppm, 10..90 urad/(N m) with plausible link masses, 0.001..0.09 deg) and written as
    options of the dataset's robot model (``robot.yaml``), so that a calibration fits them."""
    rng = np.random.default_rng(seed)
    model = auto_hayati(get_robot("a465"))
    if nongeometric:
        model = with_nongeometric(with_plausible_loads(model, "a465"), list(nongeometric))
    layout = make_layout(model)
    truth = true_errors(layout, rng) * np.where(layout.is_geometric(), errors, 1.0)
    kinds = np.array(layout.kinds)
    truth[np.isin(kinds, ("compliance", "harmonic_c", "harmonic_s"))] *= 0.1
    true_model = apply_errors(model, layout, truth)
    true_x = HANDEYE @ tf.from_vector(
        np.concatenate([rng.normal(0, 1e-3, 3), rng.normal(0, 5e-3, 3)])
    )
    q = random_q(model, n, rng, scale=0.8)
    poses = BOARD @ fk(true_model, q) @ true_x
    delta = np.concatenate([rng.normal(0, noise[0], (n, 3)), rng.normal(0, noise[1], (n, 3))], 1)
    bad = rng.choice(n, outliers, replace=False)
    for k in bad:
        direction = rng.normal(size=6)
        delta[k] += np.concatenate(
            [
                5e-3 * direction[:3] / np.linalg.norm(direction[:3]),
                np.radians(1.0) * direction[3:] / np.linalg.norm(direction[3:]),
            ]
        )
    poses = poses @ tf.from_vector(delta)
    root.mkdir(parents=True, exist_ok=True)
    ids = [f"s{k:03d}" for k in range(n)]
    robot = "a465"
    if nongeometric:
        (root / "robot.yaml").write_text(dump_model(model))
        robot = "robot.yaml"
    (root / "dataset.yaml").write_text(
        f"robot: {robot}\nhayati: auto\njoint_unit: deg\nhandeye: {{xyz: [0, 0.04, 0.06]}}\n"
    )
    (root / "samples.csv").write_text(
        write_samples(root / "samples.csv", ids, np.degrees(q), poses=poses)
    )
    return Synthetic(root, truth, true_model, true_x, [ids[k] for k in sorted(bad)], layout)
