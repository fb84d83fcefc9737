"""Compensation: corrected joint targets for wanted tool poses, computed with the calibrated model.

A controller that uses the nominal geometry sends ``q_nom = IK_nominal(T)``; the arm then reaches
``F_true(q_nom) != T``. With the calibrated model, ``q_cal = IK_calibrated(T)`` (numeric IK, joint
limits respected, the branch nearest ``q_nom``) reaches ``T`` up to what calibration could not see.

Relative measurements never see a rigid motion of the base, so positioning accuracy is judged in
the user (work-object) frame that integrators teach anyway: :func:`aligned_errors` removes the
best-fit rigid transform between wanted and reached positions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from relcal.errors import RelcalError
from relcal.robot.ik import solve
from relcal.robot.kinematics import fk
from relcal.robot.model import RobotModel


@dataclass(frozen=True)
class Compensation:
    """Corrected joints per target and the predicted correction."""

    q: np.ndarray  # (N, n) corrected joint values (rad, m)
    converged: np.ndarray  # (N,) bool
    q_nominal: np.ndarray | None  # (N, n) what the nominal model would send
    predicted_position_mm: np.ndarray | None  # (N,) |F_cal(q_nom) - T|: what compensation fixes
    predicted_rotation_deg: np.ndarray | None  # (N,)


def compensate(
    calibrated: RobotModel,
    targets: np.ndarray,
    nominal: RobotModel | None = None,
    q_nominal: np.ndarray | None = None,
) -> Compensation:
    """Joint values reaching ``targets`` ``(N, 4, 4)`` with the calibrated model.

    ``q_nominal`` (a joint program from the nominal model) or ``nominal`` (to compute it by IK)
    seeds the branch and gives the predicted correction.
    """
    if q_nominal is None and nominal is not None:
        sol = solve(nominal, targets)
        if not np.all(sol.converged):
            bad = np.flatnonzero(~sol.converged)
            raise RelcalError(
                f"targets {', '.join(str(i + 1) for i in bad[:5])} are out of the nominal "
                "model's reach or joint limits"
            )
        q_nominal = sol.q
    sol = solve(calibrated, targets, q_near=q_nominal, seed_model=nominal)
    pos = rot = None
    if q_nominal is not None:
        reached = fk(calibrated, q_nominal)
        pos = np.linalg.norm(reached[:, :3, 3] - targets[:, :3, 3], axis=1) * 1e3
        cos = (np.einsum("nij,nij->n", reached[:, :3, :3], targets[:, :3, :3]) - 1) / 2
        rot = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    return Compensation(sol.q, np.asarray(sol.converged), q_nominal, pos, rot)


def aligned_errors(wanted: np.ndarray, reached: np.ndarray) -> np.ndarray:
    """Position errors ``(N,)`` (m) after the best-fit rigid alignment of the reached positions
    ``(N, 3)`` onto the wanted ones (Kabsch): accuracy in a taught user frame."""
    cw, cr = wanted.mean(axis=0), reached.mean(axis=0)
    u, _, vt = np.linalg.svd((reached - cr).T @ (wanted - cw))
    d = np.sign(np.linalg.det(u @ vt))
    rot = (u @ np.diag([1.0, 1.0, d]) @ vt).T
    return np.linalg.norm((reached - cr) @ rot.T + cw - wanted, axis=1)


SAME_ROBOT_MM = 100.0  # flange positions of a robot and its calibration differ by millimetres
SAME_ROBOT_DEG = 20.0  # and orientations by degrees; another robot by far more


def robot_mismatch(nominal: RobotModel, calibrated: RobotModel) -> str | None:
    """None when ``calibrated`` is a calibration of the robot ``nominal`` describes; else what
    differs, in words: the number or kinds of joints, or flange poses at the same joints (at
    zero and at seeded configurations within both models' limits) farther apart than any
    calibration moves them (:data:`SAME_ROBOT_MM`, :data:`SAME_ROBOT_DEG`)."""
    if nominal.n_joints != calibrated.n_joints:
        return f"{nominal.n_joints} joints against {calibrated.n_joints}"
    if not np.array_equal(nominal.prismatic, calibrated.prismatic):
        return "other joint kinds (revolute and prismatic joints in other places)"
    rng = np.random.default_rng(0)
    lo = np.maximum(nominal.lower, calibrated.lower)
    hi = np.minimum(nominal.upper, calibrated.upper)
    lo, hi = np.where(np.isfinite(lo), lo, -np.pi), np.where(np.isfinite(hi), hi, np.pi)
    hi = np.where(hi > lo, hi, lo)
    q = np.vstack([np.clip(np.zeros(nominal.n_joints), lo, hi), rng.uniform(lo, hi, (16, len(lo)))])
    a, b = fk(nominal, q), fk(calibrated, q)
    position = float(np.linalg.norm(a[:, :3, 3] - b[:, :3, 3], axis=1).max()) * 1e3
    cos = np.clip((np.einsum("nij,nij->n", a[:, :3, :3], b[:, :3, :3]) - 1) / 2, -1.0, 1.0)
    rotation = float(np.degrees(np.arccos(cos)).max())
    if position <= SAME_ROBOT_MM and rotation <= SAME_ROBOT_DEG:
        return None
    return (
        f"at the same joints their flanges are up to {position:.0f} mm and {rotation:.0f} deg "
        f"apart (a calibration moves them by millimetres, at most {SAME_ROBOT_MM:.0f} mm)"
    )
