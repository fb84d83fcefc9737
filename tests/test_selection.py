"""Trust on real data: the learned noise model, model selection against honest baselines, and
labels that match the math."""

import json
import shutil
from dataclasses import replace

import numpy as np
import pytest
from conftest import DATA
from helpers_dataset import synthetic_dataset
from helpers_sim import make_problem

import relcal
from relcal import geometry as tf
from relcal.calibration.identifiability import analyse_problem
from relcal.calibration.identify import identify_lm
from relcal.calibration.kinds.poses import pair_left_maps, plain_rows
from relcal.calibration.measurement import (
    make_pairs,
    pair_errors,
    split_params,
    world_errors,
)
from relcal.calibration.noise import (
    _moment_design,
    estimate_pose_noise,
    pair_covariances,
    row_factors,
)
from relcal.calibration.pipeline import cross_validate
from relcal.calibration.selection import plain_whiteners, whitened
from relcal.calibration.validate import pooled, stats
from relcal.cli import main
from relcal.data.dataset import load_dataset
from relcal.data.importers import import_rct_positioner
from relcal.reporting.documents import validation_document
from relcal.robot.kinematics import fk
from relcal.robot.model import auto_hayati, load_model


def test_moment_design_is_the_pair_covariance_map(rng):
    left = rng.normal(size=(5, 6, 6))
    root = rng.normal(size=(6, 6))
    sigma = root @ root.T
    theta = np.array([sigma[a, b] for a in range(6) for b in range(a, 6)])
    expected = pair_covariances(sigma, left).reshape(-1)
    np.testing.assert_allclose(_moment_design(left) @ theta, expected, rtol=1e-12, atol=1e-12)


def test_a_diagonal_whitening_scales_the_rows_to_the_same_numbers(rng):
    # The plain weighting is one diagonal block for every pair: scaling the rows gives the block
    # products' numbers to the bit, in the same (C) order, so the sums over them are unchanged.
    jac, b = rng.normal(size=(40, 6, 9)), rng.normal(size=(40, 6))
    jac = jac[:, :, [0, 2, 4, 6, 8]]  # a column subset: not C-contiguous
    plain = plain_whiteners(40)
    np.testing.assert_array_equal(row_factors(plain), [1, 1, 1, 0.1, 0.1, 0.1])
    rows = np.arange(40) % 3 > 0
    jw, bw = whitened(plain, jac, b, rows)
    np.testing.assert_array_equal(jw, plain[rows] @ jac[rows])
    np.testing.assert_array_equal(bw, np.einsum("pij,pj->pi", plain[rows], b[rows]))
    assert jw.flags.c_contiguous and bw.flags.c_contiguous
    # per-pair blocks (the noise model) are multiplied as they are
    blocks = rng.normal(size=(40, 6, 6))
    assert row_factors(blocks) is None
    assert row_factors(np.broadcast_to(blocks[0], (40, 6, 6))) is None  # the same, not diagonal
    jw, bw = whitened(blocks, jac, b)
    np.testing.assert_array_equal(jw, blocks @ jac)
    np.testing.assert_array_equal(bw, np.einsum("pij,pj->pi", blocks, b))


def test_noise_model_recovers_a_planted_correlated_covariance(a465, rng):
    """Camera-pose errors whose translation and rotation are strongly correlated (a tilt and a
    sideways shift), measured through all pairs of 80 poses: the 6x6 covariance comes back."""
    problem, truth = make_problem(auto_hayati(a465), "invariant", "pose", rng, n_poses=80)
    problem = replace(problem, pairs=make_pairs(80, "all"))
    std = np.array([2e-4, 2e-4, 5e-4, 4e-4, 4e-4, 1e-4])
    corr = np.eye(6)
    corr[0, 4] = corr[4, 0] = 0.8  # x shift with a tilt about y
    corr[1, 3] = corr[3, 1] = -0.8
    sigma = corr * np.outer(std, std)
    eps = rng.multivariate_normal(np.zeros(6), sigma, 80)
    noisy = replace(problem, poses=problem.poses @ tf.from_vector(eps))
    learned = estimate_pose_noise(pair_errors(noisy, truth), pair_left_maps(noisy))
    np.testing.assert_allclose(learned.std, std, rtol=0.2)
    assert abs(learned.correlation[0, 4] - 0.8) < 0.12
    assert abs(learned.correlation[1, 3] + 0.8) < 0.12
    assert learned.max_translation_rotation_correlation() > 0.65


@pytest.fixture(scope="module")
def positioner(tmp_path_factory):
    root = import_rct_positioner(
        DATA / "rct_positioner/positioner_kinematic_measurements.yaml",
        tmp_path_factory.mktemp("pos") / "p",
    ).folder
    dataset = relcal.load_dataset(root)
    return dataset, relcal.measure(dataset, progress=False)


