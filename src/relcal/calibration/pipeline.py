"""From a dataset to a calibrated robot: one calibration skeleton, the measurement kind a strategy.

:func:`calibrate` is the skeleton every kind of data goes through: split off held-out samples,
check the inputs, find outlier samples, learn the noise, score the candidate models by
cross-validation on the training samples, fit the chosen model and the baseline, check the
corrections, validate on the held-out samples, and gather the settings into one
:class:`~relcal.calibration.outcome.Calibration`. What differs between relative poses, absolute
points and coincidences (their problem and nuisance parameters, noise model, outlier input, split,
linearisation for model selection, validation and plausibility checks) is supplied by a
:class:`~relcal.calibration.kinds.MeasurementKind`
(:func:`~relcal.calibration.kinds.dispatch.kind_of`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from relcal._renamed import UNSET, renamed
from relcal.calibration.arguments import check_calibrate
from relcal.calibration.coverage import describe
from relcal.calibration.identify import Result, SolverOptions, identify_lm, identify_published
from relcal.calibration.kinds import MeasurementKind, NoiseModel, Training
from relcal.calibration.kinds.dispatch import kind_of
from relcal.calibration.measurement import PairStrategy
from relcal.calibration.outcome import Calibration
from relcal.calibration.priors import layout_prior_std, problem_weights, weak_directions
from relcal.calibration.selection import (
    BASELINE_CANDIDATES,
    bootstrap_std,
    candidate_model,
    candidates,
    choose,
    choose_all,
    family,
    lin_prior,
    linearise,
    score_candidates,
    score_each,
    significant_columns,
    significant_fit,
)
from relcal.data.dataset import Dataset
from relcal.data.imaging import Measurements, measure
from relcal.data.order import in_canonical_order, natural
from relcal.errors import RelcalError
from relcal.robot.model import NONGEOMETRIC
from relcal.robot.priors import Priors


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

    from relcal.checks import check_number, check_seed

    check_number(k, "k", 2, integer=True)
    check_seed(seed)
    dataset, measurements = in_canonical_order(dataset, measurements)
    if measurements is None:
        measurements = measure(dataset)
    kind = kind_of(dataset, measurements, options.get("pairing", "auto"))
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
    pairing: PairStrategy = "auto",
    method: str = "lm",
    loss: str = "linear",
    reject_outliers: bool = UNSET,
    holdout_ids: Sequence[str] | None = None,
    select_folds: int = 5,
    selection: str = "cv",
    nongeometric: str | Sequence[str] = "auto",
    weightings: Sequence[str] = ("plain",),
    priors: str = "model",
    *,
    keep_outliers: bool = False,
) -> Calibration:
    """Choose, fit and validate a model on the training samples; validate on the held-out ones.

    Steps: a fit of the identifiable geometry flags training samples that fit badly (left out of
    what follows unless ``keep_outliers``); the noise is learned from the residuals; candidate
    models (the measurement frames only, geometry, non-geometric families) under the row
    weightings are scored by ``select_folds``-fold cross-validation over training samples and
    the simplest one within two standard errors of the best is fitted (``selection="all"``
    takes the largest, ``"conservative"`` then drops parameters below 3 standard deviations),
    with the baseline (the frames alone) beside it.

    Weak data degrade gracefully: a candidate family of non-geometric terms that these samples
    do not determine (and varied ones would) is dropped from the selection, named in the
    settings (``dropped_candidates``) and the reason; link parameters that they barely
    determine are held by their priors (or at nominal where they are not determined at all) and
    named (``weak_directions``). Only data that determine not even the baseline are refused.

    Parameters
    ----------
    dataset : Dataset
        The samples (:func:`relcal.load_dataset` or :meth:`Dataset.from_arrays`).
    measurements : Measurements, optional
        The camera poses of :func:`relcal.measure` (measured here if not given).
    holdout : float
        Share of the samples (placements for coincidence data) held out for validation,
        0 <= holdout < 1; 0: no validation.
    seed : int
        Seed of the held-out split and the cross-validation folds (0 or more).
    pairing : {"auto", "all", "consecutive", "star", "board"}
        Which pairs of training samples form relative measurements: ``auto`` (all pairs up to
        :data:`~relcal.calibration.measurement.AUTO_ALL_PAIRS` usable samples, ``board``
        above), all, consecutive or star pairs, or ``board`` (each pose against ``W F X``, the
        board transform ``W`` estimated: linear in the samples).
    method : {"lm", "published"}
        The solver (:class:`SolverOptions`).
    loss : {"linear", "huber", "cauchy", "soft_l1"}
        Loss of the fits once outliers are out, with either ``method`` (the published solver
        reweights its iterations: the same robust cost).
    reject_outliers : bool
        Deprecated (a DeprecationWarning; removed in relcal 0.2): ``reject_outliers=False`` is
        ``keep_outliers=True``. Not given by default.
    holdout_ids : sequence of str, optional
        The validation samples by id (placements by name for coincidence data), instead of a
        random share ``holdout``.
    select_folds : int
        Folds (2 or more) of the cross-validation over training samples that scores the
        candidate models.
    selection : {"cv", "conservative", "all"}
        Model selection: the simplest candidate within two standard errors of the best, then
        only parameters above 3 standard deviations, or every identifiable parameter.
    nongeometric : str or sequence of str
        The families of non-geometric terms offered to model selection on top of those the
        model file enables: ``"auto"`` every family the model can have
        (:func:`relcal.robot.model.nongeometric_options`), ``"none"``, or a list such as
        ``["scale", "harmonic"]``.
    weightings : sequence of str
        The row weightings each candidate of relative poses is tried with, ``plain`` and/or
        ``noise model`` (each pair whitened by its learned 6x6 covariance; its predicted
        standard deviations can be 20 to 40 % small on the parameters of parallel axes,
        measured by Monte Carlo, so it is not the default).
    priors : {"model", "none"}
        ``"model"`` holds weakly determined directions by the model's manufacturing tolerances
        (``priors:`` of the model file, :mod:`relcal.calibration.priors`; maximum a posteriori
        fits), ``"none"`` fits plain least squares whatever the model says.
    keep_outliers : bool
        Keep the training samples that fit badly in the fit (the command line's
        ``--keep-outliers``); by default they are left out. Keyword only.

    Returns
    -------
    Calibration
        The chosen model's fit (``result``), the baseline, the held-out validation and the
        calibrated model (``model``).

    Raises
    ------
    ArgumentError
        An argument of the wrong type or out of range: a path instead of a :class:`Dataset`,
        measurements of another dataset, ``holdout_ids="s1"`` instead of a list, an unknown
        choice, or ``reject_outliers`` and ``keep_outliers`` that disagree.
    RelcalError
        Data that are wrong (units, conventions, another robot; named with the likely cause), an
        unknown weighting, too few usable samples, or a calibration above the memory limit.

    Examples
    --------
    >>> import relcal
    >>> dataset = relcal.load_dataset("examples/tiago-pro-poses")  # from the repository root
    >>> cal = relcal.calibrate(dataset, nongeometric="none")
    >>> cal.result.converged, len(cal.test)  # a quarter of the 48 samples held out
    (True, 12)
    >>> before, after = cal.validation.rms("before"), cal.validation.rms("calibrated")
    >>> bool(after < before)  # held-out position RMS, mm
    True
    """
    keep_outliers = renamed(
        "calibrate", "reject_outliers", reject_outliers, "keep_outliers", keep_outliers, False,
        lambda reject: not reject,
    )  # fmt: skip
    reject_outliers = not keep_outliers  # the settings key of results.json and the registry
    check_calibrate(
        dataset, measurements, holdout, seed, pairing, method, loss, holdout_ids, select_folds,
        selection, nongeometric, weightings, keep_outliers, priors,
    )  # fmt: skip
    options = _Options(
        holdout, seed, pairing, method, loss, reject_outliers, holdout_ids, select_folds,
        selection, nongeometric, tuple(weightings), priors,
    )  # fmt: skip
    # The samples in their content's order: what follows depends on the data alone.
    dataset, measurements = in_canonical_order(dataset, measurements)
    if measurements is None:
        measurements = measure(dataset)
    kind, train, test, coverage = _split(dataset, measurements, options)
    # Plausibility of the inputs (a wrong unit, joint order, board size, robot): before fitting.
    plausibility = kind.check_inputs(train)
    # Candidate families the samples do not determine are dropped (degrade, do not refuse).
    kind, training, dropped = _drop_undetermined(kind, kind.training(train), train)
    cleaned = _without_outliers(kind, training, options)
    selected = _selection(kind, cleaned, options)
    chosen = _chosen(kind, cleaned, selected, options)
    training, result = cleaned.training, chosen.result
    weighting = chosen.pick.weighting
    # What a geometry-only file (URDF, vendor files) can hold: validated on its own at export.
    geometry = _geometry_only(
        kind, training, result, weighting, loss, selected.noise if selected.fits is None else None,
        selected.priors_of.get(weighting),
    )  # fmt: skip
    boot = _bootstrap(kind, selected, chosen, seed)
    # The plausibility gate (a wrong input absorbed by the model, terms beyond their bounds,
    # intervals the bootstrap contradicts): before anything is written.
    warnings = kind.check_model(training, result, chosen.baseline, boot)
    reason = chosen.reason
    if dropped:
        reason += "; dropped (not determined by these samples): " + "; ".join(
            f"candidates with {d['family']} terms" for d in dropped
        )
    dataset = kind.dataset
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
        "selection_folds": selected.folds,
        "weighting": weighting,
        "reject_outliers": reject_outliers,
        **({"priors": dataset.model.priors.to_dict()} if cleaned.with_priors else {}),
        **_weak_setting(training, result, cleaned, dataset.q[cleaned.train]),
        **({"dropped_candidates": dropped} if dropped else {}),
        **({} if plausibility is None else {"plausibility": plausibility}),
        "coverage": coverage,
        **selected.noise.settings,
        **kind.settings(training),
        **kind.result_settings(training, result),
    }
    return Calibration(
        dataset=dataset,
        measurements=measurements,
        problem=kind.weighted(training, weighting, selected.noise.whiteners),
        result=result,
        baseline=chosen.baseline,
        validation=kind.validate(training, result, chosen.baseline, test, screen=reject_outliers),
        train=cleaned.train,
        test=test,
        settings=settings,
        outliers=cleaned.outlier_ids,
        noise=selected.noise.noise,
        selection=tuple(selected.scores),
        chosen=chosen.index,
        reason=reason,
        bootstrap_std=boot,
        warnings=tuple(warnings),
        geometry=geometry,
        kind=kind,  # its validate measures each exported file (calibration.artifacts)
    )


# --- the stages of calibrate ---------------------------------------------------------------------


@dataclass(frozen=True)
class _Options:
    """The choices of one :func:`calibrate` run, as given (checked)."""

    holdout: float
    seed: int
    pairing: PairStrategy
    method: str
    loss: str
    reject_outliers: bool
    holdout_ids: Sequence[str] | None
    select_folds: int
    selection: str
    nongeometric: str | Sequence[str]
    weightings: tuple[str, ...]
    priors: str


def _split(
    dataset: Dataset, measurements: Measurements, options: _Options
) -> tuple[MeasurementKind, np.ndarray, np.ndarray, dict]:
    """The measurement kind of the data (its model with the candidate non-geometric families,
    and without priors for ``priors="none"``), the training and held-out samples (whole
    configurations), and what the samples cover (:func:`_coverage`)."""
    kind = kind_of(dataset, measurements, options.pairing)
    train, test = kind.split(options.holdout, options.seed, options.holdout_ids)
    coverage = _coverage(kind, test, options.holdout_ids)
    model = candidate_model(dataset.model, options.nongeometric)
    if options.priors == "none":
        model = replace(model, priors=Priors(enabled=False))
    return replace(kind, dataset=replace(dataset, model=model)), train, test, coverage


@dataclass(frozen=True)
class _Cleaned:
    """The training samples the calibration fits (``train``; outliers left out unless kept) and
    their ``training`` problem; ``full``: the geometry fitted there with the run's loss;
    ``outlier_ids``: the training samples that fit badly; ``std``: the priors' standard
    deviations (``with_priors`` when any is finite) and ``prior``: the plain weighting's prior
    rows (None without priors)."""

    training: Training
    train: np.ndarray
    full: Result
    outlier_ids: tuple[str, ...]
    std: np.ndarray
    with_priors: bool
    prior: np.ndarray | None


def _without_outliers(kind: MeasurementKind, training: Training, options: _Options) -> _Cleaned:
    """Outliers: samples whose measurements fit badly at a fit of the geometry
    (:func:`_outliers`), left out unless kept; then the geometry fitted with the run's loss on
    the samples that remain."""
    method, train = options.method, training.samples
    std = layout_prior_std(training.problem)
    with_priors = bool(np.isfinite(std).any())
    detection = _fit(kind, training, training.geometric, "plain", method, kind.detection_loss)
    prior = None
    if with_priors:  # the noise level of the rows from the plain fit, then the MAP fit
        prior = _plain_prior(kind, training, method, detection, std)
        detection = _fit(
            kind, training, training.geometric, "plain", method, kind.detection_loss, prior=prior
        )
    outliers, without = _outliers(kind, training, detection, method, prior)
    outlier_ids = tuple(natural(kind.dataset.ids[train[i]] for i in outliers))
    removed = bool(options.reject_outliers and outliers.size)
    if removed:
        train = np.delete(train, outliers)
        training = kind.training(train, previous=training)
        detection = without
    full = detection  # the geometry fitted with ``loss`` on the final training samples
    if with_priors and removed:  # the rows' noise level without the outliers
        prior = _plain_prior(kind, training, method, detection, std)
    if removed or options.loss != kind.detection_loss:
        start = None if kind.refit_from_nominal else detection.params
        full = _fit(
            kind, training, training.geometric, "plain", method, options.loss, initial=start,
            prior=prior,
        )  # fmt: skip
    if with_priors and removed:
        full, prior = _settled_prior(kind, training, options, full, prior, std)
    return _Cleaned(training, train, full, outlier_ids, std, with_priors, prior)


def _settled_prior(
    kind: MeasurementKind,
    training: Training,
    options: _Options,
    full: Result,
    prior: np.ndarray | None,
    std: np.ndarray,
    rounds: int = 3,
) -> tuple[Result, np.ndarray | None]:
    """The fit and its prior rows once the rows' noise level is measured at the fit itself:
    the level of the first fit without the outliers was measured where the search for them left
    the estimate (a start bent by the outliers, on its way), and a level measured too high holds
    the directions the priors hold too firmly (an estimate 10x off the truth's held-out error
    was seen). Refitted while the level falls by more than a tenth."""
    for _ in range(rounds):
        if prior is None:
            break
        again = _plain_prior(kind, training, options.method, full, std)
        if again is None or np.max(again) > 0.9 * np.max(prior):
            break
        prior = again
        full = _fit(
            kind, training, training.geometric, "plain", options.method, options.loss,
            initial=full.params, prior=prior,
        )  # fmt: skip
    return full, prior


@dataclass(frozen=True)
class _Selected:
    """Model selection: the learned ``noise``, each candidate's cross-validated ``scores`` over
    ``folds`` folds, the shared linearisation ``lin`` (None when each candidate was fitted:
    ``fits``), and the prior rows of each weighting's nonlinear fits (``priors_of``) and of the
    linearised ones (``lin_priors``; None without priors)."""

    noise: NoiseModel
    scores: list
    folds: int
    lin: object | None
    fits: list[Result] | None
    priors_of: dict
    lin_priors: dict | None


def _selection(kind: MeasurementKind, cleaned: _Cleaned, options: _Options) -> _Selected:
    """Noise, candidate models and their cross-validated scores on the training samples."""
    training, full, std = cleaned.training, cleaned.full, cleaned.std
    lin = linearise(training.problem, full.params) if kind.shared_linearisation else None
    noise = kind.learn_noise(training, full, lin)
    cands = candidates(training.problem, training.ident.subset, kind.weightings(options.weightings))
    folds_k = max(2, min(options.select_folds, len(cleaned.train) // 2))
    priors_of = {"plain": cleaned.prior}  # the prior rows of each weighting's nonlinear fits
    if cleaned.with_priors:
        for w in {c.weighting for c in cands} - {"plain"}:
            priors_of[w] = _prior(kind, training, w, noise.whiteners, full.params, std)
    if not kind.shared_linearisation:  # every candidate fitted, and linearised at its own fit
        fits = [
            _fit(
                kind,
                training,
                c.columns,
                c.weighting,
                _method(c, options.method),
                options.loss,
                full.params,
                prior=priors_of.get(c.weighting),
            )  # fmt: skip
            for c in cands
        ]
        scores = score_each(
            training.problem, fits, cands, folds_k, options.seed,
            std if cleaned.with_priors else None,
        )  # fmt: skip
        return _Selected(noise, scores, folds_k, None, fits, priors_of, None)
    lin_priors = None
    if cleaned.with_priors:
        used = {c.weighting for c in cands}  # (the kind may learn more weightings)
        lin_priors = {
            w: lin_prior(lin, whiten, full.params, std)
            for w, whiten in noise.whiteners.items()
            if w in used
        }
    scores = score_candidates(lin, noise.whiteners, cands, folds_k, options.seed, lin_priors)
    return _Selected(noise, scores, folds_k, lin, None, priors_of, lin_priors)


@dataclass(frozen=True)
class _Chosen:
    """The chosen candidate (``index`` into the scores, ``pick``, why: ``reason``), its fit
    ``result`` on ``columns``, and the ``baseline`` (the best-scoring candidate of the measurement
    frames alone)."""

    index: int
    pick: object
    reason: str
    columns: np.ndarray
    result: Result
    baseline: Result


def _chosen(
    kind: MeasurementKind, cleaned: _Cleaned, selected: _Selected, options: _Options
) -> _Chosen:
    """The chosen model's fit and the baseline's (``selection="conservative"``: then only the
    parameters above 3 standard deviations)."""
    training, full, scores, fits = cleaned.training, cleaned.full, selected.scores, selected.fits
    method, loss, noise = options.method, options.loss, selected.noise
    conservative = options.selection == "conservative"
    chosen, reason = choose_all(scores) if options.selection == "all" else choose(scores)
    pick = scores[chosen].candidate
    at_baseline = [k for k, s in enumerate(scores) if s.candidate.name in BASELINE_CANDIDATES]
    base = min(at_baseline, key=lambda k: np.mean(scores[k].per_sample))
    he = scores[base].candidate
    pick_prior = selected.priors_of.get(pick.weighting)
    if fits is None:
        baseline = _fit(
            kind, training, he.columns, he.weighting, "lm", loss, full.params, noise,
            selected.priors_of.get(he.weighting),
        )  # fmt: skip
    else:
        baseline = fits[base]
    columns = pick.columns
    if pick.name in BASELINE_CANDIDATES:
        return _Chosen(chosen, pick, reason, columns, baseline, baseline)
    if fits is None:
        if conservative:
            weighted = kind.weighted(training, pick.weighting, noise.whiteners)
            columns = significant_columns(
                weighted, training.ident, columns, noise.noise.noise, full.params
            )
        result = _fit(
            kind, training, columns, pick.weighting, method, loss, full.params, noise, pick_prior
        )
    else:
        result = fits[chosen]
        if conservative:
            initial = result.params

            def refit(cols: np.ndarray) -> Result:
                return _fit(
                    kind, training, cols, "plain", method, loss, initial, prior=cleaned.prior
                )

            result = significant_fit(training.problem, result, columns, refit)
    if conservative:
        reason += "; parameters below 3 standard deviations dropped (--selection conservative)"
    return _Chosen(chosen, pick, reason, columns, result, baseline)


def _bootstrap(
    kind: MeasurementKind, selected: _Selected, chosen: _Chosen, seed: int
) -> np.ndarray | None:
    """Bootstrap standard deviations of the chosen columns over training samples, where model
    selection shares one linearisation (None otherwise)."""
    if not kind.shared_linearisation:
        return None
    weighting = chosen.pick.weighting
    prior = None if selected.lin_priors is None else selected.lin_priors.get(weighting)
    return bootstrap_std(
        selected.lin, selected.noise.whiteners[weighting], chosen.columns, seed=seed, prior=prior
    )


def _weak_setting(training: Training, result: Result, cleaned: _Cleaned, q: np.ndarray) -> dict:
    """``{"weak_directions": [...]}`` of :func:`_weak`, or nothing when there are none."""
    weak = _weak(training, result, cleaned.std if cleaned.with_priors else None, q)
    return {"weak_directions": weak} if weak else {}


def _coverage(kind: MeasurementKind, test: np.ndarray, holdout_ids) -> dict:
    """What the usable samples cover (:func:`relcal.calibration.coverage.describe`), how many
    distinct configurations are held out, and the samples held out only because they repeat a
    configuration of a sample named in ``holdout_ids``."""
    ds = kind.dataset
    usable = kind.usable()
    doc = describe(kind.coverage, ds.model, [ds.ids[i] for i in usable])
    doc["held_out_configurations"] = len(np.unique(kind.configurations()[test]))
    if holdout_ids is not None:
        named = set(holdout_ids)
        doc["held_out_with_repeats"] = [ds.ids[i] for i in test if ds.ids[i] not in named]
    return doc


def _geometry_only(
    kind: MeasurementKind,
    training: Training,
    result: Result,
    weighting: str,
    loss: str,
    noise: NoiseModel | None,
    prior: np.ndarray | None,
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
    return _fit(kind, training, columns, weighting, "lm", loss, initial, noise, prior)


def _method(candidate, method: str) -> str:
    """The solver of a candidate's fit: the baseline (the frames alone) always by
    Levenberg-Marquardt on its columns, so that every method is compared with the same
    baseline."""
    return "lm" if candidate.name in BASELINE_CANDIDATES else method


def _outliers(
    kind: MeasurementKind,
    training: Training,
    detection: Result,
    method: str,
    prior: np.ndarray | None = None,
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
            kind, sub, sub.geometric, "plain", method, kind.detection_loss,
            initial=detection.params, prior=prior,
        )  # fmt: skip
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
    prior: np.ndarray | None = None,
) -> Result:
    """The nonlinear fit of ``columns`` of the training problem weighted as ``weighting`` says,
    the robust loss bending where the kind says (:meth:`MeasurementKind.f_scale`); ``noise``: the
    kind's learned :class:`~relcal.calibration.kinds.NoiseModel` (the pose noise goes into the
    result's covariance); ``prior``: the prior rows' weights ``(P,)`` of a maximum a posteriori
    fit (:func:`_prior`). Both solvers estimate ``columns`` only, the others at nominal, and
    minimise the same cost (the published one reweighted for a robust loss)."""
    whiteners = None if noise is None else noise.whiteners
    weighted = kind.weighted(training, weighting, whiteners)
    sub = replace(training.ident, subset=np.asarray(columns))
    std = None if prior is None else layout_prior_std(weighted)
    # Where a robust loss bends (the linear loss has none: its evaluation at nominal is spared).
    f_scale = 1.0 if loss == "linear" else kind.f_scale(weighted)
    if method == "published":
        o = SolverOptions(method="published")
        result = identify_published(
            weighted,
            o.rcond,
            o.tol,
            o.max_iterations,
            sub,
            initial,
            prior=prior,
            prior_std=std,
            loss=loss,
            f_scale=f_scale,
        )
    else:
        result = identify_lm(
            weighted, 200, sub, loss, f_scale, initial=initial, prior=prior, prior_std=std
        )
    if noise is None or noise.noise is None:
        return result
    return replace(result, noise=noise.noise.noise)  # the learned pose noise's levels


def _prior(
    kind: MeasurementKind,
    training: Training,
    weighting: str,
    whiteners: dict[str, np.ndarray] | None,
    params: np.ndarray,
    std: np.ndarray,
) -> np.ndarray | None:
    """The prior rows' weights ``(P,)`` of the training problem weighted as ``weighting`` says,
    the rows' noise level measured at ``params`` (:func:`priors.problem_weights`)."""
    return problem_weights(kind.weighted(training, weighting, whiteners), params, std)


