"""Placements are clusters: the covariance of a coincidence calibration when the samples of one
placement share systematic errors (relcal.calibration.uncertainty.clustered_covariance)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import DATA

from relcal.calibration.coincidence import (
    coincidence_problem,
    make_coincidence,
    row_placements,
)
from relcal.calibration.identifiability import analyse_problem
from relcal.calibration.identify import least_squares_covariance
from relcal.calibration.measurement import residuals
from relcal.calibration.uncertainty import (
    DESIGN_EFFECT,
    INDEPENDENT,
    clustered_covariance,
    design_effect,
)
from relcal.errors import RelcalError
from relcal.geometry import DEG, MM
from relcal.robot.kinematics import make_layout
from relcal.robot.urdf import load_urdf
from relcal.sim.coincidence import simulate_coincidence
from relcal.sim.scenario import random_errors

# --- a plain linear model: the design effect against Monte Carlo truth ---------------------------


def linear_model(rng, clusters=6, rows=40, shared=5):
    """A Jacobian ``(clusters * rows, shared + clusters)``: ``shared`` columns seen by every
    cluster, and one offset column per cluster (the cluster's own nuisance, like a placement's
    group points), and each row's cluster."""
    m = clusters * rows
    labels = np.repeat(np.arange(clusters), rows)
    own = np.zeros((m, clusters))
    own[np.arange(m), labels] = 1.0
    return np.hstack([rng.normal(size=(m, shared)), own]), labels


def draw(rng, a, labels, sigma, tau, shared):
    """Residual noise with a per-cluster random effect on the shared parameters (each cluster
    sees its own parameters ``p + delta_c``, ``delta_c ~ N(0, tau^2)``), the estimate and its
    residuals."""
    delta = rng.normal(0.0, tau, (labels.max() + 1, shared))
    y = np.einsum("mk,mk->m", a[:, :shared], delta[labels]) + rng.normal(0.0, sigma, len(a))
    est, *_ = np.linalg.lstsq(a, y, rcond=None)
    return est, y - a @ est


def test_independent_rows_have_a_design_effect_of_one_on_average():
    rng = np.random.default_rng(0)
    a, labels = linear_model(rng)
    effects = []
    for _ in range(400):
        _, r = draw(rng, a, labels, sigma=1.0, tau=0.0, shared=5)
        effects.append(design_effect(a, r, labels)[0])
    effects = np.array(effects)
    dof = design_effect(a, r, labels)[1]
    # the exact mean under independence: E[Q] = E0[Q] (s^2 nearly exact with 240 rows)
    assert np.mean(effects) == pytest.approx(1.0, abs=0.05)
    # Satterthwaite: Var[Q / E0] = 2 / dof (plus the small share of s^2's own noise)
    assert np.var(effects) == pytest.approx(2.0 / dof, rel=0.3)


def test_clustered_variances_match_the_spread_of_repeated_estimates():
    """Per-cluster random parameter offsets: the independent covariance understates the spread
    of the estimate over repetitions, the design effect restores it (on average over the
    parameters, which is what one factor can do)."""
    rng = np.random.default_rng(1)
    shared = 5
    a, labels = linear_model(rng, clusters=8, shared=shared)
    subset = np.arange(a.shape[1])
    ests, old, new = [], [], []
    for _ in range(300):
        est, r = draw(rng, a, labels, sigma=1.0, tau=0.3, shared=shared)
        out = clustered_covariance(a, r, subset, labels)
        ests.append(est[:shared])
        old.append(np.diag(out.independent)[:shared])
        new.append(np.diag(out.covariance)[:shared])
        assert out.method == DESIGN_EFFECT and out.clusters == 8
    truth = np.var(np.array(ests), axis=0)  # the true parameters are zero: spread about them
    ratio_old = np.mean(np.mean(old, axis=0) / truth)
    ratio_new = np.mean(np.mean(new, axis=0) / truth)
    assert ratio_old < 0.5  # the clusters dominate: independent variances far too small
    assert ratio_new == pytest.approx(1.0, abs=0.25)


def test_one_cluster_keeps_the_independent_covariance():
    rng = np.random.default_rng(2)
    a = rng.normal(size=(30, 3))
    r = rng.normal(size=30)
    out = clustered_covariance(a, r, np.arange(3), np.zeros(30, dtype=int))
    np.testing.assert_array_equal(out.covariance, least_squares_covariance(a, r, np.arange(3)))
    assert out.method == INDEPENDENT and out.inflation == 1.0
    assert out.settings()["design_effect"] is None


def test_the_covariance_is_never_narrower_than_for_independent_samples():
    rng = np.random.default_rng(3)
    a, labels = linear_model(rng, clusters=3)
    out = clustered_covariance(a, rng.normal(size=len(a)) * 1e-3, np.arange(8), labels)
    assert out.inflation >= 1.0
    np.testing.assert_allclose(out.covariance, out.independent * out.inflation)


def test_mismatched_sizes_are_refused():
    with pytest.raises(RelcalError, match="clusters"):
        design_effect(np.ones((4, 2)), np.ones(4), np.zeros(3, dtype=int))


# --- simulated coincidences with per-placement systematic errors ---------------------------------

