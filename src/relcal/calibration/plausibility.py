"""Plausibility checks: catch data that would calibrate "successfully" into a wrong model.

Each check compares what was measured with what the nominal model commands, using quantities that
do not depend on the unknowns of the calibration:

- **Relative rotations.** For a pair (i, j) the measured ``B = C_i^-1 C_j`` and the commanded
  ``A = F_i^-1 F_j`` satisfy ``A X = X B``: ``B`` is ``A`` seen in another frame, so both rotate by
  the same angle, and their axes differ by one fixed rotation ``R_X`` for every pair. The misfit of
  ``R_A`` against ``R_X R_B R_X^T`` with the best ``R_X`` (an SVD of the rotation vectors) is the
  robot's small geometric error plus measurement noise when the data are right, and tens of
  degrees when quaternions are w-first, poses are inverted or joints are in the wrong unit. The
  alternatives are tried and the one that fits is named.
- **Translation scale.** With ``R_X`` known, ``(R_A - I) t_X - s R_X t_B = -t_A`` is linear in
  ``t_X`` and a scale ``s``: ``1/s`` is how much larger the measured translations are than the
  modelled ones (1000 for millimetres, the ratio of the declared to the true board square).
  Rotations about one fixed point (a 2-axis positioner with intersecting axes) leave the scale
  undetermined; the check then says nothing.
- **Magnitudes.** Joint readings against the model's limits, positions beyond any cell, a
  hand-eye guess in millimetres.
- **Corrections.** Each identified correction against a tolerance per kind: a 75 mm link
  correction is not a calibration but a wrong input absorbed by the model.

The functions are pure (arrays in, numbers or a message out); :func:`check_inputs` and
:func:`check_corrections` gather them for the measurement kinds
(:mod:`relcal.calibration.kinds`), whose checks :func:`relcal.calibration.pipeline.calibrate`
calls before identifying and before anything is written.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from relcal import geometry as tf
from relcal.calibration.handeye import (
    LEVER,
    PURE_TRANSLATION,
    align_rotations,
    handeye_rotation,
    rotation_vectors,
    solve_handeye,
)
from relcal.calibration.noise import robust_scale
from relcal.errors import RelcalError
from relcal.geometry import relative

MAX_PAIRS = 2000  # pairs used by the checks (all pairs up to 63 samples)
RATIO = 3.0  # an alternative reading that fits the rotations this much better is named
SURE_AXIS = np.radians(150)  # relative rotations below this angle have a sure axis
SAME_CONFIGURATION = np.radians(0.05)  # rad (a prismatic joint: 0.05 mm): joints this close are
# one configuration recorded again: such a pair is repeatability data, no motion to compare
MIN_PAIRS = 6  # pairs that carry a motion, fewer: the check cannot tell
# Measured over modelled translations that a reading may need and still be offered as the fix:
# the same unit, or millimetres for metres either way (the scale check then names it).
PLAUSIBLE_SCALES = ((0.5, 2.0), (500.0, 2000.0), (0.0005, 0.002))


@dataclass(frozen=True)
class Tolerances:
    """Thresholds of the plausibility checks (SI units); ``tolerances:`` in dataset.yaml sets
    them as ``length_mm``, ``angle_deg``, ``handeye_mm``, ``handeye_deg``, ``rotation_deg``,
    ``scale_percent``, ``joint_limit_deg``, ``translation_mm``."""

    length: float = 0.010  # m, largest plausible correction of a link length (a, d)
    angle: float = np.radians(5.0)  # rad, of a joint offset or twist (theta_off, alpha, beta)
    handeye_length: float = 0.05  # m, of the hand-eye translation from its starting value
    handeye_angle: float = np.radians(5.0)  # rad, of the hand-eye rotation
    rotation: float = np.radians(10.0)  # rad, median relative-rotation misfit
    scale: float = 0.05  # relative, measured/modelled translation scale minus one
    joint_limit: float = np.radians(5.0)  # rad, reading beyond a joint limit
    translation: float = 0.1  # m, median relative-translation misfit after the best hand-eye

    FIELDS = {
        "length_mm": ("length", 1e-3),
        "angle_deg": ("angle", np.pi / 180),
        "handeye_mm": ("handeye_length", 1e-3),
        "handeye_deg": ("handeye_angle", np.pi / 180),
        "rotation_deg": ("rotation", np.pi / 180),
        "scale_percent": ("scale", 1e-2),
        "joint_limit_deg": ("joint_limit", np.pi / 180),
        "translation_mm": ("translation", 1e-3),
    }

    @classmethod
    def from_display(cls, values: dict[str, float] | None) -> Tolerances:
        """From the dataset.yaml form (mm, deg, percent)."""
        kwargs = {cls.FIELDS[k][0]: float(v) * cls.FIELDS[k][1] for k, v in (values or {}).items()}
        return cls(**kwargs)


# --- pure pieces ---------------------------------------------------------------------------------


def check_pairs(n: int, rng_seed: int = 0) -> np.ndarray:
    """Index pairs ``(P, 2)`` for the checks: all pairs, or ``MAX_PAIRS`` random ones (picked by
    their position in the list of all pairs, which is never formed: linear in ``n``)."""
    total = n * (n - 1) // 2
    if total <= MAX_PAIRS:
        i, j = np.triu_indices(n, 1)
        return np.stack([i, j], axis=1)
    pick = np.sort(np.random.default_rng(rng_seed).choice(total, MAX_PAIRS, replace=False))
    starts = np.cumsum(np.r_[0, np.arange(n - 1, 0, -1)])  # where row i of triu_indices starts
    i = np.searchsorted(starts, pick, side="right") - 1
    return np.stack([i, i + 1 + pick - starts[i]], axis=1)


def rotation_misfit(commanded: np.ndarray, measured: np.ndarray) -> tuple[float, np.ndarray]:
    """Median angle (rad) of ``R_A^T R_X R_B R_X^T`` over the pairs with the best ``R_X``, and
    that ``R_X``. Independent of the hand-eye transform; near zero for right data."""
    rx = align_rotations(commanded, measured, SURE_AXIS)
    rb = np.einsum("ij,pjk,lk->pil", rx, measured[:, :3, :3], rx)
    diff = np.swapaxes(commanded[:, :3, :3], 1, 2) @ rb
    return float(np.median(np.linalg.norm(tf.log_rotation(diff), axis=1))), rx


def angle_misfit(commanded: np.ndarray, measured: np.ndarray) -> float:
    """Median difference (rad) of the rotation angles of commanded and measured relative
    motions: invariant under any hand-eye transform."""
    a = np.linalg.norm(tf.log_rotation(commanded[:, :3, :3]), axis=1)
    b = np.linalg.norm(tf.log_rotation(measured[:, :3, :3]), axis=1)
    return float(np.median(np.abs(a - b)))


@dataclass(frozen=True)
class Scale:
    """Measured over modelled translations: ``ratio`` and its standard deviation ``std``
    (relative); ``determined`` is False when the motions cannot tell (rotations about a point)."""

    ratio: float
    std: float
    determined: bool
    handeye_translation: np.ndarray | None = None  # (3,) t_X of the fit, m
    residual: float = float("nan")  # RMS of the fit's translation rows, m
    translation_known: bool = True  # the pairs turn enough about every axis to fix t_X
    motion: float = float("nan")  # median length of the commanded relative translations, m
    rotation_misfit: float = float("nan")  # median over the pairs that turn, rad (check_inputs)


def translation_scale(
    commanded: np.ndarray, measured: np.ndarray, rx: np.ndarray, robust: bool = True
) -> Scale:
    """Solve ``(R_A - I) t_X - s R_X t_B = -t_A`` for ``t_X`` and ``s`` (least squares over the
    pairs); the ratio is ``1/s``. Its standard deviation comes from the fit's residual.

    ``robust``: pairs whose residual is more than 3 times the median are left out and the fit
    repeated (three rounds), so that one wrong sample (a mistyped joint reading) does not pass
    for a wrong unit of all of them; ``residual`` is then the median pair residual (m)."""
    m = np.concatenate(
        [
            commanded[:, :3, :3] - np.eye(3),
            -np.einsum("ij,pj->pi", rx, measured[:, :3, 3])[:, :, None],
        ],
        axis=2,
    )  # (P, 3, 4)
    rhs = -commanded[:, :3, 3]  # (P, 3)
    keep = np.ones(len(m), dtype=bool)
    for _ in range(4 if robust else 1):
        rows, b = m[keep].reshape(-1, 4), rhs[keep].reshape(-1)
        col = np.linalg.norm(rows, axis=0)
        col[col == 0] = 1.0
        sol, *_ = np.linalg.lstsq(rows / col, b, rcond=None)
        sol = sol / col
        norms = np.linalg.norm(np.einsum("pij,j->pi", m, sol) - rhs, axis=1)
        if not robust:
            break
        cut = 3.0 * max(float(np.median(norms)), 1e-9)
        new = norms <= cut
        if new.sum() < max(4, len(m) // 2) or np.array_equal(new, keep):
            break
        keep = new
    resid = (rows @ sol - b).reshape(-1)
    dof = max(len(resid) - 4, 1)
    sigma2 = float(resid @ resid) / dof
    normal = (rows / col).T @ (rows / col)
    sv = np.linalg.svd(normal, compute_uv=False)
    typical = float(np.median(norms)) if robust else float(np.sqrt(np.mean(norms**2)))
    if sv[-1] <= 1e-12 * sv[0] or sol[3] == 0:
        return Scale(float("nan"), float("inf"), False, None, typical)
    s_std = np.sqrt(sigma2 * np.linalg.inv(normal)[3, 3]) / col[3]
    s = float(sol[3])
    rel = float(s_std / abs(s))
    # t_X is fixed only by pairs that turn about every axis: the weakest direction of the
    # stacked R_A - I turns by at least PURE_TRANSLATION (rms over the pairs kept)
    weakest = np.linalg.svd(rows[:, :3], compute_uv=False)[-1] / np.sqrt(max(len(rows) // 3, 1))
    known = bool(weakest > 2 * np.sin(PURE_TRANSLATION / 2))
    motion = float(np.median(np.linalg.norm(commanded[:, :3, 3], axis=1)))
    return Scale(1.0 / s, rel, bool(rel < 0.01 and s > 0), sol[:3], typical, known, motion)


def reorder_w_first(poses: np.ndarray) -> np.ndarray:
    """Poses whose quaternion columns ``qx, qy, qz, qw`` held ``w, x, y, z``, reinterpreted."""
    quat = Rotation.from_matrix(poses[:, :3, :3]).as_quat()  # the (w, x, y, z) read as (x, y, z, w)
    fixed = Rotation.from_quat(np.roll(quat, -1, axis=1)).as_matrix()
    return tf.homogeneous(fixed, poses[:, :3, 3])


def joint_problems(
    q: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    prismatic: np.ndarray,
    names: Sequence[str],
    ids: Sequence[str],
    margin: float,
) -> list[str]:
    """Readings beyond a joint's limits by more than ``margin`` (rad; 10 mm for prismatic
    joints), or beyond any physical range where no limit is set. One message per joint."""
    out = []
    for j in range(q.shape[1]):
        values = q[:, j]
        pr = bool(prismatic[j])
        tol = 0.01 if pr else margin
        absurd = 100.0 if pr else 100 * np.pi
        lo = lower[j] if np.isfinite(lower[j]) else -absurd
        hi = upper[j] if np.isfinite(upper[j]) else absurd
        bad = np.flatnonzero((values < lo - tol) | (values > hi + tol))
        if not bad.size:
            continue
        k = bad[np.argmax(np.abs(values[bad]))]
        unit, conv = ("m", 1.0) if pr else ("deg", 180 / np.pi)
        limits = (
            f"the model's limits [{lo * conv:.4g}, {hi * conv:.4g}] {unit}"
            if np.isfinite(lower[j]) or np.isfinite(upper[j])
            else f"any physical range (|q| < {absurd * conv:.4g} {unit})"
        )
        few = len(bad) <= max(2, len(values) // 20)
        cause = (
            "a mistyped reading or a wrong row? fix or remove "
            + ("it" if len(bad) == 1 else "them")
            if few
            else "wrong joint order or unit, or another robot or chain (root and tip links)?"
        )
        out.append(
            f"sample {ids[k]}: q{j + 1} ({names[j]}) = {values[k] * conv:.6g} {unit} is outside "
            f"{limits} ({len(bad)} of {len(values)} readings of this joint are): {cause}"
        )
    return out


def position_problems(poses: np.ndarray, ids: Sequence[str]) -> list[str]:
    """Measured positions in millimetres (median distance above 20 m) or absurd (one sample
    beyond 1 km or 100 times the median)."""
    dist = np.linalg.norm(poses[:, :3, 3], axis=1)
    median = float(np.median(dist))
    if median > 20.0:
        return [
            f"poses look like millimetres: the median distance is {median:.4g} m (a camera and "
            f"board within a cell are metres apart); give x, y, z in metres (fix: x, y, z "
            "divided by 1000)"
        ]
    bad = np.flatnonzero(dist > max(1e3, 100 * median))
    if bad.size:
        k = bad[np.argmax(dist[bad])]
        return [
            f"sample {ids[k]}: position x, y, z = {np.array2string(poses[k, :3, 3], precision=4)} "
            f"m is not physical (the median distance is {median:.3g} m)"
        ]
    return []


# --- gathering: inputs and corrections -----------------------------------------------------------


def swap_xyz(poses: np.ndarray, i: int, j: int) -> np.ndarray:
    """Poses whose position columns ``i`` and ``j`` (0 x, 1 y, 2 z) were swapped, read back."""
    out = poses.copy()
    out[:, [i, j], 3] = poses[:, [j, i], 3]
    return out


@dataclass(frozen=True)
class Reading:
    """A reading of the joints (``joints``: how to get the true joint values from the given
    ones) and of the measured poses that might have been meant, and how to say and fix it."""

    label: str
    joints: Callable[[np.ndarray], np.ndarray] | None = None
    poses: Callable[[np.ndarray], np.ndarray] | None = None


_COLUMNS = "xyz"


def joint_readings(
    model, q: np.ndarray, margin: float, joint_unit: str | None = None
) -> list[Reading]:
    """The joint mix-ups worth trying: two columns swapped, one joint's sign reversed, the
    columns in reverse order, and the other angle unit than the one declared (``joint_unit``;
    both when it is not known). A reading that would put readings beyond the joint limits is
    not offered (following it would be refused)."""
    n = q.shape[1]
    revolute = ~np.asarray(model.prismatic)
    names = [f"q{i + 1}" for i in range(n)]
    out: list[Reading] = []

    def swap(i: int, j: int) -> Callable[[np.ndarray], np.ndarray]:
        order = list(range(n))
        order[i], order[j] = j, i
        return lambda v: v[:, order]

    def negate(i: int) -> Callable[[np.ndarray], np.ndarray]:
        sign = np.ones(n)
        sign[i] = -1.0
        return lambda v: v * sign

    for i in range(n):
        for j in range(i + 1, n):
            out.append(
                Reading(
                    f"joint columns {names[i]} and {names[j]} look swapped (fix: swap the names "
                    f"{names[i]} and {names[j]} in the samples file's header)",
                    swap(i, j),
                )
            )
    for i in range(n):
        out.append(
            Reading(
                f"{names[i]} looks negated, its readings of the opposite sign (fix: negate the "
                f"{names[i]} column, or reverse joint {i + 1}'s direction in the model)",
                negate(i),
            )
        )
    if n > 2:
        out.append(
            Reading(
                f"the joint columns look in reverse order ({names[-1]} .. {names[0]}; fix: "
                "reverse the joint names in the samples file's header)",
                lambda v: v[:, ::-1],
            )
        )
    if joint_unit in (None, "deg"):
        out.append(
            Reading(
                "joint angles look like radians declared as degrees (fix: joint_unit: rad in "
                "dataset.yaml)",
                lambda v: np.where(revolute, v * (180 / np.pi), v),
            )
        )
    if joint_unit in (None, "rad"):
        out.append(
            Reading(
                "joint angles look like degrees declared as radians (fix: joint_unit: deg in "
                "dataset.yaml)",
                lambda v: np.where(revolute, v * (np.pi / 180), v),
            )
        )
    plausible = []
    for reading in out:
        alt = reading.joints(q)  # type: ignore[misc]
        if np.array_equal(alt, q):
            continue  # the same numbers (a joint that never moves): nothing to tell
        problems = joint_problems(
            alt, model.lower, model.upper, model.prismatic, model.joint_names, [""] * len(q), margin
        )
        if not problems:
            plausible.append(reading)
    return plausible


def rpy_reread(
    poses: np.ndarray, factor: float, euler: str = "xyz", meant: str | None = None
) -> np.ndarray:
    """Poses given as roll, pitch, yaw (rotation sequence ``euler``, SciPy's) whose angle numbers
    were in another unit (times ``factor``) or of another sequence (``meant``): the angles
    recovered and read that way (exact for the small angles of radians read as degrees and for
    angles in the sequence's principal range, up to the Euler angles' own ambiguity otherwise)."""
    rpy = Rotation.from_matrix(poses[:, :3, :3]).as_euler(euler) * factor
    rotation = Rotation.from_euler(meant or euler, rpy).as_matrix()
    return tf.homogeneous(rotation, poses[:, :3, 3])


#: Rotation sequences a roll, pitch, yaw export may have meant (the Tait-Bryan ones, extrinsic
#: lower case and intrinsic upper case, as SciPy's ``from_euler``)
EULER_SEQUENCES = tuple(
    s for order in ("xyz", "xzy", "yxz", "yzx", "zxy", "zyx") for s in (order, order.upper())
)


def pose_readings(
    mode: str, poses_given: bool, pose_angle_unit: str | None = None, euler: str | None = None
) -> list[Reading]:
    """The measured-pose mix-ups worth trying: inverted poses (or the other mode), w-first
    quaternions, two position columns swapped (for poses given in a table), and roll, pitch,
    yaw in the other angle unit than ``pose_angle_unit`` declares or of another rotation
    sequence than ``euler`` (for poses given so)."""
    other = "board in camera" if mode == "eye_in_hand" else "camera in board"
    wanted = "camera in board" if mode == "eye_in_hand" else "board in camera"
    swapped = "eye_to_hand" if mode == "eye_in_hand" else "eye_in_hand"
    if mode == "robot_world" and not poses_given:
        inverted = (
            "the camera poses look inverted (robot_world with images measures the camera on the "
            "flange against a fixed board; a fixed camera and the board on the flange is mode: "
            "eye_to_hand)"
        )
    elif mode == "robot_world":
        inverted = (
            "poses look inverted (the world in the camera or marker frame given, the camera or "
            "marker in the world frame expected for robot_world; fix: give the camera or marker "
            "pose in the world frame)"
        )
    elif poses_given:
        inverted = (
            f"poses look inverted ({other} given, {wanted} expected for {mode}; fix: give "
            f"{wanted}, or mode: {swapped} if that is the setup)"
        )
    else:
        inverted = f"the camera poses look inverted (mode: {swapped} meant, not {mode}?)"
    out = [Reading(inverted, poses=tf.invert)]
    if poses_given:
        wfirst = (
            "quaternions look w-first (qx, qy, qz, qw columns expected in x, y, z, w order; "
            "fix: name the columns qw, qx, qy, qz in the header)"
        )
        out.append(Reading(wfirst, poses=reorder_w_first))
        out.append(
            Reading(f"{wfirst} and {inverted}", poses=lambda c: tf.invert(reorder_w_first(c)))
        )
        seq = euler or "xyz"
        if pose_angle_unit == "deg":
            out.append(
                Reading(
                    "roll, pitch, yaw look like radians declared as degrees (fix: "
                    "pose_angle_unit: rad in dataset.yaml)",
                    poses=lambda c: rpy_reread(c, 180 / np.pi, seq),
                )
            )
        elif pose_angle_unit == "rad":
            out.append(
                Reading(
                    "roll, pitch, yaw look like degrees declared as radians (fix: "
                    "pose_angle_unit: deg in dataset.yaml)",
                    poses=lambda c: rpy_reread(c, np.pi / 180, seq),
                )
            )
        if euler is not None:
            out.extend(
                Reading(
                    f"roll, pitch, yaw look like the rotation sequence {meant}, not {euler} "
                    f"(fix: euler: {meant} in dataset.yaml)",
                    poses=lambda c, meant=meant: rpy_reread(c, 1.0, euler, meant),
                )
                for meant in EULER_SEQUENCES
                if meant != euler
            )
        for i, j in ((0, 1), (0, 2), (1, 2)):
            out.append(
                Reading(
                    f"position columns {_COLUMNS[i]} and {_COLUMNS[j]} look swapped (fix: swap "
                    f"the names {_COLUMNS[i]} and {_COLUMNS[j]} in the samples file's header)",
                    poses=lambda c, i=i, j=j: swap_xyz(c, i, j),
                )
            )
    return out


@dataclass(frozen=True)
class _Fit:
    label: str
    misfit: float  # median relative-rotation misfit over the pairs that turn, rad (NaN: too few
    # pairs turn to tell)
    translation: float  # median relative-translation misfit after the best hand-eye, m, over
    # the pairs that move (inf when the rotations do not fit, NaN when R_X is not determined)
    ratio: float = float("nan")  # measured over modelled translations (NaN: not determined)

    def fits(self, tolerances: Tolerances) -> bool:
        """Rotations and translations within the tolerances (what cannot be told passes), with
        a translation scale a reading may need (:data:`PLAUSIBLE_SCALES`): a reading that fits
        only by shrinking every commanded motion (degrees read as radians on data that barely
        turn) is not a fit, and following it would not be safe."""
        ok_scale = not np.isfinite(self.ratio) or any(
            lo <= self.ratio <= hi for lo, hi in PLAUSIBLE_SCALES
        )
        return (
            not self.misfit > tolerances.rotation
            and not self.translation > tolerances.translation
            and ok_scale
        )


def _pair_angles(commanded: np.ndarray, measured: np.ndarray, rx: np.ndarray) -> np.ndarray:
    """Per pair, the angle (rad) of ``R_A^T R_X R_B R_X^T``."""
    rb = np.einsum("ij,pjk,lk->pil", rx, measured[:, :3, :3], rx)
    diff = np.swapaxes(commanded[:, :3, :3], 1, 2) @ rb
    return np.linalg.norm(tf.log_rotation(diff), axis=1)


def _wrong_samples(pairs: np.ndarray, values: np.ndarray, threshold: float = 5.0) -> np.ndarray:
    """Samples whose pairs misfit far more than the others' (each sample's median over its
    pairs, a robust z-score above ``threshold``), at most a quarter of them."""
    from relcal.calibration.measurement import per_sample_median

    if not len(pairs):
        return np.zeros(0, dtype=int)
    score = per_sample_median(values, pairs)
    seen = np.isfinite(score)
    centre = np.median(score[seen])
    spread = max(robust_scale(score[seen]), 1e-12 * max(centre, 1e-12))
    bad = np.flatnonzero(seen & (score - centre > threshold * spread))
    if len(bad) > seen.sum() // 4:
        bad = bad[np.argsort(score[bad])[::-1][: seen.sum() // 4]]
    return np.sort(bad)


@dataclass(frozen=True)
class _Evaluation:
    fit: _Fit
    rx: np.ndarray
    scale: Scale | None  # on the pairs of the samples kept; None when the rotations misfit
    wrong: np.ndarray  # samples left out: their pairs misfit far more than the others'


@dataclass(frozen=True)
class _Motions:
    """The relative motions ``(P, 4, 4)`` of one reading over the pairs, their rotation
    vectors ``(P, 3)`` and rotation angles ``(P,)`` (rad): computed once per reading, shared by
    every combination of readings :func:`diagnose_readings` tries."""

    transforms: np.ndarray
    rotvecs: np.ndarray
    angles: np.ndarray


def _motions(poses: np.ndarray, pairs: np.ndarray) -> _Motions:
    rel = relative(poses, pairs)
    rotvecs = rotation_vectors(rel)
    return _Motions(rel, rotvecs, np.linalg.norm(rotvecs, axis=1))


def moving_pairs(
    q: np.ndarray, pairs: np.ndarray, prismatic: np.ndarray | None = None
) -> np.ndarray:
    """Which pairs ``(P,)`` join two different configurations: some joint differs by more than
    :data:`SAME_CONFIGURATION` (rad; a thousandth of it in m for the ``prismatic`` joints). A
    pair of one configuration recorded twice carries the robot's repeatability and the
    instrument's noise, no motion: it says nothing of units, conventions or the hand-eye
    transform."""
    q = np.asarray(q, dtype=float)
    slide = np.zeros(q.shape[1], dtype=bool) if prismatic is None else np.asarray(prismatic)
    same = np.where(slide, SAME_CONFIGURATION * 1e-3, SAME_CONFIGURATION)
    return np.any(np.abs(q[pairs[:, 0]] - q[pairs[:, 1]]) > same, axis=1)


def turning_pairs(
    flange: _Motions, measured: _Motions, moving: np.ndarray, tolerance
) -> np.ndarray:
    """Which pairs can show a rotation misfit above ``tolerance`` (rad): the misfit of a pair is
    at most the sum of its two rotation angles (the angle between rotations is a metric), so
    pairs that turn less together tell nothing (a cube of ISO 9283 keeps one orientation)."""
    return moving & (flange.angles + measured.angles > tolerance)


def _rotation(
    flange: _Motions, measured: _Motions, turning: np.ndarray, moving: np.ndarray
) -> tuple[np.ndarray, bool]:
    """:func:`handeye.handeye_rotation` of one reading: the rotation vectors of the pairs that
    turn, the translations of the pairs that move without turning."""
    still = moving & (flange.angles < PURE_TRANSLATION) & (measured.angles < PURE_TRANSLATION)
    rotvecs = (flange.rotvecs, measured.rotvecs)
    return handeye_rotation(flange.transforms, measured.transforms, turning, still, rotvecs)


def _refine_rotation(
    flange: _Motions, measured: _Motions, turning: np.ndarray, moving: np.ndarray, scale: Scale
) -> np.ndarray:
    """``R_X`` refitted with every moving pair's translation, ``t_X`` and ``s`` of ``scale``:
    ``(R_A - I) t_X + t_A = s R_X t_B``, beside the rotation vectors of the pairs that turn."""
    a_rel, b_rel = flange.transforms[moving], measured.transforms[moving]
    lhs = np.einsum("pij,j->pi", a_rel[:, :3, :3] - np.eye(3), scale.handeye_translation)
    lhs = lhs + a_rel[:, :3, 3]
    rhs = b_rel[:, :3, 3] / scale.ratio
    a = np.concatenate([flange.rotvecs[turning] * LEVER, lhs])
    b = np.concatenate([measured.rotvecs[turning] * LEVER, rhs])
    return tf.kabsch(a, b)


def _misfit_rank(pairs: np.ndarray) -> int:
    """``k`` (from 1) such that the rotation misfit :func:`_evaluate` finds on ``pairs`` (the
    pairs that turn) is at least the ``k``-th smallest of any per-pair lower bounds of the
    pairs' angles: the median over the pairs it keeps, at least ``max(6, P - the pairs of the
    quarter of the samples with the most pairs)`` of them (the samples left out are at most a
    quarter of those seen, and only when 10 pairs or more), is at least the ``ceil(kept /
    2)``-th smallest bound."""
    n_pairs = len(pairs)
    kept = n_pairs
    if n_pairs >= 10:
        degree = np.bincount(np.asarray(pairs, dtype=int).ravel())
        degree = np.sort(degree[degree > 0])[::-1]
        kept = max(min(6, n_pairs), n_pairs - int(degree[: len(degree) // 4].sum()))
    return (kept + 1) // 2


MISFIT_MARGIN = 1e-6  # rad: round-off of the computed angles, far below any tolerance


def _surely_misfit(
    flange: _Motions, measured: _Motions, pairs: np.ndarray, moving: np.ndarray, tolerance: float
) -> bool:
    """Whether a reading's rotation misfit (:func:`_evaluate`) is surely above ``tolerance``
    without finding ``R_X``: the angle of ``R_A^T R_X R_B R_X^T`` is at least the difference
    of the two motions' rotation angles whatever ``R_X`` (the angle between rotations is a
    metric, and conjugation keeps an angle), so the misfit over the pairs that turn is at least
    the ``rank``-th smallest difference among them (:func:`_misfit_rank`)."""
    turning = turning_pairs(flange, measured, moving, tolerance)
    if turning.sum() < MIN_PAIRS:
        return False
    floor = np.abs(flange.angles - measured.angles)[turning]
    rank = _misfit_rank(pairs[turning])
    if not 1 <= rank <= len(floor):
        return False
    return bool(np.partition(floor, rank - 1)[rank - 1] > tolerance + MISFIT_MARGIN)


def _evaluate(
    label, flange: _Motions, measured: _Motions, pairs, tolerance, moving=None
) -> _Evaluation:
    """How well one reading fits: rotations (median over the pairs that turn:
    :func:`turning_pairs`), then translations after the best hand-eye transform (median over
    the pairs that move: :func:`moving_pairs`, default all); the samples that misfit far more
    than the rest (a few wrong rows) are left out and the fit repeated, so that they do not pass
    for a wrong reading of all samples. ``R_X`` from rotations and translations
    (:func:`handeye.handeye_rotation`), refined with ``t_X`` and the scale."""
    moving = np.ones(len(pairs), dtype=bool) if moving is None else moving
    turning = turning_pairs(flange, measured, moving, tolerance)
    rx, known = _rotation(flange, measured, turning, moving)
    a, b = flange.transforms, measured.transforms
    wrong = np.zeros(0, dtype=int)
    misfit = float("nan")
    if turning.sum() >= MIN_PAIRS:
        angles = _pair_angles(a[turning], b[turning], rx)
        if turning.sum() >= 10:
            wrong = _wrong_samples(pairs[turning], angles)
        if wrong.size:
            kept = turning & ~np.isin(pairs, wrong).any(axis=1)
            if kept.sum() >= MIN_PAIRS:
                turning = kept
                moving = moving & ~np.isin(pairs, wrong).any(axis=1)
                rx, known = _rotation(flange, measured, turning, moving)
                angles = _pair_angles(a[turning], b[turning], rx)
            else:
                wrong = np.zeros(0, dtype=int)
        misfit = float(np.median(angles))
    if misfit > tolerance:
        return _Evaluation(_Fit(label, misfit, np.inf), rx, None, wrong)
    if not known or moving.sum() < MIN_PAIRS:
        return _Evaluation(_Fit(label, misfit, float("nan")), rx, None, wrong)
    scale = translation_scale(a[moving], b[moving], rx)
    for _ in range(3):  # R_X with the translations of every moving pair, t_X and s with it
        if scale.handeye_translation is None or not np.isfinite(scale.ratio) or scale.ratio <= 0:
            break
        rx = _refine_rotation(flange, measured, turning, moving, scale)
        scale = translation_scale(a[moving], b[moving], rx)
    if turning.sum() >= MIN_PAIRS:
        misfit = float(np.median(_pair_angles(a[turning], b[turning], rx)))
    if moving.sum() >= 10 and scale.handeye_translation is not None and np.isfinite(scale.ratio):
        sol = np.concatenate([scale.handeye_translation, [1.0 / scale.ratio]])
        am, bm = a[moving], b[moving]
        m = np.concatenate(
            [am[:, :3, :3] - np.eye(3), -np.einsum("ij,pj->pi", rx, bm[:, :3, 3])[:, :, None]],
            axis=2,
        )
        norms = np.linalg.norm(np.einsum("pij,j->pi", m, sol) + am[:, :3, 3], axis=1)
        more = _wrong_samples(pairs[moving], norms)
        keep = moving & ~np.isin(pairs, more).any(axis=1)
        if more.size and keep.sum() >= MIN_PAIRS:
            scale = translation_scale(a[keep], b[keep], rx)
            wrong = np.union1d(wrong, more)
    ratio = scale.ratio if scale.determined else float("nan")
    return _Evaluation(_Fit(label, misfit, scale.residual, ratio), rx, scale, wrong)


def _deg(angle: float, digits: int = 2) -> str:
    """A misfit angle (rad) for a message, or what it means when the data cannot tell."""
    if not np.isfinite(angle):
        return "(too few pairs turn to compare)"
    return f"{np.degrees(angle):.{digits}f} deg"


def _key(value: float) -> float:
    return value if np.isfinite(value) else np.inf


@dataclass(frozen=True)
class Words:
    """How :func:`diagnose_readings` names the robot's side of the comparison in its messages."""

    motions: str  # the relative motions the measured ones are compared with
    columns: str  # the robot's columns whose other readings were tried
    check: str  # what to check when no reading fits the rotations
    lengths: str  # the robot's lengths, for translations that do not fit


