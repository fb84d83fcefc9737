"""Calibration from position-only samples (a laser tracker's reflector, a motion-capture marker).

The tracker formulation of :mod:`measurement`: ``p_k = T F(q_k) m`` with the instrument-from-base
transform ``T`` and the marker position ``m`` (flange frame) estimated with the geometry. The
baseline, the best a user gets without kinematic calibration, is the nominal model with ``T`` and
``m`` fitted to the same training points. Model selection compares it with the geometric model
by K-fold cross-validation over the training points (nonlinear refits: a point problem is small),
and validation is the absolute position error on the held-out points.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from relcal.calibration.handeye import solve_instrument
from relcal.calibration.identifiability import Identifiability, check_pose_set
from relcal.calibration.identify import Result, SolverOptions, identify, identify_lm
from relcal.calibration.measurement import Problem, pair_errors
from relcal.calibration.noise import robust_sigma
from relcal.calibration.outcome import (
    BASELINE_CANDIDATES,
    ROBUST_SCALE,
    Calibration,
    outlier_samples,
)
from relcal.calibration.plausibility import check_result
from relcal.calibration.selection import Candidate, Score, choose, sample_folds
from relcal.calibration.validate import held_out
from relcal.data.dataset import Dataset
from relcal.data.imaging import Measurements
from relcal.errors import RelcalError
from relcal.robot.kinematics import fk, make_layout

BASELINE = BASELINE_CANDIDATES[1]


def frame_columns(problem: Problem, subset: np.ndarray) -> np.ndarray:
    """The entries of ``subset`` that belong to ``T`` and ``m`` (not to the robot)."""
    kinds = problem.full_layout.kinds
    return np.array([c for c in subset if kinds[c] in ("instrument", "marker")], dtype=int)


def point_errors(problem: Problem, params: np.ndarray) -> np.ndarray:
    """Unweighted point errors ``(N, 3)`` (m)."""
    return pair_errors(problem, params)[:, :3]


def _fit(
    problem: Problem,
    ident: Identifiability,
    columns: np.ndarray,
    method: str,
    loss: str,
    initial: np.ndarray | None = None,
) -> Result:
    """The fit of ``columns`` of the weighted point problem, the robust loss bending at
    ``ROBUST_SCALE`` noise standard deviations."""
    sub = replace(ident, subset=np.asarray(columns))
    if method == "published":
        return identify(problem, SolverOptions(method="published"), sub)
    return identify_lm(problem, 200, sub, loss, ROBUST_SCALE, initial=initial)


def score_points(
    problem: Problem,
    ident: Identifiability,
    cands: list[Candidate],
    start: np.ndarray,
    k: int,
    seed: int,
    loss: str,
) -> list[Score]:
    """K-fold scores of the candidates over the training points: each fold held out, the rest
    refitted (nonlinear, from ``start``), the held-out points' squared errors kept."""
    n = len(problem.q)
    folds = sample_folds(n, k, seed)
    scores = []
    for cand in cands:
        errors = np.zeros((n, 6))
        for fold in folds:
            keep = np.setdiff1d(np.arange(n), fold)
            inner = replace(problem, q=problem.q[keep], poses=problem.poses[keep])
            fit = _fit(inner, ident, cand.columns, "lm", loss, initial=start)
            test = replace(problem, q=problem.q[fold], poses=problem.poses[fold])
            errors[fold] = pair_errors(test, fit.params)
        errors[:, 3:] = 0.0  # no orientation measured
        scores.append(Score(cand, errors, np.sum(errors[:, :3] ** 2, axis=1)))
    return scores


def significant_fit(
    problem: Problem,
    ident: Identifiability,
    full: Result,
    method: str,
    loss: str,
    z_min: float = 3.0,
) -> Result:
    """``full`` refitted without the link parameters whose estimate is below ``z_min`` standard
    deviations (``T`` and ``m`` always stay), until none is."""
    kinds = problem.full_layout.kinds
    result, cols = full, np.asarray(ident.subset)
    while True:
        z = np.abs(result.params) / np.where(np.isfinite(result.std), result.std, np.inf)
        weak = [c for c in cols if kinds[c] not in ("instrument", "marker") and z[c] < z_min]
        if not weak:
            return result
        cols = np.setdiff1d(cols, weak)
        result = _fit(problem, ident, cols, method, loss, initial=full.params)


def check_link_corrections(dataset: Dataset, problem: Problem, result: Result) -> None:
    """The plausibility check of the link corrections (points in the wrong unit, a wrong robot
    model); ``T`` and ``m`` are free by design and not checked."""
    names = problem.full_layout.names
    try:
        check_result(dataset, problem, result)
    except RelcalError as exc:
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.abs(result.params) / result.std
        weak = [n for k, n in enumerate(names) if f"{n} corrected by" in str(exc) and z[k] < 3.0]
        if not weak:
            raise
        raise RelcalError(
            f"{exc}\n{', '.join(weak)}: not determined by these points (|error| below 3 standard "
            "deviations); --select conservative leaves such parameters out"
        ) from None