MUKCA = DATA / "mukca"
TRIALS = 24  # calibrations with per-placement errors (half as many without)


@pytest.fixture(scope="module")
def panda():
    return load_urdf(MUKCA / "urdf" / "panda.urdf", None, "ball_link")


def placement(panda, errors, per_socket, seed):
    """One simulated placement (the arm's geometry ``errors`` during it), retried from another
    seed when a plate position is out of reach."""
    for attempt in range(20):
        try:
            return simulate_coincidence(
                panda,
                placements=1,
                per_socket=per_socket,
                seating=0.08 * MM,
                errors=errors,
                tool_error=0.0,
                seed=seed + 7919 * attempt,
            )
        except RelcalError:
            continue
    raise AssertionError("no reachable plate position")  # pragma: no cover


def clustered_trial(panda, seed, tau_mm, tau_deg, placements=4, per_socket=8):
    """A calibration of ``placements`` placements whose geometry each differs from the arm's by
    its own random offset (``tau_mm`` per length, ``tau_deg`` per angle: the plate's deformation,
    the temperature, what the model leaves out); the z of the geometric estimates against the
    arm's errors under the independent and the clustered covariance, and the clustered one."""
    layout = make_layout(panda)
    rng = np.random.default_rng(seed)
    arm = random_errors(layout, rng)
    size = np.where(layout.is_angle(), tau_deg * DEG, tau_mm * MM)
    q, groups, points = [], [], {}
    for c in range(placements):
        truth = placement(panda, arm + rng.normal(0.0, 1.0, layout.size) * size, per_socket,
                          1000 * seed + c)  # fmt: skip
        q.append(truth.q)
        groups += [g.replace("p0/", f"p{c}/") for g in truth.groups]
        points.update({g.replace("p0/", f"p{c}/"): p for g, p in truth.points.items()})
    q = np.concatenate(q)
    distances = [(f"p{c}/hole_0", f"p{c}/hole_1", 0.050, 0.05 * MM) for c in range(placements)]
    co = make_coincidence(panda, q, groups, distances)
    problem = coincidence_problem(panda, q, co)
    ident = analyse_problem(problem)
    planted = np.concatenate(
        [arm, -co.tool_point, (np.array([points[g] for g in co.names]) - co.points).ravel()]
    )
    held = np.setdiff1d(np.arange(len(planted)), ident.subset)  # the equivalent truth
    null = ident.null_space
    planted = planted - null @ np.linalg.lstsq(null[held], planted[held], rcond=None)[0]
    # The least-squares estimate linearised at the truth (what a covariance describes; a plain
    # Gauss-Newton from nominal wanders along the weak directions of 8 samples per socket)
    r0, a = residuals(problem, planted)
    step = np.linalg.lstsq(a[:, ident.subset], r0, rcond=None)[0]
    unc = clustered_covariance(
        a, r0 - a[:, ident.subset] @ step, ident.subset, row_placements(problem)
    )
    cols = np.flatnonzero(ident.subset < layout.size)  # the geometry
    z_old = step[cols] / np.sqrt(np.diag(unc.independent)[ident.subset[cols]])
    z_new = step[cols] / np.sqrt(np.diag(unc.covariance)[ident.subset[cols]])
    return z_old, z_new, unc


def test_intervals_cover_the_truth_with_per_placement_errors(panda):
    """Each of 4 placements (8 samples per socket, 0.08 mm seating) sees the geometry off by
    its own 0.1 mm and 0.01 deg per parameter: the independent 95 % intervals cover the arm's
    errors far less often than 95 %, the clustered ones close to it."""
    old, new, effect = [], [], []
    for seed in range(TRIALS):
        z_old, z_new, unc = clustered_trial(panda, seed, 0.1, 0.01)
        old.append(np.abs(z_old) < 1.96)
        new.append(np.abs(z_new) < 1.96)
        effect.append(unc.inflation)
    cover_old, cover_new = np.mean(np.concatenate(old)), np.mean(np.concatenate(new))
    print(f"coverage independent {cover_old:.3f}, clustered {cover_new:.3f}; std x "
          f"{np.median(np.sqrt(effect)):.2f} (median)")  # fmt: skip
    assert 0.85 <= cover_new <= 0.99
    assert cover_old < cover_new - 0.05
    assert np.median(effect) > 2.0


def test_without_per_placement_errors_the_intervals_widen_little(panda):
    old, new, effect = [], [], []
    for seed in range(TRIALS // 2):
        z_old, z_new, unc = clustered_trial(panda, 100 + seed, 0.0, 0.0)
        old.append(np.abs(z_old) < 1.96)
        new.append(np.abs(z_new) < 1.96)
        effect.append(unc.inflation)
    std_ratio = np.sqrt(effect)
    print(f"coverage independent {np.mean(np.concatenate(old)):.3f}, clustered "
          f"{np.mean(np.concatenate(new)):.3f}; std x {np.median(std_ratio):.2f} (median), "
          f"{std_ratio.max():.2f} (max)")  # fmt: skip
    assert np.median(std_ratio) < 1.1
    assert std_ratio.max() < 1.35
    assert 0.9 <= np.mean(np.concatenate(new)) <= 0.99