def test_positioner_k_fold_no_worse_than_the_baseline_or_a_plain_fit(positioner):
    """On every held-out fold of the real positioner, relcal's chosen model is at least as good
    as a plain unweighted Levenberg-Marquardt fit (rotation rows x 0.1 m/rad, all pairs) of the
    identifiable geometry and hand-eye, within 1 % of a plain fit of every identifiable parameter
    including the non-geometric candidates, and pooled over the folds better than the baseline
    beyond its interval."""
    dataset, measured = positioner
    folds = cross_validate(dataset, measured, k=5, seed=0)
    for fold in folds:
        # relcal's formulation (each pose against W F X) with its plain row weights
        plain = replace(fold.problem, pair_weights=None, weights=plain_rows(fold.problem))
        ident = analyse_problem(plain)
        kinds = plain.full_layout.kinds
        frames = ("theta_off", "a", "d", "alpha", "handeye", "board")
        geometric = np.array([c for c in ident.subset if kinds[c] in frames])
        test = np.setdiff1d(fold.test, fold.validation.outliers)
        q, poses = fold.dataset.q[test], fold.measurements.poses[test]

        plain_rms = []
        for subset in (geometric, ident.subset):
            fit = identify_lm(plain, 200, replace(ident, subset=subset))
            model, _ = split_params(plain, fit.params)
            errors = world_errors(plain, fit.params, model, q, poses)
            plain_rms.append(stats(errors)["position_mm"]["rms"])
        ours = stats(fold.validation.calibrated)["position_mm"]["rms"]
        assert ours <= plain_rms[0] * 1.001 and ours <= plain_rms[1] * 1.01, (ours, plain_rms)
    summary = validation_document(pooled([f.validation for f in folds]))
    ratio = summary["ratio_to_baseline"]["position_mm"]
    assert ratio["after_over_before"] < 0.95 and ratio["ci95"][1] < 1.0


def test_selection_keeps_the_baseline_when_nothing_is_planted(tmp_path):
    """No geometric error, only pose noise: every one of 10 seeds exports the hand-eye-only
    baseline and says so; with errors planted, the geometry is chosen."""
    for seed in range(10):
        syn = synthetic_dataset(
            tmp_path / f"n{seed}", n=40, noise=(1e-4, 2e-4), seed=seed, errors=0
        )
        cal = relcal.calibrate(relcal.load_dataset(syn.root), seed=seed)
        assert cal.exported == "baseline", cal.selection[cal.chosen].candidate.name
        assert np.array_equal(cal.result.params, cal.baseline.params)
    syn = synthetic_dataset(tmp_path / "planted", n=40, noise=(1e-4, 2e-4), seed=0)
    cal = relcal.calibrate(relcal.load_dataset(syn.root), seed=0)
    assert cal.exported == "calibrated" and "geometric" in cal.selection[cal.chosen].candidate.name
    assert not cal.hurts


def test_calibration_that_hurts_exits_1_and_writes_nothing(tmp_path, capsys):
    """Force every parameter in (--selection all) on 12 samples with no error: when the held-out
    error exceeds the baseline's beyond its interval, the command fails and leaves no outputs;
    when it exceeds it within the interval, it says so and writes the baseline, never the worse
    model, with the verdict "do not deploy"."""
    out = tmp_path / "out"
    for seed in range(12):
        syn = synthetic_dataset(
            tmp_path / f"d{seed}", n=12, noise=(3e-4, 5e-4), seed=seed, errors=0
        )
        argv = ["calibrate", str(syn.root), "--out", str(out), "--selection", "all", "--seed", "0"]
        code = main([*argv, "--json", str(tmp_path / f"r{seed}.json")])
        captured = capsys.readouterr()
        if code == 1:
            break
        assert code == 0 and out.exists()
        doc = json.loads((tmp_path / f"r{seed}.json").read_text())
        ratio = doc["validation"]["ratio_to_baseline"]["position_mm"]
        assert ratio["ci95"][0] <= 1.0
        worse = ratio["after_over_before"] > 1
        assert ("worse than the baseline" in captured.out) == worse
        assert doc["exported"] == ("baseline" if worse else "calibrated")
        if worse:
            assert doc["verdict"]["code"] == "do not deploy"
            assert "calibrated model is" in doc["verdict"]["text"]
            assert "the baseline was written" in captured.out
            nominal = load_dataset(syn.root).model
            written = load_model(out / "model.yaml")
            q = np.zeros((1, nominal.n_joints))
            np.testing.assert_allclose(fk(written, q), fk(nominal, q), atol=1e-12)
            for entry in doc["artifacts"]["files"]:  # each file is the baseline, ratio 1
                held = entry["held_out"]
                assert held["position_rms_mm"] == pytest.approx(
                    doc["validation"]["baseline"]["position_mm"]["rms"], rel=1e-9
                )
        shutil.rmtree(out)
    else:
        pytest.fail("no seed made the forced model significantly worse than the baseline")
    assert "worse than the baseline" in captured.err and "nothing was written" in captured.err
    assert not out.exists() and not (tmp_path / f"r{seed}.json").exists()


