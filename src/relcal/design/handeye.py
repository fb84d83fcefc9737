"""Planning for the hand-eye transform alone (``relcal plan --for handeye``): the same candidates,
line of sight, selection and travel order as a calibration plan, with another criterion and one
rule on pairs of poses.

The criterion
    The Cramer-Rao bound of ``X`` alone: the identification problem of ``C_k = W F_k X`` with the
    kinematics known (no kinematic parameter free, :data:`relcal.calibration.handeye_fit.EMPTY`)
    in the frame-invariant formulation, so that the board's pose ``W`` is the nuisance that
    :class:`~relcal.design.criteria.Information` eliminates. Every criterion of the calibration
    plan (``worst``, ``A``, ``O1`` .. ``O5``) then applies to the six components of ``X``: the
    worst-component standard deviation (angles counted as the displacement they cause
    ``length_scale`` away) favours motions that turn by tens of degrees about spread axes, since
    rotations about one axis leave the translation along it free and small rotations leave the
    rotation barely seen.

The rule
    The closed forms the refined estimate starts from (OpenCV's, :mod:`relcal.calibration.
    handeye_closed`) use every pair of samples: a pair whose relative rotation is near 180 deg
    has a rotation axis (and a quaternion sign) lost in the noise, and a pair that barely moves
    carries an axis that is pure noise; the job then leaves such samples out. :class:`PairRule`
    keeps them out of the plan instead: a candidate that would form such a pair with a chosen
    pose is not chosen (in the greedy selection, the exchanges and the exchanges for short
    moves alike, :mod:`relcal.design.search`).

What a plan reports (:func:`motion_quality`): the predicted standard deviations of ``X`` in the
flange frame (mm, and deg about the flange's axes, as ``relcal handeye`` prints them), the
spread of the relative rotation axes (singular values of the pairs' rotation vectors, the
smallest over the largest: 0 when every motion turns about one axis) and the smallest and
largest relative rotation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from relcal import geometry as tf
from relcal.calibration.handeye_closed import MAX_PAIR_DEG, MIN_PAIR_DEG, MIN_PAIR_MM
from relcal.calibration.handeye_fit import EMPTY
from relcal.calibration.measurement import Problem
from relcal.robot.kinematics import fk
from relcal.robot.model import RobotModel

PURPOSES = ("calibrate", "handeye")


def handeye_problem(model: RobotModel, q: np.ndarray, handeye: np.ndarray) -> Problem:
    """The problem of ``X`` alone at configurations ``q`` ``(N, n)`` (rad, m): the nominal camera
    poses ``F(q) X``, no kinematic parameter free, the board pose the nuisance (frame-invariant
    formulation, consecutive pairs: the per-pose information does not depend on the pairing)."""
    poses = fk(model, q) @ handeye
    return Problem(model, EMPTY, q, poses, "invariant", "pose", None, handeye)


@dataclass(frozen=True)
class PairRule:
    """Which candidates may not join a set: those forming, with a pose of it, a pair whose
    relative rotation exceeds ``max_deg`` or that turns less than ``min_deg`` while moving less
    than ``min_mm`` (the flange poses ``(P, 4, 4)`` of the pool, m; the camera's relative
    rotation is the same angle)."""

    flange: np.ndarray
    min_deg: float = MIN_PAIR_DEG
    max_deg: float = MAX_PAIR_DEG
    min_mm: float = MIN_PAIR_MM

    @classmethod
    def of(cls, model: RobotModel, pool: np.ndarray) -> PairRule:
        """The rule over the candidates ``pool`` ``(P, n)`` (rad, m) of ``model``."""
        return cls(fk(model, pool))

    def bad_pairs(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """``(len(a), len(b))`` mask of the pairs of pool indices that break the rule."""
        fa, fb = self.flange[np.asarray(a, dtype=int)], self.flange[np.asarray(b, dtype=int)]
        trace = np.einsum("iab,jab->ij", fa[:, :3, :3], fb[:, :3, :3])
        angle = np.degrees(np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0)))
        moved = np.linalg.norm(fa[:, None, :3, 3] - fb[None, :, :3, 3], axis=-1) * 1e3
        return (angle > self.max_deg) | ((angle < self.min_deg) & (moved < self.min_mm))

    def conflicts(self, chosen: np.ndarray) -> np.ndarray:
        """Pool indices that break the rule with a pose of ``chosen`` (pool indices)."""
        chosen = np.asarray(chosen, dtype=int)
        if not len(chosen):
            return np.zeros(0, dtype=int)
        bad = self.bad_pairs(np.arange(len(self.flange)), chosen).any(axis=1)
        return np.setdiff1d(np.flatnonzero(bad), chosen)

    def excluded(self, chosen: np.ndarray, others: np.ndarray | None = None) -> np.ndarray:
        """``chosen`` and every candidate breaking the rule with ``others`` (default
        ``chosen``): what a selection step may not pick."""
        chosen = np.asarray(chosen, dtype=int)
        others = chosen if others is None else np.asarray(others, dtype=int)
        return np.union1d(chosen, self.conflicts(others))


def excluded(rule: PairRule | None, chosen: np.ndarray, others: np.ndarray | None = None):
    """``chosen`` plus what ``rule`` excludes beside ``others`` (no rule: ``chosen``)."""
    if rule is None:
        return np.asarray(chosen, dtype=int)
    return rule.excluded(chosen, others)


@dataclass(frozen=True)
class MotionQuality:
    """What a set of poses gives the hand-eye ``X`` (see the module docstring).

    Parameters
    ----------
    xyz_std : (3,) ndarray of float
        Predicted standard deviations of ``X``'s translation along the flange's x, y, z, m.
    rotation_std : (3,) ndarray of float
        Of its rotation about the flange's x, y, z axes, rad.
    axis_spread : (3,) ndarray of float
        Singular values of the pairs' relative rotation vectors (flange frame) over the
        largest: ``(1, s2/s1, s3/s1)``; the last is 0 when the motions turn about at most two
        axes, the second 0 when about one.
    min_rotation, max_rotation : float
        The smallest and largest relative rotation of a pair, rad.
    bad_pairs : int
        Pairs breaking :class:`PairRule` (turning near 180 deg, or barely moving).
    n_poses : int
    camera_std : tuple of two (3,) ndarray of float, optional
        Eye-to-hand: what the job delivers, the fixed camera in the base frame, predicted
        standard deviations of its position along the base's x, y, z (m) and of its rotation
        about them (rad) (:func:`fixed_camera_std`); None for a camera on the flange.
    """

    xyz_std: np.ndarray
    rotation_std: np.ndarray
    axis_spread: np.ndarray
    min_rotation: float
    max_rotation: float
    bad_pairs: int
    n_poses: int
    camera_std: tuple[np.ndarray, np.ndarray] | None = None


def fixed_camera_std(
    model: RobotModel,
    q: np.ndarray,
    handeye: np.ndarray,
    camera_pose: np.ndarray,
    noise: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Predicted standard deviations of a fixed camera's pose in the base frame (what an
    eye-to-hand job delivers) from configurations ``q`` ``(K, n)`` (rad, m) with the board on the
    flange at ``handeye`` (flange-from-board) and the camera at ``camera_pose`` (base-from-camera):
    the Cramer-Rao bound of ``X`` and ``W`` (:func:`~relcal.calibration.handeye_job.
    frames_covariance`, each board pose measured with the error covariance ``noise`` ``(6, 6)``,
    m, rad) carried to ``W^-1``. Returns the position's along the base's x, y, z (m) and the
    rotation's about them (rad)."""
    from relcal.calibration.handeye_job import frames_covariance

    world = tf.invert(camera_pose)
    flange = fk(model, q)
    cov = frames_covariance(flange, world @ flange @ handeye, handeye, world, noise)
    step = 1e-7
    jac = np.empty((6, 6))
    for i in range(6):
        d = np.zeros(6)
        d[i] = step
        plus, minus = (tf.invert(world @ tf.from_vector(s * d)) for s in (1.0, -1.0))
        jac[:3, i] = (plus[:3, 3] - minus[:3, 3]) / (2 * step)
        jac[3:, i] = tf.log_rotation(plus[:3, :3] @ minus[:3, :3].T) / (2 * step)
    par = jac @ cov[6:, 6:] @ jac.T
    std = np.sqrt(np.clip(np.diag(par), 0.0, None))
    return std[:3], std[3:]


