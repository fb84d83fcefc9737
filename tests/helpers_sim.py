"""Synthetic relative-measurement problems built straight from joint configurations (no IK)."""

from dataclasses import replace

import numpy as np
from conftest import random_q

from relcal import geometry as tf
from relcal.calibration.measurement import Problem, make_pairs, residuals, split_params
from relcal.robot.kinematics import fk, make_layout

HANDEYE = tf.from_vector(np.array([0.0, 0.04, 0.06, 0.05, -0.03, 0.2]))
BOARD = tf.from_vector(np.array([0.5, 0.1, -0.2, 3.0, 0.1, 0.4]))


def true_errors(layout, rng, extra: int = 0):
    """Errors of 0.1..0.9 mm and 0.01..0.9 deg with random signs (plus ``extra`` hand-eye)."""
    angle = layout.is_angle()
    size = np.where(angle, np.radians(rng.uniform(0.01, 0.9, layout.size)), 0.0)
    size = np.where(angle, size, rng.uniform(0.1, 0.9, layout.size) * 1e-3)
    out = size * rng.choice([-1.0, 1.0], layout.size)
    return np.concatenate([out, rng.normal(0, 1e-3, extra)])


def measured_poses(problem_like: Problem, truth: np.ndarray, q: np.ndarray) -> np.ndarray:
    """What the camera would measure: C = W F X for the invariant form, F (base-aligned, shifted
    by an unknown translation) for the others."""
    model, handeye = split_params(problem_like, truth)
    poses = fk(model, q)
    if problem_like.formulation == "invariant":
        return BOARD @ poses @ handeye
    shifted = poses.copy()
    shifted[:, :3, 3] += [0.3, -0.2, 0.1] if problem_like.formulation == "published" else 0.0
    return shifted


def make_problem(model, formulation, measure, rng, n_poses=40, noise=0.0, layout=None):
    """A problem with known truth; ``noise`` is the pose noise (m and rad) of each measurement."""
    layout = layout or make_layout(model)
    q = random_q(model, n_poses, rng)
    shell = Problem(
        model,
        layout,
        q,
        np.zeros((n_poses, 4, 4)),
        formulation,
        measure,
        make_pairs(n_poses),
        HANDEYE,
    )
    extra = 6 if formulation == "invariant" else 0
    truth = true_errors(layout, rng, extra)
    poses = measured_poses(shell, truth, q)
    if noise:
        poses = poses @ tf.from_vector(rng.normal(0, noise, (n_poses, 6)))
    problem = Problem(model, layout, q, poses, formulation, measure, make_pairs(n_poses), HANDEYE)
    return problem, truth


def held_out_error(problem, params, truth, rng, n=30):
    """Largest residual of ``params`` on new, noise-free measurements of the same kind (all pairs
    of ``n`` new poses): zero when every identifiable combination is recovered."""
    q = random_q(problem.model, n, rng)
    shell = replace(problem, q=q, poses=np.zeros((n, 4, 4)), pairs=make_pairs(n, "all"))
    held_out = replace(shell, poses=measured_poses(shell, truth, q))
    return np.abs(residuals(held_out, params, jacobian=False)).max()


# Plausible link masses (kg) and centres of mass (m, in each link's frame), and a 1 kg payload
# 5 cm beyond the tool: the A465 from its ~31 kg total (waist, upper arm, forearm, wrist), the FR3
# rounded from the identified Panda parameters of Gaz et al. (IEEE RA-L 2019).
LOADS = {
    "a465": (
        [8.0, 6.0, 4.0, 1.2, 0.8, 0.3],
        [
            [0.0, -0.1, 0.0],
            [-0.15, 0.0, 0.02],
            [0.0, -0.02, 0.15],
            [0.0, 0.03, 0.0],
            [0.0, 0.0, 0.02],
            [0.0, 0.0, -0.02],
        ],
    ),
    "franka_fr3": (
        [4.97, 0.65, 3.23, 3.59, 1.23, 1.67, 0.74],
        [
            [0.004, 0.002, -0.048],
            [-0.003, -0.029, 0.003],
            [0.028, 0.039, -0.067],
            [-0.053, 0.104, 0.028],
            [-0.012, 0.041, -0.038],
            [0.060, -0.014, -0.011],
            [0.011, -0.004, 0.062],
        ],
    ),
}


def with_plausible_loads(model, name: str):
    """``model`` (built-in ``name``) with the link masses of :data:`LOADS` and a 1 kg payload."""
    from relcal.robot.model import with_loads

    mass, com = LOADS[name]
    return with_loads(model, np.array(mass), np.array(com), 1.0, np.array([0.0, 0.0, 0.05]))


def numeric_jacobian(problem, params: np.ndarray, h: float = 1e-7, columns=None) -> np.ndarray:
    """Central differences ``(M, len(columns))`` of the residuals at ``params`` (all columns by
    default), in the sign of :func:`relcal.calibration.measurement.residuals`' Jacobian
    (``r(p + dp) ~ r(p) - A dp``)."""
    cols = []
    for step in h * np.eye(len(params))[np.arange(len(params)) if columns is None else columns]:
        plus = residuals(problem, params + step, jacobian=False)
        minus = residuals(problem, params - step, jacobian=False)
        cols.append(-(plus - minus) / (2 * h))
    return np.stack(cols, axis=1)
