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

from dataclasses import dataclass, replace

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
from relcal.calibration.measurement import Problem, make_pairs, residuals
from relcal.calibration.noise import Noise
from relcal.calibration.uncertainty import (
    Accuracy,
    Estimator,
    Uncertainty,
    format_uncertainty,
    parameter_covariance,
    predicted_accuracy,
)
from relcal.geometry import DEG
from relcal.robot.kinematics import fk, make_layout
from relcal.robot.model import RobotModel


def nominal_problem(
    model: RobotModel,
    q: np.ndarray,
    handeye: np.ndarray,
    formulation: str = "invariant",
    measure: str = "pose",
    pairing: str = "consecutive",
) -> Problem:
    """The identification problem at configurations ``q`` ``(N, n)`` with the nominal camera
    poses as measurements (the Jacobian, and so everything here, does not depend on them).
    ``handeye`` is the flange-from-camera ``X``: estimated (frame-invariant) or the tool."""
    if formulation == "invariant":
        ident_model, x = model, handeye
    else:
        ident_model, x = replace(model, tool=model.tool @ handeye), np.eye(4)
    return Problem(
        model=ident_model,
        layout=make_layout(model),
        q=q,
        poses=fk(ident_model, q) @ x,
        formulation=formulation,
        measure=measure,
        pairs=make_pairs(len(q), pairing),
        handeye=x,
    )


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

    @property
    def not_estimated(self) -> list[str]:
        keep = set(self.identifiability.subset.tolist())
        return [n for k, n in enumerate(self.names) if k not in keep]

    def to_dict(self) -> dict:
        """JSON-ready (SI units)."""
        ident = self.identifiability
        out: dict = {
            "robot": self.robot,
            "formulation": self.formulation,
            "measure": self.measure,
            "handeye": self.handeye,
            "n_poses": self.n_poses,
            "n_measurements": self.n_measurements,
            "n_rows": self.n_rows,
            "n_params": len(self.names),
            "rank": ident.rank,
            "rcond": ident.rcond,
            "singular_values": [float(s) for s in ident.singular_values],
            "subset_singular_values": [float(s) for s in self.subset_singular_values],
            "indices": self.indices.as_dict(),
            "identifiable_subset": [self.names[k] for k in ident.subset],
            "not_estimated": self.not_estimated,
            "unidentifiable": [
                {
                    "names": list(c.names),
                    "coefficients": list(c.coefficients),
                    "reason": c.reason,
                    "text": c.describe(),
                }
                for c in ident.combinations
            ],
            "parallel_axes": [
                {
                    "joints": list(p.joints),
                    "angle_deg": p.angle_deg,
                    "hayati": p.hayati,
                    "misalignment_deg": p.misalignment_deg,
                    "std_d_m": list(p.std_d) if p.std_d else None,
                }
                for p in self.parallel
            ],
        }
        if self.uncertainty is not None and self.noise is not None:
            unc = self.uncertainty
            out["noise"] = {
                "position_m": self.noise.position,
                "orientation_rad": self.noise.orientation,
                "joints_rad": self.noise.joints,
            }
            out["estimator"] = unc.estimator
            out["parameters"] = [
                {
                    "name": unc.names[k],
                    "unit": "rad" if unc.is_angle[k] else "m",
                    "std": float(unc.std[k]),
                    "crb_std": float(unc.crb_std[k]),
                    "identifiable": bool(unc.identifiable[k]),
                }
                for k in unc.subset
            ]
            out["correlations"] = [
                {"a": a, "b": b, "rho": rho} for a, b, rho in unc.strongest_correlations(12)
            ]
        if self.accuracy is not None:
            out["predicted_accuracy"] = self.accuracy.summary()
        return out


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
        handeye=handeye if problem.formulation == "invariant" else "known",
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
    )


def _wrap(items: list[str], width: int = 96, indent: str = "  ") -> list[str]:
    lines, line = [], indent
    for item in items:
        if len(line) + len(item) + 1 > width and line.strip():
            lines.append(line.rstrip())
            line = indent
        line += item + " "
    if line.strip():
        lines.append(line.rstrip())
    return lines