def motion_quality(
    model: RobotModel,
    q: np.ndarray,
    handeye: np.ndarray,
    covariance: np.ndarray,
    fixed: tuple[np.ndarray, np.ndarray] | None = None,
) -> MotionQuality:
    """The hand-eye quality of configurations ``q`` ``(K, n)`` (rad, m) given the predicted
    covariance ``(6, 6)`` of ``X exp(xi)`` (translation m, rotation rad, in the camera frame, the
    order of :func:`handeye_problem`'s columns): standard deviations carried to the flange frame
    (``R_X`` applied to both halves), and the spread of the motions. ``fixed``: ``(camera_pose,
    noise)`` of a fixed camera (eye-to-hand), whose predicted pose is added
    (:func:`fixed_camera_std`)."""
    rot = np.asarray(handeye, float)[:3, :3]
    turn = np.zeros((6, 6))
    turn[:3, :3] = turn[3:, 3:] = rot
    parent = turn @ covariance @ turn.T
    std = np.sqrt(np.clip(np.diag(parent), 0.0, None))
    flange = fk(model, q)
    i, j = np.triu_indices(len(q), 1)
    vec = tf.log_rotation((tf.invert(flange[i]) @ flange[j])[:, :3, :3])  # flange frame
    angles = np.linalg.norm(vec, axis=1)
    s = np.linalg.svd(vec, compute_uv=False) if len(vec) else np.zeros(3)
    s = np.r_[s, np.zeros(3)][:3]
    spread = s / s[0] if s[0] > 0 else np.zeros(3)
    rule = PairRule(flange)
    bad = rule.bad_pairs(np.arange(len(q)), np.arange(len(q)))
    return MotionQuality(
        xyz_std=std[:3],
        rotation_std=std[3:],
        axis_spread=spread,
        min_rotation=float(angles.min()) if len(angles) else 0.0,
        max_rotation=float(angles.max()) if len(angles) else 0.0,
        bad_pairs=int(np.triu(bad, 1).sum()),
        n_poses=len(q),
        camera_std=None if fixed is None else fixed_camera_std(model, q, handeye, *fixed),
    )