def calibrate_points(
    dataset: Dataset,
    measurements: Measurements,
    train: np.ndarray,
    test: np.ndarray,
    holdout: float,
    seed: int,
    method: str,
    loss: str,
    reject_outliers: bool,
    select_folds: int = 5,
    selection: str = "cv",
) -> Calibration:
    """:func:`pipeline.calibrate` for position-only samples.

    Starting guesses of ``T`` and ``m`` come from a registration of the nominal flange points
    (``m`` from ``handeye.xyz`` when given). A least-squares fit gives the robust point noise,
    which weights the rows; a Huber fit flags outlier points (left out with ``reject_outliers``);
    the baseline (``T`` and ``m`` alone) and the geometric model are scored by cross-validation
    and the simpler one is kept unless the other is better by more than a standard error
    (``selection="all"`` keeps the geometric model; ``"conservative"`` then drops the link
    parameters below 3 standard deviations, refitting until none is).
    """
    layout = make_layout(dataset.model)
    points = measurements.poses[:, :3, 3]
    marker0 = None if dataset.handeye is None else dataset.handeye[:3, 3]

    def problem_on(samples: np.ndarray) -> Problem:
        flange = fk(dataset.model, dataset.q[samples])
        instrument, marker = solve_instrument(flange, points[samples], marker0)
        return Problem(
            dataset.model,
            layout,
            dataset.q[samples],
            measurements.poses[samples],
            "tracker",
            "position",
            instrument=instrument,
            marker=marker,
        )

    def weighted_on(samples: np.ndarray) -> tuple[Problem, Identifiability, float]:
        problem = problem_on(samples)
        ident = check_pose_set(problem, str(dataset.spec_path))
        first = identify(problem, SolverOptions(), ident)
        sigma = float(robust_sigma(pair_errors(problem, first.params))[0])
        return replace(problem, weights=np.full(6, 1.0 / sigma)), ident, sigma

    problem, ident, sigma = weighted_on(train)
    robust = _fit(problem, ident, ident.subset, method, "huber")
    per_point = np.stack([np.arange(len(train))] * 2, axis=1)
    outliers = outlier_samples(point_errors(problem, robust.params) / sigma, per_point)
    outlier_ids = tuple(dataset.ids[train[i]] for i in outliers)
    if reject_outliers and outliers.size:
        train = np.delete(train, outliers)
        problem, ident, sigma = weighted_on(train)
        robust = _fit(problem, ident, ident.subset, method, "huber")
    full = robust if loss == "huber" else _fit(problem, ident, ident.subset, method, loss)

    frames = frame_columns(problem, ident.subset)
    cands = [Candidate(BASELINE, frames, "plain"), Candidate("geometric", ident.subset, "plain")]
    folds_k = max(2, min(select_folds, len(train) // 2))
    scores = score_points(problem, ident, cands, full.params, folds_k, seed, loss)
    if selection == "all":
        chosen, reason = 1, "all identifiable parameters (--select all)"
    else:
        chosen, reason = choose(scores)
    baseline = _fit(problem, ident, frames, "lm", loss, initial=full.params)
    result = baseline if chosen == 0 else full
    if selection == "conservative" and chosen != 0:
        result = significant_fit(problem, ident, full, method, loss)
        reason += "; parameters below 3 standard deviations dropped (--select conservative)"

    check_link_corrections(dataset, problem, result)
    validation = None
    if len(test) >= 1:
        everything = replace(problem, q=dataset.q, poses=measurements.poses)
        validation = held_out(everything, result, test, baseline=baseline)
    settings = {
        "holdout_fraction": holdout,
        "seed": seed,
        "pairing": None,
        "method": method,
        "loss": loss,
        "formulation": "tracker",
        "measure": "position",
        "mode": dataset.mode,
        "hayati_joints": [int(i) + 1 for i in np.flatnonzero(dataset.model.hayati)],
        "selection": selection,
        "selection_folds": folds_k,
        "weighting": "plain",
        "reject_outliers": reject_outliers,
        "point_sigma_m": sigma,
        "baseline": "nominal geometry with the instrument transform and the marker fitted to "
        "the training points",
    }
    return Calibration(
        dataset,
        measurements,
        problem,
        result,
        baseline,
        validation,
        train,
        test,
        settings,
        outlier_ids,
        None,
        tuple(scores),
        chosen,
        reason,
        None,
    )
