"""Model selection for position-only (tracker) samples: the pose path's candidates, scoring and
choice (calibration.selection) on points, against planted non-geometric errors, against nothing
planted over many seeds, against brute-force refits, and on the real TIAGo Pro positions."""

from dataclasses import replace

import numpy as np
import pytest
from conftest import DATA, random_q
from helpers_sim import true_errors, with_plausible_loads

from relcal import geometry as tf
from relcal.calibration.measurement import residuals
from relcal.calibration.pipeline import calibrate
from relcal.calibration.selection import (
    Candidate,
    candidates,
    family,
    linearise,
    plain_whiteners,
    sample_folds,
    score_candidates,
)
from relcal.data.dataset import load_dataset
from relcal.data.imaging import measure
from relcal.reporting.documents import validation_document
from relcal.robot.kinematics import apply_errors, fk, make_layout
from relcal.robot.loading import get_robot
from relcal.robot.model import auto_hayati, dump_model, with_nongeometric

INSTRUMENT = tf.from_vector(np.array([1.1, -0.3, 0.2, 0.05, -0.1, 2.0]))  # tracker from base
MARKER = np.array([0.02, -0.01, 0.11])  # flange frame, m
SIGMA = 50e-6  # point noise per axis, m
FAMILIES = {"scale": ("scale",), "compliance": ("compliance",), "harmonic": ("harmonic",)}
FAMILIES["all"] = ("scale", "compliance", "harmonic")
PLANTED = {  # SI: scale (1), compliance (rad/(N m)), harmonics (rad); FR3 with plausible masses
    "scale[1]": -6e-4, "scale[4]": 7e-4, "scale[6]": -5e-4,
    "compliance[2]": 3e-5, "compliance[4]": 5e-5,
    "harmonic_c[1]": 2e-4, "harmonic_s[3]": -3e-4, "harmonic_c[5]": 3e-4,
}  # fmt: skip


def point_dataset(root, n, seed, families=()):
    """``n`` noisy marker points of an FR3 with geometric errors of 0.1..0.9 mm and 0.01..0.9
    deg and the :data:`PLANTED` terms of ``families``; the dataset's robot file has link masses
    and no non-geometric options (model selection offers them). Returns the truth by name."""
    rng = np.random.default_rng(seed)
    nominal = with_plausible_loads(auto_hayati(get_robot("franka_fr3")), "franka_fr3")
    model = with_nongeometric(nominal, ["scale", "compliance", "harmonic"])
    layout = make_layout(model)
    truth = true_errors(layout, rng) * layout.is_geometric()
    for name, value in PLANTED.items():
        if name.split("_")[0].split("[")[0] in families:
            truth[layout.names.index(name)] = value
    q = random_q(model, n, rng, scale=0.8)
    flange = fk(apply_errors(model, layout, truth), q)
    p = (flange[:, :3, :3] @ MARKER + flange[:, :3, 3]) @ INSTRUMENT[:3, :3].T + INSTRUMENT[:3, 3]
    p += rng.normal(0, SIGMA, p.shape)
    root.mkdir(parents=True, exist_ok=True)
    (root / "robot.yaml").write_text(dump_model(nominal))
    (root / "dataset.yaml").write_text("robot: robot.yaml\njoint_unit: rad\n")
    rows = [",".join(["id", "x", "y", "z", *model.joint_names])]
    rows += [",".join(f"{v:.17g}" for v in [k, *p[k], *q[k]]) for k in range(n)]
    (root / "samples.csv").write_text("\n".join(rows) + "\n")
    return dict(zip(layout.names, truth, strict=True))


def _calibrate(root, **options):
    ds = load_dataset(root)
    return calibrate(ds, measure(ds, progress=False), **options)


def _rms(cal) -> float:
    return validation_document(cal.validation)["calibrated"]["position_mm"]["rms"]


@pytest.mark.parametrize("planted", list(FAMILIES))
def test_planted_terms_are_chosen_and_recovered(tmp_path, planted):
    """Each family planted alone (and all three together) on 100 points: exactly that family
    is chosen, every term of it is recovered within its standard deviation (planted or zero),
    and held-out points come down to the noise floor, which the geometry alone misses."""
    truth = point_dataset(tmp_path / "d", 100, seed=0, families=FAMILIES[planted])
    cal = _calibrate(tmp_path / "d", holdout=0.25)
    chosen = cal.selection[cal.chosen].candidate
    assert chosen.name == "geometric + " + " + ".join(FAMILIES[planted]), cal.reason
    names = cal.problem.full_layout.names
    kinds = cal.problem.full_layout.kinds
    terms = [k for k in chosen.columns if family(kinds[k]) not in ("frames", "geometric")]
    assert terms and all(np.isfinite(cal.std[terms]))
    z = (cal.result.params[terms] - np.array([truth[names[k]] for k in terms])) / cal.std[terms]
    assert np.abs(z).max() < 3.5, dict(zip(np.array(names)[terms], np.round(z, 2), strict=True))
    assert np.mean(z**2) < 2.0  # about one for an honest covariance
    for name in PLANTED:
        if name in np.array(names)[terms]:
            k = names.index(name)
            assert abs(cal.result.params[k] - truth[name]) < 3 * cal.std[k]
    floor = np.sqrt(3) * SIGMA * 1e3  # RMS norm of a 3-D Gaussian error, mm
    assert _rms(cal) < 1.3 * floor
    if planted == "all":
        geometric = _calibrate(tmp_path / "d", holdout=0.25, nongeometric="none")
        assert geometric.selection[geometric.chosen].candidate.name == "geometric"
        assert _rms(geometric) > 3 * floor
    # The exported model keeps only the chosen families.
    assert {t for f in cal.model.nongeometric for t in f} == set(FAMILIES[planted])