JOINT_WORDS = Words(
    "commanded ones",
    "joint order, signs and unit",
    "Check the robot model, and whether these samples belong to this robot",
    "the robot model's link lengths",
)
FLANGE_WORDS = Words(
    "logged flange motions",
    "flange quaternion order and pose direction",
    "Check that each row's flange pose and measured pose were recorded together (the same "
    "moment, the same row), and the flange columns (fx .. fqw: the flange in the robot's base "
    "frame)",
    "the flange positions' unit",
)


def diagnose_readings(
    q: np.ndarray,
    poses: np.ndarray,
    fk: Callable[[np.ndarray], np.ndarray],
    joints: Sequence[Reading],
    measured: Sequence[Reading],
    tolerances: Tolerances,
    pairs: np.ndarray,
    given_valid: bool = True,
    moving: np.ndarray | None = None,
    words: Words | None = None,
) -> tuple[str | None, _Evaluation | None]:
    """``None`` and the evaluation of the data as given (``R_X``, the scale found, the samples
    whose pairs misfit far more than the others') when they agree with the model; else a message
    naming the reading that fits (an alternative of the joints, of the poses, or one of each),
    or saying by how much nothing does.

    Only motions that carry information count: the rotations over the pairs that turn
    (:func:`turning_pairs`), the translations over the pairs that move (``moving``, default
    all: :func:`moving_pairs` leaves out a configuration recorded again). The rotations decide
    first (their agreement does not depend on the hand-eye transform); the translations (after
    the best hand-eye transform and scale, median over the pairs, robust to a few wrong samples)
    decide between readings the rotations cannot tell apart: two parallel joints swapped turn
    the flange alike and move it differently. A reading is named only when it fits (both within
    the tolerances, with a plausible scale: :meth:`_Fit.fits`) and 3 times better than the data
    as given; ``given_valid`` False (readings beyond the joint limits) lets any reading that
    fits be named. What the data cannot tell (too few pairs turn, ``R_X`` not determined) is
    never a reason to refuse. ``words``: what the messages call the robot's motions and what
    they advise (:data:`JOINT_WORDS` by default)."""
    words = words or JOINT_WORDS
    tol, tol_t = tolerances.rotation, tolerances.translation
    moving = np.ones(len(pairs), dtype=bool) if moving is None else np.asarray(moving, bool)
    flange = fk(q) if given_valid else None
    evaluation = None
    given_motions = _motions(poses, pairs)
    if flange is not None:
        evaluation = _evaluate("", _motions(flange, pairs), given_motions, pairs, tol, moving)
        given = evaluation.fit
        if not given.misfit > tol / 5 and not given.translation > tol_t / 2:
            return None, evaluation  # the right data (or data that cannot tell): nothing to try
    else:
        given = _Fit("", np.inf, np.inf)
    fits: list[_Fit] = []
    reads: dict = {None: given_motions}  # each reading's motions, computed once
    for jr in [None, *joints]:
        flange_jr = flange if jr is None else fk(jr.joints(q))
        if flange_jr is None:
            continue
        moved = None
        for pr in [None, *measured]:
            if jr is None and pr is None:
                continue
            if jr is not None and pr is not None and "position columns" in pr.label:
                continue  # one mix-up of the positions at a time
            label = " and ".join(r.label for r in (jr, pr) if r is not None)
            if pr not in reads:
                reads[pr] = _motions(pr.poses(poses), pairs)  # type: ignore[union-attr]
            moved = moved or _motions(flange_jr, pairs)
            if _surely_misfit(moved, reads[pr], pairs, moving, tol):
                continue  # its rotations do not fit: not a reading that fits, never named
            fits.append(_evaluate(label, moved, reads[pr], pairs, tol, moving).fit)
    fitting = [f for f in fits if f.fits(tolerances)]
    best = min(fitting, key=lambda f: (_key(f.translation), _key(f.misfit)), default=None)
    if best is not None:
        if given.misfit > tol:  # (a reading whose pairs barely turn fits in rotation)
            better = not best.misfit >= given.misfit / RATIO
        else:  # the rotations agree as given: the translations must be 3x better, or the
            # rotations 3x better with translations as good
            better = best.translation < given.translation / RATIO or (
                best.misfit < given.misfit / RATIO and best.translation <= given.translation
            )
        if better:
            alike = [
                f.label for f in fitting if _key(f.translation) <= 1.5 * best.translation + 1e-6
            ] or [best.label]
            alike = sorted(alike, key=lambda label: label.count(" and "))[:3]
            return (
                f"{' or '.join(alike)}: read that way the relative rotations agree with the "
                f"{words.motions} to {_deg(best.misfit)} and the relative translations to "
                f"{best.translation * 1e3:.3g} mm (median); as given "
                + (
                    "some joint readings are beyond their limits"
                    if not given_valid
                    else f"they disagree by {_deg(given.misfit, 1)} and "
                    + (
                        f"{given.translation * 1e3:.3g} mm"
                        if np.isfinite(given.translation)
                        else "translations not comparable"
                    )
                ),
                evaluation,
            )
    if not given_valid:
        return None, None  # the caller names the readings beyond the limits
    if given.misfit > tol:
        turning = turning_pairs(_motions(flange, pairs), given_motions, moving, tol)
        a, b = relative(flange, pairs[turning]), relative(poses, pairs[turning])
        return (
            f"measured relative rotations disagree with the {words.motions} by a median "
            f"{np.degrees(given.misfit):.1f} deg over the {turning.sum()} pairs that turn (their "
            f"rotation angles alone by {np.degrees(angle_misfit(a, b)):.1f} deg; expected < "
            f"{np.degrees(tol):.1f} deg for any hand-eye transform), and no other reading of the "
            f"columns ({words.columns}; quaternion order; pose direction) fits. {words.check}",
            evaluation,
        )
    if given.translation > tol_t:
        return (
            f"measured relative translations disagree with the {words.motions} by a median "
            f"{given.translation * 1e3:.4g} mm after the best hand-eye transform (expected < "
            f"{tol_t * 1e3:.3g} mm, translation_mm in dataset.yaml tolerances), while the "
            f"rotations agree to {_deg(given.misfit)}, and no other reading of "
            f"the columns fits. Check the x, y, z columns (order, signs), {words.lengths}, and "
            "whether the poses are of the flange-mounted camera",
            evaluation,
        )
    return None, evaluation


