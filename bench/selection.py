"""Cost of a calibration with model selection against one plain fit of the same data.

114 samples of a 7-joint arm (the Franka FR3 with Hayati's beta where axes are parallel, planted
geometric errors of 0.1..0.9 mm and 0.01..0.9 deg, pose noise 0.05 mm / 0.01 deg), all pairs:
``relcal.calibrate`` (outlier fit, noise model, 5-fold cross-validated selection among the
candidates and weightings, the chosen fit, the baseline fit, bootstrap) against one
``scipy.optimize.least_squares`` Levenberg-Marquardt fit of every identifiable parameter on the
same training pairs, with relcal's analytic Jacobian (the cheapest honest peer: a finite-difference
Jacobian would flatter the ratio). Goal: model selection within 5x of the plain fit.
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from relcal import geometry as tf
from relcal.calibration.identifiability import analyse_problem
from relcal.calibration.identify import identify_lm
from relcal.calibration.pipeline import calibrate
from relcal.data.dataset import load_dataset, write_samples
from relcal.data.imaging import measure
from relcal.robot.kinematics import apply_errors, fk, make_layout
from relcal.robot.loading import get_robot
from relcal.robot.model import auto_hayati

N_SAMPLES = 114
GOAL = 5.0  # model selection within this many plain fits


def _dataset(root: Path, seed: int = 0) -> Path:
    rng = np.random.default_rng(seed)
    model = auto_hayati(get_robot("franka_fr3"))
    layout = make_layout(model)
    angle = layout.is_angle()
    size = np.where(angle, np.radians(rng.uniform(0.01, 0.9, layout.size)), 0.0)
    size = np.where(angle, size, rng.uniform(0.1, 0.9, layout.size) * 1e-3)
    truth = size * rng.choice([-1.0, 1.0], layout.size)
    true_model = apply_errors(model, layout, truth)
    lo, hi = model.lower, model.upper
    q = rng.uniform(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), (N_SAMPLES, model.n_joints))
    handeye = tf.from_vector(np.array([0.0, 0.04, 0.06, 0.0, 0.0, 0.0]))
    board = tf.from_vector(np.array([0.5, 0.1, -0.2, 3.0, 0.1, 0.4]))
    noise = np.c_[
        rng.normal(0, 5e-5, (N_SAMPLES, 3)), rng.normal(0, np.radians(0.01), (N_SAMPLES, 3))
    ]
    poses = board @ fk(true_model, q) @ handeye @ tf.from_vector(noise)
    root.mkdir(parents=True, exist_ok=True)
    ids = [f"s{k:03d}" for k in range(N_SAMPLES)]
    (root / "dataset.yaml").write_text(
        "robot: franka_fr3\nhayati: auto\njoint_unit: deg\nhandeye: {xyz: [0, 0.04, 0.06]}\n"
    )
    (root / "samples.csv").write_text(
        write_samples(root / "samples.csv", ids, np.degrees(q), poses=poses)
    )
    return root


def _least_time(fn, repeat: int = 3) -> float:
    best = float("inf")
    for _ in range(repeat):
        start = time.process_time()
        fn()
        best = min(best, time.process_time() - start)
    return best


def run() -> list[dict]:
    with tempfile.TemporaryDirectory() as tmp:
        dataset = load_dataset(_dataset(Path(tmp) / "fr3"))
        measured = measure(dataset, progress=False)
        cal = calibrate(dataset, measured)
        plain = replace(cal.problem, weights=np.r_[np.ones(3), np.full(3, 0.1)], pair_weights=None)
        ident = analyse_problem(plain)
        selection_s = _least_time(lambda: calibrate(dataset, measured))
        plain_s = _least_time(lambda: identify_lm(plain, 200, ident))
    chosen = cal.selection[cal.chosen].candidate
    pairs = len(cal.problem.pair_indices())
    return [
        {
            "task": f"calibrate with model selection, {N_SAMPLES} samples of a 7-joint arm "
            f"(FR3), all {pairs} training pairs",
            "value": selection_s,
            "unit": "s",
            "peer": plain_s,
            "peer_name": "one plain scipy least_squares fit (analytic Jacobian)",
            "ratio": plain_s / selection_s,
            "goal": f"within {GOAL:g}x of the plain fit",
            "goal_ratio": 1 / GOAL,
            "note": f"chose {chosen.name} ({chosen.weighting}) of {len(cal.selection)} candidates",
        }
    ]


if __name__ == "__main__":
    for row in run():
        print(row)
