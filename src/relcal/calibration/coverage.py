"""What a set of samples covers: distinct configurations, joints that never moved, singular poses.

Validation holds out samples to predict what a new session would show. It can only do so when
what is held out is new to the fit:

- **Repeated configurations.** A recording that visits the same joint configuration several
  times (the corners of an ISO 9283 cube, a plan run twice, jittered copies) holds, for the
  kinematic error, one configuration several times: a held-out copy of a training configuration
  shows only the measurement noise, never the model's error elsewhere. Samples whose joints agree
  within :data:`SAME_RAD` (revolute) and :data:`SAME_M` (prismatic) are one *configuration*
  (:func:`configuration_clusters`), and whole configurations are held out together.
- **Joints that never moved** (:func:`still_joints`): the held-out samples share the joint's
  one value, so the validation says nothing of the model's error at the joint's other values.
- **Singular configurations** (:func:`singular_samples`): where the flange Jacobian loses rank
  (two axes aligned, the wrist of a 6R arm at ``q5 = 0``) some joints move the flange alike, and
  what separates them elsewhere is not seen.

:class:`Coverage` gathers the three for a set of samples; the verdict
(:mod:`relcal.calibration.verdict`) reads it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from relcal.robot.kinematics import fk
from relcal.robot.model import RobotModel

#: Joint values that agree within these are one configuration: well above the repeatability of
#: a joint (thousandths of a degree on the IPA UR10's repeated poses) and of jittered copies,
#: well below the spacing of distinct poses of a plan (degrees to tens of degrees).
SAME_RAD = np.radians(0.5)
SAME_M = 0.0005
#: A joint whose range over the samples is below these never moved.
STILL_RAD = np.radians(0.5)
STILL_M = 0.0005
#: A configuration is singular when the flange Jacobian's smallest singular value (of its
#: expected rank, translation rows in units of the arm's reach) is below this share of its
#: largest: within about half a degree of two axes aligning.
SINGULAR_RATIO = 1e-2


def _scaled(model: RobotModel, q: np.ndarray) -> np.ndarray:
    """Joint values in units of their tolerance :data:`SAME_RAD` / :data:`SAME_M` (absurd
    readings, which the plausibility checks refuse later, clipped to stay finite)."""
    scale = np.where(model.prismatic, SAME_M, SAME_RAD)
    return np.clip(np.nan_to_num(np.asarray(q, dtype=float) / scale), -1e12, 1e12)


def configuration_clusters(model: RobotModel, q: np.ndarray) -> np.ndarray:
    """The configuration of each sample ``(N,)``: samples whose joint values ``q`` ``(N, n)``
    agree within the tolerances share a label (0, 1, ... in the order of each configuration's
    first sample).

    Samples closer than the tolerance in every joint are linked, and linked samples are one
    configuration. A chain of links that spans more than four tolerances (a slow sweep recorded
    densely, not a repeated pose) is cut into pieces of at most that span, greedily in sample
    order, so that a trajectory does not become one configuration.
    """
    n = len(q)
    if n == 0:
        return np.zeros(0, dtype=int)
    x = _scaled(model, q)
    pairs = cKDTree(x).query_pairs(1.0, p=np.inf, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    by_label = np.argsort(labels, kind="stable")
    groups = np.split(by_label, np.flatnonzero(np.diff(labels[by_label])) + 1)
    groups.sort(key=lambda members: members[0])  # in the order of their first sample
    out = np.full(n, -1)
    count = 0
    for members in groups:
        if np.ptp(x[members], axis=0).max() <= 4.0:
            out[members] = count
            count += 1
            continue
        for m in members:  # a long chain: balls of radius 2 tolerances around leaders
            if out[m] >= 0:
                continue
            near = members[(out[members] < 0) & (np.abs(x[members] - x[m]).max(axis=1) <= 2.0)]
            out[near] = count
            count += 1
    return out


def still_joints(model: RobotModel, q: np.ndarray) -> list[tuple[int, float]]:
    """The joints that never moved over ``q`` ``(N, n)``: ``(joint index, value)`` (rad or m)
    for each joint whose range is below :data:`STILL_RAD` / :data:`STILL_M`."""
    if len(q) < 2:
        return []
    q = np.asarray(q, dtype=float)
    limit = np.where(model.prismatic, STILL_M, STILL_RAD)
    return [(int(j), float(np.median(q[:, j]))) for j in np.flatnonzero(np.ptp(q, axis=0) < limit)]


def joint_jacobians(model: RobotModel, q: np.ndarray, step: float = 1e-6) -> np.ndarray:
    """The flange Jacobians ``(N, 6, n)`` in the base frame at ``q`` ``(N, n)``: the change of the
    flange position (m, at the flange) and rotation (rad) per unit of each joint (central
    differences of :func:`~relcal.robot.kinematics.fk`, valid for every model kind)."""
    q = np.asarray(q, dtype=float)
    n_s, n = q.shape
    shifted = np.repeat(q[:, None, :], 2 * n, axis=1)
    for j in range(n):
        shifted[:, 2 * j, j] += step
        shifted[:, 2 * j + 1, j] -= step
    poses = fk(model, shifted.reshape(-1, n)).reshape(n_s, n, 2, 4, 4)
    plus, minus = poses[:, :, 0], poses[:, :, 1]
    out = np.empty((n_s, 6, n))
    out[:, :3] = np.swapaxes(plus[..., :3, 3] - minus[..., :3, 3], 1, 2) / (2 * step)
    turn = plus[..., :3, :3] @ np.swapaxes(minus[..., :3, :3], -1, -2)  # base-frame rotation
    axis = np.stack(
        [turn[..., 2, 1] - turn[..., 1, 2], turn[..., 0, 2] - turn[..., 2, 0],
         turn[..., 1, 0] - turn[..., 0, 1]], axis=-1,
    ) / 2  # fmt: skip
    out[:, 3:] = np.swapaxes(axis, 1, 2) / (2 * step)
    return out


@dataclass(frozen=True)
class Singular:
    """Samples at singular configurations: ``samples`` (indices into the ``q`` given),
    ``ratio`` ``(N,)`` of every sample (smallest over largest singular value), and ``alike``,
    per singular sample the joints whose motions the lost direction combines (0-based)."""

    samples: np.ndarray
    ratio: np.ndarray
    alike: tuple[tuple[int, ...], ...]


def singular_samples(model: RobotModel, q: np.ndarray) -> Singular:
    """The samples of ``q`` ``(N, n)`` at singular configurations (:data:`SINGULAR_RATIO`), the
    flange Jacobian's translation rows in units of the arm's reach (the largest flange distance
    from the base over the samples, 0.1 m at least)."""
    q = np.asarray(q, dtype=float)
    if len(q) == 0 or not np.isfinite(q).all():
        return Singular(np.zeros(0, dtype=int), np.zeros(len(q)), ())
    jac = joint_jacobians(model, q)
    reach = max(float(np.linalg.norm(fk(model, q)[:, :3, 3], axis=1).max()), 0.1)
    jac[:, :3] /= reach
    rank = min(6, q.shape[1])
    _, s, vt = np.linalg.svd(jac)
    ratio = s[:, rank - 1] / np.maximum(s[:, 0], 1e-300)
    samples = np.flatnonzero(ratio < SINGULAR_RATIO)
    alike = []
    for k in samples:
        lost = np.abs(vt[k, rank - 1])  # the direction of the smallest singular value
        alike.append(tuple(int(j) for j in np.flatnonzero(lost > 0.25 * lost.max())))
    return Singular(samples, ratio, tuple(alike))


@dataclass(frozen=True)
class Coverage:
    """What the samples ``q`` of a calibration cover (see the module docstring).

    ``clusters`` ``(N,)``: each sample's configuration; ``still``: the joints that never moved
    with their value; ``singular``: the samples at singular configurations.
    """

    clusters: np.ndarray
    still: tuple[tuple[int, float], ...]
    singular: Singular

    @classmethod
    def of(cls, model: RobotModel, q: np.ndarray) -> Coverage:
        return cls(
            configuration_clusters(model, q),
            tuple(still_joints(model, q)),
            singular_samples(model, q),
        )

    @property
    def n_configurations(self) -> int:
        """The number of distinct configurations."""
        return int(self.clusters.max()) + 1 if len(self.clusters) else 0

    @property
    def n_repeated(self) -> int:
        """Samples that repeat an earlier sample's configuration."""
        return len(self.clusters) - self.n_configurations

    def all_singular(self) -> bool:
        """Every sample at a singular configuration."""
        return len(self.clusters) > 0 and len(self.singular.samples) == len(self.clusters)


