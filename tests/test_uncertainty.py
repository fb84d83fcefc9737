"""Noise propagation to relative measurements, parameter covariance (least squares and the
Cramer-Rao bound), per-pose information, correlation and predicted accuracy."""

from dataclasses import replace

import numpy as np
import pytest
import scipy.optimize
from conftest import random_q
from helpers_sim import make_problem, numeric_jacobian

from relcal import geometry as tf
from relcal.calibration.identifiability import analyse_problem
from relcal.calibration.identify import identify
from relcal.calibration.measurement import make_pairs, residuals
from relcal.calibration.noise import Noise
from relcal.calibration.uncertainty import (
    body_covariance,
    eliminate,
    joint_map,
    noise_map,
    parameter_covariance,
    pose_rows,
    predicted_accuracy,
)
from relcal.errors import RelcalError
from relcal.geometry import DEG, MM
from relcal.reporting.documents import accuracy_document
from relcal.robot.model import auto_hayati
from relcal.sim.scenario import clean_poses, make_scenario, measure_once, problem_for

NOISE = Noise(0.05 * MM, 0.01 * DEG, 0.002 * DEG)
CASES = [
    ("invariant", "pose"),
    ("invariant", "position"),
    ("published", "pose"),
    ("published", "position"),
    ("absolute", "pose"),
]


@pytest.fixture
def hayati(a465):
    return auto_hayati(a465)


@pytest.mark.parametrize(("formulation", "measure"), CASES)
def test_noise_map_is_the_first_order_effect_of_pose_errors(hayati, rng, formulation, measure):
    problem, truth = make_problem(hayati, formulation, measure, rng, n_poses=8)
    problem = replace(problem, pairs=make_pairs(8, "all"), weights=np.array([1, 2, 3, 4, 5, 6.0]))
    eps = rng.normal(0, 1e-7, (8, 6))
    if formulation == "invariant":  # camera-frame errors of C = W F X
        moved = problem.poses @ tf.from_vector(eps)
    else:  # base-frame errors at the tool point
        moved = problem.poses.copy()
        moved[:, :3, 3] += eps[:, :3]
        moved[:, :3, :3] = (
            tf.from_vector(np.c_[np.zeros((8, 3)), eps[:, 3:]])[:, :3, :3]
            @ (problem.poses[:, :3, :3])
        )
    before = residuals(problem, truth, jacobian=False)
    after = residuals(replace(problem, poses=moved), truth, jacobian=False)
    predicted = noise_map(problem, truth) @ eps.ravel()
    assert np.abs(after - before - predicted).max() < 1e-6 * np.abs(predicted).max()


@pytest.mark.parametrize("formulation", ["invariant", "published"])
def test_joint_errors_act_through_the_joint_jacobian(hayati, rng, formulation):
    problem, truth = make_problem(hayati, formulation, "pose", rng, n_poses=6)
    eta = rng.normal(0, 1e-7, problem.q.shape)
    before = residuals(problem, truth, jacobian=False)
    after = residuals(replace(problem, q=problem.q + eta), truth, jacobian=False)
    moved = np.einsum("nij,nj->ni", joint_map(problem, truth), eta)  # modelled pose moves
    predicted = -noise_map(problem, truth) @ moved.ravel()
    assert np.abs(after - before - predicted).max() < 1e-6 * np.abs(predicted).max()