def check_inputs(
    model,
    q: np.ndarray,
    poses: np.ndarray,
    ids: Sequence[str],
    where: str,
    *,
    fk: Callable[[np.ndarray], np.ndarray],
    mode: str = "eye_in_hand",
    handeye: np.ndarray | None = None,
    board=None,
    poses_given: bool = True,
    spec: str | None = None,
    tolerances: Tolerances = Tolerances(),
    joint_unit: str | None = None,
    pose_angle_unit: str | None = None,
    euler: str | None = None,
) -> Scale:
    """Raise :class:`RelcalError` naming the likely cause when the samples cannot be what the
    model commands; return the translation scale found (``determined`` False if the motions
    cannot tell). ``joint_unit``, ``pose_angle_unit`` and ``euler``: as dataset.yaml declares
    them (None: not known, or no roll-pitch-yaw poses), for the unit and sequence mix-ups to
    name.

    ``q`` ``(N, n)`` rad, ``poses`` ``(N, 4, 4)`` the measured ``C_k`` of usable samples, ``fk``
    the nominal forward kinematics, ``where`` the file named in messages about samples and
    ``spec`` the one about the hand-eye guess (dataset.yaml).

    Readings that might have been meant (:func:`joint_readings`, :func:`pose_readings`) are
    tried when the data as given do not fit, and the one that fits is named with its fix: a
    suggestion that, followed, gives data that pass.
    """
    spec = spec or where
    problems = joint_problems(
        q, model.lower, model.upper, model.prismatic, model.joint_names, ids, tolerances.joint_limit
    )
    _check_magnitudes(poses, ids, handeye, where, spec)
    pairs = check_pairs(len(q))
    moving = moving_pairs(q, pairs, model.prismatic)
    joints = joint_readings(model, q, tolerances.joint_limit, joint_unit)
    measured = pose_readings(mode, poses_given, pose_angle_unit, euler)
    few = bool(problems) and all("a mistyped reading" in p for p in problems)
    message, given = diagnose_readings(
        q, poses, fk, joints, measured, tolerances, pairs, not problems or few, moving
    )
    if message and not (problems and few):
        raise RelcalError(f"{where}: {message}")
    if problems:
        raise RelcalError(f"{where}: " + "\n".join(problems))
    # The step search linearises about X: the data's own hand-eye, not a guess from a drawing
    # (a guess off by degrees bends the frames' scatter past the linear fit and passes for a
    # step: 8 mm on clean synthetic data with the 12 deg guess of the tests' sets).
    try:
        x = solve_handeye(fk(q), poses)
    except RelcalError:
        x = handeye  # the motions fix no hand-eye transform: the guess, or nothing to tell
    moved = None if x is None else moved_frame(model, q, poses, x, fk)
    if moved is not None:
        raise RelcalError(f"{where}: {moved_message(ids, moved[0], moved[1], len(q), mode)}")
    return _check_scale_and_guess(given, handeye, board, poses_given, where, spec, tolerances)


