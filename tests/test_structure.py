"""Validation that sees the structure of a recording: repeated configurations are held out
together, joints that never moved and singular samples are named, and the verdict's interval is
honest against a fresh session of the same simulated robot (its lower bound at most twice the
improvement the fresh session shows)."""

import numpy as np
import pytest
from conftest import random_q
from helpers_sim import BOARD, HANDEYE, true_errors

import relcal
from relcal import geometry as tf
from relcal.calibration.coverage import (
    configuration_clusters,
    singular_samples,
    still_joints,
)
from relcal.calibration.measurement import fit_world
from relcal.robot.kinematics import apply_errors, fk, make_layout
from relcal.robot.loading import get_robot

NOISE = (0.05e-3, np.radians(0.01))  # pose noise: 0.05 mm, 0.01 deg per axis


def _poses(truth_model, q, rng):
    poses = BOARD @ fk(truth_model, q) @ HANDEYE
    noise = np.r_[np.full(3, NOISE[0]), np.full(3, NOISE[1])]
    return poses @ tf.from_vector(rng.normal(0, 1, (len(q), 6)) * noise)


def _robot(seed=5):
    nominal = get_robot("a465")
    rng = np.random.default_rng(seed)
    truth = apply_errors(nominal, make_layout(nominal), true_errors(make_layout(nominal), rng))
    return nominal, truth, rng


def _fresh_improvement(cal, truth, rng, n=60):
    """Baseline RMS over calibrated RMS of world-frame position errors on a fresh session of
    ``truth`` (random configurations, the world transform refitted there for each model, the
    hand-eye the calibration's own)."""
    q = random_q(truth, n, rng)
    poses = _poses(truth, q, rng)
    rms = {}
    for name, model, fit in (
        ("baseline", cal.dataset.model, cal.baseline),
        ("calibrated", cal.model, cal.result),
    ):
        from relcal.calibration.measurement import split_params

        _, handeye = split_params(cal.problem, fit.params)
        world = fit_world(model, handeye, q, poses)
        err = tf.invert(world @ fk(model, q) @ handeye) @ poses
        rms[name] = np.sqrt(np.mean(np.sum(err[:, :3, 3] ** 2, axis=1)))
    return rms["baseline"] / rms["calibrated"]


def _honest(cal, truth, rng):
    v = cal.verdict()
    true = _fresh_improvement(cal, truth, rng)
    assert v.interval is not None
    assert v.interval[0] <= 2 * true, (v.text, true)
    return v, true


def test_repeats_are_one_configuration():
    model = get_robot("a465")
    rng = np.random.default_rng(0)
    base = random_q(model, 4, rng)
    q = np.repeat(base, 10, axis=0) + rng.normal(0, np.radians(0.01), (40, 6))
    labels = configuration_clusters(model, q)
    assert labels.max() + 1 == 4
    assert all(len(set(labels[k * 10 : k * 10 + 10])) == 1 for k in range(4))
    # a dense sweep (0.1 deg steps over 60 deg) is not one configuration
    sweep = np.zeros((600, 6))
    sweep[:, 0] = np.radians(np.arange(600) * 0.1)
    assert configuration_clusters(model, sweep).max() + 1 >= 600 * 0.1 / 2.0


def test_jittered_copies_held_out_whole_and_the_verdict_honest():
    """40 samples that are 4 configurations jittered by 0.01 deg: whole configurations held out,
    4 distinct configurations said, no "deploy", and an honest interval."""
    nominal, truth, rng = _robot()
    base = random_q(nominal, 4, rng)
    q = np.repeat(base, 10, axis=0) + rng.normal(0, np.radians(0.01), (40, 6))
    ds = relcal.Dataset.from_arrays(nominal, q, _poses(truth, q, rng))
    cal = relcal.calibrate(ds, nongeometric="none")
    cov = cal.settings["coverage"]
    assert cov["configurations"] == 4 and cov["repeated_samples"] == 36
    labels = configuration_clusters(nominal, cal.dataset.q)
    assert not set(labels[cal.train]) & set(labels[cal.test])
    v, _ = _honest(cal, truth, rng)
    assert v.code != "deploy" and v.n_configurations == 1


def test_a_joint_that_never_moved_is_named_and_the_verdict_honest():
    nominal, truth, rng = _robot(6)
    q = random_q(nominal, 40, rng)
    q[:, 3] = np.radians(30.0)
    ds = relcal.Dataset.from_arrays(nominal, q, _poses(truth, q, rng))
    cal = relcal.calibrate(ds, nongeometric="none")
    still = cal.settings["coverage"]["still_joints"]
    assert [s["joint"] for s in still] == [4] and still[0]["value"] == pytest.approx(30.0)
    v, _ = _honest(cal, truth, rng)
    assert v.code != "deploy"
    assert any("joint 4" in text and "never moved" in text for text in v.limits)


def test_every_sample_at_the_wrist_singularity_is_named_and_the_verdict_honest():
    nominal, truth, rng = _robot(7)
    q = random_q(nominal, 40, rng)
    q[:, 4] = 0.0  # the wrist: joints 4 and 6 aligned
    assert len(singular_samples(nominal, q).samples) == 40
    ds = relcal.Dataset.from_arrays(nominal, q, _poses(truth, q, rng))
    cal = relcal.calibrate(ds, nongeometric="none")
    cov = cal.settings["coverage"]
    assert len(cov["singular_samples"]) == 40
    assert [s["joint"] for s in cov["still_joints"]] == [5]
    v, _ = _honest(cal, truth, rng)
    assert v.code != "deploy"
    assert any("singular" in text for text in v.limits)


def test_well_spread_samples_still_deploy_and_the_interval_holds():
    """The rules above do not take "deploy" from a good set: random configurations, all joints
    moving, no repeats."""
    nominal, truth, rng = _robot(8)
    q = random_q(nominal, 60, rng)
    ds = relcal.Dataset.from_arrays(nominal, q, _poses(truth, q, rng))
    cal = relcal.calibrate(ds, nongeometric="none")
    assert cal.settings["coverage"]["limits"] == []
    assert still_joints(nominal, q) == []
    v, true = _honest(cal, truth, rng)
    assert v.code == "deploy"
    assert v.interval == v.held_out_interval
    assert v.interval[0] <= true <= 3 * v.interval[1]
