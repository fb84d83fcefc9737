"""Forward kinematics against explicit DH products, and the analytic parameter Jacobian against
finite differences, for standard and modified DH, with Hayati's beta, base and tool."""

from dataclasses import replace

import numpy as np
import pytest
from conftest import random_q

from relcal import geometry as tf
from relcal.robot.kinematics import apply_errors, fk, forward_frames, make_layout, pose_jacobian
from relcal.robot.loading import get_robot
from relcal.robot.model import auto_hayati


def trans(x=0.0, y=0.0, z=0.0):
    t = np.eye(4)
    t[:3, 3] = (x, y, z)
    return t


def rot(axis, angle):
    c, s = np.cos(angle), np.sin(angle)
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    r = np.eye(4)
    r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
    return r


def explicit_fk(model, q):
    """The DESIGN.md product written out element by element, one configuration."""
    t = model.base.copy()
    for i in range(model.n_joints):
        theta = model.theta_off[i] + (0 if model.prismatic[i] else q[i])
        d = model.d[i] + (q[i] if model.prismatic[i] else 0)
        if model.convention == "dh":
            a = rot("z", theta) @ trans(z=d) @ trans(x=model.a[i]) @ rot("x", model.alpha[i])
            a = a @ rot("y", model.beta[i])
        else:
            a = rot("x", model.alpha[i]) @ rot("y", model.beta[i]) @ trans(x=model.a[i])
            a = a @ rot("z", theta) @ trans(z=d)
        t = t @ a
    return t @ model.tool


def perturbed(model, rng):
    """A model with random base, tool, betas and a prismatic joint, to exercise every branch."""
    n = model.n_joints
    prismatic = np.zeros(n, dtype=bool)
    prismatic[2] = True
    return replace(
        model,
        beta=rng.normal(0, 0.1, n),
        prismatic=prismatic,
        base=tf.from_vector(rng.normal(0, 0.3, 6)),
        tool=tf.from_vector(rng.normal(0, 0.3, 6)),
    )


@pytest.mark.parametrize("name", ["a465", "franka_fr3"])
def test_fk_matches_explicit_product(name, rng):
    model = perturbed(get_robot(name), rng)
    q = rng.uniform(-2, 2, (7, model.n_joints))
    poses = fk(model, q)
    for k in range(len(q)):
        np.testing.assert_allclose(poses[k], explicit_fk(model, q[k]), atol=1e-12)
    np.testing.assert_allclose(forward_frames(model, q)[:, -1] @ model.tool, poses, atol=1e-12)


def test_a465_zero_configuration_by_hand(a465):
    # q = 0, following the axes by hand: A1 = Tz(.33) Rx(90) turns z1 to -y0; A2 = Tx(.303) moves
    # to (.303, 0, .33); A3 = Rx(90) turns z3 to -z0; A4 = Tz(.33) Rx(-90) goes down to z = 0 and
    # turns z4 to -y0; A5 = Rx(90) turns z5 to -z0; A6 = Tz(.076) ends at z = -0.076.
    pose = fk(a465, np.zeros((1, 6)))[0]
    np.testing.assert_allclose(pose[:3, 3], [0.303, 0.0, -0.076], atol=1e-12)
    np.testing.assert_allclose(pose[:3, 2], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(pose[:3, 0], [1, 0, 0], atol=1e-12)


def numeric_jacobian(model, q, layout, h=1e-6):
    """Central differences of position and of the base-frame small rotation."""
    base = fk(model, q)
    out = np.empty((len(q), 6, layout.size))
    for k in range(layout.size):
        e = np.zeros(layout.size)
        e[k] = h
        plus, minus = fk(apply_errors(model, layout, e), q), fk(apply_errors(model, layout, -e), q)
        out[:, :3, k] = (plus[:, :3, 3] - minus[:, :3, 3]) / (2 * h)
        d_rot = (plus[:, :3, :3] - minus[:, :3, :3]) / (2 * h) @ np.swapaxes(base[:, :3, :3], 1, 2)
        out[:, 3:, k] = np.stack([d_rot[:, 2, 1], d_rot[:, 0, 2], d_rot[:, 1, 0]], axis=-1)
    return out


@pytest.mark.parametrize("name", ["a465", "franka_fr3"])
def test_jacobian_matches_finite_differences(name, rng):
    model = perturbed(auto_hayati(get_robot(name)), rng)
    if not model.hayati.any():  # the FR3 has no parallel axes: exercise a modified-DH beta anyway
        model = replace(model, hayati=np.arange(model.n_joints) == 3)
    layout = make_layout(model, base=True, tool=True)
    q = random_q(model, 6, rng)
    pose, jac = pose_jacobian(model, q, layout)
    np.testing.assert_allclose(pose, fk(model, q), atol=1e-12)
    np.testing.assert_allclose(jac, numeric_jacobian(model, q, layout), atol=1e-8)


def test_layout_order_and_hayati(a465):
    layout = make_layout(a465)
    assert layout.names[:7] == (*[f"theta_off[{i}]" for i in range(1, 7)], "a[1]")
    assert layout.size == 24
    hay = make_layout(auto_hayati(a465))
    assert "beta[2]" in hay.names and "d[2]" not in hay.names and hay.size == 24


def test_fk_of_one_configuration_is_one_pose(a465, rng):
    """``fk`` of ``(n,)`` is ``(4, 4)``; of ``(N, n)`` it stays ``(N, 4, 4)``, even for N = 1."""
    q = rng.uniform(-1, 1, (3, 6))
    batch = fk(a465, q)
    assert batch.shape == (3, 4, 4)
    assert fk(a465, q[:1]).shape == (1, 4, 4)
    one = fk(a465, q[1])
    assert one.shape == (4, 4)
    np.testing.assert_array_equal(one, batch[1])
    assert fk(a465, list(q[2])).shape == (4, 4)
