"""The board formulation (issue 20): each camera pose against ``W F(q) X``, with the board transform
``W`` estimated, instead of all ``N (N - 1) / 2`` pairs: its exact Jacobian, the same estimate and
the same information as all pairs, ``--pairs auto``, and per-sample statistics that stay linear."""

import re
from dataclasses import replace

import numpy as np
import pytest
from conftest import random_q
from helpers_sim import BOARD, HANDEYE, numeric_jacobian

from relcal import geometry as tf
from relcal.calibration.identifiability import analyse_problem
from relcal.calibration.identify import identify_lm
from relcal.calibration.measurement import (
    Problem,
    board_frame,
    board_guess,
    capped_pairs,
    make_pairs,
    per_sample_median,
    residuals,
    resolve_pairing,
    split_params,
)
from relcal.calibration.noise import Noise
from relcal.calibration.uncertainty import parameter_covariance
from relcal.errors import RelcalError
from relcal.robot.kinematics import fk, make_layout
from relcal.robot.loading import get_robot
from relcal.robot.model import auto_hayati

FRAMES = [0.005, -0.003, 0.004, 0.05, -0.03, 0.04, 0.01, 0.02, -0.01, 0.02, 0.05, -0.03]


def board_problem(model, q, truth, noise=0.0, rng=None, board=BOARD) -> Problem:
    """Camera poses ``W F X`` of the model with errors ``truth`` (geometry, hand-eye and board
    6-vectors), with body-frame pose noise ``noise`` (m and rad); the guesses ``HANDEYE`` and
    ``board``."""
    shell = Problem(
        model, make_layout(model), q, np.tile(np.eye(4), (len(q), 1, 1)), "board", "pose",
        None, HANDEYE, board=board,
    )  # fmt: skip
    true_model, handeye = split_params(shell, truth)
    poses = board_frame(shell, truth) @ fk(true_model, q) @ handeye
    if noise:
        poses = poses @ tf.from_vector(rng.normal(0, noise, (len(q), 6)))
    return replace(shell, poses=poses)


def planted(model, rng, scale=1e-3):
    """Geometric errors (about a millimetre and a milliradian) and the frames' 6-vectors."""
    layout = make_layout(model)
    return np.r_[rng.normal(0, scale, layout.size), FRAMES]


@pytest.fixture
def arm():
    return auto_hayati(get_robot("a465"))


def test_jacobian_matches_finite_differences_at_the_truth_and_far_from_it(arm, rng):
    q = random_q(arm, 8, rng)
    truth = planted(arm, rng)
    problem = board_problem(arm, q, truth)
    r, a = residuals(problem, truth)
    assert np.abs(r).max() < 1e-12
    assert a.shape == (problem.n_residuals(), problem.full_layout.size) == (48, len(truth))
    np.testing.assert_allclose(a, numeric_jacobian(problem, truth), atol=1e-7)
    # centimetres and degrees of residual: the exact Jacobian of the residual, not the model's
    params = truth + rng.normal(0, 0.02, len(truth))
    r, a = residuals(problem, params)
    assert np.abs(r).max() > 0.02
    fd = numeric_jacobian(problem, params)
    assert np.abs(a - fd).max() <= 1e-6 * np.linalg.norm(fd, axis=0).max()
    # the model's Jacobian differs from it there (the residual's tangent), so both are tested
    model_jac = residuals(problem, params, model_jacobian=True)[1]
    assert np.abs(model_jac - fd).max() > 1e-3 * np.linalg.norm(fd, axis=0).max()


def test_position_only_rows_are_in_the_measured_cameras_frame(arm, rng):
    """Position-only board measurements: ``R_C^T (t_C - t_model)``, exact Jacobian far from the
    truth, and the hand-eye's rotation without any effect on them (it turns the camera about its
    own centre): the cost does not change along it, and the analysis names it."""
    q = random_q(arm, 30, rng)
    truth = planted(arm, rng)
    problem = replace(board_problem(arm, q, truth), measure="position")
    assert problem.n_residuals() == 90
    params = truth + rng.normal(0, 0.02, len(truth))
    r, a = residuals(problem, params)
    model, handeye = split_params(problem, params)
    modelled = board_frame(problem, params) @ fk(model, q) @ handeye
    shift = problem.poses[:, :3, 3] - modelled[:, :3, 3]
    want = np.einsum("nji,nj->ni", problem.poses[:, :3, :3], shift).ravel()
    np.testing.assert_allclose(r, want, atol=1e-15)
    fd = numeric_jacobian(problem, params)
    assert np.abs(a - fd).max() <= 1e-6 * np.linalg.norm(fd, axis=0).max()
    n_geo = problem.layout.size
    turned = params.copy()
    turned[n_geo + 3 : n_geo + 6] += [0.1, -0.2, 0.05]  # the hand-eye's rotation, far
    np.testing.assert_allclose(residuals(problem, turned, jacobian=False), r, atol=1e-14)
    assert np.abs(a[:, n_geo + 3 : n_geo + 6]).max() < 1e-14
    ident = analyse_problem(problem)  # at the guesses, millimetres and degrees away
    assert ident.rank == analyse_problem(replace(problem, measure="pose")).rank - 3
    named = {c.names: c.reason for c in ident.combinations}
    for c in ("rx", "ry", "rz"):
        assert "camera positions do not see" in named[(f"handeye.{c}",)]


