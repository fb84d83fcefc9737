"""Identification against known synthetic errors: exact recovery without noise, named
unidentifiable combinations, smooth degradation with noise, and the relative rank tolerance."""

from dataclasses import replace

import numpy as np
import pytest
from helpers_sim import held_out_error, make_problem, measured_poses

from relcal.calibration.identifiability import analyse_problem
from relcal.calibration.identify import SolverOptions, identify
from relcal.robot.kinematics import make_layout
from relcal.robot.model import auto_hayati

CASES = [(f, m) for f in ("published", "invariant") for m in ("position", "pose")]


MODELS = ["a465", "a465 hayati"]


@pytest.mark.parametrize("robot", MODELS)
@pytest.mark.parametrize(("formulation", "measure"), CASES)
def test_noise_free_recovery(robot, formulation, measure, a465, rng):
    # Every direction held at nominal is either an exact symmetry (a rigid motion of the base, a
    # change of the tool or hand-eye transform) or one of the nominal model only, which the data
    # determine at the estimate and the fit then estimates (d[2] - d[3] of the A465's parallel
    # axes, which the planted twists tilt apart; in the base frame, position only, the flange
    # point's first-order-only symmetries): noise-free data are fitted to round-off.
    model = auto_hayati(a465) if robot.endswith("hayati") else a465
    problem, truth = make_problem(model, formulation, measure, rng)
    for method in ("published", "lm"):
        result = identify(problem, SolverOptions(method=method))
        assert result.converged
        assert result.residual_norm < 1e-12
        ok = result.identifiable
        # The parallel pair's d are told apart only by the twist between the axes (0.065 deg
        # here): round-off of metre-sized poses over that, tenths of a nanometre at most.
        pair = np.isin(result.names, ["d[2]", "d[3]"])
        rest = ok & ~pair
        rel = np.linalg.norm(result.params[rest] - truth[rest]) / np.linalg.norm(truth[rest])
        assert rel < 1e-9
        assert np.abs(result.params[ok & pair] - truth[ok & pair]).max(initial=0) < 1e-10
        # Every identifiable combination is recovered: the estimate predicts held-out relative
        # measurements exactly, whatever the truth does along the unidentifiable directions.
        assert held_out_error(problem, result.params, truth, rng) < 1e-12
        held = np.setdiff1d(np.arange(len(truth)), result.identifiability.subset)
        assert not np.any(result.params[held])  # held at nominal, never a minimum-norm split
        if robot == "a465":  # the parallel pair: one of it estimated too, both identified
            assert set(result.identifiability.determined) & {"d[2]", "d[3]"}
            assert ok[pair].all()


@pytest.mark.parametrize(("formulation", "measure"), CASES)
def test_unidentifiable_combinations_are_named(formulation, measure, a465, rng):
    # With noise (10 um, 10 urad) the data do not determine d[2] - d[3] (its standard
    # deviation grows as one over the twist between the axes): held, and named.
    problem, truth = make_problem(a465, formulation, measure, rng, noise=1e-5)
    result = identify(problem, SolverOptions(method="published"))
    assert result.converged
    assert not {"d[2]", "d[3]"} & set(result.identifiability.determined)
    ok = result.identifiable
    # The unidentifiable ones are named, never silently reported as identified.
    text = "\n".join(result.unidentifiable)
    assert "d[1]" in text and "rigid motion of the robot base" in text
    pair = [c for c in result.identifiability.combinations if set(c.names) == {"d[2]", "d[3]"}]
    assert len(pair) == 1 and "parallel axes of joints 2, 3" in pair[0].reason
    # Only the sum is identifiable: the null direction is d[2] - d[3].
    assert pair[0].coefficients[0] == pytest.approx(-pair[0].coefficients[1])
    assert not ok[list(result.names).index("d[2]")] and not ok[list(result.names).index("d[1]")]
    if formulation == "invariant":
        assert "theta_off[1]: acts as a rigid motion" in text
        assert sum("hand-eye transform X" in c for c in result.unidentifiable) == 4
    # Both solvers hold the same directions and reach the same estimate.
    lm = identify(problem)
    assert 0.5 * result.residual_norm**2 == pytest.approx(0.5 * lm.residual_norm**2, rel=1e-6)
    assert np.abs(result.params - lm.params).max() < 1e-8


@pytest.mark.parametrize("measure", ["position", "pose"])
def test_a_symmetry_of_the_truth_is_never_estimated(measure, a465, rng):
    # Planted errors that keep axes 2 and 3 parallel (no twist between them): d[2] - d[3] is
    # then a symmetry of the truth too, which no data determine; it stays held and named, and
    # the noise-free fit is still exact.
    problem, truth = make_problem(a465, "published", measure, rng)
    truth[list(problem.full_layout.names).index("alpha[2]")] = 0.0
    problem = replace(problem, poses=measured_poses(problem, truth, problem.q))
    result = identify(problem, SolverOptions(method="published"))
    assert result.converged and result.residual_norm < 1e-12
    assert not {"d[2]", "d[3]"} & set(result.identifiability.determined)
    assert any(set(c.names) == {"d[2]", "d[3]"} for c in result.identifiability.combinations)
    assert held_out_error(problem, result.params, truth, rng) < 1e-12


