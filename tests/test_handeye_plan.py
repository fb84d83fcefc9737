"""``relcal plan --for handeye``: poses chosen for the hand-eye ``X`` alone, checked against planted
truth: the plan's predicted and simulated errors of ``X`` are smaller than those of random
feasible poses of the same count, no pair of its poses turns near 180 deg, and the command
prints and writes what it predicts."""

from __future__ import annotations

import json

import numpy as np
import pytest

import relcal
from relcal import geometry as tf
from relcal.calibration.handeye_fit import fit_poses
from relcal.design.cell import Cell
from relcal.design.criteria import DEFAULT_NOISE
from relcal.design.handeye import PairRule
from relcal.design.plan import plan
from relcal.robot.kinematics import fk

N_POSES = 12
W_TRUE = tf.from_xyz_rpy(np.array([0.4, -0.1, 0.3]), np.radians([178.0, 3.0, -40.0]))


@pytest.fixture(scope="module")
def ur5e_plan():
    model = relcal.get_robot("ur5e")
    cell = Cell(handeye=tf.from_xyz_rpy(np.array([0.01, 0.05, 0.07]), np.radians([2, -3, 20])))
    res = plan(model, cell, n_poses=N_POSES, n_candidates=400, random_sets=15, n_validation=10,
               purpose="handeye", seed=3)  # fmt: skip
    return model, cell, res


def simulated_errors(model, q, x, seeds) -> np.ndarray:
    """``(S, 6)`` errors ``xi`` of ``X_hat = X exp(xi)`` (m, rad) of the refined fit on camera
    poses ``W F(q) X exp(eps)`` with the planning noise (isotropic 0.05 mm, 0.01 deg)."""
    flange = fk(model, q)
    sd = np.r_[np.full(3, DEFAULT_NOISE.position), np.full(3, DEFAULT_NOISE.orientation)]
    out = []
    for seed in seeds:
        eps = np.random.default_rng(seed).normal(size=(len(q), 6)) * sd
        poses = W_TRUE @ flange @ x @ tf.from_vector(eps)
        start = x @ tf.from_vector(np.r_[0.002, -0.001, 0.003, 0.01, -0.02, 0.01])
        fit = fit_poses(model, q, poses, start, W_TRUE, reject=False)
        out.append(tf.to_vector(tf.invert(x) @ fit.handeye))
    return np.array(out)


def test_plan_beats_random_poses_predicted_and_simulated(ur5e_plan):
    model, cell, res = ur5e_plan
    assert res.purpose == "handeye" and len(res.q) >= N_POSES
    assert res.plan.uncertainty.names == tuple(
        f"handeye.{c}" for c in ("tx", "ty", "tz", "rx", "ry", "rz")
    )
    # predicted: the worst component (angles as the displacement 0.5 m away) is smaller
    assert res.plan.worst[1] < res.random_median_worst
    # no pair of the plan turns near 180 deg or barely moves; random sets have such pairs
    assert res.motion.bad_pairs == 0
    assert res.random_motion is not None and res.random_motion.n_poses == len(res.q)
    assert res.motion.axis_spread[2] > 0.2  # rotation axes spread over three directions
    # simulated: the refined estimate's spread over noisy data sets, plan against the median
    # random set, in units of the same weighting as the criterion
    weights = np.r_[np.ones(3), np.full(3, 0.5)]
    seeds = range(40)
    planned = simulated_errors(model, res.q, cell.handeye, seeds)
    random = simulated_errors(model, res.random_q, cell.handeye, seeds)
    worst_planned = np.max(np.sqrt(np.mean(planned**2, axis=0)) * weights)
    worst_random = np.max(np.sqrt(np.mean(random**2, axis=0)) * weights)
    assert worst_planned < worst_random, (worst_planned, worst_random)
    # and the plan's prediction is what the simulation shows (40 sets: +-25 %)
    predicted = np.sqrt(np.diag(res.plan.uncertainty.crb))
    empirical = np.sqrt(np.mean(planned**2, axis=0))
    assert np.allclose(empirical, predicted, rtol=0.3), empirical / predicted


