"""Weakly determined directions held by priors: the maximum a posteriori fit and its names.

The cost of a fit with priors is the weighted residual of the data plus one row per estimated
parameter with a prior (:mod:`relcal.robot.priors`),

    ``|r_w(p)|^2 + sum_k (w_k p_k)^2``,   ``w_k = sqrt(c) s / sigma_k``,

where ``s`` is the noise level of one weighted residual row (robust, from a fit of the same
rows), ``sigma_k`` the prior's standard deviation and ``c`` how many times the rows count each
sample's information: relative pose pairs over all pairs count every pose in ``N - 1`` pairs,
which makes ``J^T J / s^2`` about ``N / 2`` times the information the ``N`` poses hold
(``c = pairs / (N - 1)``); points and coincidences count each sample once (``c`` about 1).
Dividing the cost by ``c s^2`` gives ``|r_w|^2 / (c s^2) + sum (p_k / sigma_k)^2``: the negative
log posterior of Gaussian noise and Gaussian priors. Along a direction the data determine well
the prior rows change nothing that matters; along a weak one they hold the estimate within its
manufacturing tolerance instead of letting noise drive it to centimetres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from relcal.calibration.measurement import Problem, residuals
from relcal.robot.kinematics import label_joints, parameter_label
from relcal.robot.model import RobotModel
from relcal.robot.priors import prior_std

HELD_SHARE = 0.5  # a parameter whose posterior variance is above this share of its prior's


def layout_prior_std(problem: Problem, model: RobotModel | None = None) -> np.ndarray:
    """``(P,)`` prior standard deviations of ``problem.full_layout`` (SI units; inf where there
    is none) from the priors of ``model`` (default: the problem's)."""
    model = problem.model if model is None else model
    layout = problem.full_layout
    joint = np.asarray(layout.index)
    n_geo = problem.layout.size
    prismatic = np.asarray(model.prismatic, bool)

    def prismatic_of(k: int) -> bool:
        return k < n_geo and 0 <= joint[k] < len(prismatic) and bool(prismatic[joint[k]])

    return prior_std(layout.names, layout.kinds, model.priors, prismatic_of)


def overcount(n_blocks: int, n_samples: int) -> float:
    """How many times ``n_blocks`` measurement blocks (pairs, or points) of ``n_samples``
    samples count each sample's information: ``n_blocks / (n_samples - 1)``, at least 1."""
    return max(1.0, n_blocks / max(n_samples - 1, 1))


def noise_level(rows: np.ndarray) -> float:
    """Robust standard deviation (1.4826 median absolute value) of the non-zero residual rows
    ``rows`` (any shape; exact zeros are rows a formulation leaves empty)."""
    r = np.abs(np.asarray(rows, float).ravel())
    r = r[r > 0]
    if not len(r):
        return 0.0
    return float(1.4826 * np.median(r))


def row_weights(std: np.ndarray, noise: float, count: float) -> np.ndarray:
    """``(P,)`` prior-row weights ``sqrt(count) noise / std`` (0 where ``std`` is inf)."""
    std = np.asarray(std, float)
    with np.errstate(divide="ignore"):
        w = np.sqrt(count) * noise / std
    return np.where(np.isfinite(std), w, 0.0)


def problem_weights(weighted: Problem, params: np.ndarray, std: np.ndarray) -> np.ndarray | None:
    """The prior-row weights ``(P,)`` of the (weighted) ``problem`` whose rows at ``params`` give
    the noise level; None when no parameter has a prior (a plain fit)."""
    std = np.asarray(std, float)
    if not np.isfinite(std).any():
        return None
    r = residuals(weighted, params, jacobian=False)
    n = len(weighted.q)
    blocks = len(weighted.pair_indices()) if weighted.formulation == "invariant" else n
    noise = noise_level(r)
    if noise <= 0:
        return None
    return row_weights(std, noise, overcount(blocks, n))


@dataclass(frozen=True)
class WeakDirection:
    """A parameter the data barely determine, held near nominal by its prior: its name, the
    joint it belongs to (empty for none), the unit it is shown in and the factor from SI, the
    prior's and the posterior's standard deviation and what the data alone would give (SI
    units; inf: nothing), and the joint's travel in the data (rad, or m for a prismatic joint;
    None if unknown)."""

    name: str
    joint: str
    unit: str  # the unit a person reads (mm, deg, ppm, urad/Nm, um/N)
    factor: float  # from SI to ``unit``
    prior_std: float
    posterior_std: float
    data_std: float
    joint_travel: float | None = None
    joint_prismatic: bool = False
    label: str = ""  # the name shown (:func:`relcal.robot.kinematics.parameter_label`)

    def describe(self) -> str:
        """One line in words, with the joint's name and the units a person reads."""
        unit, conv = self.unit, self.factor
        if np.isfinite(self.data_std):
            alone = f"the data alone determine it to +- {self.data_std * conv:.3g} {unit}"
        else:
            alone = "the data alone do not determine it"
        travel = ""
        if self.joint_travel is not None:
            t_unit, t_conv = ("mm", 1e3) if self.joint_prismatic else ("deg", 180 / np.pi)
            travel = f"; {self.joint} moved over {self.joint_travel * t_conv:.3g} {t_unit}"
        shown = self.label or self.name
        where = f" ({self.joint})" if self.joint and f"[{self.joint}]" not in shown else ""
        return (
            f"{shown}{where}: held by its prior of {self.prior_std * conv:.3g} {unit} "
            f"(estimate +- {self.posterior_std * conv:.3g} {unit}; {alone}{travel})"
        )

    def to_dict(self) -> dict:
        return {
            "parameter": self.name,
            "joint": self.joint,
            "unit": self.unit,
            "factor_from_si": self.factor,
            "prior_std": self.prior_std,
            "posterior_std": self.posterior_std,
            "data_std": self.data_std if np.isfinite(self.data_std) else None,
            "joint_travel": self.joint_travel,
            "text": self.describe(),
        }


def weak_directions(
    problem: Problem,
    subset: np.ndarray,
    data_cov: np.ndarray,
    post_cov: np.ndarray,
    std: np.ndarray,
    q: np.ndarray | None = None,
    share: float = HELD_SHARE,
) -> list[WeakDirection]:
    """The estimated parameters (of ``subset``) that their prior rather than the data holds:
    posterior variance above ``share`` of the prior's (the data contribute less information
    than the prior). ``data_cov`` and ``post_cov`` ``(P, P)``: the covariance of the data alone
    and with the priors; ``std`` ``(P,)`` the priors (SI); ``q`` ``(N, n)``: the joints of the
    data, for each joint's travel."""
    layout = problem.full_layout
    model = problem.model
    n_geo = problem.layout.size
    factors, units = layout.display()
    out = []
    for k in np.asarray(subset, dtype=int):
        if not np.isfinite(std[k]):
            continue
        post = float(np.sqrt(max(post_cov[k, k], 0.0)))
        if not post**2 > share * std[k] ** 2:
            continue
        data = float(data_cov[k, k])
        data = float(np.sqrt(data)) if np.isfinite(data) and data >= 0 else np.inf
        i = int(layout.index[k]) if k < n_geo else -1
        if layout.kinds[k] == "origin":  # index 6 * joint + component
            i //= 6
        joint, travel, prismatic = "", None, False
        if 0 <= i < model.n_joints:
            joint, prismatic = model.joint_names[i], bool(model.prismatic[i])
            travel = None if q is None else float(np.ptp(q[:, i]))
        out.append(
            WeakDirection(
                layout.names[k],
                joint,
                units[k],
                float(factors[k]),
                float(std[k]),
                post,
                data,
                travel,
                prismatic,
                parameter_label(layout.names[k], label_joints(model)),
            )
        )
    return out
