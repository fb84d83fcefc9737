"""The information each candidate pose brings and the criteria a set of poses is chosen by.

Each candidate's information (whitened per-pose Jacobian, :func:`uncertainty.pose_rows`) is
additive; the information of a set, with the unknown board pose eliminated, is that of any
connected pairing weighted by its full noise covariance (the Cramer-Rao bound). Criteria:

- ``O1`` .. ``O5``: the observability indices of the scaled information (column scales fixed from
  the whole candidate pool, so that sets compare), ``O1`` being D-optimality;
- ``A``: smallest trace of the scaled covariance;
- ``worst``: smallest worst-parameter standard deviation, angles counted as the displacement they
  cause ``length_scale`` away.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from relcal.calibration.identifiability import (
    DEFAULT_RCOND,
    Indices,
    analyse_problem,
    index_values,
    observability_indices,
)
from relcal.calibration.measurement import Formulation, Measure, Problem, camera_problem
from relcal.calibration.noise import Noise
from relcal.calibration.uncertainty import (
    Accuracy,
    Uncertainty,
    eliminate,
    pose_rows,
    predicted_accuracy,
)
from relcal.design.cell import Cell
from relcal.geometry import DEG, MM
from relcal.robot.model import RobotModel

Criterion = Literal["O1", "O2", "O3", "O4", "O5", "A", "worst"]
CRITERIA: tuple[str, ...] = ("O1", "O2", "O3", "O4", "O5", "A", "worst")
DEFAULT_NOISE = Noise(0.05 * MM, 0.01 * DEG, 0.001 * DEG)
_RIDGE = 1e-6  # added to the scaled information so that early greedy steps are defined


def selection_problem(
    model: RobotModel,
    cell: Cell,
    q: np.ndarray,
    formulation: Formulation = "invariant",
    measure: Measure = "pose",
) -> Problem:
    """The identification problem the plan is for (poses are the nominal camera poses)."""
    return camera_problem(model, q, cell.handeye, formulation, measure)


@dataclass(frozen=True)
class Information:
    """Per-candidate whitened Jacobians of the estimated parameters plus the nuisance (the board
    pose), and the fixed scales that make criteria of different sets comparable."""

    rows: np.ndarray  # (N, r, k + h)
    h: int
    subset: np.ndarray  # (k,) parameter indices (problem.full_layout)
    names: tuple[str, ...]  # full layout names
    is_angle: np.ndarray  # (P,)
    scale: np.ndarray  # (k,) column scales: RMS information per pose over the whole pool
    weights: np.ndarray  # (k,) length-equivalent factors (1 for m, length_scale for rad)
    identifiable: np.ndarray  # (P,)
    ridge: np.ndarray  # (k + h,) regularisation of the diagonal (early greedy steps)

    @property
    def k(self) -> int:
        return len(self.subset)

    def total(self, idx: np.ndarray) -> np.ndarray:
        """Summed information ``(k + h, k + h)`` of the candidates ``idx`` (nuisance kept)."""
        r = self.rows[np.asarray(idx, dtype=int)]
        return np.einsum("nri,nrj->ij", r, r)

    def of(self, idx: np.ndarray) -> np.ndarray:
        """Information ``(k, k)`` of the set ``idx`` with the nuisance eliminated."""
        return eliminate(self.total(idx), self.h)


def information(
    problem: Problem, noise: Noise, length_scale: float, rcond: float = DEFAULT_RCOND
) -> Information:
    """Per-pose information of the candidate problem's identifiable subset (judged on the whole
    pool with the relative rank tolerance)."""
    rows, h = pose_rows(problem, noise)
    layout = problem.full_layout
    ident = analyse_problem(problem, rcond)
    subset = ident.subset
    cols = np.r_[subset, np.arange(layout.size, layout.size + h)]
    sub = rows[:, :, cols]
    full = np.einsum("nri,nrj->ij", sub, sub)
    scale = np.sqrt(np.diag(eliminate(full, h)) / len(rows))
    nuisance = np.diag(full)[len(subset) :] / len(rows)
    angle = layout.is_angle()
    return Information(
        rows=sub,
        h=h,
        subset=subset,
        names=layout.names,
        is_angle=angle,
        scale=scale,
        weights=np.where(angle[subset], length_scale, 1.0),
        identifiable=ident.identifiable,
        ridge=_RIDGE * np.r_[scale**2, nuisance],
    )


def _from_variances(info: Information, var: np.ndarray, name: str) -> np.ndarray:
    if name == "worst":
        return -(np.sqrt(np.clip(var, 0, None)) * info.weights).max(axis=-1)
    return -np.sum(var * info.scale**2, axis=-1)  # A: trace of the scaled covariance


def criterion(info: Information, totals: np.ndarray, name: str, n_meas: int) -> np.ndarray:
    """Values to maximise ``(...,)`` of summed information ``(..., k + h, k + h)``."""
    if name not in CRITERIA:
        raise ValueError(f"unknown criterion '{name}': use one of {', '.join(CRITERIA)}")
    mats = eliminate(totals + np.diag(info.ridge), info.h)
    scaled = mats / np.outer(info.scale, info.scale)
    if name in ("worst", "A"):
        cov = np.linalg.inv(scaled) / np.outer(info.scale, info.scale)
        return _from_variances(info, np.diagonal(cov, axis1=-2, axis2=-1), name)
    s = np.sqrt(np.clip(np.linalg.eigvalsh(scaled), 1e-300, None))  # scaled singular values
    return index_values(s, name, n_meas)


_FAST = ("worst", "A", "O1")


def _prepare(info: Information, base: np.ndarray, name: str) -> tuple[np.ndarray, ...]:
    """What every candidate's score against the summed information ``base`` shares: ``(base,)``
    for the eigenvalue criteria, else the regularised matrix, its inverse and log-determinant."""
    if name not in _FAST:
        return (base,)
    reg = base + np.diag(info.ridge)
    return reg, np.linalg.inv(reg), np.linalg.slogdet(reg)[1]


def _scores(info: Information, prepared: tuple, rows: np.ndarray, name: str, n_meas: int):
    """Criterion ``(N,)`` of the prepared base plus each candidate's rows ``(N, r, Q)``.

    ``worst``, ``A`` and ``O1`` use rank-r updates of one inverse (Woodbury, determinant lemma):
    the top-left ``k x k`` block of the inverse of the full information is the covariance of the
    parameters with the nuisance eliminated. The others need eigenvalues of every candidate set.
    """
    if name not in _FAST:
        totals = prepared[0][None] + np.swapaxes(rows, -1, -2) @ rows
        return criterion(info, totals, name, n_meas)
    reg, inv, logdet_full = prepared
    v = rows @ inv  # (N, r, Q)
    small = np.eye(rows.shape[1]) + v @ np.swapaxes(rows, -1, -2)  # (N, r, r)
    k = info.k
    if name == "O1":
        _, logdet_small = np.linalg.slogdet(small)
        logdet = logdet_full + logdet_small
        if info.h:
            rh = rows[..., k:]
            nuis = reg[k:, k:] + np.swapaxes(rh, -1, -2) @ rh
            logdet = logdet - np.linalg.slogdet(nuis)[1]
        logdet = logdet - 2 * np.sum(np.log(info.scale))
        return np.exp(logdet / (2 * k)) / np.sqrt(n_meas)
    w = np.linalg.solve(small, v[..., :k])  # (N, r, k)
    var = np.diag(inv)[:k] - np.sum(v[..., :k] * w, axis=-2)
    return _from_variances(info, var, name)


def _values(info: Information, base: np.ndarray, add: np.ndarray, name: str, n_meas: int):
    """Criterion of ``base + rows[c]^T rows[c]`` for every candidate ``c`` in ``add``."""
    return _scores(info, _prepare(info, base, name), info.rows[add], name, n_meas)


@dataclass(frozen=True)
class Quality:
    """Predicted quality of a set of poses (noise-weighted estimator, Cramer-Rao bound)."""

    uncertainty: Uncertainty
    worst: tuple[str, float]  # parameter and its length-equivalent std (m)
    worst_length: tuple[str, float]  # largest std among lengths (m)
    worst_angle: tuple[str, float]  # largest std among angles (rad)
    median: float  # median length-equivalent std (m)
    indices: Indices
    accuracy: Accuracy | None = None


def quality(
    info: Information,
    idx: np.ndarray,
    problem: Problem | None = None,
    q_validation: np.ndarray | None = None,
) -> Quality:
    """Standard deviations, observability indices and (with the pool's ``problem`` and validation
    poses) the predicted accuracy of the set ``idx`` of candidates."""
    mat = info.of(idx)
    cov = np.linalg.inv(mat / np.outer(info.scale, info.scale)) / np.outer(info.scale, info.scale)
    cov = 0.5 * (cov + cov.T)
    unc = Uncertainty(
        names=info.names,
        is_angle=info.is_angle,
        subset=info.subset,
        crb=cov,
        least_squares=None,
        estimator="weighted",
        identifiable=info.identifiable,
    )
    std = np.sqrt(np.diag(cov))
    eq = std * info.weights
    names = [info.names[p] for p in info.subset]
    angle = info.is_angle[info.subset]

    def worst_of(mask: np.ndarray) -> tuple[str, float]:
        if not mask.any():
            return "-", float("nan")
        k = int(np.argmax(np.where(mask, std, -np.inf)))
        return names[k], float(std[k])

    s = np.sqrt(np.clip(np.linalg.eigvalsh(mat / np.outer(info.scale, info.scale)), 0, None))
    acc = None
    if problem is not None and q_validation is not None:
        acc = predicted_accuracy(problem, unc, q_validation)
    return Quality(
        uncertainty=unc,
        worst=(names[int(np.argmax(eq))], float(eq.max())),
        worst_length=worst_of(~angle),
        worst_angle=worst_of(angle),
        median=float(np.median(eq)),
        indices=observability_indices(s, len(idx)),
        accuracy=acc,
    )
