"""Weakly determined directions are held (priors, truncation) and named, not refused (issue 18
items 5 and 6).

The scenario of the issue: an arm whose wrist joints barely move. A plain least squares then
drives the wrist's parameters to centimetres (the plausibility gate refuses them); the maximum a
posteriori fit with the default priors keeps them within their tolerances, names them with their
joints, and predicts held-out samples as well as an independent reference: a plain SciPy
Levenberg-Marquardt of the subset that QR with column pivoting selects at the noise level.
"""

from __future__ import annotations

import csv
import json
from dataclasses import replace

import numpy as np
import pytest
import scipy.linalg
import scipy.optimize
from conftest import DATA, random_q
from helpers_sim import true_errors

from relcal import geometry as tf
from relcal.calibration.identify import gradient_check, posterior_covariance
from relcal.calibration.measurement import (
    make_pairs,
    pair_errors,
    residuals,
    split_params,
    world_errors,
)
from relcal.calibration.pipeline import calibrate
from relcal.calibration.priors import overcount, row_weights
from relcal.calibration.validate import subset
from relcal.cli import main
from relcal.data.dataset import Dataset, load_dataset, write_samples
from relcal.errors import RelcalError
from relcal.robot.kinematics import apply_errors, fk, make_layout
from relcal.robot.loading import get_robot
from relcal.robot.model import dump_model, load_model, model_from_dict, model_to_dict
from relcal.robot.priors import Priors

REAL = pytest.mark.skipif(not DATA.is_dir(), reason="real data not available")
TIAGO = DATA / "tiago_pro"
NOISE = (5e-4, np.radians(0.1))  # motion capture: 0.5 mm, 0.1 deg per pose
GUESS = tf.from_vector(np.array([0.0, 0.04, 0.06, 0.0, 0.0, 0.0]))


def _poses(model, q, rng, guess=GUESS):
    """Measured poses of a perturbed ``model`` (errors of 0.1..0.9 mm and 0.01..0.9 deg), the
    hand-eye 1 mm / 0.3 deg off its guess, with :data:`NOISE`."""
    layout = make_layout(model)
    true_model = apply_errors(model, layout, true_errors(layout, rng))
    true_x = guess @ tf.from_vector(np.r_[rng.normal(0, 1e-3, 3), rng.normal(0, 5e-3, 3)])
    board = tf.from_vector(np.array([0.5, 0.1, -0.3, 0.1, 3.0, 0.2]))
    n = len(q)
    delta = np.c_[rng.normal(0, NOISE[0], (n, 3)), rng.normal(0, NOISE[1], (n, 3))]
    return board @ fk(true_model, q) @ true_x @ tf.from_vector(delta)


def _held_out_mm(cal, params) -> float:
    """Held-out position RMS (mm) of ``params``: of the test samples' poses in the world frame
    (the board formulation, relcal's default), or over the pairs of the test samples."""
    if cal.problem.formulation == "board":
        model, _ = split_params(cal.problem, params)
        test = cal.test
        poses = cal.measurements.poses[test]
        err = world_errors(cal.problem, params, model, cal.dataset.q[test], poses)[:, :3]
        return float(np.sqrt(np.mean(np.sum(err**2, axis=1)))) * 1e3
    n = len(cal.dataset.q)
    every = replace(cal.problem, q=cal.dataset.q, poses=cal.measurements.poses)
    every = replace(every, pairs=make_pairs(n, "all"))
    err = pair_errors(subset(every, cal.test, "all"), params)[:, :3]
    return float(np.sqrt(np.mean(np.sum(err**2, axis=1)))) * 1e3