def test_right_jacobian_and_body_covariance(rng):
    phi = np.array([0.3, -1.1, 0.7])
    dphi = rng.normal(0, 1e-7, 3)
    r0 = tf.from_vector(np.r_[0, 0, 0, phi])
    r1 = tf.from_vector(np.r_[0, 0, 0, phi + dphi])
    body = tf.to_vector(tf.invert(r0) @ r1)[3:]
    np.testing.assert_allclose(body, tf.right_jacobian(phi) @ dphi, rtol=1e-6, atol=1e-14)
    # A covariance given on to_vector(C) maps to the body frame used by the propagation.
    vec = np.array([0.4, 0.1, 0.3, 0.3, -1.1, 0.7])
    pose = tf.from_vector(vec)
    cov = np.diag([1e-8, 2e-8, 3e-8, 1e-7, 2e-7, 3e-7])
    samples = rng.multivariate_normal(np.zeros(6), cov, 4000) * 1e-2  # small: linear regime
    errors = tf.to_vector(tf.invert(pose) @ tf.from_vector(vec + samples))
    expected = body_covariance(pose[None], cov[None] * 1e-4)[0]
    np.testing.assert_allclose(np.cov(errors.T), expected, rtol=0.1, atol=0.05 * expected.max())


@pytest.mark.parametrize(("formulation", "measure"), [c for c in CASES if c[1] == "pose"])
def test_cramer_rao_bound_does_not_depend_on_pairing_or_order(hayati, rng, formulation, measure):
    problem, _ = make_problem(hayati, formulation, measure, rng, n_poses=15)
    ident = analyse_problem(problem)
    bounds = []
    strategies = ["consecutive"] if formulation == "absolute" else ["consecutive", "star", "all"]
    for pairing in strategies:
        p = replace(problem, pairs=make_pairs(15, pairing))
        bounds.append(parameter_covariance(p, NOISE, ident).crb)
    order = rng.permutation(15)
    shuffled = replace(problem, q=problem.q[order], poses=problem.poses[order])
    bounds.append(parameter_covariance(shuffled, NOISE, ident).crb)
    # The per-pose information with the board pose eliminated gives the same bound.
    rows, h = pose_rows(problem, NOISE)
    info = eliminate(np.einsum("nri,nrj->ij", rows, rows), h)
    s = ident.subset
    bounds.append(np.linalg.inv(info[np.ix_(s, s)]))
    d = np.sqrt(np.diag(bounds[0]))
    for b in bounds[1:]:
        np.testing.assert_allclose(b / np.outer(d, d), bounds[0] / np.outer(d, d), atol=1e-9)


def _noisy(problem, rng, noise=NOISE):
    """The same measurements with noise drawn as the sensor makes it: every camera pose moved in
    its own frame, ``C exp(eps)`` (isotropic per axis), every joint reading off by ``eta``."""
    n, n_joints = problem.q.shape
    sd = np.r_[np.full(3, noise.position), np.full(3, noise.orientation)]
    eps = rng.normal(0.0, 1.0, (n, 6)) * sd
    eta = rng.normal(0.0, noise.joints, (n, n_joints))
    return replace(problem, poses=problem.poses @ tf.from_vector(eps), q=problem.q + eta)