def test_layout_pairs_and_guess(arm, rng):
    q = random_q(arm, 20, rng)
    truth = planted(arm, rng)
    problem = board_problem(arm, q, truth)
    names = problem.full_layout.names
    assert names[-12:-6] == tuple(f"handeye.{c}" for c in ("tx", "ty", "tz", "rx", "ry", "rz"))
    assert names[-6:] == tuple(f"board.{c}" for c in ("tx", "ty", "tz", "rx", "ry", "rz"))
    assert problem.pair_indices().tolist() == [[k, k] for k in range(20)]
    true_model, handeye = split_params(problem, truth)
    # from the true flange poses and hand-eye, the guess is the board itself
    exact = board_guess(fk(true_model, q), problem.poses, handeye)
    np.testing.assert_allclose(exact, board_frame(problem, truth), atol=1e-12)
    # from the nominal model, within the errors' reach of it
    rough = board_guess(fk(arm, q), problem.poses, HANDEYE)
    assert np.abs(tf.to_vector(tf.invert(rough) @ board_frame(problem, truth))).max() < 0.2


def test_board_and_all_pairs_estimate_the_same_geometry(arm, rng):
    """Planted errors, pose noise of 0.1 mm and 0.1 mrad: the two formulations agree within the
    predicted standard deviation on every identified parameter."""
    n, noise = 60, 1e-4
    q = random_q(arm, n, rng)
    truth = planted(arm, rng)
    board = board_problem(arm, q, truth, noise, rng)
    guess = board_guess(fk(arm, q), board.poses, HANDEYE)
    board = replace(board, board=guess)  # the pipeline's start: no knowledge of W
    pairs = Problem(
        arm, board.layout, q, board.poses, "invariant", "pose", make_pairs(n, "all"), HANDEYE
    )
    fit_b, fit_p = identify_lm(board), identify_lm(pairs)
    assert fit_b.converged and fit_p.converged
    n_geo = board.layout.size
    geo_b = fit_b.identifiability.subset[fit_b.identifiability.subset < n_geo]
    geo_p = fit_p.identifiability.subset[fit_p.identifiability.subset < n_geo]
    np.testing.assert_array_equal(geo_b, geo_p)  # W takes what relative measurements cancel
    std = np.sqrt(np.diag(fit_b.covariance))[geo_b]
    diff = np.abs(fit_b.params[geo_b] - fit_p.params[geo_b])
    # two estimators of the same data (all pairs weigh the poses differently): within one
    # predicted standard deviation each, and a third of one on average
    assert np.all(diff < std) and np.sqrt(np.mean((diff / std) ** 2)) < 0.35, diff / std
    # and both are the truth within their standard deviations (the identifiable part: compare
    # predictions of held-out relative poses, noise free)
    held = random_q(arm, 30, rng)
    clean = board_problem(arm, held, truth)
    test = Problem(arm, board.layout, held, clean.poses, "invariant", "pose",
                   make_pairs(30, "all"), HANDEYE)  # fmt: skip
    for fit in (fit_b, fit_p):
        err = residuals(test, fit.params[: n_geo + 6], jacobian=False).reshape(-1, 6)
        assert np.sqrt(np.mean(np.sum(err[:, :3] ** 2, axis=1))) < 1e-4  # below the noise
    assert fit_b.gradient_check.decrement < 1e-6