def _joint(model: RobotModel, j: int) -> str:
    """``joint 5 (wrist2)``: 1-based, with its name."""
    name = model.joint_names[j] if j < len(model.joint_names) else ""
    return f"joint {j + 1}" + (f" ({name})" if name and name != f"joint{j + 1}" else "")


def _value(model: RobotModel, j: int, value: float) -> str:
    return f"{value * 1e3:.1f} mm" if model.prismatic[j] else f"{np.degrees(value):.1f} deg"


def describe(coverage: Coverage, model: RobotModel, ids: list[str]) -> dict:
    """What ``coverage`` (of the samples ``ids``) says, JSON-ready: ``configurations`` (distinct),
    ``repeated_samples``, ``still_joints`` (``joint``, ``name``, ``value`` in deg or mm),
    ``singular_samples`` (ids) and ``limits``: in words, what held-out samples of this set
    cannot show (a joint that never moved; every sample at a singular configuration)."""
    limits = []
    still = []
    for j, value in coverage.still:
        still.append(
            {
                "joint": j + 1,
                "name": model.joint_names[j],
                "value": float(value * 1e3 if model.prismatic[j] else np.degrees(value)),
                "unit": "mm" if model.prismatic[j] else "deg",
            }
        )
        limits.append(
            f"{_joint(model, j)} never moved (at {_value(model, j, value)} in every sample): the "
            "model is not validated at its other values"
        )
    singular = coverage.singular
    if coverage.all_singular():
        joints = sorted({j for alike in singular.alike for j in alike})
        which = ", ".join(str(j + 1) for j in joints)
        limits.append(
            f"every sample is at a singular configuration (joints {which} move the flange "
            "alike): what tells them apart elsewhere is not validated"
        )
    return {
        "configurations": coverage.n_configurations,
        "repeated_samples": coverage.n_repeated,
        "still_joints": still,
        "singular_samples": [ids[k] for k in singular.samples],
        "limits": limits,
    }
