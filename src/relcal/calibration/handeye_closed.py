"""The closed-form hand-eye methods every hand-eye user starts from: OpenCV's.

Every mode is ``C_k = W F_k X``: ``F_k`` the flange in the robot's base frame, ``C_k`` the measured
pose (the camera in the board frame eye-in-hand, the board in the camera frame eye-to-hand, the
camera or marker in the world frame robot-world), ``X`` on the flange and ``W`` fixed in the cell.

- ``AX = XB`` (:data:`HAND_EYE`: Tsai, Park, Horaud, Andreff, Daniilidis) through
  ``cv2.calibrateHandEye``, which takes ``F_k`` as ``gripper2base`` and ``C_k^-1`` as
  ``target2cam`` and returns ``X`` as ``cam2gripper``; ``W`` then follows from the samples
  (:func:`world_given`).
- ``AX = ZB`` (:data:`ROBOT_WORLD`: Shah, Li) through ``cv2.calibrateRobotWorldHandEye``, which
  takes ``C_k^-1`` as ``world2cam`` and ``F_k^-1`` as ``base2gripper`` and returns both,
  ``W`` as ``base2world`` and ``X^-1`` as ``gripper2cam``.

OpenCV forms every pair of the samples it is given. A pair that barely moves (less than
:data:`MIN_PAIR_DEG` and :data:`MIN_PAIR_MM`: a configuration recorded again) has a rotation axis
that is pure noise, and pairs turning near 180 degrees have quaternions whose sign is a coin toss
(Horaud and Daniilidis flipped on them); so the samples passed are those with no such pair
(:func:`informative_samples`: the fewest samples are left out). A pure translation (no rotation,
a real move) stays: it carries the hand-eye rotation (``t_A = R_X t_B``) and harms no method;
on the real circle-grid set, 8 of whose 15 samples only translate, leaving those out made every
closed form's training misfit 25 to 60 % worse. A method that returns NaN (Andreff on real
data), or a matrix that is not a rotation, is reported as failed with the reason, never used.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from relcal import geometry as tf
from relcal.data.flange import mean_rotation

HAND_EYE = ("tsai", "park", "horaud", "andreff", "daniilidis")
ROBOT_WORLD = ("shah", "li")
METHODS = HAND_EYE + ROBOT_WORLD
TITLES = {
    "tsai": "Tsai-Lenz",
    "park": "Park-Martin",
    "horaud": "Horaud-Dornaika",
    "andreff": "Andreff",
    "daniilidis": "Daniilidis",
    "shah": "Shah",
    "li": "Li",
}
MIN_PAIR_DEG = 2.0  # a pair turning less and moving less than MIN_PAIR_MM barely moved at all
MIN_PAIR_MM = 2.0
MAX_PAIR_DEG = 170.0  # a pair turning more has a quaternion sign lost in the noise
MAX_SAMPLES = 80  # OpenCV forms all n (n - 1) / 2 pairs: the spread-out samples of a larger set
MIN_SAMPLES = 3


@dataclass(frozen=True)
class ClosedForm:
    """One closed-form method's answer.

    Parameters
    ----------
    method : str
        One of :data:`METHODS`.
    handeye : (4, 4) ndarray of float or None
        ``X``, the flange-to-camera (or flange-to-marker) transform, m; None when it failed.
    world : (4, 4) ndarray of float or None
        ``W``, the fixed frame's transform (board, camera or world from base), m; None when
        failed.
    failure : str or None
        Why the method gave no answer (NaN, not a rotation, too few samples), or None.
    """

    method: str
    handeye: np.ndarray | None
    world: np.ndarray | None
    failure: str | None = None

    @property
    def ok(self) -> bool:
        return self.failure is None


@dataclass(frozen=True)
class Selection:
    """The samples passed to the closed forms and why the others were left out.

    ``used`` ``(n,)`` indices into the samples given; ``left_out`` ``{index: reason}``.
    """

    used: np.ndarray
    left_out: dict[int, str]


def rotation_angles(poses: np.ndarray) -> np.ndarray:
    """``(N, N)``: the angle (rad) of the relative rotation of every two poses ``(N, 4, 4)``."""
    rot = poses[:, :3, :3]
    trace = np.einsum("iab,jab->ij", rot, rot)  # trace(R_i^T R_j)
    return np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0))


def canonical_order(*arrays: np.ndarray) -> np.ndarray:
    """A permutation of the samples that depends on their values alone (lexicographic over the
    flattened arrays ``(N, ...)``): what is computed in this order does not change when the
    input rows are reordered."""
    keys = np.concatenate([np.asarray(a, dtype=float).reshape(len(a), -1) for a in arrays], axis=1)
    keys = np.nan_to_num(keys, nan=np.inf)
    return np.lexsort(keys.T[::-1])


def informative_samples(
    flange: np.ndarray,
    measured: np.ndarray,
    min_deg: float = MIN_PAIR_DEG,
    max_deg: float = MAX_PAIR_DEG,
    max_samples: int = MAX_SAMPLES,
    min_mm: float = MIN_PAIR_MM,
) -> Selection:
    """The most samples with no pair that barely moves (turning less than ``min_deg`` and
    moving less than ``min_mm``) or turns more than ``max_deg``, in the flange poses or the
    measured poses ``(N, 4, 4)`` (greedy: the sample in the most bad pairs goes first, ties to
    the one turning least from the others), at most ``max_samples`` (then the most spread out).
    Independent of the order of the samples."""
    n = len(flange)
    order = canonical_order(flange, measured)
    angles = np.maximum(rotation_angles(flange[order]), rotation_angles(measured[order]))
    low = np.minimum(rotation_angles(flange[order]), rotation_angles(measured[order]))
    pos = flange[order][:, :3, 3]
    moved = np.linalg.norm(pos[:, None] - pos[None], axis=-1) * 1e3
    bad = (low < np.radians(min_deg)) & (moved < min_mm) | (angles > np.radians(max_deg))
    np.fill_diagonal(bad, False)
    keep = np.ones(n, dtype=bool)
    left: dict[int, str] = {}
    spread = angles.sum(axis=1)
    while True:
        sub = bad & keep[:, None] & keep[None, :]
        count = sub.sum(axis=1)
        if not count.any():
            break
        worst = max(np.flatnonzero(count == count.max()), key=lambda k: (-spread[k], k))
        partner = int(np.flatnonzero(sub[worst])[0])
        turn = np.degrees(
            angles[worst, partner]
            if angles[worst, partner] > np.radians(max_deg)
            else low[worst, partner]
        )
        why = "near 180 deg" if turn > max_deg else f"and moves less than {min_mm:g} mm"
        left[int(order[worst])] = (
            f"turns {turn:.2f} deg ({why}) from another sample and {int(count[worst])} in all"
        )
        keep[worst] = False
    while keep.sum() > max_samples:  # the most spread out: drop the one closest to the others
        kept = np.flatnonzero(keep)
        closest = kept[np.argmin(np.sort(angles[np.ix_(kept, kept)], axis=1)[:, 1])]
        left[int(order[closest])] = f"beyond the {max_samples} most spread-out samples"
        keep[closest] = False
    return Selection(np.sort(order[keep]), left)


def world_given(flange: np.ndarray, measured: np.ndarray, handeye: np.ndarray) -> np.ndarray:
    """``W`` ``(4, 4)`` given ``X``: the mean of ``C_k (F_k X)^-1`` over the samples (rotations
    by their chordal mean, translations averaged)."""
    each = measured @ tf.invert(flange @ handeye)
    return tf.homogeneous(mean_rotation(each[:, :3, :3]), each[:, :3, 3].mean(axis=0))


def _checked(method: str, rot, trans) -> tuple[np.ndarray | None, str | None]:
    rot, trans = np.asarray(rot, dtype=float), np.asarray(trans, dtype=float).reshape(-1)
    if rot.shape != (3, 3) or trans.shape != (3,):
        return None, f"{TITLES[method]} returned no transform"
    if not (np.all(np.isfinite(rot)) and np.all(np.isfinite(trans))):
        return None, f"{TITLES[method]} returned NaN (a known failure of the method on such data)"
    ortho = np.abs(rot.T @ rot - np.eye(3)).max()
    if ortho > 1e-5 or np.linalg.det(rot) < 0:
        return None, (
            f"{TITLES[method]} returned a matrix that is not a rotation (det "
            f"{np.linalg.det(rot):+.3f}: a reflection or a sign flip)"
        )
    u, _, vt = np.linalg.svd(rot)  # exact to round-off
    return tf.homogeneous(u @ vt, trans), None


def solve(method: str, flange: np.ndarray, measured: np.ndarray) -> ClosedForm:
    """One closed-form method on the samples given (all their pairs, as OpenCV forms them).

    Parameters
    ----------
    method : str
        One of :data:`METHODS`.
    flange, measured : (N, 4, 4) ndarray of float
        ``F_k`` and ``C_k`` of ``C_k = W F_k X``, m.

    Returns
    -------
    ClosedForm
        ``X`` and ``W``, or the reason the method failed.
    """
    import cv2

    if len(flange) < MIN_SAMPLES:
        return ClosedForm(method, None, None, f"{len(flange)} samples: at least 3 are needed")
    inverse_c = tf.invert(measured)
    try:
        if method in HAND_EYE:
            flag = getattr(cv2, f"CALIB_HAND_EYE_{method.upper()}")
            rot, trans = cv2.calibrateHandEye(
                list(flange[:, :3, :3]),
                list(flange[:, :3, 3:]),
                list(inverse_c[:, :3, :3]),
                list(inverse_c[:, :3, 3:]),
                method=flag,
            )
            x, why = _checked(method, rot, trans)
            return ClosedForm(
                method, x, None if x is None else world_given(flange, measured, x), why
            )
        flag = getattr(cv2, f"CALIB_ROBOT_WORLD_HAND_EYE_{method.upper()}")
        inverse_f = tf.invert(flange)
        rot_w, trans_w, rot_x, trans_x = cv2.calibrateRobotWorldHandEye(
            list(inverse_c[:, :3, :3]),
            list(inverse_c[:, :3, 3:]),
            list(inverse_f[:, :3, :3]),
            list(inverse_f[:, :3, 3:]),
            method=flag,
        )
    except cv2.error as exc:
        text = str(exc).strip().splitlines()[-1] if str(exc).strip() else "cv2.error"
        return ClosedForm(method, None, None, f"{TITLES[method]}: OpenCV refused: {text}")
    w, why_w = _checked(method, rot_w, trans_w)
    x_inv, why_x = _checked(method, rot_x, trans_x)
    if w is None or x_inv is None:
        return ClosedForm(method, None, None, why_w or why_x)
    return ClosedForm(method, tf.invert(x_inv), w)


def closed_forms(
    flange: np.ndarray,
    measured: np.ndarray,
    methods: tuple[str, ...] = METHODS,
    selection: Selection | None = None,
) -> tuple[list[ClosedForm], Selection]:
    """Every closed-form method on the informative samples (:func:`informative_samples`), passed
    to OpenCV in an order that depends on their values alone.

    Parameters
    ----------
    flange, measured : (N, 4, 4) ndarray of float
        ``F_k`` and ``C_k`` of ``C_k = W F_k X``, m.
    methods : tuple of str
        Which of :data:`METHODS`.
    selection : Selection, optional
        The samples to use (default :func:`informative_samples`).

    Returns
    -------
    answers : list of ClosedForm
        One per method, in the order of ``methods``.
    selection : Selection
        The samples used and why the others were not.
    """
    selection = selection or informative_samples(flange, measured)
    used = selection.used[canonical_order(flange[selection.used], measured[selection.used])]
    if len(used) < MIN_SAMPLES:
        why = (
            f"{len(used)} of {len(flange)} samples carry rotation information (every other pair "
            f"turns less than {MIN_PAIR_DEG:g} deg or near 180 deg): the closed forms need 3"
        )
        return [ClosedForm(m, None, None, why) for m in methods], selection
    return [solve(m, flange[used], measured[used]) for m in methods], selection