def _check_magnitudes(
    poses: np.ndarray, ids: Sequence[str], handeye: np.ndarray | None, where: str, spec: str
) -> None:
    """Measured positions in millimetres or absurd, a hand-eye guess in millimetres."""
    units = position_problems(poses, ids)
    if units:
        raise RelcalError(f"{where}: " + "\n".join(units))
    if handeye is not None and np.linalg.norm(handeye[:3, 3]) > 2.0:
        xyz = np.array2string(handeye[:3, 3], precision=4)
        raise RelcalError(
            f"{spec}: handeye: xyz {xyz} m is {np.linalg.norm(handeye[:3, 3]):.4g} m from the "
            "flange: looks like millimetres (give metres)"
        )


def _check_scale_and_guess(
    given: _Evaluation,
    handeye: np.ndarray | None,
    board,
    poses_given: bool,
    where: str,
    spec: str,
    tolerances: Tolerances,
    model_word: str = "the robot model",
) -> Scale:
    """The data as given fit in rotation: their translation scale (a wrong unit or board size)
    and the hand-eye guess against what they say; the scale found."""
    rx, scale, misfit = given.rx, given.scale, given.fit.misfit
    if scale is None or not scale.determined:
        scale = scale or Scale(float("nan"), float("inf"), False)
        return replace(scale, rotation_misfit=misfit)
    if scale_problem(scale, tolerances):
        message = scale_message(scale.ratio, board, poses_given, model_word)
        raise RelcalError(f"{where}: {message}")
    if handeye is not None:
        tx = scale.handeye_translation if scale.translation_known else None
        message = guess_problem(handeye, rx, tx)
        if message:
            raise RelcalError(f"{spec}: {message}")
    return replace(scale, rotation_misfit=misfit)


