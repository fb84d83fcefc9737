"""From a dataset to a calibrated robot: measure, pair, identify, validate.

``measure`` turns images (or given poses) into camera poses ``C_k`` with rejected frames and their
reasons; ``calibrate`` splits off held-out samples, identifies the geometry and the hand-eye
transform with the frame-invariant formulation on the identifiable subset, and validates.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from relcal.calibration.handeye import solve_handeye
from relcal.calibration.identifiability import check_pose_set
from relcal.calibration.identify import Result, SolverOptions, calibrated_handeye, identify
from relcal.calibration.measurement import PairStrategy, Problem, make_pairs, pair_errors
from relcal.calibration.noise import Noise, robust_sigma
from relcal.calibration.validate import Validation, folds, held_out, split
from relcal.data.dataset import Dataset
from relcal.data.imaging import Measurements, measure
from relcal.errors import RelcalError
from relcal.robot.export import calibrated_model
from relcal.robot.kinematics import fk, make_layout
from relcal.robot.model import RobotModel

ROBUST_SCALE = 3.0  # residual (in noise standard deviations) where the robust loss bends


def _sample_indices(dataset: Dataset, ids: Sequence[str]) -> np.ndarray:
    where = {sid: k for k, sid in enumerate(dataset.ids)}
    unknown = [sid for sid in ids if sid not in where]
    if unknown:
        raise RelcalError(
            f"held-out sample id(s) {', '.join(unknown[:5])} are not in {dataset.spec_path.parent}"
        )
    return np.array(sorted(where[sid] for sid in ids), dtype=int)


def cross_validate(
    dataset: Dataset, measurements: Measurements, k: int = 5, seed: int = 0, **options
) -> list[Calibration]:
    """k-fold cross-validation: each fold of the usable samples held out once."""
    usable = np.flatnonzero(measurements.ok)
    return [
        calibrate(
            dataset,
            measurements,
            seed=seed,
            holdout_ids=[dataset.ids[i] for i in usable[f]],
            **options,
        )
        for f in folds(len(usable), k, seed)
    ]


@dataclass(frozen=True)
class Calibration:
    """Everything a calibration produced."""

    dataset: Dataset
    measurements: Measurements
    problem: Problem  # on the training samples
    result: Result
    validation: Validation | None
    train: np.ndarray  # sample indices
    test: np.ndarray
    settings: dict
    outliers: tuple[str, ...] = ()  # ids of training samples that fit badly
    std: np.ndarray | None = None  # (P,) standard deviations (m, rad); NaN if not estimated

    @property
    def model(self) -> RobotModel:
        """The calibrated robot model (the identified geometric errors applied)."""
        return calibrated_model(self.problem.model, self.problem.layout, self.result.params)

    @property
    def handeye(self) -> np.ndarray:
        """The calibrated hand-eye transform ``X`` ``(4, 4)``."""
        return calibrated_handeye(self.problem, self.result)


def calibrate(
    dataset: Dataset,
    measurements: Measurements | None = None,
    holdout: float = 0.25,
    seed: int = 0,
    pairing: PairStrategy = "all",
    method: str = "lm",
    loss: str = "huber",
    reject_outliers: bool = True,
    holdout_ids: Sequence[str] | None = None,
) -> Calibration:
    """Identify geometry and hand-eye on the training samples, validate on the held-out ones.

    Training samples whose pairs fit badly after a robust fit are reported as outliers and, with
    ``reject_outliers``, left out of a second fit. ``holdout_ids`` names the validation samples
    (instead of a random share ``holdout``). ``measurements``: the camera poses of
    :func:`data.imaging.measure` (measured here if not given).
    """
    if measurements is None:
        measurements = measure(dataset)
    usable = np.flatnonzero(measurements.ok)
    if len(usable) < 4:
        raise RelcalError(
            f"{dataset.spec_path}: only {len(usable)} usable samples; at least 4 are needed "
            "(and many more for a useful calibration)"
        )
    if holdout_ids is not None:
        test = _sample_indices(dataset, holdout_ids)
        train = np.setdiff1d(usable, test)
        test = np.intersect1d(usable, test)
    elif holdout > 0:
        train_idx, test_idx = split(len(usable), holdout, seed)
        train, test = usable[train_idx], usable[test_idx]
    else:
        train, test = usable, np.zeros(0, dtype=int)
    layout = make_layout(dataset.model)
    poses = measurements.poses
    handeye = dataset.handeye
    if handeye is None:
        handeye = solve_handeye(fk(dataset.model, dataset.q[train]), poses[train])
    problem = Problem(
        model=dataset.model,
        layout=layout,
        q=dataset.q[train],
        poses=poses[train],
        formulation="invariant",
        measure="pose",
        pairs=make_pairs(len(train), pairing),
        handeye=handeye,
    )
    problem, result, sigma = weighted_fit(problem, dataset, method, loss)
    outliers = outlier_samples(pair_errors(problem, result.params), problem.pair_indices())
    outlier_ids = tuple(dataset.ids[train[i]] for i in outliers)
    if reject_outliers and outliers.size:
        train = np.delete(train, outliers)
        problem = replace(
            problem,
            q=dataset.q[train],
            poses=poses[train],
            pairs=make_pairs(len(train), pairing),
            weights=None,
        )
        problem, result, sigma = weighted_fit(problem, dataset, method, loss)
    std = parameter_std(problem, result, sigma)
    validation = None
    if len(test) >= 2:
        full = Problem(dataset.model, layout, dataset.q, poses, "invariant", "pose", None, handeye)
        validation = held_out(full, result, test)
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
    }
    settings["row_sigma"] = {"position_m": float(sigma[0]), "orientation_rad": float(sigma[3])}
    settings["reject_outliers"] = reject_outliers
    return Calibration(
        dataset, measurements, problem, result, validation, train, test, settings, outlier_ids, std
    )


def parameter_std(problem: Problem, result: Result, sigma: np.ndarray) -> np.ndarray:
    """Standard deviations ``(P,)`` of the estimate: the least-squares covariance of
    :mod:`uncertainty` (pair correlations included), with per-pose noise taken as the
    robust pair noise ``sigma`` over sqrt(2) (each pair carries the noise of two poses)."""
    from relcal.calibration.uncertainty import parameter_covariance

    noise = Noise(position=sigma[0] / np.sqrt(2), orientation=sigma[3] / np.sqrt(2))
    unc = parameter_covariance(problem, noise, result.identifiability, params=result.params)
    return unc.std


def weighted_fit(
    problem: Problem, dataset: Dataset, method: str, loss: str
) -> tuple[Problem, Result, np.ndarray]:
    """A least-squares fit gives robust noise levels of the translation and rotation rows; the
    final fit weights the rows by them (so metres and radians compare) with the chosen loss.
    Returns the weighted problem, its result and the row noise levels ``(6,)``."""
    ident = check_pose_set(problem, str(dataset.spec_path))
    first = identify(problem, SolverOptions(), ident)
    sigma = robust_sigma(pair_errors(problem, first.params))
    problem = replace(problem, weights=1.0 / sigma)
    options = SolverOptions(method=method, loss=loss, f_scale=ROBUST_SCALE)
    return problem, identify(problem, options, ident), sigma


def outlier_samples(weighted: np.ndarray, pairs: np.ndarray, threshold: float = 5.0) -> np.ndarray:
    """Indices of samples whose pairs fit badly: each sample's score is the median normalised
    error of its pairs; a robust z-score above ``threshold`` flags it."""
    norms = np.linalg.norm(weighted, axis=1)
    n = int(pairs.max()) + 1
    score = np.array([np.median(norms[(pairs == k).any(axis=1)]) for k in range(n)])
    spread = 1.4826 * np.median(np.abs(score - np.median(score)))
    return np.flatnonzero((score - np.median(score)) > threshold * max(spread, 1e-12))
