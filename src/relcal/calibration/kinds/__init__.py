"""Measurement kinds: what one kind of data supplies to the one calibration skeleton.

:func:`relcal.calibration.pipeline.calibrate` is the skeleton (split, plausibility of the inputs,
outliers, noise, candidate models, cross-validated selection, the fits of the chosen model and of
the baseline, plausibility of the corrections, validation, settings, the
:class:`~relcal.calibration.outcome.Calibration` record). A :class:`MeasurementKind` supplies what
differs between kinds of data, and nothing else:

- its :class:`~relcal.calibration.measurement.Problem` on a set of samples (the residual and its
  exact Jacobian with respect to the kinematics and to its own nuisance parameters live in
  :func:`relcal.calibration.measurement.residuals`, by ``formulation``), with the nuisance
  parameters' initial guess (:meth:`MeasurementKind.training`);
- its row weighting and noise model (:meth:`~MeasurementKind.weighted`,
  :meth:`~MeasurementKind.learn_noise`, :meth:`~MeasurementKind.f_scale`);
- the input of the outlier rule (:meth:`~MeasurementKind.outliers`);
- how it splits samples for validation (:meth:`~MeasurementKind.split`,
  :meth:`~MeasurementKind.folds`) and how it validates (:meth:`~MeasurementKind.validate`);
- how model selection linearises (:attr:`~MeasurementKind.shared_linearisation`);
- its plausibility checks (:meth:`~MeasurementKind.check_inputs`,
  :meth:`~MeasurementKind.check_result`); its identifiability reasons are named by
  :func:`relcal.calibration.identifiability.explainer` for its formulation.

The kinds: :class:`~relcal.calibration.kinds.poses.PoseKind` (relative camera or mocap poses),
:class:`~relcal.calibration.kinds.points.PointKind` (absolute points of a tracker or a marker) and
:class:`~relcal.calibration.kinds.coincidence.CoincidenceKind` (a tool point seated again and again
at unknown points, with known distances). :func:`~relcal.calibration.kinds.dispatch.kind_of`
picks one for a dataset.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import ClassVar

import numpy as np

from relcal.calibration.coverage import Coverage
from relcal.calibration.identifiability import Identifiability
from relcal.calibration.identify import Result
from relcal.calibration.measurement import PairStrategy, Problem
from relcal.calibration.noise import PoseNoise
from relcal.calibration.validate import split_units, unit_folds
from relcal.data.dataset import Dataset
from relcal.data.imaging import Measurements
from relcal.errors import RelcalError


@dataclass(frozen=True)
class Training:
    """The training samples as a kind prepares them for the skeleton.

    ``problem``: the identification problem on ``samples`` (dataset indices), its nuisance
    parameters guessed from them; for kinds whose noise is learned before the fits (points,
    coincidence) already weighted by it (``sigma``, m). ``ident``: identifiability at the
    nominal model; ``geometric``: the frames and geometry of ``ident.subset`` (no non-geometric
    term), what the first fits estimate.
    """

    samples: np.ndarray
    problem: Problem
    ident: Identifiability
    geometric: np.ndarray
    sigma: float | None = None


@dataclass(frozen=True)
class NoiseModel:
    """What a kind learned of its noise from the residuals of the full fit: the pose noise
    (poses), the row whitening of each weighting (None: the plain weighting of the linearised
    blocks), and what goes into the settings of the record."""

    noise: PoseNoise | None = None
    whiteners: dict[str, np.ndarray] | None = None
    settings: dict = field(default_factory=dict)


@dataclass(frozen=True)
class MeasurementKind:
    """What one kind of measurement supplies to the skeleton (see the module docstring).

    This base class splits by sample (held-out samples drawn at random, or named by id) and
    leaves the rest to its subclasses. Class attributes describe the kind:
    """

    dataset: Dataset
    measurements: Measurements
    pairing: PairStrategy = "auto"

    formulation: ClassVar[str]  # of measurement.residuals
    measure: ClassVar[str]  # "pose" or "position"
    baseline: ClassVar[str]  # name of the candidate without kinematic correction
    detection_loss: ClassVar[str]  # loss of the fit whose residuals find the outlier samples
    # Model selection: one linearisation at the geometric fit shared by every candidate (a
    # bootstrap of the chosen model's standard deviations comes with it), or each candidate
    # fitted to every training sample and linearised at its own fit.
    shared_linearisation: ClassVar[bool]
    # The fit of the geometry after outlier rejection starts from nominal (else from the fit
    # that found the outliers).
    refit_from_nominal: ClassVar[bool]
    pairing_setting: ClassVar[bool] = True  # the pairing is a setting of this kind

    # --- splitting ---------------------------------------------------------------------------

    def usable(self) -> np.ndarray:
        """Indices of the usable samples (measured, not rejected)."""
        return np.flatnonzero(self.measurements.ok)

    @cached_property
    def coverage(self) -> Coverage:
        """What the usable samples cover (:class:`~relcal.calibration.coverage.Coverage`): their
        distinct configurations (in the order of :meth:`usable`), the joints that never moved,
        the samples at singular configurations (indices into :meth:`usable`)."""
        return Coverage.of(self.dataset.model, self.dataset.q[self.usable()])

    def configurations(self) -> np.ndarray:
        """Each sample's configuration ``(N,)`` (:attr:`coverage`'s clusters), -1 for samples
        that are not usable: samples of one configuration are held out together."""
        out = np.full(len(self.dataset.ids), -1)
        out[self.usable()] = self.coverage.clusters
        return out

    def split(
        self, holdout: float, seed: int, holdout_ids: Sequence[str] | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Training and held-out sample indices among the usable samples: whole configurations
        (:attr:`coverage`), a random share ``holdout`` of them (seeded), or those of the samples
        named by ``holdout_ids`` (with every repeat of their configurations: a copy of a
        held-out configuration is never trained on)."""
        usable = self.usable()
        if len(usable) < 4:
            raise RelcalError(
                f"{self.dataset.spec_path}: only {len(usable)} usable samples; at least 4 are "
                "needed (and many more for a useful calibration)"
            )
        labels = self.coverage.clusters
        if holdout_ids is not None:
            test = np.intersect1d(usable, self.sample_indices(holdout_ids))
            held = np.isin(labels, labels[np.searchsorted(usable, test)])
            return usable[~held], usable[held]
        if holdout > 0:
            train_idx, test_idx = split_units(labels, holdout, seed)
            return usable[train_idx], usable[test_idx]
        return usable, np.zeros(0, dtype=int)

    def folds(self, k: int, seed: int) -> list[list[str]]:
        """The held-out ids (:meth:`split`'s ``holdout_ids``) of each of ``k`` folds of whole
        configurations; each fold holds out at least 2 usable samples, so ``k`` is 2 to half of
        them (and at most the number of distinct configurations)."""
        usable = self.usable()
        n_conf = self.coverage.n_configurations
        most = min(len(usable) // 2, n_conf)
        if not 2 <= k <= most:
            where = self.dataset.spec_path.parent if self.dataset.spec_path else ""
            repeats = (
                f" in {n_conf} distinct configurations (repeats are held out together)"
                if n_conf < len(usable)
                else ""
            )
            raise RelcalError(
                f"--kfold {k}: {where} has {len(usable)} usable samples{repeats}; each fold "
                f"needs at least 2 held-out samples, so K is 2 to {most}"
            )
        labels = self.coverage.clusters
        return [[self.dataset.ids[i] for i in usable[f]] for f in unit_folds(labels, k, seed)]

    def sample_indices(self, ids: Sequence[str]) -> np.ndarray:
        """Sorted indices of the samples named ``ids``."""
        where = {sid: k for k, sid in enumerate(self.dataset.ids)}
        unknown = [sid for sid in ids if sid not in where]
        if unknown:
            ds = self.dataset
            folder = (ds.spec_path.parent if ds.spec_path else ds.root).resolve()
            numbered = ds.ids == tuple(str(k + 1) for k in range(len(ds.ids)))
            how = " (no id column: the samples are numbered 1 to N by row)" if numbered else ""
            raise RelcalError(
                f"held-out sample id(s) {', '.join(map(str, unknown[:5]))} are not in {folder}{how}"
            )
        return np.array(sorted(where[sid] for sid in ids), dtype=int)

    # --- the kind's problem, noise and outlier input --------------------------------------------

    def training(self, train: np.ndarray, previous: Training | None = None) -> Training:
        """The training problem on ``train``; ``previous``: the one before outliers were left
        out (a kind may keep its guesses and its identifiability analysis)."""
        raise NotImplementedError

    def weighted(
        self, training: Training, weighting: str, whiteners: dict[str, np.ndarray] | None = None
    ) -> Problem:
        """The training problem with its rows weighted as ``weighting`` says."""
        return training.problem

    def f_scale(self, weighted: Problem) -> float:
        """The weighted residual where a robust loss bends."""
        raise NotImplementedError

    def outliers(self, training: Training, detection: Result) -> np.ndarray:
        """Positions (in ``training.samples``) of the samples that fit badly at ``detection``."""
        raise NotImplementedError

    def learn_noise(self, training: Training, full: Result, lin) -> NoiseModel:
        """The noise learned from the residuals of ``full`` (the geometric fit; ``lin``: its
        linearisation when :attr:`shared_linearisation`)."""
        return NoiseModel()

    def weightings(self, requested: Sequence[str]) -> tuple[str, ...]:
        """The row weightings each candidate is tried with."""
        return tuple(requested)

    # --- plausibility and validation ------------------------------------------------------------

    def check_data(self) -> dict | None:
        """The input gate of every entry point (calibrate, verify, the Python API and the command
        line): refuse data that cannot be this robot's measurements, naming the likely cause,
        before anything is fitted, on every usable sample (held-out ones too): joint readings
        against the model's limits, measured magnitudes, the chain against the measurements.
        Returns what the checks measured, for the settings (None: nothing). This base checks the
        joint readings alone (:func:`~relcal.calibration.plausibility.check_joint_dataset`)."""
        from relcal.calibration.plausibility import check_joint_dataset

        check_joint_dataset(self.dataset, self.measurements)
        return None

    def check_inputs(self, train: np.ndarray) -> dict | None:
        """:meth:`check_data` before a calibration on the samples ``train`` (a kind may check
        more there, e.g. the memory the calibration needs)."""
        return self.check_data()

    def check_result(self, training: Training, result: Result) -> None:
        """Refuse corrections too large to be a calibration."""
        raise NotImplementedError

    def check_model(
        self,
        training: Training,
        result: Result,
        baseline: Result | None = None,
        bootstrap: np.ndarray | None = None,
    ) -> list[str]:
        """The plausibility gate before a model is written, the same for every kind: the kind's
        own :meth:`check_result` (which frames are free), then
        :func:`relcal.calibration.plausibility.check_calibration` (non-geometric bounds, frames
        against ``baseline``, joint limits, predicted against ``bootstrap`` standard
        deviations). Raises on refusal; returns the warnings."""
        from relcal.calibration.plausibility import check_calibration

        self.check_result(training, result)
        q = self.dataset.q[training.samples]
        return check_calibration(
            self.dataset, training.problem, result, baseline, bootstrap, q=q, links=False
        )

    def validate(
        self,
        training: Training,
        result: Result,
        baseline: Result,
        test: np.ndarray,
        screen: bool = False,
    ):
        """Held-out errors of ``result`` and ``baseline`` on the samples ``test`` (None when
        there are too few); with ``screen``, held-out samples that fit badly under both are
        named and left out, as training outliers are (:func:`validate.held_out_outliers`)."""
        raise NotImplementedError

    def settings(self, training: Training) -> dict:
        """What the record's settings say of this kind beyond the skeleton's."""
        return {}

    def result_settings(self, training: Training, result: Result) -> dict:
        """What the record's settings say of the chosen fit beyond the skeleton's (e.g. how its
        covariance was computed)."""
        return {}