SAME_FLANGE = 5e-5  # m: flange poses this close (and SAME_CONFIGURATION in rad) are one pose


FLANGE_WFIRST = (
    "flange quaternions look w-first (fqx, fqy, fqz, fqw expected in x, y, z, w order; fix: name "
    "the columns fqw, fqx, fqy, fqz in the header)"
)
FLANGE_INVERTED = (
    "flange poses look inverted (the base in the flange frame given, the flange in the robot's "
    "base frame expected; fix: export the flange pose in the base frame)"
)


def _either_inverted(flange: np.ndarray, poses: np.ndarray, message: str, label: str) -> str:
    """``message`` named the measured poses inverted (``label``): the flange poses inverted fit
    exactly as well (``F^-1, C^-1`` is as consistent as ``F, C``, the roles of ``X`` and ``W``
    swapped), so both are named, with the distance from the flange each puts the camera at."""

    def distance(f: np.ndarray, c: np.ndarray) -> str:
        try:
            return f"{np.linalg.norm(solve_handeye(f, c)[:3, 3]):.3g} m"
        except RelcalError:
            return "not determined"

    at = message.find(": read that way")
    return (
        f"{FLANGE_INVERTED}, or {label}: the relative motions fit either reading alike (read "
        "the first way the camera or marker is "
        f"{distance(tf.invert(flange), poses)} from the flange, the second way "
        f"{distance(flange, tf.invert(poses))}); fix the one that is wrong"
        + (message[at:] if at >= 0 else "")
    )


def check_flange_inputs(
    flange: np.ndarray,
    poses: np.ndarray,
    ids: Sequence[str],
    where: str,
    *,
    mode: str = "eye_in_hand",
    handeye: np.ndarray | None = None,
    board=None,
    poses_given: bool = True,
    spec: str | None = None,
    tolerances: Tolerances = Tolerances(),
    pose_angle_unit: str | None = None,
    euler: str | None = None,
) -> Scale:
    """:func:`check_inputs` for flange poses logged by a controller (no robot model): the
    measured poses ``(N, 4, 4)`` against the flange poses ``(N, 4, 4)`` (m) by the relations
    that hold whatever the hand-eye transform, the same rotation angle and a common ``R_X`` for
    every relative motion, and one translation scale, and a fixed frame that moved mid-session
    (:func:`moved_frame`, no geometry fitted). Readings of the flange poses
    (w-first quaternions) and of the measured ones (:func:`pose_readings`) are tried when
    the data as given do not fit, and the one that fits is named with its fix (the flange poses
    inverted fit exactly as the measured poses inverted: both are named). Give the samples
    in an order of their own (the checks draw pairs by position beyond 63 samples). Returns
    the translation scale found."""
    spec = spec or where
    _check_magnitudes(poses, ids, handeye, where, spec)
    pairs = check_pairs(len(flange))
    rel = relative(flange, pairs)
    moving = (np.linalg.norm(rel[:, :3, 3], axis=1) > SAME_FLANGE) | (
        np.linalg.norm(rotation_vectors(rel), axis=1) > SAME_CONFIGURATION
    )

    measured = pose_readings(mode, poses_given, pose_angle_unit, euler)
    wfirst = [Reading(FLANGE_WFIRST, joints=reorder_w_first)]
    message, given = diagnose_readings(
        flange, poses, lambda f: f, wfirst, measured, tolerances, pairs, True, moving, FLANGE_WORDS
    )
    if message and message.startswith(measured[0].label):  # the measured poses inverted
        message = _either_inverted(flange, poses, message, measured[0].label)
    if message:
        raise RelcalError(f"{where}: {message}")
    try:  # the step search linearises about the data's own X (see check_inputs)
        x = solve_handeye(flange, poses)
    except RelcalError:
        x = handeye
    if x is not None:
        flat = flange.reshape(len(flange), 16)
        moved = moved_frame(None, flat, poses, x, lambda v: v.reshape(-1, 4, 4))
        if moved is not None:
            text = moved_message(ids, moved[0], moved[1], len(flange), mode)
            raise RelcalError(f"{where}: {text}")
    return _check_scale_and_guess(
        given, handeye, board, poses_given, where, spec, tolerances, "the flange positions"
    )


def scale_problem(scale: Scale, tolerances: Tolerances = Tolerances()) -> bool:
    """Whether a determined translation scale is off: beyond ``tolerances.scale`` and beyond 3
    times what the data can tell, the larger of its standard deviation and the translations'
    misfit relative to their length (a robot's geometric errors stretch and turn the relative
    translations by a few percent over a small region, such as one ISO 9283 cube: that is
    model error, not a wrong unit or board size)."""
    if not scale.determined:
        return False
    off = abs(scale.ratio - 1.0)
    relative = scale.residual / scale.motion if scale.motion > 0 else 0.0
    return bool(off > tolerances.scale and off > 3 * max(scale.std * scale.ratio, relative))


MOVED_LENGTH = 0.005  # m: a step of the fixed frame smaller than this is not named
MOVED_ANGLE = np.radians(0.5)  # rad: likewise for its rotation
MOVED_FIT = 3.0  # the step stands this many times out of the residuals, and shrinks them so


