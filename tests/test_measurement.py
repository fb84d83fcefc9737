"""Residuals and Jacobians of the three measurement formulations."""

from dataclasses import replace

import numpy as np
import pytest
from helpers_sim import make_problem, measured_poses, numeric_jacobian

from relcal import geometry as tf
from relcal.calibration.measurement import make_pairs, residuals


def test_pairing_strategies():
    assert make_pairs(5).tolist() == [[0, 1], [1, 2], [2, 3], [3, 4]]
    assert make_pairs(4, "star", reference=2).tolist() == [[2, 0], [2, 1], [2, 3]]
    assert len(make_pairs(6, "all")) == 15
    with pytest.raises(ValueError, match="pairing: unknown str .ring."):
        make_pairs(3, "ring")


@pytest.mark.parametrize("formulation", ["absolute", "published", "invariant"])
@pytest.mark.parametrize("measure", ["position", "pose"])
def test_residual_jacobian_matches_finite_differences(formulation, measure, a465, rng):
    problem, truth = make_problem(a465, formulation, measure, rng, n_poses=8)
    n_geo = problem.layout.size
    # the hand-eye 6-vector far from its guess (5 mm, 3 deg): the columns are per unit change
    # of the vector, exact anywhere
    truth[n_geo:] = [0.005, -0.003, 0.004, 0.05, -0.03, 0.04][: len(truth) - n_geo]
    problem = replace(problem, poses=measured_poses(problem, truth, problem.q))
    r, jac = residuals(problem, truth)
    assert np.abs(r).max() < 1e-12
    assert jac.shape == (problem.n_residuals(), problem.full_layout.size)
    np.testing.assert_allclose(jac, numeric_jacobian(problem, truth), atol=1e-7)


def test_invariant_residual_ignores_board_and_base_rotation(a465, rng):
    problem, truth = make_problem(a465, "invariant", "pose", rng, n_poses=10)
    moved = tf.from_vector(rng.normal(0, 1, 6)) @ problem.poses
    r0 = residuals(problem, truth, jacobian=False)
    r1 = residuals(replace(problem, poses=moved), truth, jacobian=False)
    np.testing.assert_allclose(r0, r1, atol=1e-12)
    spun = truth.copy()
    spun[0] += 0.3  # theta_off[1]: a rotation of the whole arm about the base axis
    np.testing.assert_allclose(residuals(problem, spun, jacobian=False), r0, atol=1e-12)