def test_board_carries_the_information_of_all_pairs(arm, rng):
    """The Cramer-Rao bound of the board formulation (W a nuisance) equals that of any connected
    pairing weighted by its full covariance: the same information."""
    n = 25
    q = random_q(arm, n, rng)
    truth = planted(arm, rng)
    board = board_problem(arm, q, truth)
    pairs = Problem(
        arm, board.layout, q, board.poses, "invariant", "pose", make_pairs(n, "all"), HANDEYE
    )
    noise = Noise(position=1e-4, orientation=2e-4)
    unc_p = parameter_covariance(pairs, noise, params=truth[:-6], estimator="weighted")
    subset = np.r_[unc_p.subset, np.arange(len(truth) - 6, len(truth))]  # + the board
    unc_b = parameter_covariance(board, noise, params=truth, subset=subset, estimator="weighted")
    k = len(unc_p.subset)
    np.testing.assert_allclose(unc_b.crb[:k, :k], unc_p.crb, rtol=1e-6, atol=1e-18)
    # with the same level on every row, the least-squares (sandwich) covariance of the board
    # formulation is its Cramer-Rao bound (the poses are independent); all pairs' is larger
    same = Noise(position=1e-4, orientation=1e-4)
    unc_b = parameter_covariance(board, same, params=truth, subset=subset)
    np.testing.assert_allclose(unc_b.least_squares, unc_b.crb, rtol=1e-6, atol=1e-18)
    unc_p = parameter_covariance(pairs, same, params=truth[:-6])
    assert np.all(np.diag(unc_p.least_squares) >= np.diag(unc_b.least_squares[:k, :k]) * 0.999)


def test_auto_pairing_and_bounded_pair_sets():
    # camera poses: the board formulation whatever the size; the published simulation's base
    # frame formulations cannot take it: all pairs up to 300 poses
    assert resolve_pairing("auto", 3) == resolve_pairing("auto", 5000) == "board"
    assert resolve_pairing("auto", 300, "published") == "all"
    assert resolve_pairing("auto", 301, "published") == "board"
    assert resolve_pairing("consecutive", 5000) == "consecutive"
    assert make_pairs(4, "board").tolist() == [[0, 0], [1, 1], [2, 2], [3, 3]]
    assert make_pairs(300, "auto").tolist() == make_pairs(300, "board").tolist()
    np.testing.assert_array_equal(capped_pairs(10, 45), make_pairs(10, "all"))
    pairs = capped_pairs(5000, 1000, seed=3)
    assert pairs.shape == (1000, 2) and np.all(pairs[:, 0] < pairs[:, 1]) and pairs.max() < 5000
    assert len(np.unique(pairs[:, 0] * 5000 + pairs[:, 1])) == 1000
    np.testing.assert_array_equal(pairs, capped_pairs(5000, 1000, seed=3))  # seeded


def test_per_sample_median_is_the_median_over_each_samples_pairs(rng):
    pairs = make_pairs(9, "all")[rng.permutation(36)[:25]]
    pairs = np.r_[pairs, [[4, 4]]]  # a sample's own measurement counts once
    values = rng.normal(size=len(pairs))
    got = per_sample_median(values, pairs)
    for k in range(9):
        mine = (pairs == k).any(axis=1)
        want = np.median(values[mine]) if mine.any() else np.nan
        np.testing.assert_equal(got[k], want)


def test_calibrate_with_the_board_agrees_with_all_pairs(tmp_path):
    """The whole pipeline (outliers, noise, model selection, fits, validation) on one synthetic
    set with planted outliers, once with each pairing: the same outliers, the same chosen model,
    the same estimate within its standard deviation, held-out errors alike."""
    from helpers_dataset import synthetic_dataset

    import relcal

    syn = synthetic_dataset(tmp_path / "d", n=80, outliers=4, noise=(5e-5, 5e-5))
    ds = relcal.load_dataset(syn.root)
    board, pairs = (relcal.calibrate(ds, pairing=p) for p in ("board", "all"))
    assert board.settings["pairing"] == "board" and pairs.settings["pairing"] == "all"
    ids = board.dataset.ids  # (the samples in their content's order)
    planted = {s for s in syn.ids if ids.index(s) in board.train or s in board.outliers}
    # the board formulation finds exactly the planted ones; all pairs finds them too (its rule,
    # each sample's median over its pairs, can add one clean sample: s053 in this draw)
    assert planted and set(board.outliers) == planted
    assert planted <= set(pairs.outliers) and len(set(pairs.outliers) - planted) <= 1
    assert board.result.converged and pairs.result.converged
    # the pose noise learned from the residuals: the planted 0.05 mm and 0.05 mrad, both ways
    for cal in (board, pairs):
        assert cal.noise.noise.position == pytest.approx(5e-5, rel=0.2)
        assert cal.noise.noise.orientation == pytest.approx(5e-5, rel=0.2)
    assert board.selection[board.chosen].candidate.name == "geometric"
    assert pairs.selection[pairs.chosen].candidate.name == "geometric"
    n_geo = board.problem.layout.size
    subset = board.result.identifiability.subset
    geo = subset[subset < n_geo]
    np.testing.assert_array_equal(geo, pairs.result.identifiability.subset[: len(geo)])
    std_b, std_p = board.result.std[geo], pairs.result.std[geo]
    # each estimate is the planted truth within its own predicted standard deviations
    for fit, std in ((board.result, std_b), (pairs.result, std_p)):
        z = np.abs(fit.params[geo] - syn.truth[geo]) / std
        assert z.max() < 3.5 and np.sqrt(np.mean(z**2)) < 1.5, z
    # the predicted standard deviations (pose by pose) against a bootstrap over the samples
    ratio = board.bootstrap_std[subset] / board.result.std[subset]
    assert 0.8 < np.median(ratio) < 1.25 and ratio.min() > 0.6 and ratio.max() < 1.6, ratio
    # and the two agree within the larger of their standard deviations (the board's is the
    # smaller here: its rows weighted by the camera's lever arm, it uses the rotations better)
    assert np.median(std_b / std_p) < 1.0
    z = np.abs(board.result.params[geo] - pairs.result.params[geo]) / np.maximum(std_b, std_p)
    assert z.max() < 3.0 and np.sqrt(np.mean(z**2)) < 1.0, z  # (one training sample apart)
    # validated on the same held-out pairs (relative poses; a planted outlier among them: the
    # median pair), alike and far below the baseline
    np.testing.assert_array_equal(board.validation.pairs, pairs.validation.pairs)

    def median_mm(errors):
        return np.median(np.linalg.norm(errors[:, :3], axis=1)) * 1e3

    med_b, med_p = median_mm(board.validation.calibrated), median_mm(pairs.validation.calibrated)
    assert abs(med_b - med_p) < 0.25 * med_p and med_b < 0.02 * median_mm(board.validation.before)