_FORMULATION_TEXT = {
    "invariant": "frame-invariant formulation",
    "published": "published formulation (base-aligned)",
    "absolute": "absolute poses",
}


def format_report(rep: Report) -> str:
    """The report as text for a person (mm and degrees)."""
    ident = rep.identifiability
    what = "relative position only" if rep.measure == "position" else "relative full pose"
    if rep.formulation == "absolute":
        what = "position only" if rep.measure == "position" else "full pose"
    he = {"estimated": "hand-eye estimated", "known": "hand-eye known"}[rep.handeye]
    lines = [
        f"{rep.robot}: {_FORMULATION_TEXT[rep.formulation]}, {what}, {he}",
        f"{rep.n_poses} poses, {rep.n_measurements} measurements, {rep.n_rows} rows, "
        f"{len(rep.names)} parameters",
        "",
        "singular values of the identification Jacobian (unit-norm columns), largest first:",
    ]
    s = ident.singular_values
    shown = [f"{v:.3g}" for v in s[: ident.rank]]
    if ident.rank < len(s):
        shown += ["|"] + [f"{v:.1e}" for v in s[ident.rank :]]
    lines += _wrap(shown)
    lines.append(
        f"rank {ident.rank} of {len(s)} (relative tolerance {ident.rcond:g}; values after '|' "
        "are zero up to round-off or too small to identify)"
    )
    ind = rep.indices
    lines += [
        "",
        f"observability indices of the identifiable subset ({len(ident.subset)} parameters, "
        f"m = {rep.n_measurements}):",
        f"  O1 Borm-Menq (prod s)^(1/L)/sqrt(m)      {ind.O1:.4g}",
        f"  O2 inverse condition number s_min/s_max  {ind.O2:.4g}"
        f"   (condition number {ind.condition_number:.4g})",
        f"  O3 minimum singular value s_min          {ind.O3:.4g}",
        f"  O4 noise amplification s_min^2/s_max     {ind.O4:.4g}",
        f"  O5 1 / sum(1/s_i)                        {ind.O5:.4g}",
        "",
        f"identifiable subset (QR with column pivoting), {len(ident.subset)} parameters:",
    ]
    lines += _wrap([rep.names[k] for k in ident.subset])
    if rep.not_estimated:
        lines.append("not estimated (held at nominal; each is part of a combination below):")
        lines += _wrap(rep.not_estimated)
    if ident.combinations:
        lines += ["", "unidentifiable combinations, with the reason:"]
        lines += [f"  - {c.describe()}" for c in ident.combinations]
    else:
        lines += ["", "every parameter is identifiable"]
    for p in rep.parallel:
        a, b = p.joints
        lines.append("")
        if p.hayati:
            lines.append(
                f"parallel axes {a} and {b} ({p.angle_deg:.3g} deg apart): Hayati's beta[{a}] "
                f"replaces d[{a}], so the pair is resolved"
            )
            continue
        lines.append(
            f"parallel axes {a} and {b} ({p.angle_deg:.3g} deg apart): with standard DH d[{a}] "
            f"and d[{b}] are inseparable (only their sum is identifiable)."
        )
        if p.std_d is not None:
            lines.append(
                f"  Real axes are never exactly parallel: {p.misalignment_deg:g} deg off, both "
                f"count as identifiable and their standard deviations explode to "
                f"{p.std_d[0] * 1e3:.3g} mm and {p.std_d[1] * 1e3:.3g} mm at this noise."
            )
        lines.append("  Cure: --hayati auto (Hayati's beta for the pair), or hayati: true in YAML")
    if rep.uncertainty is not None and rep.noise is not None:
        n = rep.noise
        lines += [
            "",
            f"uncertainty with noise {n.position * 1e3:g} mm, {n.orientation / DEG:g} deg per "
            f"pose, {np.max(n.joints) / DEG:g} deg per joint reading "
            f"({rep.uncertainty.estimator.replace('_', ' ')} estimator):",
            format_uncertainty(rep.uncertainty, rep.accuracy),
        ]
    return "\n".join(lines)
