"""From a dataset to a calibrated robot: measure, pair, identify, validate.

``measure`` turns images (or given poses) into camera poses ``C_k`` with rejected frames and their
reasons; ``calibrate`` splits off held-out samples, identifies the geometry and the hand-eye
transform with the frame-invariant formulation on the identifiable subset, and validates.
Position-only samples (a tracker's reflector, a marker) take the tracker formulation instead: the
instrument-to-base transform and the marker position are estimated with the geometry, and the
held-out check is the absolute position error with both refitted on the training samples.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from relcal import geometry as tf
from relcal.calibration.handeye import solve_handeye
from relcal.calibration.identifiability import check_pose_set
from relcal.calibration.identify import (
    Result,
    SolverOptions,
    identify,
    identify_lm,
)
from relcal.calibration.measurement import (
    PairStrategy,
    Problem,
    make_pairs,
    pair_errors,
    relative_measurements,
    residuals,
)
from relcal.calibration.noise import (
    Noise,
    PoseNoise,
    estimate_pose_noise,
    pair_whiteners,
    robust_sigma,
)
from relcal.calibration.outcome import (
    ROBUST_SCALE,
    Calibration,
    outlier_samples,
)
from relcal.calibration.plausibility import check_dataset, check_result
from relcal.calibration.selection import (
    WEIGHTINGS,
    Linearised,
    candidate_model,
    candidates,
    choose,
    choose_all,
    fit,
    geometric_columns,
    linearise,
    plain_whiteners,
    score_candidates,
    solve_normal,
)
from relcal.calibration.tracker import calibrate_points
from relcal.calibration.uncertainty import parameter_covariance
from relcal.calibration.validate import (
    folds,
    held_out,
    split,
)
from relcal.checks import check_calibrate
from relcal.data.dataset import Dataset
from relcal.data.imaging import Measurements, measure
from relcal.errors import RelcalError
from relcal.limits import check_calibration_memory
from relcal.robot.kinematics import fk, make_layout

DETECTION_LOSS = "linear"  # of the fit whose residuals find the outlier samples


def _sample_indices(dataset: Dataset, ids: Sequence[str]) -> np.ndarray:
    where = {sid: k for k, sid in enumerate(dataset.ids)}
    unknown = [sid for sid in ids if sid not in where]
    if unknown:
        where = (dataset.spec_path.parent if dataset.spec_path else dataset.root).resolve()
        numbered = dataset.ids == tuple(str(k + 1) for k in range(len(dataset.ids)))
        how = " (no id column: the samples are numbered 1 to N by row)" if numbered else ""
        raise RelcalError(
            f"held-out sample id(s) {', '.join(map(str, unknown[:5]))} are not in {where}{how}"
        )
    return np.array(sorted(where[sid] for sid in ids), dtype=int)


def cross_validate(
    dataset: Dataset,
    measurements: Measurements,
    k: int = 5,
    seed: int = 0,
    progress: bool = False,
    **options,
) -> list[Calibration]:
    """k-fold cross-validation: each fold of the usable samples held out once (``progress``: a
    progress bar over the folds)."""
    from tqdm import tqdm

    usable = np.flatnonzero(measurements.ok)
    parts = folds(len(usable), k, seed)
    return [
        calibrate(
            dataset,
            measurements,
            seed=seed,
            holdout_ids=[dataset.ids[i] for i in usable[f]],
            **options,
        )
        for f in tqdm(parts, disable=not progress, desc="cross-validation", unit="fold")
    ]


def calibrate(
    dataset: Dataset,
    measurements: Measurements | None = None,
    holdout: float = 0.25,
    seed: int = 0,
    pairing: PairStrategy = "all",
    method: str = "lm",
    loss: str = "linear",
    reject_outliers: bool = True,
    holdout_ids: Sequence[str] | None = None,
    select_folds: int = 5,
    selection: str = "cv",
    nongeometric: str | Sequence[str] = "auto",
    weightings: Sequence[str] = ("plain",),
) -> Calibration:
    """Choose, fit and validate a model on the training samples; validate on the held-out ones.

    Steps: a robust fit of the identifiable subset flags training samples whose pairs fit badly
    (left out of what follows with ``reject_outliers``); the full 6x6 pose noise is learned from
    its residuals; candidate models (hand-eye only, geometry, non-geometric families) under two
    row weightings are scored by ``select_folds``-fold cross-validation over training samples
    and the simplest one within a standard error of the best is fitted (``selection="all"``
    takes the largest, ``"conservative"`` then drops parameters below 3 standard deviations).
    ``holdout_ids`` names the validation samples (instead of a random share ``holdout``);
    ``measurements``: the camera poses of :func:`data.imaging.measure` (measured here if not
    given). ``nongeometric``: the families of non-geometric terms offered to model selection on
    top of those the model file enables: ``"auto"`` every family the model can have
    (:func:`robot.model.nongeometric_options`), ``"none"``, or a list. ``weightings``: the row
    weightings each candidate is tried with, ``plain`` and/or ``noise model`` (each pair
    whitened by its learned 6x6 covariance; its predicted standard deviations can be 20 to 40 %
    small on the parameters of parallel axes, measured by Monte Carlo, so it is not the
    default).
    """
    check_calibrate(
        dataset, measurements, holdout, seed, pairing, method, loss, holdout_ids, select_folds,
        selection,
    )  # fmt: skip
    unknown = sorted(set(weightings) - set(WEIGHTINGS))
    if unknown or not weightings:
        raise RelcalError(f"weightings {list(weightings)}: use {' and/or '.join(WEIGHTINGS)}")
    if measurements is None:
        measurements = measure(dataset)
    if selection not in ("cv", "conservative", "all"):
        raise RelcalError(f"unknown selection '{selection}': use cv, conservative or all")
    train, test = _split(dataset, measurements, holdout, seed, holdout_ids)
    if dataset.measured == "position":
        return calibrate_points(
            dataset,
            measurements,
            train,
            test,
            holdout=holdout,
            seed=seed,
            method=method,
            loss=loss,
            reject_outliers=reject_outliers,
            select_folds=select_folds,
            selection=selection,
            nongeometric=nongeometric,
        )
    dataset = replace(dataset, model=candidate_model(dataset.model, nongeometric))
    check_calibration_memory(  # all pairs are quadratic: refused before they are formed
        len(dataset.ids),
        pairing,
        make_layout(dataset.model).size + 6,
        str(dataset.root),
        len(train),
    )
    plausibility = check_dataset(dataset, measurements)  # a wrong unit, order or board size
    poses = measurements.poses
    handeye = dataset.handeye
    if handeye is None:
        handeye = solve_handeye(fk(dataset.model, dataset.q[train]), poses[train])
    layout = make_layout(dataset.model)

    def problem_on(samples: np.ndarray) -> Problem:
        return Problem(
            dataset.model,
            layout,
            dataset.q[samples],
            poses[samples],
            "invariant",
            "pose",
            make_pairs(len(samples), pairing),
            handeye,
        )

    problem = problem_on(train)
    ident = check_pose_set(problem, str(dataset.spec_path))
    # A fit finds the samples whose pairs fit badly (a robust per-sample median of their pair
    # errors: a few bad samples do not hide among their pairs); the fits after it use ``loss``.
    # The geometry (with the hand-eye) finds the samples whose pairs fit badly, robustly, and
    # gives the residuals the noise is learned from and the point the candidates are linearised
    # at; non-geometric terms are small there and enter the candidates only.
    geometric = geometric_columns(problem, ident.subset)
    full = _fit(problem, ident, geometric, "plain", method, DETECTION_LOSS)
    outliers = outlier_samples(_normalised(pair_errors(problem, full.params)), problem.pairs)
    # gross outliers bend the fit and can hide others: look again without the ones found, until
    # no more are (a few rounds at most)
    kept, dropped = np.arange(len(train)), np.zeros(0, dtype=int)
    for _ in range(4):
        if not outliers.size or len(kept) - len(outliers) < 4:
            break
        dropped, kept = np.concatenate([dropped, kept[outliers]]), np.delete(kept, outliers)
        problem = problem_on(train[kept])
        full = _fit(problem, ident, geometric, "plain", method, DETECTION_LOSS, initial=full.params)
        outliers = outlier_samples(_normalised(pair_errors(problem, full.params)), problem.pairs)
    outliers = np.sort(dropped)
    outlier_ids = tuple(dataset.ids[train[i]] for i in outliers)
    if reject_outliers and outliers.size:
        train = np.delete(train, outliers)
    problem = problem_on(train)
    if (reject_outliers and outliers.size) or loss != DETECTION_LOSS:
        full = _fit(problem, ident, geometric, "plain", method, loss, initial=full.params)

    left = pair_left_maps(problem)
    lin = linearise(problem, full.params)
    fitted = (lin.pairs, lin.jac[:, :, geometric], np.diag(plain_whiteners(1)[0]))
    noise = estimate_pose_noise(pair_errors(problem, full.params), left, fitted)
    whiteners = {
        "plain": plain_whiteners(len(left)),
        "noise model": pair_whiteners(noise.covariance, left),
    }
    cands = candidates(problem, ident.subset, tuple(weightings))
    folds_k = max(2, min(select_folds, len(train) // 2))
    scores = score_candidates(lin, whiteners, cands, folds_k, seed)
    chosen, reason = choose_all(scores) if selection == "all" else choose(scores)
    pick = scores[chosen].candidate
    columns = pick.columns
    if selection == "conservative" and pick.name != "hand-eye only":
        weighted = weighted_problem(problem, pick.weighting, whiteners)
        columns = significant_columns(weighted, ident, columns, noise.noise, full.params)
        reason += "; parameters below 3 standard deviations dropped (--select conservative)"

    he_scores = [s for s in scores if s.candidate.name == "hand-eye only"]
    he = min(he_scores, key=lambda s: np.mean(s.per_sample)).candidate
    start = full.params
    baseline = _fit(problem, ident, he.columns, he.weighting, "lm", loss, whiteners, noise, start)
    if pick.name == "hand-eye only":
        result = baseline
    else:
        result = _fit(
            problem, ident, columns, pick.weighting, method, loss, whiteners, noise, start
        )
    check_result(dataset, problem, result)  # corrections too large to be a calibration
    boot = bootstrap_std(lin, whiteners[pick.weighting], columns, seed=seed)

    validation = None
    if len(test) >= 2:
        everything = problem_on(np.arange(len(dataset.ids)))
        validation = held_out(
            everything, result, test, baseline=baseline, train=train if reject_outliers else None
        )
    settings = {
        "holdout_fraction": holdout,
        "seed": seed,
        "pairing": pairing,
        "method": method,
        "loss": loss,
        "formulation": "invariant",
        "measure": "pose",
        "mode": dataset.mode,
        "hayati_joints": [int(i) + 1 for i in np.flatnonzero(dataset.model.hayati)],
        "selection": selection,
        "selection_folds": folds_k,
        "weighting": pick.weighting,
        "reject_outliers": reject_outliers,
        "plausibility": plausibility,
    }
    return Calibration(
        dataset=dataset,
        measurements=measurements,
        problem=weighted_problem(problem, pick.weighting, whiteners),
        result=result,
        baseline=baseline,
        validation=validation,
        train=train,
        test=test,
        settings=settings,
        outliers=outlier_ids,
        noise=noise,
        selection=tuple(scores),
        chosen=chosen,
        reason=reason,
        bootstrap_std=boot,
    )


def _split(
    dataset: Dataset,
    measurements: Measurements,
    holdout: float,
    seed: int,
    holdout_ids: Sequence[str] | None,
) -> tuple[np.ndarray, np.ndarray]:
    """Training and held-out sample indices among the usable samples."""
    usable = np.flatnonzero(measurements.ok)
    if len(usable) < 4:
        raise RelcalError(
            f"{dataset.spec_path}: only {len(usable)} usable samples; at least 4 are needed "
            "(and many more for a useful calibration)"
        )
    if holdout_ids is not None:
        test = _sample_indices(dataset, holdout_ids)
        return np.setdiff1d(usable, test), np.intersect1d(usable, test)
    if holdout > 0:
        train_idx, test_idx = split(len(usable), holdout, seed)
        return usable[train_idx], usable[test_idx]
    return usable, np.zeros(0, dtype=int)


def weighted_problem(
    problem: Problem, weighting: str, whiteners: dict[str, np.ndarray] | None = None
) -> Problem:
    """``problem`` with the rows weighted as ``weighting`` says (the plain weighting is diagonal:
    row factors, no per-pair blocks)."""
    if weighting == "plain":
        return replace(problem, weights=np.diag(plain_whiteners(1)[0]), pair_weights=None)
    return replace(problem, weights=None, pair_weights=whiteners[weighting])


def _blocks(problem: Problem) -> np.ndarray:
    """The problem's row weighting as per-pair blocks ``(P, 6, 6)``."""
    if problem.pair_weights is not None:
        return problem.pair_weights
    w = np.ones(6) if problem.weights is None else problem.weights
    return np.broadcast_to(np.diag(w), (len(problem.pair_indices()), 6, 6))


