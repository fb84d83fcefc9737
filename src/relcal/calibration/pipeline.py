"""From a dataset to a calibrated robot: one calibration skeleton, the measurement kind a strategy.

:func:`calibrate` is the skeleton every kind of data goes through: split off held-out samples,
check the inputs, find outlier samples, learn the noise, score the candidate models by
cross-validation on the training samples, fit the chosen model and the baseline, check the
corrections, validate on the held-out samples, and gather the settings into one
:class:`~relcal.calibration.outcome.Calibration`. What differs between relative poses, absolute
points and coincidences (their problem and nuisance parameters, noise model, outlier input, split,
linearisation for model selection, validation and plausibility checks) is supplied by a
:class:`~relcal.calibration.kinds.MeasurementKind` (:func:`~relcal.calibration.kinds.kind_of`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from relcal.calibration.identify import Result, SolverOptions, identify, identify_lm
from relcal.calibration.kinds import MeasurementKind, NoiseModel, Training, kind_of
from relcal.calibration.measurement import PairStrategy
from relcal.calibration.outcome import Calibration
from relcal.calibration.selection import (
    BASELINE_CANDIDATES,
    WEIGHTINGS,
    bootstrap_std,
    candidate_model,
    candidates,
    choose,
    choose_all,
    linearise,
    score_candidates,
    score_each,
    significant_columns,
    significant_fit,
)
from relcal.checks import check_calibrate
from relcal.data.dataset import Dataset
from relcal.data.imaging import Measurements, measure
from relcal.errors import RelcalError

SELECTIONS = ("cv", "conservative", "all")


def cross_validate(
    dataset: Dataset,
    measurements: Measurements | None = None,
    k: int = 5,
    seed: int = 0,
    progress: bool = False,
    **options,
) -> list[Calibration]:
    """k-fold cross-validation: each fold held out once, as the measurement kind splits (usable
    samples; whole placements for coincidences); ``progress``: a progress bar over the folds."""
    from tqdm import tqdm

    if measurements is None:
        measurements = measure(dataset)
    kind = kind_of(dataset, measurements, options.get("pairing", "all"))
    parts = kind.folds(k, seed)
    return [
        calibrate(dataset, measurements, seed=seed, holdout_ids=ids, **options)
        for ids in tqdm(parts, disable=not progress, desc="cross-validation", unit="fold")
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

    Steps: a fit of the identifiable geometry flags training samples that fit badly (left out of
    what follows with ``reject_outliers``); the noise is learned from the residuals; candidate
    models (the measurement frames only, geometry, non-geometric families) under the row
    weightings are scored by ``select_folds``-fold cross-validation over training samples and
    the simplest one within two standard errors of the best is fitted (``selection="all"``
    takes the largest, ``"conservative"`` then drops parameters below 3 standard deviations),
    with the baseline (the frames alone) beside it. ``holdout_ids`` names the validation
    samples (placements for coincidence data) instead of a random share ``holdout``;
    ``measurements``: the camera poses of :func:`data.imaging.measure` (measured here if not
    given). ``nongeometric``: the families of non-geometric terms offered to model selection on
    top of those the model file enables: ``"auto"`` every family the model can have
    (:func:`robot.model.nongeometric_options`), ``"none"``, or a list. ``weightings``: the row
    weightings each candidate of relative poses is tried with, ``plain`` and/or ``noise model``
    (each pair whitened by its learned 6x6 covariance; its predicted standard deviations can be
    20 to 40 % small on the parameters of parallel axes, measured by Monte Carlo, so it is not
    the default). ``loss``: of the fits once outliers are out (``lm`` only).
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
    if selection not in SELECTIONS:
        raise RelcalError(f"unknown selection '{selection}': use cv, conservative or all")
    kind = kind_of(dataset, measurements, pairing)
    train, test = kind.split(holdout, seed, holdout_ids)
    dataset = replace(dataset, model=candidate_model(dataset.model, nongeometric))
    kind = replace(kind, dataset=dataset)

    # Plausibility of the inputs (a wrong unit, joint order, board size, robot): before fitting.
    plausibility = kind.check_inputs(train)

    # Outliers: samples whose measurements fit badly at a fit of the geometry.
    training = kind.training(train)
    detection = _fit(kind, training, training.geometric, "plain", method, kind.detection_loss)
    outliers, without = _outliers(kind, training, detection, method)
    outlier_ids = tuple(dataset.ids[train[i]] for i in outliers)
    removed = bool(reject_outliers and outliers.size)
    if removed:
        train = np.delete(train, outliers)
        training = kind.training(train, previous=training)
        detection = without
    full = detection  # the geometry fitted with ``loss`` on the final training samples
    if removed or loss != kind.detection_loss:
        start = None if kind.refit_from_nominal else detection.params
        full = _fit(kind, training, training.geometric, "plain", method, loss, initial=start)

    # Noise, candidates and their cross-validated scores.
    lin = linearise(training.problem, full.params) if kind.shared_linearisation else None
    noise = kind.learn_noise(training, full, lin)
    cands = candidates(training.problem, training.ident.subset, kind.weightings(weightings))
    folds_k = max(2, min(select_folds, len(train) // 2))
    fits = None
    if kind.shared_linearisation:
        scores = score_candidates(lin, noise.whiteners, cands, folds_k, seed)
    else:  # every candidate fitted, and linearised at its own fit
        fits = [
            _fit(kind, training, c.columns, c.weighting, _method(c, method), loss, full.params)
            for c in cands
        ]
        scores = score_each(training.problem, fits, cands, folds_k, seed)

    # The chosen model and the baseline (the best-scoring candidate of the frames alone).
    chosen, reason = choose_all(scores) if selection == "all" else choose(scores)
    pick = scores[chosen].candidate
    at_baseline = [k for k, s in enumerate(scores) if s.candidate.name in BASELINE_CANDIDATES]
    base = min(at_baseline, key=lambda k: np.mean(scores[k].per_sample))
    he = scores[base].candidate
    if fits is None:
        baseline = _fit(kind, training, he.columns, he.weighting, "lm", loss, full.params, noise)
    else:
        baseline = fits[base]
    columns = pick.columns
    if pick.name in BASELINE_CANDIDATES:
        result = baseline
    elif fits is None:
        if selection == "conservative":
            weighted = kind.weighted(training, pick.weighting, noise.whiteners)
            columns = significant_columns(
                weighted, training.ident, columns, noise.noise.noise, full.params
            )
        args = (pick.weighting, method, loss, full.params, noise)
        result = _fit(kind, training, columns, *args)
    else:
        result = fits[chosen]
        if selection == "conservative":
            initial = result.params

            def refit(cols: np.ndarray) -> Result:
                return _fit(kind, training, cols, "plain", method, loss, initial)

            result = significant_fit(training.problem, result, columns, refit)
    if selection == "conservative" and pick.name not in BASELINE_CANDIDATES:
        reason += "; parameters below 3 standard deviations dropped (--select conservative)"

    # Plausibility of the corrections (a wrong input absorbed by the model): before writing.
    kind.check_result(training, result)
    # What a geometry-only file (URDF, vendor files) can hold: validated on its own at export.
    geometry = _geometry_only(kind, training, result, pick.weighting, loss, noise, fits is None)

    boot = None
    if kind.shared_linearisation:
        boot = bootstrap_std(lin, noise.whiteners[pick.weighting], columns, seed=seed)
    settings = {
        "holdout_fraction": holdout,
        "seed": seed,
        "pairing": pairing if kind.pairing_setting else None,
        "method": method,
        "loss": loss,
        "formulation": kind.formulation,
        "measure": kind.measure,
        "mode": dataset.mode,
        "hayati_joints": [int(i) + 1 for i in np.flatnonzero(dataset.model.hayati)],
        "selection": selection,
        "selection_folds": folds_k,
        "weighting": pick.weighting,
        "reject_outliers": reject_outliers,
        **({} if plausibility is None else {"plausibility": plausibility}),
        **noise.settings,
        **kind.settings(training),
    }
    return Calibration(
        dataset=dataset,
        measurements=measurements,
        problem=kind.weighted(training, pick.weighting, noise.whiteners),
        result=result,
        baseline=baseline,
        validation=kind.validate(training, result, baseline, test, screen=reject_outliers),
        train=train,
        test=test,
        settings=settings,
        outliers=outlier_ids,
        noise=noise.noise,
        selection=tuple(scores),
        chosen=chosen,
        reason=reason,
        bootstrap_std=boot,
        geometry=geometry,
    )


def _geometry_only(
    kind: MeasurementKind,
    training: Training,
    result: Result,
    weighting: str,
    loss: str,
    noise: NoiseModel,
    with_noise: bool,
) -> Result | None:
    """The chosen model's fitted columns without its non-geometric terms, refitted (by
    Levenberg-Marquardt, from the chosen fit with those terms at zero): the best model that a
    file holding geometry only (URDF, UR and Franka files) can express. None when the chosen
    model has no non-geometric term: those files then hold the validated model itself."""
    layout = training.problem.layout
    fitted = np.asarray(result.identifiability.subset)
    geometric = layout.is_geometric()
    terms = np.array([c for c in fitted if c < layout.size and not geometric[c]], dtype=int)
    if terms.size == 0:
        return None
    initial = result.params.copy()
    initial[terms] = 0.0
    columns = np.setdiff1d(fitted, terms)
    return _fit(
        kind, training, columns, weighting, "lm", loss, initial, noise if with_noise else None
    )


def _method(candidate, method: str) -> str:
    """The solver of a candidate's fit: the baseline (the frames alone) always by
    Levenberg-Marquardt on its columns (the published method estimates every column)."""
    return "lm" if candidate.name in BASELINE_CANDIDATES else method


def _outliers(
    kind: MeasurementKind, training: Training, detection: Result, method: str
) -> tuple[np.ndarray, Result]:
    """Positions (in ``training.samples``) of the samples that fit badly at ``detection``, and
    the detection fit without them. Gross outliers bend the fit and can hide others: the search
    repeats without the ones found until no more are (a few rounds at most)."""
    samples = training.samples
    found = kind.outliers(training, detection)
    kept, dropped = np.arange(len(samples)), np.zeros(0, dtype=int)
    for _ in range(4):
        if not found.size or len(kept) - len(found) < 4:
            break
        dropped, kept = np.concatenate([dropped, kept[found]]), np.delete(kept, found)
        sub = kind.training(samples[kept], previous=training)
        detection = _fit(
            kind, sub, sub.geometric, "plain", method, kind.detection_loss, initial=detection.params
        )
        found = kind.outliers(sub, detection)
    return np.sort(dropped), detection


def _fit(
    kind: MeasurementKind,
    training: Training,
    columns: np.ndarray,
    weighting: str,
    method: str,
    loss: str,
    initial: np.ndarray | None = None,
    noise: NoiseModel | None = None,
) -> Result:
    """The nonlinear fit of ``columns`` of the training problem weighted as ``weighting`` says,
    the robust loss bending where the kind says (:meth:`MeasurementKind.f_scale`); ``noise``: the
    kind's learned :class:`~relcal.calibration.kinds.NoiseModel` (the pose noise goes into the
    result's covariance)."""
    whiteners = None if noise is None else noise.whiteners
    weighted = kind.weighted(training, weighting, whiteners)
    if method == "published":
        result = identify(weighted, SolverOptions(method="published"), training.ident)
    else:
        sub = replace(training.ident, subset=np.asarray(columns))
        f_scale = kind.f_scale(weighted)
        result = identify_lm(weighted, 200, sub, loss, f_scale, initial=initial)
    if noise is None or noise.noise is None:
        return result
    return replace(result, noise=noise.noise.noise)  # the learned pose noise's levels