def test_selection_rarely_adds_a_term_that_is_not_there(tmp_path):
    """Geometric errors planted, no non-geometric ones, 40 points of 50 um noise: over 20 seeds
    model selection adds a family at most 3 times (the pose path's allowance is 5 %: a 5 % rate
    exceeds 3 of 20 with probability 1.6 %; measured: none of 100 seeds adds one)."""
    added = []
    for seed in range(20):
        point_dataset(tmp_path / f"s{seed}", 40, seed=seed)
        cal = _calibrate(tmp_path / f"s{seed}", holdout=0.0, seed=seed)
        name = cal.selection[cal.chosen].candidate.name
        assert name.startswith("geometric"), name  # the planted geometry is always found
        added += [name] if name != "geometric" else []
    assert len(added) <= 3, added


def test_point_scores_equal_brute_force_refits(tmp_path):
    """The linearised point problem reproduces the residuals at its point, and score_candidates
    on points gives each held-out point's squared error of an independent least-squares refit
    of the other folds' rows (per point: one sample, no pairs)."""
    point_dataset(tmp_path / "d", 30, seed=1, families=("scale",))
    cal = _calibrate(tmp_path / "d", holdout=0.0)
    problem, params = cal.problem, cal.result.params
    lin = linearise(problem, params)
    r = residuals(replace(problem, weights=None), params, jacobian=False).reshape(-1, 3)
    np.testing.assert_allclose(lin.b[:, :3] - lin.jac[:, :3] @ params, r, atol=1e-15)
    assert not lin.b[:, 3:].any() and not lin.jac[:, 3:].any()  # no orientation measured
    assert np.array_equal(lin.pairs, np.repeat(np.arange(30)[:, None], 2, axis=1))
    cands = candidates(problem, cal.result.identifiability.subset)
    assert [c.name for c in cands][:2] == ["instrument and marker only", "geometric"]
    scores = score_candidates(lin, {"plain": plain_whiteners(30)}, cands, k=5, seed=3)
    for cand, score in zip(cands, scores, strict=True):
        expected = np.zeros(30)
        for fold in sample_folds(30, 5, 3):
            keep = np.setdiff1d(np.arange(30), fold)
            a = lin.jac[keep][:, :3][:, :, cand.columns].reshape(-1, len(cand.columns))
            b = lin.b[keep][:, :3].reshape(-1)
            scale = np.linalg.norm(a, axis=0)
            fit = np.zeros(len(params))
            fit[cand.columns] = np.linalg.lstsq(a / scale, b, rcond=None)[0] / scale
            held = lin.b[fold, :3] - lin.jac[fold, :3] @ fit
            expected[fold] = np.sum(held**2, axis=1)
        np.testing.assert_allclose(score.per_sample, expected, rtol=1e-6, atol=1e-18)
        assert isinstance(score.candidate, Candidate) and score.orientation_rms == 0.0


@pytest.mark.skipif(not (DATA / "tiago_pro").is_dir(), reason="real data not available")
def test_real_tiago_positions_choose_compliance(tmp_path):
    """The real TIAGo Pro's 94 marker positions through its URDF: with the non-geometric
    candidates (compliance from the URDF's link masses) the conservative selection keeps
    compliance, and the held-out points beat both the baseline (nominal, T and m fitted) and the
    geometry alone beyond the intervals of the ratios."""
    pytest.importorskip("relcal.robot.urdf")
    folder = DATA / "tiago_pro"
    (tmp_path / "dataset.yaml").write_text(
        f"robot: {{urdf: {folder / 'tiago_pro.urdf'}, root: base_footprint, "
        "tip: gripper_right_pal_atc_base_link}\njoint_unit: rad\n"
        f"columns: {{x: x1, y: y1, z: z1}}\nsamples: {folder / 'mocap_position_20260702.csv'}\n"
        "tolerances: {angle_deg: 5}\n"
    )
    cal = _calibrate(tmp_path, selection="conservative")
    geometric = _calibrate(tmp_path, selection="conservative", nongeometric="none")
    assert "compliance" in cal.selection[cal.chosen].candidate.name, cal.reason
    assert geometric.selection[geometric.chosen].candidate.name == "geometric"
    doc = validation_document(cal.validation)
    assert doc["ratio_to_baseline"]["position_mm"]["ci95"][1] < 1.0
    # The same held-out points, the same baseline: the geometric model's ratio lies above the
    # interval of the model with compliance.
    np.testing.assert_allclose(cal.validation.before, geometric.validation.before, atol=1e-9)
    geo_ratio = validation_document(geometric.validation)["ratio_to_baseline"]["position_mm"]
    assert geo_ratio["after_over_before"] > doc["ratio_to_baseline"]["position_mm"]["ci95"][1]
    kinds = cal.problem.full_layout.kinds
    free = [k for k in np.flatnonzero(np.isfinite(cal.std)) if kinds[k] == "compliance"]
    assert free and np.all(np.abs(cal.result.params[free]) >= 3 * cal.std[free])
