"""Absolute points of an instrument whose frame is unknown (a laser tracker's reflector, a
motion-capture marker): the tracker formulation ``p_k = T F(q_k) m`` with the instrument-from-base
transform ``T`` and the marker position ``m`` (flange frame) estimated with the geometry.

What the kind supplies to the skeleton: guesses of ``T`` and ``m`` by a registration of the nominal
flange points on every training set (:func:`~relcal.calibration.handeye.solve_instrument`; ``m``
from ``handeye.xyz`` in dataset.yaml when given), the robust point noise of a least-squares fit of
the geometry weighting every row, a Huber fit whose point errors find the outliers, each model
selection candidate fitted to every training point and linearised at its own fit (a fold moves a
fit only a little, while the candidates differ by corrections of degrees, which one shared
linearisation would bend: on the real TIAGo Pro positions the baseline's cross-validated RMS comes
out 31.1 mm linearised at the geometric fit against 28.5 mm with nonlinear refits of every fold),
and validation by the absolute point errors of the held-out samples, ``T`` and ``m`` of the
training fit.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from relcal.calibration.handeye import solve_instrument
from relcal.calibration.identifiability import check_pose_set
from relcal.calibration.identify import Result, SolverOptions, identify
from relcal.calibration.kinds import MeasurementKind, NoiseModel, Training
from relcal.calibration.measurement import Problem, pair_errors
from relcal.calibration.noise import robust_sigma
from relcal.calibration.outcome import ROBUST_SCALE, outlier_samples
from relcal.calibration.plausibility import check_point_dataset, check_result
from relcal.calibration.selection import geometric_columns
from relcal.calibration.validate import held_out
from relcal.robot.kinematics import fk, make_layout


def point_errors(problem: Problem, params: np.ndarray) -> np.ndarray:
    """Unweighted point errors ``(N, 3)`` (m) of the point-per-sample formulations."""
    return pair_errors(problem, params)[:, :3]


@dataclass(frozen=True)
class PointKind(MeasurementKind):
    """Absolute points of a tracker or a marker; see the module docstring."""

    formulation = "tracker"
    measure = "position"
    baseline = "instrument and marker only"
    detection_loss = "huber"
    shared_linearisation = False
    refit_from_nominal = True
    pairing_setting = False
    what = "points"  # how messages name the samples

    def problem_on(self, samples: np.ndarray) -> Problem:
        """The tracker problem of ``samples``, ``T`` and ``m`` guessed from them."""
        ds, poses = self.dataset, self.measurements.poses
        marker0 = None if ds.handeye is None else ds.handeye[:3, 3]
        flange = fk(ds.model, ds.q[samples])
        instrument, marker = solve_instrument(flange, poses[samples, :3, 3], marker0)
        return Problem(
            model=ds.model,
            layout=make_layout(ds.model),
            q=ds.q[samples],
            poses=poses[samples],
            formulation="tracker",
            measure="position",
            instrument=instrument,
            marker=marker,
        )

    def training(self, train: np.ndarray, previous: Training | None = None) -> Training:
        """The problem weighted by the robust point noise of a least-squares fit of the geometry
        (non-geometric terms are small there and enter the candidates only); guesses and the
        analysis are those of ``train`` alone."""
        problem = self.problem_on(train)
        ident = check_pose_set(problem, str(self.dataset.spec_path), refuse=False)
        geometric = geometric_columns(problem, ident.subset)
        first = identify(problem, SolverOptions(), replace(ident, subset=geometric))
        sigma = float(robust_sigma(pair_errors(problem, first.params))[0])
        weighted = replace(problem, weights=np.full(6, 1.0 / sigma))
        return Training(train, weighted, ident, geometric, sigma)

    def f_scale(self, weighted: Problem) -> float:
        """:data:`ROBUST_SCALE` noise standard deviations (the rows are whitened)."""
        return ROBUST_SCALE

    def outliers(self, training: Training, detection: Result) -> np.ndarray:
        """Each sample's point error in units of the point noise."""
        n = len(training.samples)
        per_point = np.stack([np.arange(n)] * 2, axis=1)
        errors = point_errors(training.problem, detection.params) / training.sigma
        return outlier_samples(errors, per_point)

    def learn_noise(self, training: Training, full: Result, lin) -> NoiseModel:
        return NoiseModel(settings={"point_sigma_m": training.sigma})

    def weightings(self, requested) -> tuple[str, ...]:
        return ("plain",)

    def check_data(self) -> dict:
        """Joint limits, magnitudes, and the points against the commanded flange positions, a
        wrong joint order or unit named
        (:func:`~relcal.calibration.plausibility.check_point_dataset`)."""
        return check_point_dataset(self.dataset, self.measurements)

    def check_result(self, training: Training, result: Result) -> None:
        """The link corrections (the nuisance frames are free by design); a refused parameter
        that the data do not determine is named so."""
        check_result(self.dataset, training.problem, result, self.what)

    def validate(
        self,
        training: Training,
        result: Result,
        baseline: Result,
        test: np.ndarray,
        screen: bool = False,
    ):
        """Absolute point errors of the held-out samples (at least one)."""
        if len(test) < 1:
            return None
        everything = replace(training.problem, q=self.dataset.q, poses=self.measurements.poses)
        train = training.samples if screen else None
        return held_out(everything, result, test, baseline=baseline, train=train)

    def settings(self, training: Training) -> dict:
        return {
            "baseline": "nominal geometry with the instrument transform and the marker fitted "
            "to the training points"
        }
