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


# --- the plausibility gate -----------------------------------------------------------------------

GATE_SAMPLES = 64  # configurations the gate's reference corrections are computed at
GATE_MARGIN = 2.0  # a correction may be this many times the largest reference correction
GATE_FLOOR_RAD = np.radians(0.05)  # ... plus this (rad; m for prismatic joints: GATE_FLOOR_M)
GATE_FLOOR_M = 5e-5
GATE_FLOOR_MM = 0.5  # predicted nominal miss: margin times the largest reference miss plus this
GATE_FLOOR_DEG = 0.05
GATE_SINGULAR = 0.02  # inverse condition (0.5 m) below which joint corrections are not gated


@dataclass(frozen=True)
class CorrectionGate:
    """The largest corrections a calibration can produce: per joint ``joint`` ``(n,)`` (rad,
    m), and the largest predicted miss of the nominal joints, ``position_mm`` and
    ``rotation_deg``, each :data:`GATE_MARGIN` times what the calibrated model needs against its
    own nominal model over ``n_samples`` configurations spread over the joint ranges (away from
    singularities), plus a floor."""

    joint: np.ndarray
    position_mm: float
    rotation_deg: float
    n_samples: int


def _inverse_condition(model: RobotModel, q: np.ndarray, length_scale: float = 0.5) -> np.ndarray:
    from relcal.robot.ik import joint_layout
    from relcal.robot.kinematics import pose_jacobian

    _, jac = pose_jacobian(model, q, joint_layout(model))
    jac = jac.copy()
    jac[:, :3] /= length_scale
    s = np.linalg.svd(jac, compute_uv=False)
    return s[:, -1] / s[:, 0]


def correction_gate(
    calibrated: RobotModel,
    nominal: RobotModel,
    lower: np.ndarray | None = None,
    upper: np.ndarray | None = None,
    n_samples: int = GATE_SAMPLES,
    seed: int = 0,
) -> CorrectionGate:
    """What compensating with ``calibrated`` for its own ``nominal`` model takes, measured: at
    ``n_samples`` configurations drawn within ``lower`` .. ``upper`` (default the joint limits,
    revolute joints within one turn), the nominal tool pose is reached with ``calibrated`` by
    inverse kinematics from the nominal joints; the largest joint change and the largest miss of
    the nominal joints, times :data:`GATE_MARGIN`, plus a floor, bound what a plausible
    correction can be. A correction beyond it means another robot or chain than the one
    calibrated, an inverse-kinematics branch flip, or a target at a singularity."""
    lo = calibrated.lower if lower is None else np.asarray(lower, dtype=float)
    hi = calibrated.upper if upper is None else np.asarray(upper, dtype=float)
    revolute = ~calibrated.prismatic
    lo = np.where(revolute, np.maximum(lo, np.maximum(calibrated.lower, -np.pi)), lo)
    hi = np.where(revolute, np.minimum(hi, np.minimum(calibrated.upper, np.pi)), hi)
    lo = np.where(np.isfinite(lo), lo, -1.0)  # an unlimited prismatic joint: +-1 m
    hi = np.where(np.isfinite(hi), hi, 1.0)
    lo, hi = np.minimum(lo, hi), np.maximum(lo, hi)
    rng = np.random.default_rng(seed)
    q = rng.uniform(lo, hi, (4 * n_samples, calibrated.n_joints))
    q = q[_inverse_condition(nominal, q) >= GATE_SINGULAR][:n_samples]
    if not len(q):
        q = np.atleast_2d((lo + hi) / 2)
    targets = fk(nominal, q)
    sol = solve(calibrated, targets, q_near=q, seed_model=nominal)
    ok = np.asarray(sol.converged)
    dq = np.abs(sol.q - q)[ok] if ok.any() else np.zeros((1, calibrated.n_joints))
    reached = fk(calibrated, q)
    miss = np.linalg.norm(reached[:, :3, 3] - targets[:, :3, 3], axis=1) * 1e3
    cos = (np.einsum("nij,nij->n", reached[:, :3, :3], targets[:, :3, :3]) - 1) / 2
    turn = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    floor = np.where(calibrated.prismatic, GATE_FLOOR_M, GATE_FLOOR_RAD)
    return CorrectionGate(
        joint=GATE_MARGIN * dq.max(axis=0) + floor,
        position_mm=float(GATE_MARGIN * miss.max() + GATE_FLOOR_MM),
        rotation_deg=float(GATE_MARGIN * turn.max() + GATE_FLOOR_DEG),
        n_samples=len(q),
    )


def implausible(
    comp: Compensation, gate: CorrectionGate, calibrated: RobotModel | None = None
) -> np.ndarray:
    """``(N,)`` bool: targets whose predicted miss exceeds ``gate``, or whose correction (any
    joint) does away from singularities (with ``calibrated``: where the inverse condition at the
    corrected and at the nominal joints is at least :data:`GATE_SINGULAR`; near a singularity a
    small pose correction takes large joint moves, which the caller warns about)."""
    bad = np.zeros(len(comp.q), dtype=bool)
    if comp.q_nominal is not None:
        regular = np.ones(len(comp.q), dtype=bool)
        if calibrated is not None:
            cond = np.minimum(
                _inverse_condition(calibrated, comp.q),
                _inverse_condition(calibrated, comp.q_nominal),
            )
            regular = cond >= GATE_SINGULAR
        bad |= regular & (np.abs(comp.q - comp.q_nominal) > gate.joint).any(axis=1)
    if comp.predicted_position_mm is not None:
        bad |= comp.predicted_position_mm > gate.position_mm
    if comp.predicted_rotation_deg is not None:
        bad |= comp.predicted_rotation_deg > gate.rotation_deg
    return bad & comp.converged


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