def pair_left_maps(problem: Problem) -> np.ndarray:
    """``-Ad(M_ij^-1)`` ``(P, 6, 6)`` of the measured relative motions: how pose i's error enters
    pair (i, j)'s residual (pose j's enters as itself)."""
    measured = relative_measurements(problem.poses, problem.pair_indices())
    return -tf.adjoint(tf.invert(measured))


def _normalised(errors: np.ndarray) -> np.ndarray:
    """Pair errors in units of their robust noise levels (translation and rotation apart)."""
    return errors / robust_sigma(errors)


def _fit(
    problem: Problem,
    ident,
    columns: np.ndarray,
    weighting: str,
    method: str,
    loss: str,
    whiteners: dict[str, np.ndarray] | None = None,
    noise: PoseNoise | None = None,
    initial: np.ndarray | None = None,
) -> Result:
    """The nonlinear fit of ``columns`` under ``weighting``, the robust loss bending at
    ``ROBUST_SCALE`` robust standard deviations of the weighted rows."""
    weighted = weighted_problem(problem, weighting, whiteners)
    if method == "published":
        result = identify(weighted, SolverOptions(method="published"), ident)
    else:
        r0 = residuals(weighted, np.zeros(problem.full_layout.size), jacobian=False)
        scale = 1.4826 * np.median(np.abs(r0 - np.median(r0)))
        options = SolverOptions(loss=loss, f_scale=ROBUST_SCALE * max(scale, 1e-12))
        sub = replace(ident, subset=np.asarray(columns))
        result = identify_lm(weighted, 200, sub, options.loss, options.f_scale, initial=initial)
    return replace(result, noise=noise.noise) if noise is not None else result


