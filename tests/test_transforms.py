"""Closed-form rotation-vector conversions against SciPy's ``Rotation``, including the hard
cases: the identity, tiny angles, angles near and at pi, and batches of any leading shape."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from relcal import geometry as tf


def unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@pytest.fixture
def rotvecs(rng):
    axes = unit(rng.normal(size=(500, 3)))
    return np.concatenate(
        [
            Rotation.random(2000, random_state=7).as_rotvec(),
            axes * rng.uniform(0, 1e-9, (500, 1)),  # tiny
            axes * rng.uniform(1e-6, 1e-3, (500, 1)),  # small, around the series switch
            axes * (np.pi / 2 + rng.uniform(-1e-9, 1e-9, (500, 1))),  # branch switch at 90 deg
            axes * (np.pi - rng.uniform(0, 1e-6, (500, 1))),  # close to pi
            axes * np.pi,  # pi: axis sign is arbitrary
            np.zeros((1, 3)),
            np.eye(3) * np.pi,
        ]
    )


def test_exp_rotation_matches_scipy(rotvecs):
    np.testing.assert_allclose(
        tf.exp_rotation(rotvecs), Rotation.from_rotvec(rotvecs).as_matrix(), rtol=0, atol=2e-15
    )


def test_log_rotation_inverts_exp(rotvecs):
    matrices = Rotation.from_rotvec(rotvecs).as_matrix()
    back = tf.log_rotation(matrices)
    assert np.all(np.linalg.norm(back, axis=-1) <= np.pi + 1e-15)
    # Same rotation to round-off (at pi, w and -w are the same rotation).
    error = (Rotation.from_matrix(matrices).inv() * Rotation.from_rotvec(back)).magnitude()
    assert error.max() < 4e-15
    # Same vector as SciPy where it is unique.
    reference = Rotation.from_matrix(matrices).as_rotvec()
    unique = np.linalg.norm(reference, axis=-1) < np.pi - 1e-3
    np.testing.assert_allclose(back[unique], reference[unique], rtol=0, atol=4e-15)


def test_log_of_tiny_rotation_keeps_relative_precision():
    w = np.array([3e-12, -1e-12, 2e-12])
    np.testing.assert_allclose(tf.log_rotation(tf.exp_rotation(w)), w, rtol=1e-9, atol=0)


def test_vectors_round_trip_any_shape(rng):
    vec = rng.normal(0, 0.5, (2, 3, 6))
    transforms = tf.from_vector(vec)
    assert transforms.shape == (2, 3, 4, 4)
    np.testing.assert_allclose(tf.to_vector(transforms), vec, atol=1e-14)
    assert tf.from_vector(vec[0, 0]).shape == (4, 4)
    np.testing.assert_allclose(tf.to_vector(tf.from_vector(vec[0, 0])), vec[0, 0], atol=1e-14)
    np.testing.assert_allclose(tf.from_vector(np.zeros(6)), np.eye(4), atol=0)