def _reference(cal) -> np.ndarray:
    """A plain SciPy LM of the parameters that QR with column pivoting keeps at the noise level:
    the columns scaled by a typical error (1 mm, 1 deg; the hand-eye likewise), kept while the
    pivot's ``|R_kk|`` (the residual a typical error along a new direction adds) exceeds three
    noise levels of the training pairs. Nothing of relcal's selection, priors or solver."""
    problem = cal.problem
    layout = problem.full_layout
    _, jac = residuals(problem, np.zeros(layout.size))
    typical = np.where(layout.is_angle(), np.radians(1.0), 1e-3)
    _, r, piv = scipy.linalg.qr(jac * typical, mode="economic", pivoting=True)
    rows = residuals(problem, cal.result.params, jacobian=False)
    noise = 1.4826 * np.median(np.abs(rows)) * np.sqrt(len(cal.train) / 2)
    keep = np.sort(piv[np.abs(np.diag(r)) > 3 * noise])

    def fun(x):
        full = np.zeros(layout.size)
        full[keep] = x
        return residuals(problem, full, jacobian=False)

    sol = scipy.optimize.least_squares(fun, np.zeros(len(keep)), method="lm", x_scale="jac")
    out = np.zeros(layout.size)
    out[keep] = sol.x
    return out


def _corrections_mm_deg(cal) -> np.ndarray:
    """|link corrections| in mm and deg (the measurement frames left out)."""
    layout = cal.problem.full_layout
    link = np.array([k not in ("handeye", "board") for k in layout.kinds])
    conv = np.where(layout.is_angle(), 180 / np.pi, 1e3)
    return np.abs(cal.result.params * conv)[link]


def _assert_held_and_named(cal, joints: tuple[str, ...]) -> None:
    """Plausible corrections, the weak directions named with these joints, and held-out errors
    as good as the reference's (within 10 %) and far better than the baseline's."""
    assert _corrections_mm_deg(cal).max() < 5.0  # the default tolerances are 10 mm and 5 deg
    weak = cal.settings["weak_directions"]
    assert any(j in w["text"] for w in weak for j in joints), weak
    assert all(w["held"] in ("by its prior", "at nominal") for w in weak)
    ours, ref = _held_out_mm(cal, cal.result.params), _held_out_mm(cal, _reference(cal))
    assert ours <= 1.1 * ref, (ours, ref)
    assert ours < 0.3 * _held_out_mm(cal, cal.baseline.params)
    assert cal.result.converged


def test_a_barely_moving_wrist_is_held_by_priors_not_refused():
    """A 7-joint arm, 61 samples, joints 5 to 7 moving over 4 degrees: the plain least squares
    puts a wrist link length beyond 10 mm (refused), the default priors hold it."""
    rng = np.random.default_rng(1)
    model = get_robot("franka_fr3")
    q = random_q(model, 61, rng, 0.8)
    q[:, 4:] = np.radians(30) + rng.uniform(-1, 1, (61, 3)) * np.radians(2)
    dataset = Dataset.from_arrays(model, q, _poses(model, q, rng), handeye=GUESS, hayati="off")
    # all pairs of poses (the board formulation's default fit happens to stay plausible here)
    with pytest.raises(RelcalError, match="too large to be plausible"):
        calibrate(dataset, priors="none", pairing="all")
    _assert_held_and_named(calibrate(dataset), model.joint_names[4:])
    cal = calibrate(dataset, pairing="all")
    _assert_held_and_named(cal, model.joint_names[4:])
    # the wrist joints' travel is in the words
    assert any("moved over" in w["text"] for w in cal.settings["weak_directions"])
    # non-geometric candidates these samples cannot determine are dropped and named, not refused
    assert {d["family"] for d in cal.settings["dropped_candidates"]} >= {"scale"}
    assert "dropped (not determined by these samples)" in cal.reason


