"""Inverse kinematics: FK(IK(T)) = T, all closed-form branches, limits, calibrated chains."""

from dataclasses import replace

import numpy as np
import pytest
from conftest import random_q

from relcal import geometry as tf
from relcal.errors import RelcalError
from relcal.robot import ik
from relcal.robot.kinematics import apply_errors, fk, make_layout, pose_jacobian
from relcal.robot.loading import get_robot
from relcal.robot.model import auto_hayati

LIBRARY = ["a465", "puma560", "ur5e", "franka_fr3", "irb120"]
CLOSED_FORM = ["a465", "puma560", "irb120"]
TOL = 1e-9


def assert_reaches(model, q, targets, tol=TOL):
    err = tf.pose_error(targets, fk(model, np.atleast_2d(q)))
    assert np.abs(err).max() < tol


def perturbed(name, rng, scale=1e-3):
    """A calibrated-looking model: Hayati on parallel axes, all parameters off by ~1 mm / mrad."""
    nominal = auto_hayati(get_robot(name))
    layout = make_layout(nominal, base=True, tool=True)
    model = apply_errors(nominal, layout, rng.normal(0, scale, layout.size))
    return replace(model, name=f"{name} (perturbed)")


def general_spherical_arm(rng):
    """A 6R arm with the closed-form structure but no convenient numbers: odd twists, offsets,
    antiparallel joints 2-3, betas that keep the wrist spherical, a base and a tool."""
    base = get_robot("puma560")
    return replace(
        base,
        name="odd arm",
        theta_off=rng.uniform(-np.pi, np.pi, 6),
        d=np.array([0.4, 0.05, -0.12, 0.5, 0.0, 0.09]),
        a=np.array([0.15, 0.6, 0.08, 0.0, 0.0, 0.03]),
        alpha=np.radians([70.0, 180.0, -80.0, 100.0, -60.0, 20.0]),
        beta=np.radians([5.0, 0.0, -7.0, 4.0, 3.0, 9.0]),
        lower=np.full(6, -np.pi),
        upper=np.full(6, np.pi),
        base=tf.from_xyz_rpy(np.array([0.1, -0.2, 0.3]), np.array([0.2, -0.1, 0.4])),
        tool=tf.from_xyz_rpy(np.array([0.01, 0.02, 0.15]), np.array([0.3, 0.2, -0.5])),
    )


# --- closed form -------------------------------------------------------------------------------


def check_all_branches(model, q):
    targets = fk(model, q)
    for qi, target in zip(q, targets, strict=True):
        sols = ik.solve_closed_form(model, target)
        assert 1 <= len(sols) <= 8
        assert ik.within_limits(model, sols).all()
        assert_reaches(model, sols, np.repeat(target[None], len(sols), 0))
        gap = np.abs(ik.wrap_angle(sols - qi)).max(axis=1)
        assert gap.min() < 1e-7, "the generating configuration is among the solutions"


@pytest.mark.parametrize("name", CLOSED_FORM)
def test_closed_form_finds_every_branch(name, rng):
    model = get_robot(name)
    check_all_branches(model, random_q(model, 40, rng))


def test_closed_form_handles_offsets_twists_base_and_tool(rng):
    model = general_spherical_arm(rng)
    assert ik.closed_form_problem(model) is None
    check_all_branches(model, rng.uniform(-np.pi, np.pi, (40, 6)))


def test_closed_form_returns_eight_branches_for_a_dextrous_puma_pose():
    model = get_robot("puma560")
    target = fk(model, np.array([[0.3, 0.2, 0.4, 0.5, 0.6, 0.7]]))[0]
    sols = ik.solve_closed_form(model, target, respect_limits=False)
    assert len(sols) == 8
    assert_reaches(model, sols, np.repeat(target[None], 8, 0))
    assert np.all(np.abs(sols) <= np.pi)


@pytest.mark.parametrize("name", ["ur5e", "franka_fr3"])
def test_closed_form_refuses_robots_without_spherical_wrist(name):
    model = get_robot(name)
    target = fk(model, np.zeros((1, model.n_joints)))[0]
    with pytest.raises(RelcalError, match="no closed-form inverse kinematics"):
        ik.solve_closed_form(model, target)


def test_closed_form_refuses_a_calibrated_wrist(rng):
    model = perturbed("a465", rng)
    assert not ik.has_spherical_wrist(model)
    with pytest.raises(RelcalError, match="do not meet in one point"):
        ik.solve_closed_form(model, fk(model, np.zeros((1, 6)))[0])