def _plain_prior(
    kind: MeasurementKind, training: Training, method: str, fitted: Result, std: np.ndarray
) -> np.ndarray | None:
    """The prior rows' weights of the plain weighting, the rows' noise level measured at the
    geometry's ``fitted`` (the detection fit) and, when that fit had a robust loss, at a linear
    fit too, the lower level kept: a robust loss bends at the noise level, so on nearly
    noise-free rows it is an L1 fit that can stop far from the optimum, and its residuals would
    overstate the noise (priors far too strong: a noise-free simulation's estimate biased by
    0.1 mm). The weights are proportional to the level; None (no prior rows) when a fit leaves
    no noise at all."""
    prior = _prior(kind, training, "plain", None, fitted.params, std)
    if kind.detection_loss == "linear" or prior is None:
        return prior
    linear = _fit(kind, training, training.geometric, "plain", method, "linear", fitted.params)
    other = _prior(kind, training, "plain", None, linear.params, std)
    if other is None:
        return None
    return prior if np.max(prior) <= np.max(other) else other


SHOWN_MEMBERS = 6  # of a combination named in a dropped candidate's reason
SHOWN_COMBINATIONS = 3  # combinations named in one reason


def _drop_undetermined(
    kind: MeasurementKind, training: Training, train: np.ndarray
) -> tuple[MeasurementKind, Training, list[dict]]:
    """The kind and training problem without the non-geometric families that a combination the
    samples leave undetermined (and varied samples would determine) involves, and what was
    dropped: ``[{"family", "reason"}]``. Refuses when such a combination involves only the
    measurement frames: then not even the baseline can be fitted."""
    dropped: list[dict] = []
    for _ in range(len(NONGEOMETRIC) + 1):
        weak = training.ident.weak
        if not weak:
            break
        layout = training.problem.full_layout
        kind_of_name = dict(zip(layout.names, layout.kinds, strict=True))
        families: dict[str, list[str]] = {}
        for combo in weak:
            # the families of its leading members (a share below a tenth is round-off's)
            lead = max(abs(c) for c in combo.coefficients)
            members = [
                n
                for n, c in zip(combo.names, combo.coefficients, strict=True)
                if abs(c) >= 0.1 * lead
            ]
            fams = {family(kind_of_name[n]) for n in members}
            named = " with ".join(members[:SHOWN_MEMBERS]) + (
                f" and {len(members) - SHOWN_MEMBERS} more" if len(members) > SHOWN_MEMBERS else ""
            )
            if fams == {"frames"}:
                raise RelcalError(
                    f"{kind.dataset.spec_path}: these samples do not determine even the "
                    f"measurement frames ({combo.describe()}); no model, not even the baseline, "
                    "can be fitted: add samples that vary the joints"
                )
            for f in sorted(fams - {"frames", "geometric"}):  # (a set's order varies by run)
                families.setdefault(f, []).append(named)
        if not families:
            break
        model = kind.dataset.model
        flags = tuple(tuple(t for t in f if t not in families) for f in model.nongeometric)
        for f, combos in sorted(families.items()):
            dropped.append(
                {
                    "family": f,
                    "reason": f"{f} terms are not determined by these samples (the joints "
                    "vary too little to tell them from the other parameters): one combination "
                    "of " + "; one of ".join(combos[:SHOWN_COMBINATIONS]) + " is left "
                    "undetermined"
                    + (
                        f" (and {len(combos) - SHOWN_COMBINATIONS} more combinations)"
                        if len(combos) > SHOWN_COMBINATIONS
                        else ""
                    ),
                }
            )
        dataset = replace(kind.dataset, model=replace(model, nongeometric=flags))
        kind = replace(kind, dataset=dataset)
        training = kind.training(train)
    return kind, training, dropped