def _tiago_narrow_wrist(folder, seed: int) -> None:
    """The TIAGo Pro's 48 real configurations (PAL's URDF) with the wrist compressed about its
    median: arm_right_6_joint over 27 deg, arm_right_7_joint over 2.6 deg (the travel of the
    humanoid's wrist in the issue); poses of a perturbed arm with motion-capture noise."""
    rows = list(csv.DictReader((TIAGO / "mocap_pose_20260805.csv").open()))
    q = np.array([[float(r[k]) for k in r if k.endswith("joint")] for r in rows])
    for j, span in ((6, 27.0), (7, 2.6)):
        mid = np.median(q[:, j])
        q[:, j] = mid + (q[:, j] - mid) / np.ptp(q[:, j]) * np.radians(span)
    model = get_robot(TIAGO / "tiago_pro.urdf", "base_footprint", "gripper_right_pal_atc_base_link")
    guess = tf.from_vector(np.array([0.0, 0.0, 0.142, 0.0, 0.0, 0.0]))
    poses = _poses(model, q, np.random.default_rng(seed), guess)
    folder.mkdir()
    ids = [f"s{k:02d}" for k in range(len(q))]
    (folder / "samples.csv").write_text(write_samples(folder / "samples.csv", ids, q, poses=poses))
    (folder / "dataset.yaml").write_text(
        f"robot: {{urdf: {TIAGO / 'tiago_pro.urdf'}, root: base_footprint, "
        "tip: gripper_right_pal_atc_base_link}\njoint_unit: rad\n"
        "handeye: {xyz: [0, 0, 0.142]}\nsamples: samples.csv\n"
    )


@REAL
def test_tiago_pro_with_a_narrow_wrist_calibrates_and_names_the_wrist(tmp_path):
    folder = tmp_path / "tiago"
    _tiago_narrow_wrist(folder, seed=1)
    dataset = load_dataset(folder)
    with pytest.raises(RelcalError, match="too large to be plausible"):
        calibrate(dataset, priors="none", pairing="all")
    cal = calibrate(dataset)
    _assert_held_and_named(cal, ("arm_right_6_joint", "arm_right_7_joint"))
    # the command line exits 0 and results.json names the weak directions
    out, report = tmp_path / "out", tmp_path / "report.html"
    argv = ["calibrate", str(folder), "--out", str(out), "--report", str(report), "--quiet"]
    assert main(argv) == 0
    doc = json.loads((out / "results.json").read_text())
    weak = doc["identification"]["weak_directions"]
    assert any("arm_right_7_joint" in text for text in weak), weak
    html = report.read_text()
    assert "Weakly determined directions" in html and "a[arm_right_7_joint]: held by its" in html
    assert doc["settings"]["priors"]["length_mm"] == 1.0


@REAL
def test_circle_grid_default_recipe_drops_the_undetermined_candidates(tmp_path):
    """The default recipe of docs/tutorials/images.md on the real circle-grid set: exit 0 (it
    was refused: 'scale[4] +2.06e+09 ppm, vary the joints more'), the joint-scale and harmonic
    candidates dropped and named."""
    folder, out = tmp_path / "circles", tmp_path / "out"
    source = DATA / "rct_circle_grid_eye_in_hand"
    assert main(["import", "rct-images", str(source), "--out", str(folder), "--quiet"]) == 0
    assert main(["calibrate", str(folder), "--out", str(tmp_path / "default"), "--quiet"]) == 0
    # with relative pairs and these training images (seed 2), the scale and harmonic families
    # are left undetermined: dropped and named
    argv = ["calibrate", str(folder), "--out", str(out), "--pairing", "all", "--seed", "2"]
    argv += ["--quiet"]
    assert main(argv) == 0
    doc = json.loads((out / "results.json").read_text())
    dropped = doc["settings"]["dropped_candidates"]
    assert {d["family"] for d in dropped} == {"scale", "harmonic"}
    assert all("not determined by these samples" in d["reason"] for d in dropped)
    names = {s["name"] for s in doc["model_selection"]["candidates"]}
    assert not any("scale" in n or "harmonic" in n for n in names), names


