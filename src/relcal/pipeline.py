"""From a dataset to a calibrated robot: measure, pair, identify, validate.

``measure`` turns images (or given poses) into camera poses ``C_k`` with rejected frames and their
reasons; ``calibrate`` splits off held-out samples, identifies the geometry and the hand-eye
transform with the frame-invariant formulation on the identifiable subset, and validates.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from relcal.dataset import Dataset
from relcal.errors import RelcalError
from relcal.handeye import solve_handeye
from relcal.identifiability import Identifiability
from relcal.identify import Result, analyse_problem, identify
from relcal.kinematics import fk, make_layout
from relcal.measurement import PairStrategy, Problem, make_pairs
from relcal.validate import Validation, held_out, split


@dataclass(frozen=True)
class Measurements:
    """Camera poses ``C_k`` per sample and which samples are usable."""

    poses: np.ndarray  # (N, 4, 4); NaN where rejected
    ok: np.ndarray  # (N,) bool
    reasons: tuple[str, ...]  # "" for accepted samples
    rms_px: np.ndarray  # (N,) reprojection RMS, NaN without images
    covariance: np.ndarray | None = None  # (N, 6, 6) of (translation, rotation vector), or None
    camera: object = None  # the intrinsics used (given or calibrated)
    intrinsics_report: dict = field(default_factory=dict)


def measure(dataset: Dataset, workers: int = 2, progress: bool = True) -> Measurements:
    """Camera poses of every sample: given directly, or from the images."""
    n = len(dataset.ids)
    if dataset.poses is not None:
        return Measurements(
            poses=dataset.poses,
            ok=np.ones(n, dtype=bool),
            reasons=("",) * n,
            rms_px=np.full(n, np.nan),
        )
    from relcal.imaging import measure_dataset_images

    return measure_dataset_images(dataset, workers=workers, progress=progress)


def check_poses(problem: Problem, dataset: Dataset, seed: int = 0) -> Identifiability:
    """Identifiability at the dataset's poses; an error if they identify less than generic poses
    would (the structural null space of this robot and formulation), naming what they miss."""
    ident = analyse_problem(problem)
    rng = np.random.default_rng(seed)
    model = problem.model
    lo = np.where(np.isfinite(model.lower), model.lower, -np.pi)
    hi = np.where(np.isfinite(model.upper), model.upper, np.pi)
    generic = rng.uniform(lo, hi, (max(30, len(problem.q)), model.n_joints))
    reference = analyse_problem(
        replace(
            problem, q=generic, poses=np.broadcast_to(np.eye(4), (len(generic), 4, 4)), pairs=None
        )
    )
    if ident.rank < reference.rank:
        known = {c.names for c in reference.combinations}
        extra = [c.describe() for c in ident.combinations if c.names not in known]
        raise RelcalError(
            f"{dataset.spec_path}: the poses identify only {ident.rank} of the {reference.rank} "
            "parameter combinations that varied poses would; vary the joints more. Not "
            "determined by these poses: " + "; ".join(extra or ["(mixed combinations)"])
        )
    return ident


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


def calibrate(
    dataset: Dataset,
    measurements: Measurements,
    holdout: float = 0.25,
    seed: int = 0,
    pairing: PairStrategy = "all",
    method: str = "lm",
    loss: str = "linear",
) -> Calibration:
    """Identify geometry and hand-eye on the training samples, validate on the held-out ones."""
    usable = np.flatnonzero(measurements.ok)
    if len(usable) < 4:
        raise RelcalError(
            f"{dataset.spec_path}: only {len(usable)} usable samples; at least 4 are needed "
            "(and many more for a useful calibration)"
        )
    if holdout > 0:
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
    ident = check_poses(problem, dataset)
    kwargs = {"loss": loss} if method == "lm" else {}
    result = identify(problem, method, identifiability=ident, **kwargs)
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
    return Calibration(dataset, measurements, problem, result, validation, train, test, settings)
