"""Calibration from position-only samples (a laser tracker's reflector, a motion-capture marker).

The tracker formulation of :mod:`measurement`: ``p_k = T F(q_k) m`` with the instrument-from-base
transform ``T`` and the marker position ``m`` (flange frame) estimated with the robot's
parameters. The baseline, the best a user gets without kinematic calibration, is the nominal model
with ``T`` and ``m`` fitted to the same training points. Model selection is the pose path's
(:mod:`selection`): the same nested candidates (``T`` and ``m`` only, + geometry, + each
non-geometric family, + all), scored by K-fold cross-validation over the training points and
chosen by the same rule; validation is the absolute position error on the held-out points.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from relcal.calibration.handeye import solve_instrument
from relcal.calibration.identifiability import Identifiability, check_pose_set
from relcal.calibration.identify import Result, SolverOptions, identify, identify_lm
from relcal.calibration.measurement import Problem, pair_errors
from relcal.calibration.noise import robust_sigma
from relcal.calibration.outcome import ROBUST_SCALE, Calibration, outlier_samples
from relcal.calibration.plausibility import check_result
from relcal.calibration.selection import (
    Candidate,
    Score,
    candidate_model,
    candidates,
    choose,
    choose_all,
    family,
    geometric_columns,
    linearise,
    plain_whiteners,
    score_candidates,
)
from relcal.calibration.validate import held_out
from relcal.data.dataset import Dataset
from relcal.data.imaging import Measurements
from relcal.errors import RelcalError
from relcal.robot.kinematics import fk, make_layout


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
    fits: list[Result],
    cands: list[Candidate],
    k: int,
    seed: int,
) -> list[Score]:
    """K-fold scores of the candidates over the training points by :func:`selection.
    score_candidates`, each candidate's folds refitted on the point problem linearised at its own
    fit to every training point (``fits``, one per candidate): a fold moves a fit only a little,
    while the candidates differ by corrections of degrees, which one shared linearisation would
    bend (on the real TIAGo Pro positions the baseline's cross-validated RMS comes out 31.1 mm
    linearised at the geometric fit against 28.5 mm with nonlinear refits of every fold; per
    candidate, every one of the six within 0.02 mm of its nonlinear refits)."""
    plain = {"plain": plain_whiteners(len(problem.q))}
    return [
        score_candidates(linearise(problem, fit.params), plain, [cand], k, seed)[0]
        for cand, fit in zip(cands, fits, strict=True)
    ]


def significant_fit(
    problem: Problem,
    ident: Identifiability,
    fit: Result,
    columns: np.ndarray,
    method: str,
    loss: str,
    z_min: float = 3.0,
) -> Result:
    """``fit`` (of ``columns``) refitted without the link parameters whose estimate is below
    ``z_min`` standard deviations (``T`` and ``m`` always stay), until none is."""
    kinds = problem.full_layout.kinds
    result, cols = fit, np.asarray(columns)
    while True:
        z = np.abs(result.params) / np.where(np.isfinite(result.std), result.std, np.inf)
        weak = [c for c in cols if family(kinds[c]) != "frames" and z[c] < z_min]
        if not weak:
            return result
        cols = np.setdiff1d(cols, weak)
        result = _fit(problem, ident, cols, method, loss, initial=fit.params)


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
    nongeometric: str | Sequence[str] = "auto",
) -> Calibration:
    """:func:`pipeline.calibrate` for position-only samples.

    Starting guesses of ``T`` and ``m`` come from a registration of the nominal flange points
    (``m`` from ``handeye.xyz`` when given). A least-squares fit of the geometry gives the robust
    point noise, which weights the rows; a Huber fit flags outlier points (left out with
    ``reject_outliers``). The candidates of :func:`selection.candidates` (``T`` and ``m`` alone,
    + geometry, + each non-geometric family of ``nongeometric`` as in :func:`pipeline.calibrate`,
    + all) are each fitted to the training points and scored by ``select_folds``-fold
    cross-validation; :func:`selection.choose` keeps the simplest within two standard errors of
    the best (``selection="all"`` the largest; ``"conservative"`` then drops the link parameters
    below 3 standard deviations, refitting until none is).
    """
    dataset = replace(dataset, model=candidate_model(dataset.model, nongeometric))
    layout = make_layout(dataset.model)
    points = measurements.poses[:, :3, 3]
    marker0 = None if dataset.handeye is None else dataset.handeye[:3, 3]

    def problem_on(samples: np.ndarray) -> Problem:
        flange = fk(dataset.model, dataset.q[samples])
        instrument, marker = solve_instrument(flange, points[samples], marker0)
        return Problem(
            model=dataset.model,
            layout=layout,
            q=dataset.q[samples],
            poses=measurements.poses[samples],
            formulation="tracker",
            measure="position",
            instrument=instrument,
            marker=marker,
        )

    def weighted_on(samples: np.ndarray) -> tuple[Problem, Identifiability, np.ndarray, float]:
        """The problem weighted by the robust point noise of a least-squares fit of the
        geometry (non-geometric terms are small there and enter the candidates only)."""
        problem = problem_on(samples)
        ident = check_pose_set(problem, str(dataset.spec_path))
        geometric = geometric_columns(problem, ident.subset)
        first = identify(problem, SolverOptions(), replace(ident, subset=geometric))
        sigma = float(robust_sigma(pair_errors(problem, first.params))[0])
        return replace(problem, weights=np.full(6, 1.0 / sigma)), ident, geometric, sigma

    problem, ident, geometric, sigma = weighted_on(train)
    robust = _fit(problem, ident, geometric, method, "huber")
    per_point = np.stack([np.arange(len(train))] * 2, axis=1)
    outliers = outlier_samples(point_errors(problem, robust.params) / sigma, per_point)
    outlier_ids = tuple(dataset.ids[train[i]] for i in outliers)
    if reject_outliers and outliers.size:
        train = np.delete(train, outliers)
        problem, ident, geometric, sigma = weighted_on(train)
        robust = _fit(problem, ident, geometric, method, "huber")
    full = robust if loss == "huber" else _fit(problem, ident, geometric, method, loss)

    cands = candidates(problem, ident.subset)
    fits = [_fit(problem, ident, c.columns, method, loss, initial=full.params) for c in cands]
    folds_k = max(2, min(select_folds, len(train) // 2))
    scores = score_points(problem, fits, cands, folds_k, seed)
    chosen, reason = choose_all(scores) if selection == "all" else choose(scores)
    baseline, result = fits[0], fits[chosen]
    if selection == "conservative" and chosen != 0:
        result = significant_fit(problem, ident, result, cands[chosen].columns, method, loss)
        reason += "; parameters below 3 standard deviations dropped (--select conservative)"

    check_link_corrections(dataset, problem, result)
    validation = None
    if len(test) >= 1:
        everything = replace(problem, q=dataset.q, poses=measurements.poses)
        validation = held_out(
            everything, result, test, baseline=baseline, train=train if reject_outliers else None
        )
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
        dataset=dataset,
        measurements=measurements,
        problem=problem,
        result=result,
        baseline=baseline,
        validation=validation,
        train=train,
        test=test,
        settings=settings,
        outliers=outlier_ids,
        selection=tuple(scores),
        chosen=chosen,
        reason=reason,
    )
