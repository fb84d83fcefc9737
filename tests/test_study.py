"""Monte Carlo study: the empirical spread of identified parameters against the prediction, the
bias test, seeding, and the command line."""

import json

import numpy as np
import pytest
import scipy.stats
from conftest import random_q

import relcal.sim.study
from relcal.calibration.identify import identify_weighted
from relcal.calibration.noise import Noise
from relcal.cli import main
from relcal.errors import RelcalError
from relcal.geometry import DEG, MM
from relcal.reporting.text import format_study
from relcal.robot.model import auto_hayati
from relcal.sim.scenario import clean_poses, make_scenario, problem_for
from relcal.sim.study import standard_normals, study

NOISE = Noise(0.05 * MM, 0.01 * DEG, 0.0)


@pytest.fixture
def scenario(a465):
    model = auto_hayati(a465)  # the parallel pair resolved: a well-conditioned subset
    q = random_q(model, 12, np.random.default_rng(11))
    return make_scenario(model, q, NOISE, seed=4)


def test_standard_normals_are_seeded_per_trial_and_matched_exactly():
    a = standard_normals(7, 5, 3, "random")
    b = standard_normals(7, 8, 3, "random")
    np.testing.assert_array_equal(a, b[:5])  # trial t does not depend on the number of trials
    z = standard_normals(7, 50, 10, "matched")
    np.testing.assert_allclose(z.mean(axis=0), 0, atol=1e-12)
    np.testing.assert_allclose(np.cov(z.T), np.eye(10), atol=1e-12)
    with pytest.raises(RelcalError, match="more trials than noise dimensions"):
        standard_normals(7, 10, 10, "matched")


def test_monte_carlo_agrees_with_the_cramer_rao_bound(scenario):
    # 200 trials with the noise-weighted estimator. Matched sampling removes the sampling
    # scatter of the linear part: what is left is the error of the prediction itself.
    res = study(scenario, trials=200, seed=1, workers=2, sampling="matched", progress=False)
    assert res.converged.all()
    assert len(res.subset) == 24
    assert np.all(np.abs(res.ratio - 1) < 0.10), res.ratio  # every estimated parameter
    assert np.all(np.abs(res.ratio - 1) < 0.02)  # in fact much closer
    assert np.abs(res.bias_t).max() < 0.5  # no bias beyond a fraction of a standard error
    # The noise-free estimate recovers exactly every parameter reported identifiable: with no
    # share in the null space at the nominal model and at the estimate (the true hand-eye is
    # rotated, so a symmetry curves a parameter that is free of it at the nominal model).
    reference = identify_weighted(problem_for(scenario, scenario.q, clean_poses(scenario)), NOISE)
    np.testing.assert_allclose(reference.params, res.reference, atol=1e-12)
    ok = reference.identifiable
    assert ok.sum() >= 15
    np.testing.assert_allclose(res.reference[ok], res.truth[ok], atol=1e-12)
    text = format_study(res)
    assert "predicted = Cramer-Rao bound" in text and "(unbiased)" in text


def test_independent_trials_scatter_as_the_sampling_distribution_says(scenario):
    res = study(scenario, trials=200, seed=2, workers=2, progress=False)
    k = len(res.subset)
    # Each ratio within its 99.9 % interval (Bonferroni over the parameters), and the mean
    # squared ratio (over correlated parameters) within a few percent of one.
    dof = res.trials - 1
    lo, hi = np.sqrt(scipy.stats.chi2.ppf([0.0005 / k, 1 - 0.0005 / k], dof) / dof)
    assert np.all((res.ratio > lo) & (res.ratio < hi)), res.ratio
    assert abs(res.overall_ratio - 1) < 0.08
    chi2, p = res.bias_test()  # unbiased: the mean error is consistent with zero
    assert p > 0.001, (chi2, p)


def test_least_squares_spread_matches_its_sandwich_covariance(scenario):
    res = study(
        scenario,
        trials=100,
        seed=3,
        workers=2,
        estimator="least_squares",
        sampling="matched",
        progress=False,
    )
    assert np.all(np.abs(res.ratio - 1) < 0.02), res.ratio
    # Least squares on consecutive pairs is less efficient than the weighted estimator.
    ls, crb = res.predicted.least_squares_std[res.subset], res.predicted.crb_std[res.subset]
    assert np.all(ls >= crb * (1 - 1e-9)) and np.max(ls / crb) > 1.2


def test_results_do_not_depend_on_the_number_of_workers(scenario, monkeypatch):
    one = study(scenario, trials=4, seed=5, workers=1, progress=False)
    monkeypatch.setattr(relcal.sim.study, "WORKER_STARTUP_S", 0.0)  # spawn even for 4 trials
    spawned = []
    monkeypatch.setattr(relcal.sim.study, "ProcessPoolExecutor", _recording(spawned))
    two = study(scenario, trials=4, seed=5, workers=2, progress=False, chunk=1)
    assert spawned == [2]
    # Same noise per trial; only round-off differs (BLAS threads) within the solver tolerance.
    np.testing.assert_allclose(one.estimates, two.estimates, rtol=0, atol=1e-10)


def _recording(spawned: list):
    """``ProcessPoolExecutor`` that records how many workers each pool was given."""
    from concurrent.futures import ProcessPoolExecutor

    def make(workers, **kwargs):
        spawned.append(workers)
        return ProcessPoolExecutor(workers, **kwargs)

    return make


def test_short_studies_run_in_this_process(scenario, monkeypatch):
    spawned = []
    monkeypatch.setattr(relcal.sim.study, "ProcessPoolExecutor", _recording(spawned))
    study(scenario, trials=4, seed=5, workers=2, progress=False)
    assert spawned == []  # 4 trials take far less than starting a worker


def test_a_busy_machine_does_not_send_short_studies_to_workers(scenario, monkeypatch):
    """The reference estimate stalled by 0.5 s of wall-clock time (another process on the
    cores): the 4 trials are still far less work than starting a worker."""
    import time

    real, calls = relcal.sim.study._estimate, []

    def stalled(problem, context):
        calls.append(1)
        if len(calls) == 1:  # the noise-free reference, the one that is timed
            time.sleep(0.5)
        return real(problem, context)

    spawned = []
    monkeypatch.setattr(relcal.sim.study, "_estimate", stalled)
    monkeypatch.setattr(relcal.sim.study, "ProcessPoolExecutor", _recording(spawned))
    study(scenario, trials=4, seed=5, workers=2, progress=False)
    assert spawned == [] and len(calls) == 5


def test_command_line_study(tmp_path, capsys):
    out = tmp_path / "study.json"
    code = main(
        ["study", "--robot", "a465", "--hayati", "auto", "--poses", "10", "--trials", "12"]
        + ["--noise", "0.05,0.01,0.001", "--json", str(out), "--quiet"]
    )
    assert code == 0
    doc = json.loads(out.read_text())
    assert doc["trials"] == 12 and doc["converged"] == 12
    assert doc["estimator"] == "weighted"
    assert {"name", "predicted_std", "empirical_std", "ratio", "bias_t"} <= set(
        doc["parameters"][0]
    )
    assert main(["study", "--poses", "nonsense.csv", "--trials", "3"]) == 2
    assert "not a file and not a number" in capsys.readouterr().err
