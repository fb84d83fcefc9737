"""Hand-eye calibration: closed forms, the refined estimate, its held-out proof, planted truth."""

from __future__ import annotations

import numpy as np
import pytest
from helpers_handeye import (
    NOISE,
    W_TRUE,
    X_TRUE,
    camera_poses,
    flange_poses,
    render_dataset,
    write_flange_dataset,
)

import relcal
from relcal import geometry as tf
from relcal.calibration.handeye_closed import (
    METHODS,
    _checked,
    closed_forms,
    informative_samples,
)
from relcal.calibration.handeye_fit import fit_poses
from relcal.calibration.handeye_job import handeye
from relcal.data.flange import flange_chain
from relcal.errors import RelcalError


def _frame_error(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """The 6-vector of ``truth^-1 estimate`` (m, rad): the perturbation of the fit's covariance."""
    return tf.to_vector(tf.invert(truth) @ estimate)


@pytest.mark.parametrize("mode", ["camera on the flange", "marker on the flange"])
def test_every_closed_form_recovers_exact_frames(mode):
    flange = flange_poses(12, seed=1)
    x = X_TRUE if mode == "camera on the flange" else tf.invert(X_TRUE)
    poses = camera_poses(flange, x, W_TRUE, cov=None)
    answers, selection = closed_forms(flange, poses)
    assert len(selection.used) == 12 and not selection.left_out
    assert [a.method for a in answers] == list(METHODS)
    for a in answers:
        assert a.ok, a.failure
        assert np.abs(a.handeye - x).max() < 1e-8, a.method
        assert np.abs(a.world - W_TRUE).max() < 1e-8, a.method


def test_closed_form_failures_are_named_never_used():
    rot = np.eye(3)
    assert _checked("andreff", np.full((3, 3), np.nan), np.zeros(3))[1].endswith(
        "returned NaN (a known failure of the method on such data)"
    )
    flip = np.diag([1.0, 1.0, -1.0])
    x, why = _checked("horaud", flip, np.zeros(3))
    assert x is None and "not a rotation" in why
    assert _checked("tsai", rot, np.zeros(3))[1] is None
    answers, _ = closed_forms(flange_poses(2, 0), camera_poses(flange_poses(2, 0), cov=None))
    assert all(not a.ok and "the closed forms need 3" in a.failure for a in answers)


def test_informative_samples_leave_out_tiny_and_half_turn_pairs_whatever_the_order():
    flange = flange_poses(10, seed=2)
    twin = flange[3] @ tf.from_vector([0.001, 0, 0, 0, 0, np.radians(0.5)])  # 0.5 deg, 1 mm
    slide = flange[4] @ tf.from_vector([0.05, 0, 0, 0, 0, 0])  # a pure translation: kept
    flip = flange[5] @ tf.from_vector([0, 0, 0, np.radians(178.0), 0, 0])  # 178 deg from 5
    all_f = np.concatenate([flange, twin[None], flip[None], slide[None]])
    poses = camera_poses(all_f, cov=None)
    sel = informative_samples(all_f, poses)
    assert len(sel.used) == 11 and len(sel.left_out) == 2
    assert any("moves less than 2 mm" in why for why in sel.left_out.values())
    assert any("near 180 deg" in why for why in sel.left_out.values())
    perm = np.random.default_rng(0).permutation(len(all_f))
    sel2 = informative_samples(all_f[perm], poses[perm])
    assert sorted(perm[sel2.used].tolist()) == sorted(sel.used.tolist())


def test_refined_estimate_within_its_std_and_at_least_as_good_as_the_closed_forms():
    flange = flange_poses(30, seed=3)
    poses = camera_poses(flange, seed=4)
    poses[7] = poses[7] @ tf.from_vector([0.02, 0.0, 0.0, 0.0, 0.05, 0.0])  # a bad frame
    model, q = flange_chain(flange)
    result = handeye(relcal.Dataset.from_arrays(model, q, poses), folds=5)
    fit = result.fit
    assert result.outliers and list(result.outliers) == ["7"]
    err = _frame_error(result.handeye, X_TRUE)
    std = np.sqrt(np.diag(fit.covariance))[:6]
    assert np.all(np.abs(err) < 3 * std), (err, std)
    assert fit.converged
    # on the same data, the closed forms' own error in the frame is not smaller
    mine = np.linalg.norm(err[:3])
    best = min(np.linalg.norm(_frame_error(a.handeye, X_TRUE)[:3]) for a in result.closed if a.ok)
    assert mine <= best
    # and on the same held-out samples
    val = result.validation
    assert val.rms("refined") <= min(val.rms(m) for m in METHODS)
    assert result.verdict.code == "deploy"
    assert result.exported == "refined"


def test_refined_spread_over_200_seeds_is_the_cramer_rao_bound():
    """200 data sets of 80 noisy camera poses (correlated noise in the camera frame): the spread of
    the refined frames matches the Cramer-Rao bound of the true noise within 10 %."""
    n = 80
    flange = flange_poses(n, seed=5)
    model, q = flange_chain(flange)
    truth = W_TRUE @ flange @ X_TRUE

    def residual(p):
        x, w = X_TRUE @ tf.from_vector(p[:6]), W_TRUE @ tf.from_vector(p[6:])
        return tf.to_vector(tf.invert(w @ flange @ x) @ truth).ravel()

    jac = np.empty((6 * n, 12))
    for i in range(12):  # finite differences of the residual, independent of the fit's own
        d = np.zeros(12)
        d[i] = 1e-6
        jac[:, i] = (residual(d) - residual(-d)) / 2e-6
    info = jac.T @ np.kron(np.eye(n), np.linalg.inv(NOISE)) @ jac
    crb = np.linalg.inv(info)
    start = closed_forms(flange[:10], truth[:10], ("park",))[0][0]
    est = []
    for seed in range(200):
        poses = camera_poses(flange, seed=100 + seed)
        fit = fit_poses(model, q, poses, start.handeye, start.world, reject=False)
        est.append(np.r_[_frame_error(fit.handeye, X_TRUE), _frame_error(fit.world, W_TRUE)])
    est = np.array(est)
    # the spread in units of the bound: 1 for an efficient estimator (sampling error ~3 %)
    spread = np.mean(np.einsum("ni,ij,nj->n", est, info, est)) / 12
    assert abs(spread - 1.0) < 0.10, spread
    spread_x = (
        np.mean(np.einsum("ni,ij,nj->n", est[:, :6], np.linalg.inv(crb[:6, :6]), est[:, :6])) / 6
    )
    assert abs(spread_x - 1.0) < 0.10, spread_x
    # and the fit's own covariance predicts it
    assert np.allclose(np.sqrt(np.diag(fit.covariance)), np.sqrt(np.diag(crb)), rtol=0.15)


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_rendered_images_planted_truth(tmp_path, mode):
    folder, x, w = render_dataset(tmp_path / mode, mode)
    dataset = relcal.load_dataset(folder)
    assert dataset.flange is not None  # flange poses, no robot model
    result = handeye(dataset, folds=5)
    assert result.validation.criterion == "px"
    err = _frame_error(result.handeye, x)
    std = np.sqrt(np.diag(result.fit.covariance))[:6]
    assert np.all(np.abs(err) < 3 * std), err / std
    best = min(np.linalg.norm(_frame_error(a.handeye, x)[:3]) for a in result.closed if a.ok)
    assert np.linalg.norm(err[:3]) <= best
    val = result.validation
    assert val.rms("refined") <= min(val.rms(m) for m in METHODS)
    delivered = result.transform("handeye")
    truth = x if mode == "eye_in_hand" else tf.invert(w)  # the fixed camera in the base frame
    assert np.abs(delivered[:3, 3] - truth[:3, 3]).max() < 1e-3


def test_numbers_do_not_change_when_rows_are_reordered(tmp_path):
    flange = flange_poses(16, seed=6)
    poses = camera_poses(flange, seed=7)
    a = handeye(relcal.load_dataset(write_flange_dataset(tmp_path / "a", flange, poses)))
    perm = np.random.default_rng(1).permutation(16)
    b = handeye(
        relcal.load_dataset(write_flange_dataset(tmp_path / "b", flange[perm], poses[perm]))
    )
    assert np.allclose(a.handeye, b.handeye, atol=1e-12)
    for m in ("refined", *METHODS):
        sa, sb = a.validation.summary(m), b.validation.summary(m)
        assert sa["position_mm"]["rms"] == pytest.approx(sb["position_mm"]["rms"], rel=1e-9)
        assert sa["position_mm"]["ci95"] == pytest.approx(sb["position_mm"]["ci95"], rel=1e-9)
    assert a.verdict.text == b.verdict.text


def test_flange_columns_must_be_complete(tmp_path):
    flange = flange_poses(6, seed=8)
    folder = write_flange_dataset(tmp_path / "d", flange, camera_poses(flange, cov=None))
    text = (folder / "samples.csv").read_text().replace(",fqw,", ",fqw_,", 1)
    (folder / "samples.csv").write_text(text)
    with pytest.raises(RelcalError, match="fqw"):
        relcal.load_dataset(folder)