@pytest.mark.parametrize(("formulation", "measure"), CASES)
def test_covariances_match_monte_carlo_of_the_sensor_noise(hayati, rng, formulation, measure):
    """Both covariances against Monte Carlo, with nothing of the module but the residuals: the
    least-squares one against the spread of SciPy ``least_squares`` fits of noisy measurements;
    the Cramer-Rao bound against ``(A^T S^-1 A)^-1`` with ``A`` by finite differences and ``S``
    the sampled covariance of the residual noise."""
    chain, truth = make_problem(hayati, formulation, measure, rng, n_poses=12)
    # row factors of the order of 1 / noise (m, rad), unequal per axis
    weights = np.array([2000.0, 1000.0, 3000.0, 500.0, 400.0, 300.0])[: chain.rows_per_measurement]
    chain = replace(chain, weights=np.resize(weights, 6))  # consecutive pairs
    problem = chain if formulation == "absolute" else replace(chain, pairs=make_pairs(12, "all"))
    ident = analyse_problem(problem)
    unc = parameter_covariance(problem, NOISE, ident, params=truth)  # linearised at the truth
    subset, size = ident.subset, problem.full_layout.size

    def fit(noisy):
        def full(x):
            out = np.zeros(size)
            out[subset] = x
            return out

        res = scipy.optimize.least_squares(
            lambda x: residuals(noisy, full(x), jacobian=False),
            truth[subset],
            jac=lambda x: -residuals(noisy, full(x))[1][:, subset],  # A is -dr/dp
            x_scale="jac",
            xtol=1e-12,
            ftol=1e-12,
        )
        return res.x

    estimates = np.array([fit(_noisy(problem, rng)) for _ in range(300)])
    empirical = np.cov(estimates.T)
    predicted = unc.least_squares
    d = np.sqrt(np.diag(predicted))
    e = np.sqrt(np.diag(empirical))
    np.testing.assert_allclose(e, d, rtol=0.2)
    np.testing.assert_allclose(empirical / np.outer(e, e), predicted / np.outer(d, d), atol=0.2)

    # The bound on consecutive pairs, whose residual noise has full rank.
    chain_ident = analyse_problem(chain)
    subset = chain_ident.subset
    crb = parameter_covariance(chain, NOISE, chain_ident, params=truth).crb
    clean = residuals(chain, truth, jacobian=False)
    noise = np.array([residuals(_noisy(chain, rng), truth, jacobian=False) for _ in range(4000)])
    sampled = np.cov((noise - clean).T)
    a = numeric_jacobian(chain, truth, columns=subset)
    bound = np.linalg.inv(a.T @ np.linalg.solve(sampled, a))
    d = np.sqrt(np.diag(crb))
    np.testing.assert_allclose(np.sqrt(np.diag(bound)), d, rtol=0.1)
    np.testing.assert_allclose(bound / np.outer(d, d), crb / np.outer(d, d), atol=0.1)


def test_least_squares_is_never_better_than_the_bound_and_equals_it_when_white(hayati, rng):
    problem, _ = make_problem(hayati, "invariant", "pose", rng, n_poses=15)
    for pairing in ("consecutive", "star", "all"):
        unc = parameter_covariance(replace(problem, pairs=make_pairs(15, pairing)), NOISE)
        assert np.linalg.eigvalsh(unc.least_squares - unc.crb).min() > -1e-12 * unc.crb.max()
    # Absolute poses with rows weighted by 1/sigma and no joint noise: the noise is white, so
    # least squares is the efficient estimator.
    absolute, _ = make_problem(hayati, "absolute", "pose", rng, n_poses=15)
    white = Noise(NOISE.position, NOISE.orientation, 0.0)
    w = 1 / np.r_[np.full(3, white.position), np.full(3, white.orientation)]
    unc = parameter_covariance(replace(absolute, weights=w), white)
    np.testing.assert_allclose(unc.least_squares, unc.crb, rtol=1e-8, atol=1e-12 * unc.crb.max())


def test_covariances_from_the_image_pipeline_replace_the_isotropic_noise(hayati, rng):
    problem, _ = make_problem(hayati, "invariant", "pose", rng, n_poses=10)
    iso = Noise(NOISE.position, NOISE.orientation, 0.0)
    body = np.diag(np.r_[np.full(3, iso.position**2), np.full(3, iso.orientation**2)])
    # The to_vector(C) covariance whose body-frame image is isotropic.
    vec = tf.to_vector(problem.poses)
    g = np.zeros((10, 6, 6))
    g[:, :3, :3] = np.swapaxes(problem.poses[:, :3, :3], -1, -2)
    g[:, 3:, 3:] = tf.right_jacobian(vec[:, 3:])
    g_inv = np.linalg.inv(g)
    given = g_inv @ body @ np.swapaxes(g_inv, -1, -2)
    a = parameter_covariance(problem, iso)
    b = parameter_covariance(problem, Noise(0, 0, 0), covariances=given)
    np.testing.assert_allclose(b.crb, a.crb, rtol=1e-7, atol=1e-9 * a.crb.max())
    # Doubling the image noise doubles every standard deviation.
    c = parameter_covariance(problem, Noise(0, 0, 0), covariances=4 * given)
    np.testing.assert_allclose(c.crb_std[a.subset], 2 * a.crb_std[a.subset], rtol=1e-7)


