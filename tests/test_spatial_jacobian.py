"""The spatial form of the parameter Jacobian against the tool-point form, and against finite
differences of ``F(p + dp) F(p)^-1``; the one-vector rotation exponential against the batch."""

from dataclasses import replace

import numpy as np
import pytest
from conftest import random_q

from relcal import geometry as tf
from relcal.robot.kinematics import apply_errors, fk, make_layout, pose_jacobian, spatial_jacobian
from relcal.robot.loading import get_robot
from relcal.robot.model import auto_hayati


def everything(model, rng):
    prismatic = np.zeros(model.n_joints, dtype=bool)
    prismatic[2] = True
    return replace(
        auto_hayati(model),
        beta=rng.normal(0, 0.05, model.n_joints),
        prismatic=prismatic,
        base=tf.from_vector(rng.normal(0, 0.3, 6)),
        tool=tf.from_vector(rng.normal(0, 0.3, 6)),
    )


@pytest.mark.parametrize("convention", ["dh", "mdh"])
def test_spatial_twists_are_tool_point_columns_moved_to_the_origin(convention, a465, rng):
    model = everything(replace(a465, convention=convention), rng)
    layout = make_layout(model, base=True, tool=True)
    q = random_q(model, 9, rng)
    tip, jac = pose_jacobian(model, q, layout)
    tip_s, spatial = spatial_jacobian(model, q, layout)
    np.testing.assert_allclose(tip_s, tip, atol=0)
    w = jac[:, 3:]
    moved = jac[:, :3] - np.cross(w, tip[:, :3, 3, None], axis=1)  # v_0 = v_tip - w x tip
    np.testing.assert_allclose(spatial[:, :3], moved, atol=1e-12)
    np.testing.assert_allclose(spatial[:, 3:], w, atol=0)


def test_spatial_twists_match_finite_differences(rng):
    model = everything(get_robot("a465"), rng)
    layout = make_layout(model, base=True, tool=True)
    q = random_q(model, 5, rng)
    poses, spatial = spatial_jacobian(model, q, layout)
    h = 1e-6
    for k in range(layout.size):
        step = np.zeros(layout.size)
        step[k] = h
        plus = fk(apply_errors(model, layout, step), q, backend="numpy")
        minus = fk(apply_errors(model, layout, -step), q, backend="numpy")
        # exp([S h]) ~ F(p + h) F(p)^-1: central difference of its 6-vector.
        twist = (tf.to_vector(plus @ tf.invert(poses)) - tf.to_vector(minus @ tf.invert(poses))) / (
            2 * h
        )
        # to_vector gives (translation, rotvec) of I + [S h]: translation = v h.
        np.testing.assert_allclose(twist, spatial[:, :, k], atol=1e-7, err_msg=layout.names[k])


def test_exp_rotation_one_vector_matches_batch(rng):
    for w in [*rng.normal(0, 1, (20, 3)), np.zeros(3), np.array([1e-6, 0, 0])]:
        np.testing.assert_allclose(tf.exp_rotation(w), tf.exp_rotation(w[None])[0], atol=1e-15)
