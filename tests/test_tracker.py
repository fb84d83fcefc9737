"""The tracker formulation: points p = T F(q) m with the instrument transform T and the marker m
unknown (laser tracker reflector, motion-capture marker)."""

from dataclasses import replace

import numpy as np
import pytest
from conftest import random_q
from helpers_sim import numeric_jacobian, true_errors

from relcal import geometry as tf
from relcal.calibration.handeye import solve_instrument
from relcal.calibration.identifiability import analyse_problem
from relcal.calibration.identify import identify
from relcal.calibration.measurement import Problem, residuals
from relcal.robot.kinematics import apply_errors, fk, make_layout
from relcal.robot.loading import get_robot
from relcal.robot.model import auto_hayati

INSTRUMENT = tf.from_vector(np.array([1.2, -0.4, 0.3, 0.1, -0.2, 2.5]))  # instrument-from-base
MARKER = np.array([0.01, -0.02, 0.12])  # in the flange frame, m


def points(model, layout, errors, q, instrument=INSTRUMENT, marker=MARKER):
    """What the tracker measures, ``(N, 4, 4)`` with the point in the translation."""
    flange = fk(apply_errors(model, layout, errors), q)
    out = np.broadcast_to(np.eye(4), (len(q), 4, 4)).copy()
    out[:, :3, 3] = (flange[:, :3, :3] @ marker + flange[:, :3, 3]) @ instrument[:3, :3].T
    out[:, :3, 3] += instrument[:3, 3]
    return out


def tracker_problem(model, rng, n=40, noise=0.0, guess_error=True):
    layout = make_layout(model)
    truth = true_errors(layout, rng)
    q = random_q(model, n, rng)
    measured = points(model, layout, truth, q)
    measured[:, :3, 3] += rng.normal(0, noise, (n, 3)) if noise else 0.0
    # Guesses a few mm and a degree or so off (a real instrument guess comes from
    # solve_instrument, tested below).
    delta = np.array([3e-3, -2e-3, 4e-3, 0.01, -0.02, 0.015]) if guess_error else np.zeros(6)
    problem = Problem(
        model,
        layout,
        q,
        measured,
        "tracker",
        "position",
        instrument=INSTRUMENT @ tf.from_vector(delta),
        marker=MARKER + (np.array([2e-3, 1e-3, -3e-3]) if guess_error else 0.0),
    )
    return problem, truth


@pytest.fixture
def fr3():
    return auto_hayati(get_robot("franka_fr3"))


def test_jacobian_matches_finite_differences(a465, rng):
    problem, truth = tracker_problem(a465, rng, n=8)
    # T far from its guess (5 mm, 3 deg): the columns are per unit change of its 6-vector
    instrument = np.array([0.005, -0.003, 0.004, 0.05, -0.03, 0.04])
    params = np.concatenate([truth, instrument, rng.normal(0, 1e-3, 3)])
    r, jac = residuals(problem, params)
    assert jac.shape == (3 * 8, problem.full_layout.size) == (problem.n_residuals(), len(params))
    np.testing.assert_allclose(jac, numeric_jacobian(problem, params), atol=1e-7)


def test_residual_is_zero_at_the_truth(a465, rng):
    problem, truth = tracker_problem(a465, rng, n=10, guess_error=False)
    params = np.concatenate([truth, np.zeros(9)])
    assert np.abs(residuals(problem, params, jacobian=False)).max() < 1e-12


def test_base_motion_is_named_as_absorbed_by_the_instrument(fr3, rng):
    problem, _ = tracker_problem(fr3, rng, n=30)
    ident = analyse_problem(problem)
    texts = [c.describe() for c in ident.combinations]
    reasons = " | ".join(texts)
    # The FR3's first joint axis is the base z axis: its offset and d[1] move the base rigidly.
    # The FR3's first joint (modified DH) sits on the base: its four parameters move the base
    # rigidly; the last joint's offset and d only turn the marker about, or slide it along, the
    # flange axis, by a constant amount in the flange frame.
    base = {"theta_off[1]", "a[1]", "d[1]", "alpha[1]"}
    by_t = [t for t in texts if "instrument-to-base transform T absorbs it" in t]
    by_m = [t for t in texts if "m absorbs it" in t]
    assert {t.split()[0] for t in by_t} == base, reasons
    assert {t.split()[0] for t in by_m} == {"theta_off[7]", "d[7]"}, reasons
    assert len(texts) == 6, reasons
    # T and m themselves are estimated whole (the pivoting prefers them over link parameters).
    kinds = problem.full_layout.kinds
    extra = [k for k, kind in enumerate(kinds) if kind in ("instrument", "marker")]
    assert set(extra) <= set(ident.subset.tolist())


def test_planted_errors_recovered_without_noise(fr3, rng):
    problem, truth = tracker_problem(fr3, rng, n=40)
    result = identify(problem)
    assert result.converged
    # Every identifiable combination is recovered: new noise-free points are predicted exactly,
    # and the instrument transform and the marker are found.
    q_new = random_q(fr3, 30, rng)
    fresh = replace(problem, q=q_new, poses=points(fr3, problem.layout, truth, q_new))
    assert np.abs(residuals(fresh, result.params, jacobian=False)).max() < 1e-9
    ok = result.identifiable[: problem.layout.size]
    np.testing.assert_allclose(result.params[: problem.layout.size][ok], truth[ok], atol=1e-9)
    assert ok.sum() >= problem.layout.size - 6  # only base-like combinations are left out


def test_guess_of_instrument_and_marker(fr3, rng):
    q = random_q(fr3, 30, rng)
    flange = fk(fr3, q)
    measured = points(fr3, make_layout(fr3), np.zeros(make_layout(fr3).size), q)
    instrument, marker = solve_instrument(flange, measured[:, :3, 3])
    np.testing.assert_allclose(instrument, INSTRUMENT, atol=1e-9)
    np.testing.assert_allclose(marker, MARKER, atol=1e-9)
