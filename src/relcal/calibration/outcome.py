"""What a calibration produced (:class:`Calibration`), the record of the calibration skeleton
(:mod:`pipeline`) for every measurement kind, with the rule that finds outlier samples."""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np

from relcal.calibration.identify import Result, calibrated_handeye
from relcal.calibration.measurement import Problem, pair_errors, per_sample_median
from relcal.calibration.noise import PoseNoise
from relcal.calibration.selection import BASELINE_CANDIDATES, Score
from relcal.calibration.validate import PlacementValidation, Validation
from relcal.data.dataset import Dataset
from relcal.data.imaging import Measurements
from relcal.robot.export import calibrated_model
from relcal.robot.model import RobotModel

ROBUST_SCALE = 3.0  # residual (in noise standard deviations) where the robust loss bends


@dataclass(frozen=True)
class Comparison:
    """The errors that show what a calibration did: ``before`` (the baseline) and ``after`` (the
    exported model), ``(P, 6)`` per pair (position m, rotation rad) or per point (tracker).

    ``source`` says where they come from: ``held-out pairs`` (pairs among held-out samples),
    ``held-out points`` (position-only data), ``held-out placements`` (coincidence samples of
    placements left out: each sample's spread from its group's refitted point, as a position
    error), or ``training pairs`` when nothing was held out (optimistic: the fit saw them).
    ``count`` is the number of pairs, points or samples.
    """

    before: np.ndarray
    after: np.ndarray
    source: Literal["held-out pairs", "held-out points", "held-out placements", "training pairs"]
    count: int