def test_closed_form_limit_filter():
    model = get_robot("a465")  # wrist 2 limited to +-105 deg; the flipped wrist needs -120
    q = np.radians([[20.0, 30.0, 40.0, 10.0, 120.0, 30.0]])
    target = fk(model, q)[0]
    kept = ik.solve_closed_form(model, target)
    every = ik.solve_closed_form(model, target, respect_limits=False)
    assert ik.within_limits(model, kept).all()
    assert len(every) > len(kept)
    assert np.abs(ik.wrap_angle(every - q)).max(axis=1).min() < 1e-7
    assert not ik.within_limits(model, every).all()


# --- numeric -----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", LIBRARY + ["a465 perturbed", "franka_fr3 perturbed"])
def test_numeric_round_trip_from_nearby_seed(name, rng):
    model = perturbed(name.split()[0], rng) if "perturbed" in name else get_robot(name)
    q = random_q(model, 40, rng)
    targets = fk(model, q)
    res = ik.solve_numeric(model, targets, q + rng.normal(0, 0.05, q.shape))
    assert res.converged.all()
    assert ik.within_limits(model, res.q).all()
    assert_reaches(model, res.q, targets)


def test_joint_jacobian_matches_finite_differences(rng):
    for name in ("franka_fr3", "ur5e"):
        model = get_robot(name)
        q = random_q(model, 3, rng)
        poses, jac = pose_jacobian(model, q, ik.joint_layout(model))
        h = 1e-7
        for j in range(model.n_joints):
            dq = np.zeros(model.n_joints)
            dq[j] = h
            numeric = tf.pose_error(fk(model, q + dq), poses) / h
            np.testing.assert_allclose(numeric, jac[:, :, j], atol=1e-6)


def test_numeric_respects_joint_limits(rng):
    for name in LIBRARY:
        model = get_robot(name)
        q = random_q(model, 20, rng)
        wild = rng.uniform(-2 * np.pi, 2 * np.pi, q.shape)  # mostly outside the limits
        res = ik.solve_numeric(model, fk(model, q), wild, max_iter=30)
        assert ik.within_limits(model, res.q).all()


def test_numeric_reports_a_pose_reachable_only_beyond_the_limits():
    model = get_robot("a465")
    q = np.radians([[20.0, 30.0, 40.0, 10.0, 120.0, 30.0]])  # wrist 2 beyond +-105 deg
    res = ik.solve_numeric(model, fk(model, q)[0], np.radians([20, 30, 40, 10, 100, 30]))
    assert not res.converged
    assert res.position_error + res.rotation_error > 1e-4
    assert ik.within_limits(model, res.q)


def test_single_target_gives_unbatched_result(a465):
    res = ik.solve_numeric(a465, fk(a465, np.full((1, 6), 0.3))[0], np.full(6, 0.25))
    assert res.q.shape == (6,) and res.converged.shape == () and bool(res.converged)


# --- combined ----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", LIBRARY + ["a465 perturbed", "puma560 perturbed"])
def test_solve_round_trip(name, rng):
    model = perturbed(name.split()[0], rng) if "perturbed" in name else get_robot(name)
    q = random_q(model, 40, rng)
    targets = fk(model, q)
    near = q + rng.normal(0, 0.3, q.shape)
    res = ik.solve(model, targets, near)
    assert res.converged.all()
    assert ik.within_limits(model, res.q).all()
    assert_reaches(model, res.q, targets)


@pytest.mark.parametrize("name", CLOSED_FORM)
def test_solve_picks_the_branch_nearest_q_near(name, rng):
    model = get_robot(name)
    q = random_q(model, 30, rng)
    near = q + rng.normal(0, 0.3, q.shape)
    res = ik.solve(model, fk(model, q), near)
    own = ik.nearest_equivalent(model, q, near)
    assert np.all(np.linalg.norm(res.q - near, axis=1) <= np.linalg.norm(own - near, axis=1) + 1e-9)
    assert res.iterations.max() == 0  # exact closed form needs no refinement


def test_solve_seeds_a_calibrated_arm_from_its_nominal_closed_form(rng):
    model = perturbed("irb120", rng)
    assert ik.closed_form_problem(model) is not None
    assert ik.idealised(model) is not None
    q = random_q(model, 30, rng)
    targets = fk(model, q)
    far = np.zeros_like(q)  # branches, not the seed, bring it there
    res = ik.solve(model, targets, far, seed_model=get_robot("irb120"))
    assert res.converged.all()
    assert_reaches(model, res.q, targets)


@pytest.mark.parametrize("name", ["ur5e", "franka_fr3"])
def test_solve_without_closed_form_uses_restarts(name, rng):
    model = get_robot(name)
    q = random_q(model, 30, rng)
    targets = fk(model, q)
    res = ik.solve(model, targets)  # from the default q_near, far from most targets
    assert res.converged.mean() >= 0.9
    assert_reaches(model, res.q[res.converged], targets[res.converged])
    assert ik.within_limits(model, res.q).all()