def _weak(training: Training, result: Result, std: np.ndarray | None, q: np.ndarray) -> list[dict]:
    """The weak directions of a calibration, for the settings: the combinations these samples
    leave undetermined (held at nominal: truncated) and the parameters held by their priors
    rather than by the data (:func:`priors.weak_directions`), each with a sentence in words."""
    out = [
        {
            "parameter": " + ".join(c.names),
            "held": "at nominal",
            "text": f"{c.describe()}: not determined by these samples (samples that vary the "
            f"joints more would determine it{_travel(training.problem, c.names, q)}); held at "
            "nominal",
        }
        for c in training.ident.weak
    ]
    if std is None or result.prior_std is None:
        return out
    post = result.covariance
    data = result.data_covariance  # the data's part of post, computed with it
    subset = result.identifiability.subset
    for w in weak_directions(training.problem, subset, data, post, std, q):
        out.append({**w.to_dict(), "held": "by its prior"})
    return out


def _travel(problem, names: Sequence[str], q: np.ndarray) -> str:
    """``"; joint2 moved over 0 deg, ..."`` for the joints of the link parameters ``names``
    (how far each moved in the samples ``q``), least travel first; empty without any."""
    layout = problem.full_layout
    model = problem.model
    where = {n: k for k, n in enumerate(layout.names)}
    joints = set()
    for n in names:
        k = where[n]
        if k >= problem.layout.size or layout.kinds[k] in ("base", "tool"):
            continue
        i = int(layout.index[k]) // (6 if layout.kinds[k] == "origin" else 1)
        if 0 <= i < model.n_joints:
            joints.add(i)
    if not joints:
        return ""
    travel = {i: float(np.ptp(q[:, i])) for i in joints}
    parts = []
    for i in sorted(joints, key=travel.get):
        shown = (
            f"{travel[i] * 1e3:.3g} mm"
            if model.prismatic[i]
            else f"{np.degrees(travel[i]):.3g} deg"
        )
        parts.append(f"{model.joint_names[i]} moved over {shown}")
    return "; " + ", ".join(parts)