def test_convergence_is_the_finite_difference_gradient_of_the_board_residual(arm, rng):
    q = random_q(arm, 40, rng)
    truth = planted(arm, rng)
    problem = board_problem(arm, q, truth, 1e-4, rng)
    problem = replace(problem, board=board_guess(fk(arm, q), problem.poses, HANDEYE))
    res = identify_lm(problem)
    assert res.converged and res.gradient_check.decrement < 1e-7
    cols = res.identifiability.subset
    beside = res.params.copy()
    beside[cols] += 0.05 * res.std[cols]  # a twentieth of a standard deviation off
    moved = replace(res, params=beside)
    assert moved.stopped and not moved.converged


def test_the_memory_estimate_follows_the_formulation():
    from relcal.limits import calibration_memory, check_calibration_memory

    n_params = 42
    board = [calibration_memory(n, "auto", n_params) for n in (1000, 10_000, 100_000)]
    assert board[1] - board[0] == pytest.approx((board[2] - board[1]) / 10)  # linear
    assert board[1] < 0.5 * 2**30 and board[2] < 2**31  # 10,000 and 100,000 samples fit
    # all pairs quadratic, consecutive pairs with their dense covariance chain
    assert calibration_memory(3000, "all", n_params) > 20 * 2**30
    assert calibration_memory(1000, "consecutive", n_params, 750) > 2**30
    # auto is the board formulation: its estimate at every size
    assert calibration_memory(300, "auto", n_params) == calibration_memory(300, "board", n_params)
    check_calibration_memory(10_000, "auto", n_params, "ds", 7500)  # not refused
    with pytest.raises(RelcalError, match=r"1,000,000 samples with --pairing board") as refused:
        check_calibration_memory(1_000_000, "board", n_params, "ds", 750_000)
    # the count it suggests is the largest that fits
    most = int(re.search(r"at most about ([\d,]+) samples", str(refused.value))[1].replace(",", ""))
    assert calibration_memory(most, "board", n_params) <= 2048 * 2**20
    assert calibration_memory(int(most * 1.01), "board", n_params) > 2048 * 2**20
    with pytest.raises(RelcalError, match="use --pairing board or auto"):
        check_calibration_memory(3000, "all", n_params, "ds", 2250)


def test_auto_is_the_board_formulation_for_small_sets_too(tmp_path):
    """``auto`` is the board formulation at every size: the same calibration as ``board``."""
    from helpers_dataset import synthetic_dataset

    import relcal

    ds = relcal.load_dataset(synthetic_dataset(tmp_path / "d", n=30).root)
    auto, board = relcal.calibrate(ds), relcal.calibrate(ds, pairing="board")
    assert auto.settings["pairing"] == "board" and auto.problem.formulation == "board"
    np.testing.assert_array_equal(auto.result.params, board.result.params)
    np.testing.assert_array_equal(auto.validation.calibrated, board.validation.calibrated)