def test_the_bound_is_computed_when_asked_for_and_a_silent_noise_refused_at_once(hayati, rng):
    # The covariance of a least-squares fit needs only ``least_squares``: the Cramer-Rao bound
    # (a dense whitening of every pose's noise) is computed on first use, once, and is the same.
    problem, _ = make_problem(hayati, "invariant", "pose", rng, n_poses=12)
    unc = parameter_covariance(problem, NOISE)
    assert callable(unc.__dict__["crb"])
    np.testing.assert_allclose(unc.std, unc.least_squares_std)  # the estimator's, no bound
    assert callable(unc.__dict__["crb"])
    crb = unc.crb
    assert unc.__dict__["crb"] is crb and unc.crb is crb
    np.testing.assert_array_equal(crb, crb.T)
    assert np.linalg.eigvalsh(unc.least_squares - crb).min() > -1e-12 * crb.max()
    weighted = parameter_covariance(problem, NOISE, estimator="weighted")
    np.testing.assert_array_equal(weighted.covariance, crb)
    # no noise at all: refused by parameter_covariance itself, as the bound's whitening did
    with pytest.raises(RelcalError, match="noise model is zero"):
        parameter_covariance(problem, Noise(0, 0, 0))
    with pytest.raises(RelcalError, match="noise model is zero"):
        parameter_covariance(problem, Noise(0, 0, 0), covariances=np.zeros((12, 6, 6)))


def test_correlation_and_strongest_pairs(hayati, rng):
    problem, _ = make_problem(hayati, "invariant", "pose", rng, n_poses=20)
    unc = parameter_covariance(problem, NOISE)
    corr = unc.correlation
    np.testing.assert_allclose(np.diag(corr), 1.0)
    np.testing.assert_allclose(corr, corr.T)
    assert np.abs(corr).max() <= 1 + 1e-12
    top = unc.strongest_correlations(5)
    assert len(top) == 5
    magnitudes = [abs(r) for _, _, r in top]
    assert magnitudes == sorted(magnitudes, reverse=True)
    i, j = np.triu_indices(len(corr), 1)
    assert magnitudes[0] == pytest.approx(np.abs(corr[i, j]).max())
    # Parameters outside the identifiable subset have no standard deviation.
    assert np.isnan(unc.std[~np.isin(np.arange(len(unc.names)), unc.subset)]).all()
    assert np.isfinite(unc.std[unc.subset]).all()


def test_predicted_accuracy_matches_sampled_parameter_errors(hayati, rng):
    problem, _ = make_problem(hayati, "invariant", "pose", rng, n_poses=20)
    unc = parameter_covariance(problem, NOISE)
    q_val = random_q(hayati, 6, rng)
    acc = predicted_accuracy(problem, unc, q_val)
    assert len(acc.pairs) == 15
    # Sample parameter errors from the covariance and measure the relative-pose errors they
    # cause between the validation poses (the model's own prediction, nonlinear).
    shell = replace(
        problem,
        q=q_val,
        poses=np.broadcast_to(np.eye(4), (6, 4, 4)),
        pairs=make_pairs(6, "all"),
        weights=None,
    )
    reference = residuals(shell, np.zeros(len(unc.names)), jacobian=False).reshape(-1, 6)
    draws = rng.multivariate_normal(np.zeros(len(unc.subset)), unc.covariance, 400)
    pos = []
    for x in draws:
        params = np.zeros(len(unc.names))
        params[unc.subset] = x
        r = residuals(shell, params, jacobian=False).reshape(-1, 6) - reference
        pos.append(np.linalg.norm(r[:, :3], axis=1))
    sampled = np.sqrt(np.mean(np.square(pos), axis=0))
    np.testing.assert_allclose(sampled, acc.position, rtol=0.15)
    summary = accuracy_document(acc)
    assert summary["position_mm"]["max"] == pytest.approx(acc.position.max() * 1e3)
    assert summary["orientation_deg"]["mean"] == pytest.approx(np.degrees(acc.orientation).mean())