def test_pair_rule_finds_half_turns_and_repeats():
    model = relcal.get_robot("ur5e")
    q = np.radians([[0, -90, 90, -90, -90, 0]] * 4, dtype=float)
    q[1, 5] += np.radians(175.0)  # the wrist turned by 175 deg: near a half turn
    q[2, 5] += np.radians(0.5)  # a repeat: 0.5 deg, no translation
    q[3, 5] += np.radians(60.0)  # a good pair
    rule = PairRule.of(model, q)
    bad = rule.bad_pairs(np.arange(4), np.arange(4))
    assert bad[0, 1] and bad[0, 2] and not bad[0, 3]
    assert set(rule.conflicts(np.array([0]))) == {1, 2}
    assert set(rule.excluded(np.array([3]), np.array([0]))) == {1, 2, 3}


def test_command_prints_and_writes_the_prediction(tmp_path, capsys):
    from relcal.cli import main

    out, doc = tmp_path / "plan.csv", tmp_path / "plan.json"
    code = main(["plan", "--robot", "ur5e", "--for", "handeye", "--poses", "8",
                 "--candidates", "200", "--random-sets", "3", "--out", str(out),
                 "--json", str(doc)])  # fmt: skip
    assert code == 0
    text = capsys.readouterr().out
    assert "maximising worst of the hand-eye X alone" in text
    assert "hand-eye X (flange frame" in text
    data = json.loads(doc.read_text())
    assert data["purpose"] == "handeye"
    he = data["handeye"]["plan"]
    assert len(he["std_xyz_mm"]) == 3 and he["pairs_near_180_deg_or_still"] == 0
    assert data["handeye"]["random_median"]["n_poses"] == 8
    plan_file = relcal.design.planfile.read_plan(out, relcal.get_robot("ur5e"))
    assert len(plan_file.q) >= 8


def test_handeye_plan_refuses_other_formulations():
    from relcal.errors import ArgumentError

    with pytest.raises(ArgumentError, match="purpose 'handeye'"):
        plan(relcal.get_robot("ur5e"), Cell(), n_poses=5, formulation="published",
             purpose="handeye")  # fmt: skip


def test_plan_capture_handeye_in_the_virtual_cell(tmp_path):
    """``relcal plan --for handeye``, ``relcal capture`` in the virtual cell (the sim controller
    reports its flange poses: columns fx .. fqw), then ``relcal handeye`` of the dataset: the
    logged flange poses are used, and the planted hand-eye is recovered within 3 predicted
    standard deviations."""
    import importlib.util

    if importlib.util.find_spec("mujoco") is None:  # not imported here: MUJOCO_GL is set first
        pytest.skip("the virtual cell needs MuJoCo (the virtual extra)")
    from relcal.capture.virtual import make_cell
    from relcal.cli import main

    plan_file, out, he = tmp_path / "plan.csv", tmp_path / "ds", tmp_path / "he"
    assert main(["plan", "--robot", "ur5e", "--for", "handeye", "--poses", "12",
                 "--candidates", "300", "--random-sets", "0", "--out", str(plan_file),
                 "--quiet"]) == 0  # fmt: skip
    assert main(["capture", str(plan_file), "--robot-driver", "sim", "--camera", "sim",
                 "--out", str(out), "--robot-option", "seed=7", "--quiet"]) == 0  # fmt: skip
    header = (out / "samples.csv").read_text().splitlines()[0].split(",")
    assert header[-8:] == ["fx", "fy", "fz", "fqx", "fqy", "fqz", "fqw", "image"]
    dataset = relcal.load_dataset(out)
    truth = make_cell(relcal.get_robot("ur5e"), seed=7).truth
    # the logged flange poses are the controller's (the arm's true kinematics) at the joints
    # recorded: the mean over the still window of each, so equal to the joints' to round-off
    # of the noise's second order
    expected = fk(truth.true_model, dataset.q)
    assert np.abs(dataset.flange - expected).max() < 1e-6
    assert main(["handeye", str(out), "--out", str(he), "--quiet"]) in (0, 1)
    result = relcal.handeye(dataset)
    assert result.source == "the logged flange poses"
    err = tf.to_vector(tf.invert(truth.handeye) @ result.handeye)
    std = np.sqrt(np.diag(result.fit.covariance))[:6]
    assert np.all(np.abs(err) < 3 * std), err / std
    assert (he / "handeye.yaml").is_file()