@dataclass(frozen=True)
class Calibration:
    """Everything a calibration produced.

    ``result`` is the chosen model's fit and ``baseline`` the fit of the measurement frames alone
    (nominal kinematics with the hand-eye transform, the instrument transform and marker, or the
    tool point and group points fitted): the best a user gets without kinematic calibration, and
    the primary "before" of every comparison. When the data support no kinematic correction the
    chosen model *is* the baseline (``exported == "baseline"``). ``validation``: held-out pairs
    or points (:class:`Validation`), or held-out placements of coincidence data
    (:class:`PlacementValidation`). Made by :func:`relcal.calibrate`; written by
    :func:`relcal.write_calibration`.

    Parameters
    ----------
    dataset : Dataset
        The calibrated dataset.
    measurements : Measurements
        Its measured poses (all samples).
    problem : Problem
        The identification problem of the training samples, with the chosen weighting.
    result : Result
        The chosen model's fit: parameters ``(P,)`` (m, rad) following ``problem.full_layout``.
    baseline : Result
        The fit of the measurement frames alone (nominal kinematics).
    validation : Validation, PlacementValidation or None
        Held-out errors before and after; None without held-out samples.
    train : (N_train,) ndarray of int
        Indices in ``dataset`` of the training samples fitted (outliers left out unless kept).
    test : (N_test,) ndarray of int
        Indices in ``dataset`` of the held-out samples.
    settings : dict
        The options of the run (pairing, method, loss, ...), as written to ``results.json``.
    outliers : tuple of str
        Ids of training samples that fit badly (left out of the fit unless kept).
    noise : PoseNoise or None
        The noise model learned from the residuals: a ``(6, 6)`` covariance of each pose's
        error (translation m, rotation rad).
    selection : tuple of Score
        Each candidate model's cross-validated held-out errors.
    chosen : int
        Index of the chosen candidate in ``selection``.
    reason : str
        Why that candidate was chosen, in words.
    bootstrap_std : (P,) ndarray of float or None
        Bootstrap standard deviations over training samples (m, rad); NaN if not estimated.
    warnings : tuple of str
        What the plausibility gate found doubtful but not wrong (frames moved from the
        baseline's, offsets past the joint limits, predicted and bootstrap std that disagree).
    geometry : Result or None
        The chosen columns without their non-geometric terms, refitted: the best model a
        geometry-only file (URDF, UR and Franka files) can hold, validated on its own at
        export; None when the chosen model has no non-geometric term.
    kind : MeasurementKind or None
        The measurement kind that made it (:mod:`relcal.calibration.kinds`): its ``validate``,
        the held-out metric of :attr:`validation`, measures each exported file too
        (:attr:`artifacts`).
    """

    dataset: Dataset
    measurements: Measurements
    problem: Problem  # training samples, with the chosen weighting
    result: Result
    baseline: Result
    validation: Validation | PlacementValidation | None
    train: np.ndarray  # sample indices
    test: np.ndarray
    settings: dict
    outliers: tuple[str, ...] = ()  # ids of training samples that fit badly
    noise: PoseNoise | None = None
    selection: tuple[Score, ...] = ()
    chosen: int = 0  # index into selection
    reason: str = ""
    bootstrap_std: np.ndarray | None = None  # (P,) over training samples; NaN if not estimated
    # What the plausibility gate warned of (plausibility.check_calibration), in words.
    warnings: tuple[str, ...] = ()
    # the chosen columns without the non-geometric terms, refitted: what a geometry-only file
    # (URDF, vendor files) can hold; None when the chosen model has no non-geometric term
    geometry: Result | None = None
    # the measurement kind (relcal.calibration.kinds.MeasurementKind) that made it: its
    # ``validate`` is the held-out metric, which measures each exported file too (artifacts)
    kind: Any = None

    def __repr__(self) -> str:
        from relcal._repr import plural, short

        def held_out() -> str:
            val = self.validation
            if val is None:
                return "no held-out samples"
            before, after = val.rms("before"), val.rms("calibrated")
            return f"held-out position RMS {before:.4g} -> {after:.4g} mm"

        chosen = self.selection[self.chosen].candidate.name if self.selection else ""
        return short(
            "Calibration",
            f"of {self.problem.model.name!r}",
            f"{plural(len(self.dataset.ids), 'sample')} ({len(self.train)} fitted, "
            f"{len(self.test)} held out, {len(self.outliers)} outliers)",
            f"exported {self.exported}" + (f" ({chosen})" if chosen else ""),
            "converged" if self.result.converged else "NOT converged",
            held_out,
        )

    @property
    def std(self) -> np.ndarray:
        """Standard deviations ``(P,)`` of the estimate (m, rad); NaN if not estimated."""
        return self.result.std

    @property
    def selected_baseline(self) -> bool:
        """Model selection chose the candidate without kinematic correction (the data support
        none): :attr:`result` is the baseline's fit."""
        chosen = self.selection[self.chosen].candidate if self.selection else None
        return chosen is not None and chosen.name in BASELINE_CANDIDATES

    def verdict(self):
        """The verdict on the exported model: its held-out evidence, and what the samples
        cannot show (``settings["coverage"]["limits"]``: a joint that never moved, every sample
        singular).

        Returns
        -------
        Verdict
            :class:`relcal.calibration.verdict.Verdict`: ``code`` (deploy, collect more
            samples, do not deploy, not validated), the line a person reads, the factor with
            its interval for a new session and the held-out samples' own.
        """
        from relcal.calibration.verdict import verdict

        limits = tuple(self.settings.get("coverage", {}).get("limits", ()))
        return verdict(self.validation, self.exported, self.problem.formulation, limits)

    @property
    def worse(self) -> bool:
        """The chosen calibrated model's held-out RMS (position; the spread of coincidences)
        exceeds the baseline's: it is not exported (:attr:`exported`)."""
        if self.validation is None or self.selected_baseline:
            return False
        return self.validation.rms("calibrated") > self.validation.rms("before")

    @property
    def hurts(self) -> bool:
        """:attr:`worse`, and beyond doubt: the whole 95 % interval of the held-out RMS ratio to
        the baseline (bootstrap over held-out samples) lies above 1."""
        if not self.worse:
            return False
        return self.validation.ratio()["ci95"][0] > 1.0

    @property
    def exported(self) -> str:
        """``calibrated``, or ``baseline``: model selection chose the measurement frames alone
        (the data support no kinematic correction), or the chosen model is :attr:`worse` than
        the baseline on the held-out samples (a model worse than what the user has without
        calibration is never the answer)."""
        return "baseline" if self.selected_baseline or self.worse else "calibrated"

    @property
    def exported_fit(self) -> Result:
        """The fit of the exported model: :attr:`result`, or :attr:`baseline` when the chosen
        model is :attr:`worse` than it."""
        return self.baseline if self.worse else self.result

    @property
    def export_reason(self) -> str | None:
        """Why the baseline is exported, in words (None: the calibrated model is)."""
        if self.selected_baseline:
            return "the data support no kinematic correction"
        if not self.worse:
            return None
        chosen = self.selection[self.chosen].candidate.name if self.selection else "calibrated"
        what = "spread" if isinstance(self.validation, PlacementValidation) else "position"
        return (
            f"the chosen model ({chosen}) is worse than the baseline on the held-out samples "
            f"({what} RMS {self.validation.rms('calibrated'):.3f} mm against "
            f"{self.validation.rms('before'):.3f} mm)"
        )

    @property
    def model(self) -> RobotModel:
        """The exported robot model (the identified errors applied; only the non-geometric
        terms of the chosen model switched on). Coincidence data: the tool transform ends at
        the estimated tool point (:func:`relcal.calibration.coincidence.with_tool_point`), so
        the model alone (model.yaml, the URDF's tip) predicts the ball centre it was fitted
        with, whatever the tool point absorbed. When the chosen model is :attr:`worse` than
        the baseline, the baseline's: the nominal kinematics."""
        layout = self.problem.layout
        model = self._model_of(self.exported_fit.params)
        if self.worse:
            return exported_model(model, set())
        if not self.selection:
            return model
        columns = self.selection[self.chosen].candidate.columns
        return exported_model(model, {layout.kinds[c] for c in columns if c < layout.size})

    def _model_of(self, params: np.ndarray) -> RobotModel:
        """The nominal model with the errors of ``params`` applied; for coincidences its tool
        transform ends at the tool point of ``params``
        (:func:`relcal.calibration.coincidence.with_tool_point`)."""
        model = calibrated_model(self.problem.model, self.problem.layout, params)
        if self.problem.formulation == "coincidence":
            from relcal.calibration.coincidence import split_params, with_tool_point

            model = with_tool_point(model, split_params(self.problem, params)[1])
        return model

    @property
    def geometry_model(self) -> RobotModel:
        """The model of the geometry-only files (URDF, UR and Franka files): :attr:`model` when
        the chosen model has no non-geometric term, otherwise the geometry-only refit
        (:attr:`geometry`) with every non-geometric term off (coincidences: its tool transform
        ends at the refit's own tool point, as :attr:`model`'s at the chosen fit's)."""
        if self.geometry is None or self.worse:
            return self.model
        return exported_model(self._model_of(self.geometry.params), set())

    @functools.cached_property
    def artifacts(self):
        """Every file a user can load (``model.yaml``, ``robot.urdf``, vendor files), each read
        back and validated on the held-out samples:
        :func:`relcal.calibration.artifacts.export_artifacts`."""
        from relcal.calibration.artifacts import export_artifacts

        return export_artifacts(self)

    @functools.cached_property
    def comparison(self) -> Comparison:
        """Baseline against exported model: on the held-out samples when there are some,
        otherwise the training residuals (unweighted)."""
        val = self.validation
        if isinstance(val, PlacementValidation):
            before, after = val.baseline.as_errors(), val.calibrated.as_errors()
            return Comparison(before, after, "held-out placements", len(val.samples))
        if val is not None:
            source = {"points": "held-out points", "poses": "held-out poses"}.get(
                val.what, "held-out pairs"
            )
            return Comparison(val.before, val.after, source, len(val.pairs))
        problem = replace(self.problem, weights=None, pair_weights=None)
        return Comparison(
            pair_errors(problem, self.baseline.params),
            pair_errors(problem, self.result.params),
            "training pairs",
            len(problem.pair_indices()),
        )

    @property
    def handeye(self) -> np.ndarray:
        """The hand-eye transform ``X`` ``(4, 4)`` of the exported model's fit
        (:attr:`exported_fit`)."""
        return calibrated_handeye(self.problem, self.exported_fit)


def exported_model(model: RobotModel, kinds: set[str]) -> RobotModel:
    """``model`` keeping only the non-geometric terms of the parameter ``kinds`` chosen (the
    families model selection left out are switched off again, their values are zero)."""
    keep = {k.split("_")[0] for k in kinds}
    flags = tuple(tuple(t for t in f if t in keep) for f in model.nongeometric)
    return replace(model, nongeometric=flags)


def outlier_samples(weighted: np.ndarray, pairs: np.ndarray, threshold: float = 5.0) -> np.ndarray:
    """Indices of samples whose pairs fit badly: each sample's score is the median normalised
    error of its pairs; a robust z-score above ``threshold`` flags it."""
    norms = np.linalg.norm(weighted, axis=1)
    score = per_sample_median(norms, pairs)
    spread = 1.4826 * np.median(np.abs(score - np.median(score)))
    return np.flatnonzero((score - np.median(score)) > threshold * max(spread, 1e-12))