def test_a_model_worse_than_the_baseline_is_not_exported(tmp_path, capsys):
    """Every parameter forced in (--selection all) on 20 samples with no error: the calibrated
    model is 1.05x worse than the baseline on the held-out samples, within the interval. The
    baseline is written (the nominal kinematics, every file's own number the baseline's) and
    said so; the verdict is "do not deploy", naming how much worse the rejected model was
    (it read "collect more samples: 0.95x better" and wrote the worse model)."""
    syn = synthetic_dataset(tmp_path / "d", n=20, noise=(3e-4, 5e-4), seed=7, errors=0)
    out, doc_path = tmp_path / "out", tmp_path / "r.json"
    # (seed 3: a held-out draw where it is worse within the interval; seed 0's is worse beyond
    # doubt, which writes nothing: the test above)
    argv = ["calibrate", str(syn.root), "--out", str(out), "--selection", "all", "--seed", "3"]
    assert main([*argv, "--json", str(doc_path)]) == 0
    captured = capsys.readouterr().out
    doc = json.loads(doc_path.read_text())
    ratio = doc["validation"]["ratio_to_baseline"]["position_mm"]
    assert ratio["after_over_before"] > 1 and ratio["ci95"][0] < 1  # worse, not beyond doubt
    assert doc["exported"] == "baseline" and doc["model_selection"]["chosen"] != "hand-eye only"
    assert "worse than the baseline" in doc["model_selection"]["export_reason"]
    verdict = doc["verdict"]
    assert verdict["code"] == "do not deploy" and verdict["factor"] is None
    assert f"calibrated model is {ratio['after_over_before']:.3g}x worse" in verdict["text"]
    assert f"verdict: {verdict['text']}" in captured
    assert "the baseline was written" in captured
    nominal = load_dataset(syn.root).model
    written = load_model(out / "model.yaml")
    q = np.radians(np.linspace(-40.0, 40.0, 5 * nominal.n_joints)).reshape(5, -1)
    np.testing.assert_allclose(fk(written, q), fk(nominal, q), atol=1e-12)
    baseline = doc["validation"]["baseline"]["position_mm"]["rms"]
    for entry in doc["artifacts"]["files"]:
        assert entry["written"]
        assert entry["held_out"]["position_rms_mm"] == pytest.approx(baseline, rel=1e-9)


def test_published_position_run_labels_every_exactly_recovered_parameter(a465):
    """Position only, the published solver: a parameter is shown identified exactly when its
    estimate equals the truth; the curved tool-change symmetry draws d[6] and alpha[6] in.
    Hayati's A465: without beta, the parallel pair's held d is only nearly a symmetry of the
    planted truth and nothing is recovered exactly (tests/test_identify.py)."""
    sim = relcal.simulate(auto_hayati(a465), measure="position", seed=0)
    err = np.abs(sim.result.params - sim.specified)
    unit = np.where(sim.layout.is_angle(), np.radians(1.0), 1e-3)
    exact = err / unit < 1e-7
    ok = sim.result.identifiable
    assert np.all(exact[ok])  # nothing shown identified is off
    assert np.all(ok[exact & sim.result.identifiability.identifiable])  # nothing exact hidden
    names = [n for n, k in zip(sim.layout.names, ok, strict=True) if not k]
    assert {"d[6]", "alpha[6]"} <= set(names) and "theta_off[2]" not in names


def test_selection_rarely_adds_a_term_that_is_not_there(tmp_path):
    """Geometric errors planted, no non-geometric ones: over 100 seeds (30 samples each, pose
    noise 0.05 mm / 0.1 mrad) model selection adds a non-geometric family at most 5 times."""
    added = []
    for seed in range(100):
        syn = synthetic_dataset(tmp_path / f"s{seed}", n=30, noise=(5e-5, 1e-4), seed=seed)
        cal = relcal.calibrate(relcal.load_dataset(syn.root), holdout=0.0, seed=seed)
        name = cal.selection[cal.chosen].candidate.name
        assert name.startswith("geometric"), name  # the planted geometry is always found
        added += [name] if name != "geometric" else []
        shutil.rmtree(syn.root)
    assert len(added) <= 5, added