def test_joints_that_never_move_are_held_at_nominal_and_named(tmp_path, capsys):
    """Poses that never move joints 4 and 6 of the A465 were refused ('vary the joints more'):
    now the combinations they leave undetermined are held at nominal and named with the joints'
    travel, the non-geometric candidates they cannot determine are dropped, and the run exits 0."""
    from test_bad_input import Q_FIXED_WRIST, write_dataset

    root = write_dataset(tmp_path / "d", q=Q_FIXED_WRIST)
    assert main(["calibrate", str(root), "--out", str(tmp_path / "out")]) == 0
    printed = capsys.readouterr().out
    doc = json.loads((tmp_path / "out" / "results.json").read_text())
    nominal = [w for w in doc["settings"]["weak_directions"] if w["held"] == "at nominal"]
    fixed = get_robot("a465").joint_names[3]  # joint 4
    assert any(f"{fixed} moved over 0 deg" in w["text"] for w in nominal), nominal
    assert "weakly determined:" in printed and "candidates dropped:" in printed
    assert {d["family"] for d in doc["settings"]["dropped_candidates"]} == {"scale", "harmonic"}


# -- the maximum a posteriori cost -----------------------------------------------------------


def test_priors_none_is_the_plain_least_squares_and_priors_change_the_cost():
    rng = np.random.default_rng(4)
    model = get_robot("a465")
    q = random_q(model, 30, rng, 0.8)
    dataset = Dataset.from_arrays(model, q, _poses(model, q, rng), handeye=GUESS)
    plain = calibrate(dataset, priors="none", nongeometric="none")
    assert plain.result.prior is None and "priors" not in plain.settings
    cal = calibrate(dataset, nongeometric="none")
    res = cal.result
    assert res.prior is not None and res.converged
    cols = res.identifiability.subset
    # the MAP estimate is not stationary for the data's cost alone: the prior rows count
    alone = gradient_check(cal.problem, res.params, cols)
    assert not alone.passed
    with_rows = gradient_check(cal.problem, res.params, cols, prior=res.prior)
    assert with_rows.passed


def test_prior_row_weights_follow_the_noise_and_the_pair_overcount():
    # all pairs of N samples count each sample's information N / 2 times; consecutive once
    assert overcount(45, 10) == pytest.approx(5.0)
    assert overcount(9, 10) == 1.0
    w = row_weights(np.array([1e-3, np.inf, np.radians(1.0)]), 2e-4, 4.0)
    np.testing.assert_allclose(w, [2 * 2e-4 / 1e-3, 0.0, 2 * 2e-4 / np.radians(1.0)])


def test_posterior_covariance_is_the_linear_gaussian_posterior(rng):
    """Against the textbook posterior of a linear model: ``(A^T A / s^2 + diag(1/p^2))^-1``."""
    a = rng.normal(size=(40, 4)) * [1.0, 1e-3, 10.0, 1e-2]  # one nearly flat direction
    s, prior = 0.1, np.array([np.inf, 0.5, 2.0, 0.3])
    data = np.full((5, 5), np.nan)
    data[:4, :4] = s**2 * np.linalg.inv(a.T @ a)
    got = posterior_covariance(data, np.r_[prior, np.inf], np.arange(4))
    want = np.linalg.inv(a.T @ a / s**2 + np.diag(1 / prior**2))
    np.testing.assert_allclose(got[:4, :4], want, rtol=1e-8, atol=1e-14)
    assert np.isnan(got[4, 4])


# -- priors in the model file ----------------------------------------------------------------


def test_priors_in_the_model_file_round_trip_and_bad_ones_are_refused(tmp_path):
    model = get_robot("a465")
    assert model.priors == Priors()
    data = model_to_dict(model)
    assert "priors" not in data  # the defaults are not written
    custom = model_from_dict({**data, "priors": {"length_mm": 0.2, "offset_deg": 2}})
    assert custom.priors.si("length_mm") == pytest.approx(2e-4)
    assert custom.priors.angle_deg == 0.5  # the others at their defaults
    path = tmp_path / "robot.yaml"
    path.write_text(dump_model(custom))
    assert load_model(path).priors == custom.priors
    off = model_from_dict({**data, "priors": "none"})
    assert not off.priors.enabled
    path.write_text(dump_model(off))
    assert not load_model(path).priors.enabled
    with pytest.raises(RelcalError, match="unknown prior"):
        model_from_dict({**data, "priors": {"length": 1}})
    with pytest.raises(RelcalError, match="positive"):
        model_from_dict({**data, "priors": {"angle_deg": -1.0}})