def significant_columns(
    problem: Problem,
    ident,
    columns: np.ndarray,
    noise: Noise,
    params: np.ndarray,
    z_min: float = 3.0,
) -> np.ndarray:
    """``columns`` less the link parameters whose linearised estimate is below ``z_min``
    standard deviations (hand-eye components always stay), dropped until none is."""
    kinds = problem.full_layout.kinds
    cols = np.asarray(columns)
    lin = linearise(problem, params)
    while True:
        estimate = fit(lin, _blocks(problem), cols)
        unc = parameter_covariance(problem, noise, replace(ident, subset=cols), params=params)
        z = np.abs(estimate[unc.subset]) / np.maximum(unc.std[unc.subset], 1e-300)
        weak = [c for c, zc in zip(unc.subset, z, strict=True) if zc < z_min]
        weak = [c for c in weak if kinds[c] != "handeye"]
        if not weak:
            return cols
        cols = np.setdiff1d(cols, weak)


def bootstrap_std(
    lin: Linearised, whiten: np.ndarray, columns: np.ndarray, n_boot: int = 100, seed: int = 0
) -> np.ndarray:
    """Standard deviations ``(Q,)`` of the linearised estimate over ``n_boot`` resamplings of the
    training *samples* (a pair counts as often as both its samples are drawn); NaN outside
    ``columns``. An independent check of the predicted standard deviations."""
    rng = np.random.default_rng(seed)
    k = len(columns)
    jw = whiten @ lin.jac[:, :, columns]  # (P, 6, k)
    bw = np.einsum("pij,pj->pi", whiten, lin.b)
    gram = np.einsum("pra,prb->pab", jw, jw).reshape(len(jw), k * k)  # each pair's share
    rhs = np.einsum("pra,pr->pa", jw, bw)
    i, j = lin.pairs.T
    draws = rng.integers(0, lin.n_samples, (n_boot, lin.n_samples))
    counts = np.zeros((n_boot, lin.n_samples))
    np.add.at(counts, (np.arange(n_boot)[:, None], draws), 1.0)
    weights = counts[:, i] * counts[:, j]  # (B, P): a pair counts as often as both its samples
    normals, rhss = (weights @ gram).reshape(n_boot, k, k), weights @ rhs
    draws = [solve_normal(n, r) for n, r in zip(normals, rhss, strict=True)]
    out = np.full(lin.jac.shape[-1], np.nan)
    out[columns] = np.std(draws, axis=0, ddof=1)
    return out
