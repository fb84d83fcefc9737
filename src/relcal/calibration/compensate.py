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