@pytest.mark.parametrize("formulation", ["invariant", "published"])
def test_result_std_of_position_only_relative_data(hayati, rng, formulation):
    # From the API, a relative position-only fit's covariance takes the pose noise from the
    # residuals. Those have no orientation rows (pair_errors: NaN there): the orientation noise
    # must not enter (it raised, Noise.orientation NaN), and the position rows' scatter alone
    # sets the level. With position noise only, that is the covariance of the known noise, up
    # to the residuals' estimate of its level (a robust one from 59 pairs: about 9 % spread;
    # 1.14 and 1.07 of the true level here).
    problem, truth = make_problem(hayati, formulation, "position", rng, n_poses=60)
    sigma = 0.1 * MM
    eps = np.zeros((60, 6))
    eps[:, :3] = rng.normal(0.0, sigma, (60, 3))
    problem = replace(problem, poses=problem.poses @ tf.from_vector(eps))
    result = identify(problem)
    subset = result.identifiability.subset
    held = np.setdiff1d(np.arange(len(result.params)), subset)
    assert np.isfinite(result.std[subset]).all() and (result.std[subset] > 0).all()
    assert np.isnan(result.std[held]).all()
    known = parameter_covariance(problem, Noise(sigma), result.identifiability, params=truth)
    np.testing.assert_allclose(result.std[subset], known.std[subset], rtol=0.3)


# (formulation, measure, pairing) whose std come from the pose noise the residuals show
RESIDUAL_NOISE_CASES = [
    ("invariant", "pose", "consecutive"),
    ("invariant", "position", "consecutive"),
    ("published", "position", "consecutive"),
    ("invariant", "pose", "board"),
    ("absolute", "pose", "consecutive"),  # (no pairs: each pose alone)
]


@pytest.mark.parametrize(("formulation", "measure", "pairing"), RESIDUAL_NOISE_CASES)
def test_std_from_the_residuals_match_the_spread_of_the_estimates(
    hayati, formulation, measure, pairing
):
    """Without a noise model, a fit's standard deviations take the pose noise from its own
    residuals, which are smaller than the noise (the fit takes degrees of freedom, more than one
    per parameter where pairs share poses). Over 300 seeded noisy measurements of one simulated
    A465 (30 poses, 0.05 mm and 0.01 deg per camera pose axis), the reported std of each
    estimated parameter (RMS over the trials) against the spread of its estimates. Before the
    levels counted what the fit takes, the median ratios were 0.95 (frame-invariant pose), 0.75
    (its positions), 0.79 (published positions) and 0.92 (board); now 1.03, 0.98, 1.03, 1.00.
    Absolute poses had one ``s^2 = |r|^2 / (m - k)`` of rows in m and in rad (1.61, one
    parameter 0.71, another 2.6); now their levels come apart as the pairs' do (1.01)."""
    scenario = make_scenario(
        hayati,
        noise=Noise(0.05 * MM, 0.01 * DEG),
        formulation=formulation,
        measure=measure,
        pairing=pairing,
        n_poses=30,
    )
    clean = clean_poses(scenario)
    rng = np.random.default_rng(1)
    ident, estimates, variances = None, [], []
    for _ in range(300):
        problem = problem_for(scenario, *measure_once(scenario, rng, clean))
        ident = ident or analyse_problem(problem)  # the same joints: the same analysis
        result = identify(problem, identifiability=ident)
        estimates.append(result.params[ident.subset])
        variances.append(np.diagonal(result.covariance)[ident.subset])
    ratio = np.sqrt(np.mean(variances, axis=0)) / np.std(estimates, axis=0, ddof=1)
    # 300 trials estimate each std to about 4 %
    assert 0.93 <= np.median(ratio) <= 1.07, ratio
    assert np.all((ratio >= 0.8) & (ratio <= 1.2)), ratio
