"""Identifiability report: singular values, observability indices, identifiable subset, named
unidentifiable combinations, parallel axes, and (with a noise model) parameter uncertainty.

Everything is computed on the identification Jacobian with unit-norm columns (metres and radians
compare; :func:`identifiability.scaled`) at the nominal model. The observability indices of
the calibration literature are functions of the singular values ``s_1 >= ... >= s_L`` of the
identifiable subset's scaled Jacobian (``m`` measurements):

- O1 (Borm and Menq): ``(s_1 s_2 ... s_L)^(1/L) / sqrt(m)``, the volume of the output ellipsoid
  per measurement (D-optimality);
- O2 (Driels and Pathre): ``s_L / s_1``, the inverse condition number;
- O3 (Nahvi et al.): ``s_L``, the minimum singular value (E-optimality);
- O4 (Nahvi and Hollerbach): ``s_L^2 / s_1``, the noise amplification index;
- O5 (Sun and Hollerbach): ``1 / (1/s_1 + ... + 1/s_L)``, related to A-optimality.

Larger is better for all five. On the full parameter set they are zero whenever something is
unidentifiable, which is why they are reported for the identifiable subset.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from relcal.calibration.identifiability import (
    DEFAULT_RCOND,
    HandEye,
    Identifiability,
    Indices,
    ParallelPair,
    analyse_problem,
    n_measurements,
    observability_indices,
    parallel_pairs,
    scaled,
)
from relcal.calibration.measurement import Problem, residuals
from relcal.calibration.noise import Noise
from relcal.calibration.uncertainty import (
    Accuracy,
    Estimator,
    Uncertainty,
    parameter_covariance,
    predicted_accuracy,
)
from relcal.robot.kinematics import make_layout, parameter_labels
from relcal.robot.model import RobotModel


def _misaligned(model: RobotModel, pair: ParallelPair, angle: float) -> RobotModel:
    i = pair.joints[0] - 1 if model.convention == "dh" else pair.joints[1] - 1
    alpha = model.alpha.copy()
    alpha[i] += angle
    return model.with_values(alpha=alpha)


def demonstrate_parallel(
    problem: Problem,
    pair: ParallelPair,
    noise: Noise,
    misalignment_deg: float = 0.1,
    handeye: HandEye = "estimated",
) -> ParallelPair:
    """The standard deviations of both ``d`` along a parallel pair when the axes are
    ``misalignment_deg`` off parallel, as every real robot's are: the rank test then calls both
    identifiable and the least-squares estimate of each explodes (``~ noise / misalignment``)."""
    model = _misaligned(problem.model, pair, np.radians(misalignment_deg))
    tilted = replace(problem, model=model, layout=make_layout(model))
    ident = analyse_problem(tilted, handeye=handeye)
    names = tilted.full_layout.names
    ds = [names.index(f"d[{j}]") for j in pair.joints]
    subset = np.union1d(ident.subset, ds)
    unc = parameter_covariance(tilted, noise, ident, subset=subset)
    std = unc.std
    return replace(
        pair, misalignment_deg=misalignment_deg, std_d=(float(std[ds[0]]), float(std[ds[1]]))
    )


@dataclass(frozen=True)
class Report:
    """Everything :func:`report` found."""

    robot: str
    formulation: str
    measure: str
    handeye: HandEye
    n_poses: int
    n_measurements: int
    n_rows: int
    names: tuple[str, ...]  # parameters analysed
    identifiability: Identifiability
    subset_singular_values: np.ndarray  # (k,) of the scaled Jacobian of the subset
    indices: Indices
    parallel: tuple[ParallelPair, ...]
    noise: Noise | None = None
    uncertainty: Uncertainty | None = None
    accuracy: Accuracy | None = None
    # {name: label} where a parameter is shown by another name (robots loaded from a URDF:
    # joint parameters named after their joints, relcal.robot.kinematics.parameter_label)
    labels: dict[str, str] = field(default_factory=dict)

    def label(self, name: str) -> str:
        """The name parameter ``name`` is shown by (:attr:`labels`)."""
        return self.labels.get(name, name)

    @property
    def not_estimated(self) -> list[str]:
        keep = set(self.identifiability.subset.tolist())
        return [n for k, n in enumerate(self.names) if k not in keep]


def report(
    problem: Problem,
    handeye: HandEye = "estimated",
    rcond: float = DEFAULT_RCOND,
    noise: Noise | None = None,
    q_validation: np.ndarray | None = None,
    estimator: Estimator = "weighted",
    parallel_tol_deg: float = 1.0,
    misalignment_deg: float = 0.1,
) -> Report:
    """The identifiability report of ``problem`` (its poses and pairs) at the nominal model.

    With ``noise``: the covariance of the identifiable subset, and for every parallel pair without
    Hayati's beta the standard deviations of its ``d``s at ``misalignment_deg``; with
    ``q_validation`` ``(V, n)`` as well: the predicted accuracy after calibration.
    """
    ident = analyse_problem(problem, rcond, handeye=handeye)
    _, jac = residuals(problem, np.zeros(problem.full_layout.size))
    names = problem.full_layout.names[: len(ident.column_norms)]
    unit, _ = scaled(jac[:, ident.subset])
    sub_s = np.linalg.svd(unit, compute_uv=False)
    pairs = parallel_pairs(problem.model, parallel_tol_deg)
    unc = acc = None
    if noise is not None:
        unc = parameter_covariance(problem, noise, ident, estimator=estimator)
        pairs = [
            p if p.hayati else demonstrate_parallel(problem, p, noise, misalignment_deg, handeye)
            for p in pairs
        ]
        if q_validation is not None:
            acc = predicted_accuracy(problem, unc, q_validation)
    return Report(
        robot=problem.model.name,
        formulation=problem.formulation,
        measure=problem.measure,
        handeye=handeye if problem.formulation in ("invariant", "board") else "known",
        n_poses=len(problem.q),
        n_measurements=n_measurements(problem),
        n_rows=jac.shape[0],
        names=names,
        identifiability=ident,
        subset_singular_values=sub_s,
        indices=observability_indices(sub_s, n_measurements(problem)),
        parallel=tuple(pairs),
        noise=noise,
        uncertainty=unc,
        accuracy=acc,
        labels=parameter_labels(problem.model, names),
    )