def test_the_nominal_rank_is_kept_beside_what_the_estimate_determines(a465, rng):
    # The rank and the singular values stay those of the nominal model (what the reports show
    # against the singular values); the subset counts what the estimate determines as well.
    problem, _ = make_problem(a465, "published", "pose", rng)
    nominal = analyse_problem(problem)
    result = identify(problem)
    ident = result.identifiability
    assert ident.rank == nominal.rank and len(ident.subset) == nominal.rank + 1
    np.testing.assert_array_equal(ident.singular_values, nominal.singular_values)
    assert ident.determined == ("d[3]",)
    assert problem.full_layout.names.index("d[3]") not in nominal.subset


def test_levenberg_marquardt_on_the_identifiable_subset(a465, rng):
    problem, truth = make_problem(auto_hayati(a465), "invariant", "pose", rng)
    truth_lm = identify(problem)
    truth_p = identify(problem, SolverOptions(method="published"))
    assert truth_lm.converged and truth_lm.residual_norm < 1e-10
    ok = truth_lm.identifiable
    np.testing.assert_allclose(truth_lm.params[ok], truth_p.params[ok], atol=1e-9)
    assert held_out_error(problem, truth_lm.params, truth, rng) < 1e-10


def test_hayati_beta_resolves_the_parallel_pair(a465, rng):
    problem, _ = make_problem(a465, "invariant", "pose", rng)
    plain = analyse_problem(problem)
    hay_model = auto_hayati(a465)
    cured = analyse_problem(replace(problem, model=hay_model, layout=make_layout(hay_model)))
    assert any("parallel axes" in c.reason for c in plain.combinations)
    assert not any("parallel axes" in c.reason for c in cured.combinations)
    assert cured.rank == plain.rank + 1  # beta[2] is identifiable, d[2] is gone


def test_relative_rank_tolerance_catches_nearly_parallel_axes(a465, rng):
    # Axes 1 urad from parallel: d[2] - d[3] moves the camera at second order, a singular value
    # about 1e-12 of the largest (it scales with the square of the misalignment).
    near = a465.with_values(alpha=a465.alpha + np.array([0, 1e-6, 0, 0, 0, 0]))
    problem, _ = make_problem(near, "invariant", "pose", rng)
    relative = analyse_problem(problem)
    assert any("d[2]" in c.names and "d[3]" in c.names for c in relative.combinations)
    absolute_eps = analyse_problem(problem, rcond=np.finfo(float).eps)
    # Machine epsilon counts the nearly parallel pair as rank (and round-off, at times).
    assert absolute_eps.rank > relative.rank


def test_identified_errors_degrade_smoothly_with_noise(a465):
    hay = auto_hayati(a465)
    levels = [1e-6, 1e-5, 1e-4]  # m and rad per measurement
    errors = []
    for noise in levels:
        rms = []
        for seed in range(4):
            problem, truth = make_problem(
                hay, "invariant", "pose", np.random.default_rng(seed), n_poses=40, noise=noise
            )
            result = identify(problem)
            ok = result.identifiable
            scale = result.identifiability.column_norms[ok]
            rms.append(np.sqrt(np.mean(((result.params[ok] - truth[ok]) * scale) ** 2)))
        errors.append(np.mean(rms))
    ratios = np.array(errors[1:]) / np.array(errors[:-1])
    # Linear in the noise: ten times the noise, about ten times the error.
    assert np.all((ratios > 5) & (ratios < 20)), (errors, ratios)


def test_deferred_results_pickle_with_their_values(a465, rng):
    # The null-space naming and the Cramer-Rao bound are computed on first read; a result sent
    # to another process (a fleet's workers) carries their values, not the closures that
    # compute them (which do not pickle).
    import pickle

    from relcal.calibration.noise import Noise
    from relcal.calibration.uncertainty import parameter_covariance

    problem, _ = make_problem(a465, "invariant", "pose", rng)
    fresh = analyse_problem(problem)
    copied = pickle.loads(pickle.dumps(fresh))
    assert [c.describe() for c in copied.combinations] == [
        c.describe() for c in analyse_problem(problem).combinations
    ]
    np.testing.assert_array_equal(copied.null_space, fresh.null_space)
    unc = parameter_covariance(problem, Noise(1e-4, 1e-4), identifiability=fresh)
    copied = pickle.loads(pickle.dumps(unc))
    np.testing.assert_array_equal(copied.crb, unc.crb)


def test_equivalent_parameters_are_held_the_same_way_whatever_the_round_off(a465, rng):
    # Two parameters the data see exactly alike (here two equal Jacobian columns): which one is
    # estimated must not depend on the last digit of the Jacobian (another BLAS, another order
    # of the same products), or one calibration estimates the first and the next, of the same
    # data, the second: the earlier in the layout is estimated, the other held.
    from relcal.calibration.identifiability import analyse

    layout = make_layout(a465).extended("handeye")
    jac = rng.normal(size=(200, layout.size))
    first, second = layout.names.index("handeye.ty"), layout.names.index("handeye.rx")
    for _ in range(20):  # the second column off the first by round-off, in some direction
        jac[:, second] = jac[:, first] + 1e-15 * rng.normal(size=len(jac))
        ident = analyse(jac, layout)
        assert ident.rank == layout.size - 1
        assert first in ident.subset and second not in ident.subset