def _frame_deviations(world: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``(N, 6)``: each sample's fixed frame against ``reference``, translation (m) then rotation
    vector times :data:`LEVER` (m)."""
    vec = tf.to_vector(tf.invert(reference) @ world)
    vec[:, 3:] *= LEVER
    return vec


def _frame_design(model, q, poses, handeye, fk) -> tuple[np.ndarray, np.ndarray]:
    """The deviations ``(N * 6,)`` of each sample's fixed frame ``W_k = C_k X^-1 F_k^-1`` from
    their centre, and their linearised dependence ``(N * 6, G + 12)`` on every geometric
    parameter (not the non-geometric candidates the model may carry) and on ``X`` (finite
    differences of the nominal model), with one common frame; ``model`` None: no geometric
    parameters (logged flange poses, the controller's own kinematics)."""
    from relcal.robot.kinematics import apply_errors, make_layout
    from relcal.robot.kinematics import fk as model_fk

    n = len(q)
    inv_x = tf.invert(handeye)
    world = poses @ inv_x @ tf.invert(fk(q))
    reference = tf.homogeneous(
        Rotation.from_matrix(world[:, :3, :3]).mean().as_matrix(), np.median(world[:, :3, 3], 0)
    )
    dev = _frame_deviations(world, reference)
    layout = make_layout(model) if model is not None else None
    geometric = np.flatnonzero(layout.is_geometric()) if layout is not None else []
    step = 1e-6
    columns = []
    for j in geometric:  # non-geometric candidates: not a smooth
        bump = np.zeros(layout.size)  # effect of the geometry, and the fit would follow a step
        bump[j] = step
        w = poses @ inv_x @ tf.invert(model_fk(apply_errors(model, layout, bump), q))
        columns.append(((_frame_deviations(w, reference) - dev) / step).reshape(-1))
    for j in range(6):
        vec = np.zeros(6)
        vec[j] = step
        w = poses @ tf.invert(handeye @ tf.from_vector(vec)) @ tf.invert(fk(q))
        columns.append(((_frame_deviations(w, reference) - dev) / step).reshape(-1))
    common = np.tile(np.eye(6), (n, 1))
    return dev.reshape(-1), np.concatenate([np.stack(columns, axis=1), common], axis=1)


class _Steps:
    """Robust fits of the frame deviations with and without a step between two groups."""

    def __init__(self, target: np.ndarray, design: np.ndarray) -> None:
        self.target, self.design, self.n = target, design, len(target) // 6

    def fit(self, matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A Huber fit (three reweightings at 1.5 robust standard deviations of the samples'
        residual norms, so that a few wrong samples do not pass for a step): the solution and
        the residuals ``(N, 6)``."""
        norm = np.linalg.norm(matrix, axis=0)
        norm[norm == 0] = 1.0
        scaled = matrix / norm
        weight = np.ones(self.n)
        for _ in range(3):
            rows = np.repeat(weight, 6)
            sol = np.linalg.lstsq(scaled * rows[:, None], self.target * rows, rcond=1e-8)[0]
            res = (self.target - scaled @ sol).reshape(self.n, 6)
            size = np.linalg.norm(res, axis=1)
            scale = 1.5 * max(robust_scale(size), float(np.median(size)), 1e-12)
            weight = np.sqrt(np.minimum(1.0, scale / np.maximum(size, 1e-300)))
        return sol / norm, res

    def split(self, group: np.ndarray):
        """The step between ``group`` and the rest, each sample moved to the side its residual
        fits, until nothing moves: (group, step (6,), residuals) or None."""
        n = self.n
        jump = after = None
        for _ in range(6):
            if min(group.sum(), n - group.sum()) < 3:
                return None
            indicator = np.zeros((n, 6, 6))
            indicator[group] = np.eye(6)
            sol, after = self.fit(np.concatenate([self.design, indicator.reshape(-1, 6)], 1))
            jump = sol[-6:]
            as_a = np.linalg.norm(after + np.where(group[:, None], jump, 0.0), axis=1)
            as_b = np.linalg.norm(after - np.where(group[:, None], 0.0, jump), axis=1)
            new = as_b < as_a
            if np.array_equal(new, group):
                break
            group = new
        return group, jump, after


def _typical(res: np.ndarray) -> float:
    return float(np.sqrt(np.median(np.sum(res**2, axis=1))))


MOVED_REDUNDANCY = 2.0  # rows beyond the parameters (with a step), per parameter, to tell one
MOVED_SEARCH = 300  # samples the search for a step uses (chosen by their joints, not order)


def moved_frame(
    model,
    q: np.ndarray,
    poses: np.ndarray,
    handeye: np.ndarray,
    fk: Callable[[np.ndarray], np.ndarray],
) -> tuple[np.ndarray, np.ndarray] | None:
    """Samples that see the fixed frame (the board, an eye-to-hand camera, the instrument)
    moved: ``(indices of the smaller group, the step (6,): m, rad)``, or None.

    Each sample's fixed frame ``W_k = C_k X^-1 F_k^-1`` (``poses`` ``(N, 4, 4)``, ``handeye``
    ``X``, ``fk`` the nominal kinematics) scatters with the robot's geometric errors, as a
    smooth function of the configuration; a moved board adds a step that no geometry explains.
    So the deviations of the ``W_k`` are fitted by the linearised effect of every geometric
    parameter and of ``X`` and one common frame (:func:`_frame_design`; robustly: a few wrong
    samples are down-weighted); then the samples are split in two and a step between the groups
    fitted too, each sample moved to the side its residual fits until none moves, started from
    each of the 5 samples that fit worst. The search runs on at most :data:`MOVED_SEARCH`
    samples (every k-th in the order of their joint values: the same whatever the row order),
    the split found is then settled on all. A step beyond :data:`MOVED_LENGTH` or
    :data:`MOVED_ANGLE`, :data:`MOVED_FIT` times the typical residual left, that makes the
    typical residual of the smaller group as many times smaller, with at least 3 samples on
    each side, is a moved frame. Fewer samples than :data:`MOVED_REDUNDANCY` rows per parameter
    beyond the parameters tell nothing (the geometry fits any split of them). ``model`` None:
    flange poses logged by the controller, ``q`` ``(N, 16)`` their flattened matrices and ``fk``
    what reshapes them, no geometric parameters fitted."""
    n = len(q)
    if n < 8:
        return None
    search = np.arange(n)
    if n > MOVED_SEARCH:
        order = np.lexsort(np.asarray(q, dtype=float).T[::-1])
        search = np.sort(order[:: int(np.ceil(n / MOVED_SEARCH))])
    target, design = _frame_design(model, q[search], poses[search], handeye, fk)
    norm = np.linalg.norm(design, axis=0)
    rank = np.linalg.matrix_rank(design / np.where(norm > 0, norm, 1.0), tol=1e-6)
    if len(target) - rank - 6 < MOVED_REDUNDANCY * (rank + 6):
        return None  # the geometry would fit any split: too few samples to tell a step
    steps = _Steps(target, design)
    _, residual = steps.fit(design)
    size = np.linalg.norm(residual, axis=1)
    best = None
    for seed in np.argsort(-size, kind="stable")[:5]:  # nearer to it than to a perfect fit
        found = steps.split(np.linalg.norm(residual - residual[seed], axis=1) < size)
        if found is not None and (best is None or _typical(found[2]) < _typical(best[2])):
            best = found
    if best is None or not _stands(best, residual):
        return None
    if len(search) < n:  # settled on every sample, from the step found
        target, design = _frame_design(model, q, poses, handeye, fk)
        steps = _Steps(target, design)
        _, residual = steps.fit(design)
        near = np.linalg.norm(residual - best[1], axis=1) < np.linalg.norm(residual, axis=1)
        best = steps.split(near)
        if best is None or not _stands(best, residual):
            return None
    group, jump, _ = best
    smaller = group if group.sum() <= len(group) - group.sum() else ~group
    jump = jump.copy()
    jump[3:] /= LEVER
    return np.flatnonzero(smaller), jump


def _stands(found: tuple, residual: np.ndarray) -> bool:
    """Whether a step (:meth:`_Steps.split`) is a moved frame: beyond :data:`MOVED_LENGTH` or
    :data:`MOVED_ANGLE`, :data:`MOVED_FIT` times the typical residual left, and making the
    typical residual of the smaller group as many times smaller."""
    group, jump, after = found
    smaller = group if group.sum() <= len(group) - group.sum() else ~group
    stands = np.linalg.norm(jump) > MOVED_FIT * _typical(after)
    better = _typical(residual[smaller]) > MOVED_FIT * _typical(after[smaller])
    big = np.linalg.norm(jump[:3]) > MOVED_LENGTH or np.linalg.norm(jump[3:]) > MOVED_ANGLE * LEVER
    return bool(big and stands and better)


def _natural(name: str) -> tuple:
    """A sort key that puts ``s2`` before ``s10``."""
    import re

    return tuple((0, int(p), "") if p.isdigit() else (1, 0, p) for p in re.split(r"(\d+)", name))


def moved_message(
    ids: Sequence[str], moved: np.ndarray, jump: np.ndarray, n: int, mode: str
) -> str:
    """The refusal naming the samples that saw the fixed frame moved (:func:`moved_frame`)."""
    what = "the camera" if mode == "eye_to_hand" else "the board (or the instrument)"
    names = sorted((str(ids[k]) for k in moved), key=_natural)
    listed = ", ".join(names[:8]) + (f" and {len(names) - 8} more" if len(names) > 8 else "")
    return (
        f"samples {listed} ({len(names)} of {n}) see {what} {np.linalg.norm(jump[:3]) * 1e3:.3g}"
        f" mm and {np.degrees(np.linalg.norm(jump[3:])):.3g} deg from where the other "
        f"{n - len(names)} see it, a step no error of the robot's geometry explains: it moved "
        "during the session. Calibrate each placement as a dataset of its own, or leave one "
        "group out (fix: remove those samples)"
    )


def guess_problem(
    guess: np.ndarray,
    rx: np.ndarray,
    tx: np.ndarray | None,
    max_angle: float = np.radians(30.0),
    max_distance: float = 0.2,
) -> str | None:
    """A hand-eye guess ``(4, 4)`` far from what the data say (rotation ``rx``, translation
    ``tx`` or None): a guess may be rough, but not off by more than ``max_angle`` or
    ``max_distance``, where the identification would start in the wrong valley."""
    angle = float(np.linalg.norm(tf.log_rotation(guess[:3, :3].T @ rx)))
    data = tf.homogeneous(rx, tx if tx is not None else guess[:3, 3])
    xyz, rpy = tf.to_xyz_rpy(data)
    said = f"the data say xyz {np.array2string(xyz, precision=3)} m, rpy "
    said += f"{np.array2string(np.degrees(rpy), precision=1)} deg"
    if angle > max_angle:
        return (
            f"handeye: the guess's rotation is {np.degrees(angle):.0f} deg from the one the data "
            f"say ({said}): fix rpy (degrees, roll-pitch-yaw) or leave handeye out"
        )
    if tx is not None and np.linalg.norm(guess[:3, 3] - tx) > max_distance:
        return (
            f"handeye: the guess's xyz is {np.linalg.norm(guess[:3, 3] - tx):.3g} m from the "
            f"translation the data say ({said}): fix xyz (metres) or leave handeye out"
        )
    return None


def scale_message(
    ratio: float, board, poses_given: bool, model_word: str = "the robot model"
) -> str:
    """Name the likely cause of measured translations ``ratio`` times the modelled ones
    (``model_word``: what gave the modelled ones)."""
    head = f"measured translations are {ratio:.4g}x the modelled ones"
    if 300 < ratio < 3000:
        return (
            f"poses look like millimetres ({head}); give x, y, z in metres (fix: x, y, z divided "
            "by 1000)"
        )
    if 0.0003 < ratio < 0.003:
        return (
            f"{model_word} looks like millimetres ({head}); give lengths in metres (fix: "
            f"{model_word}' lengths divided by 1000)"
        )
    if board is not None and not poses_given:
        what = "square" if board.type in ("chessboard", "charuco") else "spacing"
        return (
            f"board {what} looks {ratio:.3g}x the true size ({head}): {what} "
            f"{board.spacing:.6g} m in the board file, the data say {board.spacing / ratio:.4g} m "
            f"(fix: measure the printed board; {what} {board.spacing / ratio:.4g} m if it agrees)"
        )
    return f"{head}: a wrong length unit or scale of the poses, or a wrong robot model"


def check_corrections(
    names: Sequence[str],
    kinds: Sequence[str],
    params: np.ndarray,
    where: str,
    tolerances: Tolerances = Tolerances(),
) -> None:
    """Raise naming each identified correction larger than its kind's tolerance and the likely
    cause. ``kinds`` per entry: ``a``, ``d``, ``theta_off``, ``alpha``, ``beta``, ``handeye``,
    ``origin`` (URDF origins: ``.x``, ``.y``, ``.z`` lengths, ``.rx`` .. ``.rz`` angles);
    ``params`` in m and rad (hand-eye as translation then rotation vector)."""
    lines = []
    for k, (name, kind) in enumerate(zip(names, kinds, strict=True)):
        value = float(params[k])
        if kind in ("scale", "compliance"):
            continue  # not lengths or angles; their size is judged by model selection
        if kind == "handeye":
            comp = name.rsplit(".", 1)[-1]
            angle = comp.startswith("r")
            tol = tolerances.handeye_angle if angle else tolerances.handeye_length
            cause = (
                "the hand-eye guess in dataset.yaml is that far off (fix it or leave it out to "
                "estimate it), or the poses are wrong"
            )
            key = "handeye_deg" if angle else "handeye_mm"
        elif kind in ("a", "d") or (kind == "origin" and name[-1] in "xyz" and name[-2] == "."):
            angle, tol, key = False, tolerances.length, "length_mm"  # URDF origin x, y, z too
            cause = (
                "a wrong board size, poses in the wrong unit or a wrong robot model (a missing "
                "offset, another robot) absorbed by the link lengths"
            )
        else:
            angle, tol, key = True, tolerances.angle, "angle_deg"
            cause = "a wrong robot model (joint zero offsets, signs, twists) or joint readings"
        if abs(value) <= tol:
            continue
        unit, conv = ("deg", 180 / np.pi) if angle else ("mm", 1e3)
        lines.append(
            f"{name} corrected by {value * conv:+.4g} {unit} (tolerance {tol * conv:.3g} {unit}, "
            f"tolerances: {key} in dataset.yaml): not a calibration; likely {cause}"
        )
    if lines:
        raise RelcalError(
            f"{where}: identified corrections too large to be plausible:\n" + "\n".join(lines)
        )


# --- the two calls of the pipeline ---------------------------------------------------------------


def check_dataset(dataset, measurements) -> dict:
    """:func:`check_inputs` on the usable samples of a loaded dataset; messages name its
    samples file (or dataset.yaml for images). Returns what the checks measured, for the
    results: the median relative-rotation misfit (deg) and the translation scale (with the
    board size the data say, for images)."""
    from relcal.robot.kinematics import fk

    usable = np.flatnonzero(measurements.ok)
    if len(usable) < 4:
        check_joint_dataset(dataset, measurements)
        return {}
    where, spec = _where(dataset)
    q, poses = dataset.q[usable], measurements.poses[usable]
    scale = check_inputs(
        dataset.model,
        q,
        poses,
        [dataset.ids[i] for i in usable],
        where,
        fk=lambda v: fk(dataset.model, v),
        mode=dataset.mode,
        handeye=dataset.handeye,
        board=dataset.board,
        poses_given=dataset.poses is not None,
        spec=spec,
        tolerances=Tolerances.from_display(dataset.tolerances),
        joint_unit=getattr(dataset, "joint_unit", None),
        pose_angle_unit=getattr(dataset, "pose_angle_unit", None),
        euler=getattr(dataset, "euler", None),
    )
    out: dict = {}
    if np.isfinite(scale.rotation_misfit):  # over the pairs that turn
        out["rotation_misfit_deg"] = float(np.degrees(scale.rotation_misfit))
    if scale.determined:
        out["translation_scale"] = float(scale.ratio)
        out["translation_scale_std"] = float(scale.std * scale.ratio)
        if dataset.board is not None and dataset.poses is None:
            out["board_spacing_from_data_m"] = float(dataset.board.spacing / scale.ratio)
    return out


def check_handeye_dataset(
    dataset, flange: np.ndarray, poses: np.ndarray, order: np.ndarray, mode: str
) -> None:
    """The checks of :func:`check_dataset` for a hand-eye job, on its usable samples ``order``
    (indices into the dataset, in an order of their own) with their flange poses ``(N, 4, 4)``
    and measured poses ``(N, 4, 4)``: :func:`check_flange_inputs` for logged flange poses,
    :func:`check_inputs` for joints and a robot model. Raises :class:`RelcalError` naming the
    likely cause."""
    from relcal.robot.kinematics import fk

    where, spec = _where(dataset)
    ids = [dataset.ids[i] for i in order]
    common = {
        "mode": mode,
        "handeye": dataset.handeye,
        "board": dataset.board,
        "poses_given": dataset.poses is not None,
        "spec": spec,
        "tolerances": Tolerances.from_display(dataset.tolerances),
        "pose_angle_unit": getattr(dataset, "pose_angle_unit", None),
        "euler": getattr(dataset, "euler", None),
    }
    if dataset.flange is not None:
        check_flange_inputs(flange, poses, ids, where, **common)
    else:
        model = dataset.model
        q = np.asarray(dataset.q)[order]
        joint_unit = getattr(dataset, "joint_unit", None)
        check_inputs(
            model, q, poses, ids, where, fk=lambda v: fk(model, v), joint_unit=joint_unit, **common
        )


def _where(dataset) -> tuple[str, str]:
    """The file named in messages about samples (the samples file, dataset.yaml for images, the
    arrays of :meth:`Dataset.from_arrays`) and the dataset.yaml."""
    spec = dataset.spec_path or dataset.root / "dataset.yaml"
    samples = getattr(dataset, "samples_path", None) or spec.parent / "samples.csv"
    where = str(samples) if dataset.poses is not None else str(spec)
    if dataset.spec_path is None:  # Dataset.from_arrays: no file to name
        kind = {"position": "points", "coincidence": "joints"}.get(dataset.measured, "poses")
        where = f"{kind} (Dataset.from_arrays)" if dataset.poses is not None else "images"
    return where, str(spec)


def point_misfit(flange: np.ndarray, points: np.ndarray) -> float:
    """Median distance (m) of measured points ``(N, 3)`` from the modelled ``T F_k m`` with the
    instrument transform ``T`` and the marker ``m`` that fit best
    (:func:`~relcal.calibration.handeye.solve_instrument`); NaN when the points do not span
    three dimensions (nothing to tell)."""
    from relcal.calibration.handeye import solve_instrument

    try:
        instrument, marker = solve_instrument(flange, points)
    except RelcalError:
        return float("nan")
    in_base = flange[:, :3, :3] @ marker + flange[:, :3, 3]
    modelled = in_base @ instrument[:3, :3].T + instrument[:3, 3]
    return float(np.median(np.linalg.norm(points - modelled, axis=1)))


def check_points(
    model,
    q: np.ndarray,
    points: np.ndarray,
    ids: Sequence[str],
    where: str,
    *,
    fk: Callable[[np.ndarray], np.ndarray],
    tolerances: Tolerances = Tolerances(),
    joint_unit: str | None = None,
) -> float:
    """The checks of absolute points (a tracker's reflector, a marker) before anything is fitted,
    those of poses where they apply: readings beyond the joint limits, points beyond any cell
    (:func:`position_problems`), and the chain: the points against the commanded flange
    positions with the best instrument transform and marker (:func:`point_misfit`), within
    ``tolerances.translation`` (median) when the data are this robot's, in its joint order and
    unit. When they are not, the joint readings that might have been meant
    (:func:`joint_readings`) are tried and one that fits (3 times better, and within the
    tolerance) is named with its fix. Returns the median misfit (m; NaN when the points cannot
    tell). ``q`` ``(N, n)`` rad, ``points`` ``(N, 3)`` m."""
    poses = tf.homogeneous(np.broadcast_to(np.eye(3), (len(points), 3, 3)), points)
    units = position_problems(poses, ids)
    if units:
        raise RelcalError(f"{where}: " + "\n".join(units))
    problems = joint_problems(
        q, model.lower, model.upper, model.prismatic, model.joint_names, ids, tolerances.joint_limit
    )
    few = bool(problems) and all("a mistyped reading" in p for p in problems)
    tol = tolerances.translation
    given = point_misfit(fk(q), points) if not problems or few else np.inf
    if not given > tol / 2 and not problems:
        return given
    tried = []
    for reading in joint_readings(model, q, tolerances.joint_limit, joint_unit):
        misfit = point_misfit(fk(reading.joints(q)), points)  # type: ignore[misc]
        if misfit <= tol:
            tried.append((misfit, reading.label))
    tried.sort()
    if tried and not tried[0][0] >= given / RATIO:
        best = tried[0][0]
        alike = [label for m, label in tried if m <= 1.5 * best + 1e-6][:3]
        as_given = (
            "some joint readings are beyond their limits"
            if not np.isfinite(given)
            else f"they disagree by {given * 1e3:.3g} mm"
        )
        raise RelcalError(
            f"{where}: {' or '.join(alike)}: read that way the measured points agree with the "
            f"commanded flange positions to {best * 1e3:.3g} mm (median, after the best "
            f"instrument transform and marker); as given {as_given}"
        )
    if problems and not few:
        raise RelcalError(f"{where}: " + "\n".join(problems))
    if given > tol:
        raise RelcalError(
            f"{where}: measured points disagree with the commanded flange positions by a median "
            f"{given * 1e3:.4g} mm after the best instrument transform and marker (expected < "
            f"{tol * 1e3:.3g} mm, translation_mm in dataset.yaml tolerances), and no other "
            "reading of the joint columns (order, signs, unit) fits. Check the robot model (its "
            "root and tip links: another arm?), and whether these samples belong to this robot"
        )
    if problems:
        raise RelcalError(f"{where}: " + "\n".join(problems))
    return given


def check_point_dataset(dataset, measurements) -> dict:
    """:func:`check_points` on the usable samples of a loaded dataset of points; returns what
    the checks measured (the median point misfit at the nominal model, mm)."""
    from relcal.robot.kinematics import fk

    usable = np.flatnonzero(measurements.ok)
    where, _ = _where(dataset)
    misfit = check_points(
        dataset.model,
        dataset.q[usable],
        measurements.poses[usable, :3, 3],
        [dataset.ids[i] for i in usable],
        where,
        fk=lambda v: fk(dataset.model, v),
        tolerances=Tolerances.from_display(dataset.tolerances),
        joint_unit=getattr(dataset, "joint_unit", None),
    )
    return {"point_misfit_mm": float(misfit * 1e3)} if np.isfinite(misfit) else {}


def check_joint_dataset(dataset, measurements) -> None:
    """The joint readings of a loaded dataset's usable samples against the model's limits
    (:func:`joint_problems`): the check every kind shares, also where nothing else about the
    measurements can be checked before a fit (coincidences: their points are unknown)."""
    usable = np.flatnonzero(measurements.ok)
    where, _ = _where(dataset)
    model = dataset.model
    problems = joint_problems(
        dataset.q[usable],
        model.lower,
        model.upper,
        model.prismatic,
        model.joint_names,
        [dataset.ids[i] for i in usable],
        Tolerances.from_display(dataset.tolerances).joint_limit,
    )
    if problems:
        raise RelcalError(f"{where}: " + "\n".join(problems))


def check_result(dataset, problem, result, what: str | None = None) -> None:
    """:func:`check_corrections` on an identification result (``problem.full_layout`` order):
    the kinematic corrections. The measurement frames are free: a tracker's instrument transform
    and marker, a coincidence's tool point and group points, a board transform, and the hand-eye
    transform, whether its start was given (a guess in dataset.yaml may be rough; its
    plausibility is checked against the data beforehand, :func:`guess_problem`) or estimated
    from the data (:func:`~relcal.calibration.handeye.solve_handeye` with the nominal
    kinematics: what the motions leave undetermined there, such as the translation along the one
    axis that two tool orientations turn about, the geometry may determine, and the fit then
    moves it far from the start, rightly). A wrong input shows in the kinematic corrections
    checked here and in the inputs' checks; the frames' shift from the baseline's is warned of
    (:func:`frame_shifts`). With ``what`` (how the samples are called, e.g. ``points``), refused
    corrections below 3 standard deviations are named as not determined by the data."""
    layout = problem.full_layout
    free = ("board", "instrument", "marker", "tool_point", "point", "handeye")
    keep = [k for k, kind in enumerate(layout.kinds) if kind not in free]
    try:
        check_corrections(
            [layout.names[k] for k in keep],
            [layout.kinds[k] for k in keep],
            result.params[keep],
            str(dataset.spec_path or dataset.root),
            Tolerances.from_display(dataset.tolerances),
        )
    except RelcalError as exc:
        if what is None:
            raise
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.abs(result.params) / result.std
        names = layout.names
        weak = [n for k, n in enumerate(names) if f"{n} corrected by" in str(exc) and z[k] < 3.0]
        if not weak:
            raise
        if getattr(result, "prior", None) is None:  # a plain least squares (priors: none)
            remedy = (
                "the default priors hold such parameters at their manufacturing tolerances "
                "(leave out priors: none in the model file and --priors none)"
            )
        else:
            remedy = "even held by their priors: check the inputs (units, robot model, rows)"
        raise RelcalError(
            f"{exc}\n{', '.join(weak)}: not determined by these {what} (|error| below 3 standard "
            f"deviations); {remedy}"
        ) from None


# --- the one gate before a model is written -------------------------------------------------------

# Largest plausible non-geometric terms (SI): a joint scale of 5 %, a compliance of 5 deg per
# N m (0.1 mm per N for a prismatic joint), a first harmonic of 2 deg. Beyond them a term absorbs
# something else (a wrong unit, a wrong model, a weak direction).
NONGEOMETRIC_BOUNDS = {
    "scale": (0.05, "1"),
    "compliance": (np.radians(5.0), "rad/(N m)"),
    "harmonic_c": (np.radians(2.0), "rad"),
    "harmonic_s": (np.radians(2.0), "rad"),
}
PRISMATIC_COMPLIANCE = 1e-4  # m/N
STD_WARN = 3.0  # predicted and bootstrap standard deviations differ by more: a warning
STD_REFUSE = 10.0  # ... by more than this for the median parameter: refused
# A bootstrap of few samples draws degenerate sets (a resampling of 10 samples holds about 6
# distinct ones): compared only from this many training samples, refused only from the next.
STD_MIN_SAMPLES = 20
STD_REFUSE_SAMPLES = 40
# Below STD_MIN_SAMPLES a bootstrap is rough (a factor of a few), never orders of magnitude off:
# a median predicted std this many times below it is refused whatever the number of samples.
STD_FEW = 100.0


def nongeometric_problems(
    names: Sequence[str], kinds: Sequence[str], units: Sequence[str], params: np.ndarray
) -> list[str]:
    """One line per non-geometric term beyond :data:`NONGEOMETRIC_BOUNDS` (``params`` SI)."""
    from relcal.robot.kinematics import DISPLAY_UNITS

    lines = []
    for name, kind, unit, value in zip(names, kinds, units, params, strict=True):
        if kind not in NONGEOMETRIC_BOUNDS:
            continue
        bound = PRISMATIC_COMPLIANCE if unit == "m/N" else NONGEOMETRIC_BOUNDS[kind][0]
        if abs(value) <= bound:
            continue
        factor, shown = DISPLAY_UNITS[unit]
        lines.append(
            f"{name} = {value * factor:+.4g} {shown} (bound {bound * factor:.3g} {shown}): a term "
            "this large absorbs something else (a wrong unit or model, a direction the data do "
            "not determine)"
        )
    return lines


def frame_shifts(
    names: Sequence[str],
    kinds: Sequence[str],
    calibrated: np.ndarray,
    baseline: np.ndarray,
    tolerances: Tolerances = Tolerances(),
) -> list[str]:
    """Warnings where the calibrated model's measurement frames (hand-eye, instrument
    transform, marker, tool point) moved from the baseline's by more than the hand-eye
    tolerances: the kinematic corrections then take over part of a frame."""
    lines = []
    for kind in ("handeye", "instrument", "marker", "tool_point"):
        idx = [k for k, kd in enumerate(kinds) if kd == kind]
        if not idx:
            continue
        diff = np.asarray(calibrated, float)[idx] - np.asarray(baseline, float)[idx]
        length = float(np.linalg.norm(diff[:3]))
        angle = float(np.linalg.norm(diff[3:6])) if len(diff) >= 6 else 0.0
        if length > tolerances.handeye_length or angle > tolerances.handeye_angle:
            what = {"handeye": "hand-eye transform", "instrument": "instrument transform"}
            lines.append(
                f"the {what.get(kind, kind.replace('_', ' '))} of the calibrated model differs "
                f"from the baseline's by {length * 1e3:.3g} mm and {np.degrees(angle):.3g} "
                "deg: the kinematic corrections take over part of it (check the corrections "
                "named with it)"
            )
    return lines


def joint_limit_warnings(
    model, layout, params: np.ndarray, q: np.ndarray, tolerances: Tolerances = Tolerances()
) -> list[str]:
    """Warnings where a training configuration, read with the calibrated zero offsets, lies
    beyond the model's joint limits by more than ``tolerances.joint_limit``."""
    lines = []
    for k, (kind, i) in enumerate(zip(layout.kinds, layout.index, strict=True)):
        if kind != "theta_off" or model.prismatic[i] or params[k] == 0:
            continue
        value = q[:, i] + params[k]
        beyond = max(
            float(np.max(model.lower[i] - value, initial=-np.inf)),
            float(np.max(value - model.upper[i], initial=-np.inf)),
        )
        if np.isfinite(beyond) and beyond > tolerances.joint_limit:
            lines.append(
                f"{layout.names[k]} {np.degrees(params[k]):+.3g} deg puts {model.joint_names[i]} "
                f"{np.degrees(beyond):.3g} deg beyond its limits in the training samples"
            )
    return lines


def std_consistency(
    names: Sequence[str],
    predicted: np.ndarray,
    bootstrap: np.ndarray,
    display: tuple[np.ndarray, Sequence[str]] | None = None,
) -> tuple[list[str], str | None]:
    """Predicted standard deviations against the bootstrap's (both ``(P,)``, NaN where not
    estimated): a warning for the parameters whose predicted std is more than :data:`STD_WARN`
    times smaller than the bootstrap's (overconfident intervals), one for those more than that
    larger (conservative intervals), and a refusal (its message) when the median parameter's
    predicted std is more than :data:`STD_REFUSE` times smaller (the noise model does not
    describe the data, and every interval would be too narrow). ``display``: factors from SI
    and units for the messages (:meth:`Layout.display`; default SI)."""
    predicted, bootstrap = np.asarray(predicted, float), np.asarray(bootstrap, float)
    both = np.isfinite(predicted) & np.isfinite(bootstrap) & (predicted > 0) & (bootstrap > 0)
    if not both.any():
        return [], None
    ratio = np.ones_like(predicted)  # bootstrap over predicted: above 1, overconfident
    ratio[both] = bootstrap[both] / predicted[both]
    factor, unit = display if display is not None else (np.ones(len(names)), ("SI",) * len(names))

    def listed(ks: np.ndarray) -> str:
        shown = [
            f"{names[k]} {predicted[k] * factor[k]:.3g} vs {bootstrap[k] * factor[k]:.3g} {unit[k]}"
            for k in ks[:6]
        ]
        return ", ".join(shown) + (f" and {len(ks) - 6} more" if len(ks) > 6 else "")

    warn = []
    narrow = np.flatnonzero(both & (ratio > STD_WARN))
    if len(narrow):
        warn.append(
            f"predicted standard deviations more than {STD_WARN:g}x below the bootstrap's "
            f"(intervals too narrow): {listed(narrow)}"
        )
    wide = np.flatnonzero(both & (ratio < 1 / STD_WARN))
    if len(wide):
        warn.append(
            f"predicted standard deviations more than {STD_WARN:g}x above the bootstrap's "
            f"(intervals conservative): {listed(wide)}"
        )
    median = float(np.median(ratio[both]))
    refuse = None
    if both.sum() >= 3 and median > STD_REFUSE:
        refuse = (
            f"the bootstrap's standard deviations are {median:.3g}x the predicted ones for the "
            "median parameter: the noise model does not describe these data, and every interval "
            "would be too narrow (check for correlated, repeated or mislabelled samples)"
        )
    return warn, refuse


def check_calibration(
    dataset,
    problem,
    result,
    baseline=None,
    bootstrap: np.ndarray | None = None,
    what: str | None = None,
    q: np.ndarray | None = None,
    links: bool = True,
) -> list[str]:
    """The plausibility gate every calibration passes before a model is written (all measurement
    kinds, the command line, the Python API and the fleet: :func:`pipeline.calibrate` calls it).

    Refuses (:class:`RelcalError`) link corrections beyond the tolerances (:func:`check_result`),
    non-geometric terms beyond :data:`NONGEOMETRIC_BOUNDS` and predicted standard deviations
    grossly inconsistent with the bootstrap's; returns warnings: frames moved from the
    baseline's, zero offsets that put training samples beyond the joint limits, standard
    deviations more than :data:`STD_WARN` apart (from :data:`STD_MIN_SAMPLES` training samples;
    refused from :data:`STD_REFUSE_SAMPLES`; with fewer samples refused when :data:`STD_FEW`
    times apart, orders of magnitude no rough bootstrap explains). ``what``: how the samples are
    called (points, placements) for the messages; ``q``: the training joint values;
    ``links``: whether the link corrections are checked here (False: the measurement kind
    checked them, its frames free).
    """
    if links:
        check_result(dataset, problem, result, what)
    layout = problem.full_layout
    where = str(dataset.spec_path or dataset.root)
    lines = nongeometric_problems(layout.names, layout.kinds, layout.units(), result.params)
    if lines:
        raise RelcalError(
            f"{where}: identified non-geometric terms too large to be plausible:\n"
            + "\n".join(lines)
            + "\n(fix: check the inputs; --nongeometric none leaves these terms out)"
        )
    tol = Tolerances.from_display(dataset.tolerances)
    warnings: list[str] = []
    if baseline is not None:
        warnings += frame_shifts(layout.names, layout.kinds, result.params, baseline.params, tol)
    if q is not None:
        warnings += joint_limit_warnings(problem.model, layout, result.params, q, tol)
    n = len(problem.q) if q is None else len(q)
    if bootstrap is not None and n >= STD_MIN_SAMPLES:
        std_warnings, refuse = std_consistency(
            layout.names, result.std, bootstrap, layout.display()
        )
        if refuse and n >= STD_REFUSE_SAMPLES:
            raise RelcalError(f"{where}: {refuse}")
        warnings += std_warnings
    elif bootstrap is not None:
        ratio = median_std_ratio(result.std, bootstrap)
        if ratio > STD_FEW:
            raise RelcalError(
                f"{where}: the predicted standard deviations are {ratio:.3g}x below the "
                f"bootstrap's for the median parameter: the noise learned from {n} training "
                "samples is not a noise level (a fit that leaves almost no residual), and every "
                f"interval would be meaningless; collect more samples ({STD_MIN_SAMPLES} or more) "
                "and calibrate again"
            )
    return warnings


def median_std_ratio(predicted: np.ndarray, bootstrap: np.ndarray) -> float:
    """The median over the parameters estimated by both of the bootstrap's standard deviation
    over the predicted one (NaN when none is)."""
    predicted, bootstrap = np.asarray(predicted, float), np.asarray(bootstrap, float)
    both = np.isfinite(predicted) & np.isfinite(bootstrap) & (predicted > 0) & (bootstrap > 0)
    return float(np.median(bootstrap[both] / predicted[both])) if both.any() else float("nan")
