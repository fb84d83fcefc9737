"""Cost of a calibration with model selection against one plain fit of the same data.

114 samples of a 7-joint arm (the Franka FR3 with Hayati's beta where axes are parallel, planted
geometric errors of 0.1..0.9 mm and 0.01..0.9 deg, pose noise 0.05 mm / 0.01 deg), all pairs:
``relcal.calibrate`` (outlier fit, noise model, 5-fold cross-validated selection among the
candidates and weightings, the chosen fit, the baseline fit, bootstrap) against one
``scipy.optimize.least_squares(method="lm")`` fit of every identifiable parameter on the same
training pairs and row weighting, from the nominal model, default tolerances, with relcal's
analytic Jacobian (``residuals(problem, p)`` gives ``r`` and ``A`` with
``r(p + dp) ~ r(p) - A dp``, so the Jacobian of ``r`` is ``-A``): the plain fit a user would
write (the cheapest honest peer: a finite-difference Jacobian would flatter the ratio). The
identifiable subset is given to it for free (``analyse_problem``, not timed). relcal's own
solver on the same problem (``identify_lm``) is timed beside it, and both fits' final costs are
reported: they must agree. Goal: model selection within 5x of the plain fit.

BLAS runs on one thread, as under ``bench/run.py``, when this module is run alone.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # as bench/run.py: one BLAS thread

import tempfile  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import scipy.optimize  # noqa: E402

from relcal import geometry as tf  # noqa: E402
from relcal.calibration.identifiability import analyse_problem  # noqa: E402
from relcal.calibration.identify import identify_lm  # noqa: E402
from relcal.calibration.measurement import Problem, residuals  # noqa: E402
from relcal.calibration.pipeline import calibrate  # noqa: E402
from relcal.data.dataset import load_dataset, write_samples  # noqa: E402
from relcal.data.imaging import measure  # noqa: E402
from relcal.robot.kinematics import apply_errors, fk, make_layout  # noqa: E402
from relcal.robot.loading import get_robot  # noqa: E402
from relcal.robot.model import auto_hayati  # noqa: E402

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


def scipy_lm(problem: Problem, subset: np.ndarray) -> scipy.optimize.OptimizeResult:
    """One plain fit as a user would write it: ``scipy.optimize.least_squares(method="lm")``,
    default tolerances, of ``subset`` (the others at nominal) from the nominal model, with
    relcal's residual and its analytic Jacobian (``-A``: ``r(p + dp) ~ r(p) - A dp``)."""
    full = np.zeros(problem.full_layout.size)

    def expand(x: np.ndarray) -> np.ndarray:
        out = full.copy()
        out[subset] = x
        return out

    return scipy.optimize.least_squares(
        lambda x: residuals(problem, expand(x), jacobian=False),
        np.zeros(len(subset)),
        jac=lambda x: -residuals(problem, expand(x))[1][:, subset],
        method="lm",
    )


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
        peer = scipy_lm(plain, ident.subset)
        own = identify_lm(plain, 200, ident)
        selection_s = _least_time(lambda: calibrate(dataset, measured))
        plain_s = _least_time(lambda: scipy_lm(plain, ident.subset))
        own_s = _least_time(lambda: identify_lm(plain, 200, ident))
    chosen = cal.selection[cal.chosen].candidate
    own_cost = 0.5 * own.residual_norm**2
    pairs = len(cal.problem.pair_indices())
    return [
        {
            "task": f"calibrate with model selection, {N_SAMPLES} samples of a 7-joint arm "
            f"(FR3), all {pairs} training pairs",
            "value": selection_s,
            "unit": "s",
            "peer": plain_s,
            "peer_name": "one plain scipy least_squares LM fit (analytic Jacobian)",
            "ratio": plain_s / selection_s,
            "goal": f"within {GOAL:g}x of the plain fit",
            "goal_ratio": 1 / GOAL,
            "note": f"chose {chosen.name} ({chosen.weighting}) of {len(cal.selection)} "
            f"candidates; the peer fitted {len(ident.subset)} parameters in {peer.nfev} "
            f"evaluations ({peer.njev} Jacobians), cost {peer.cost:.9g}; identify_lm on the "
            f"same problem {own_s:.3g} s, cost {own_cost:.9g}",
        }
    ]


if __name__ == "__main__":
    for row in run():
        print(row)
