"""Hand-eye calibration as a job of its own: every closed form beside the refined estimate, scored
on the same held-out samples.

``C_k = W F_k X`` (:mod:`relcal.calibration.handeye_closed`) in three modes; what is delivered:

- ``eye_in_hand``: ``X``, the camera on the flange (parent: the flange, child: the camera);
- ``eye_to_hand``: ``W^-1``, the fixed camera in the robot's base frame (``X``, the board on the
  flange, is a by-product);
- ``robot_world``: both, ``X`` (the camera or marker on the flange) and ``W`` (the robot's base in
  the world frame: parent the world, child the base).

The flow (:func:`handeye`): the closed forms on the informative samples; the refined estimate
(:mod:`relcal.calibration.handeye_fit`: reprojection error with images, the learned pose noise
otherwise; bad frames left out) from the best of them; what the motions leave undetermined,
named and held (at the ``handeye:`` guess of ``dataset.yaml``) or refused, what noisy
measurements leave only weak named and delivered with its standard deviation; then K-fold
cross-validation by sample (configurations that repeat held out together), every method refitted
on each fold's training samples and scored on its held-out ones: the predicted camera (or marker)
pose ``W F_k X`` against the measured one (mm, deg) and, with images, the reprojection error
(px). Everything is computed in an order of the samples that depends on their values alone, so
reordering the rows changes no number.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from relcal import geometry as tf
from relcal.calibration.handeye_closed import (
    METHODS,
    TITLES,
    ClosedForm,
    Selection,
    canonical_order,
    closed_forms,
    informative_samples,
    rotation_angles,
)
from relcal.calibration.handeye_fit import (
    Corners,
    FrameFit,
    fit_images,
    fit_poses,
    reprojection_rms,
    sample_errors,
)
from relcal.calibration.verdict import MIN_HELD_OUT, MIN_JUDGED, Verdict, times
from relcal.errors import RelcalError

DEFAULT_FOLDS = 5
N_BOOT = 2000
MIN_SAMPLES = 4  # fewer usable samples: no hand-eye
MIN_VALIDATED = 6  # fewer usable samples: no cross-validation
# A delivered transform's direction is "not determined" when its standard deviation exceeds:
HOLD_MM = 5.0
HOLD_DEG = 1.0
# The guess of dataset.yaml (a mount drawing) holds what the data leave free, with this std:
GUESS_MM = 10.0
GUESS_DEG = 5.0
# What the motions alone determine: a direction whose standard deviation would stay above HOLD_MM
# (HOLD_DEG) even were each pose measured to NOMINAL_MM and NOMINAL_DEG (a camera seeing a board
# well) is undetermined by the motions (rotations about parallel axes, rotations too small); one
# they would determine but these measurements' noise leaves above it is weak: delivered with its
# standard deviation, and the verdict asks for more samples.
NOMINAL_MM = 1.0
NOMINAL_DEG = 0.1
TINY_DEG = 5.0  # the largest rotation between samples below this: rotations too small
PARALLEL_RATIO = 0.05  # second over first singular value of the rotation axes: one axis
REPEAT_M = 2e-4  # flange poses closer than this (and REPEAT_RAD) are one configuration, repeated
REPEAT_RAD = 5e-4
REFINED = "refined"


@dataclass(frozen=True)
class Delivered:
    """One transform the job delivers: ``key`` (``handeye``, ``world``), ``parent`` and ``child``
    frame names, ``transform`` ``(4, 4)`` (child in parent, m), standard deviations of ``xyz``
    (m) and of the rotation about the parent's x, y, z axes (``rotation_std``, rad; roll,
    pitch and yaw themselves have no useful deviation near pitch = 90 deg) (NaN where not
    determined), the directions the motions leave undetermined (no value is given), those
    held at the guess of ``dataset.yaml``, and the weak ones (the motions determine them, the
    measurements' noise only to a standard deviation above :data:`HOLD_MM` or :data:`HOLD_DEG`),
    in words."""

    key: str
    parent: str
    child: str
    transform: np.ndarray
    xyz_std: np.ndarray
    rotation_std: np.ndarray
    undetermined: tuple[str, ...] = ()
    held: tuple[str, ...] = ()
    weak: tuple[str, ...] = ()


@dataclass(frozen=True)
class HeldOut:
    """Held-out errors of every method on the same samples.

    ``samples`` ``(n,)`` indices (into the dataset's samples) of the held-out samples, ``fold``
    ``(n,)`` the fold of each; ``errors`` ``{method: (n, 6)}`` per-sample errors of the predicted
    pose (m, rad; NaN where the method failed in that fold); ``px`` ``{method: (n,)}`` the
    reprojection RMS of each held-out image (px), with images; ``failures`` ``{method: [reason,
    ...]}`` per fold that failed; ``criterion`` ``px`` or ``position_mm``: what ranks them.
    """

    samples: np.ndarray
    fold: np.ndarray
    errors: dict[str, np.ndarray]
    px: dict[str, np.ndarray] | None
    failures: dict[str, list[str]]
    n_folds: int
    criterion: str
    seed: int = 0

    def summary(self, method: str) -> dict[str, Any]:
        """RMS (and mean, max) of ``method``'s held-out errors, mm and deg (and px), with 95 %
        intervals from a bootstrap over the samples it predicted."""
        from relcal.calibration.validate import rms_interval, stats

        err = self.errors[method]
        ok = np.all(np.isfinite(err), axis=1)
        out: dict[str, Any] = {"n_samples": int(ok.sum())}
        if not ok.any():
            return out
        k = np.arange(int(ok.sum()))
        pairs = np.stack([k, k], axis=1)
        s = stats(err[ok])
        ci = rms_interval(pairs, err[ok], N_BOOT, self.seed)
        for key in ("position_mm", "orientation_deg"):
            if key in s:
                out[key] = {**s[key], "ci95": ci.get(key)}
        if self.px is not None:
            v = self.px[method][ok]
            out["px"] = {
                "rms": float(np.sqrt(np.mean(v**2))),
                "mean": float(np.mean(v)),
                "max": float(np.max(v)),
                "ci95": _bootstrap_rms(v, self.seed),
            }
        return out

    def ratio(self, method: str, to: str = REFINED) -> dict[str, Any] | None:
        """RMS of ``to`` over RMS of ``method`` on the samples both predicted, with a 95 %
        interval from a paired bootstrap over them (below 1: ``to`` is better)."""
        from relcal.calibration.validate import ratio_interval

        a, b = self.errors[to], self.errors[method]
        ok = np.all(np.isfinite(a), axis=1) & np.all(np.isfinite(b), axis=1)
        if ok.sum() < 2:
            return None
        k = np.arange(int(ok.sum()))
        out = ratio_interval(np.stack([k, k], axis=1), b[ok], a[ok], N_BOOT, self.seed)
        if self.px is not None:
            out["px"] = _bootstrap_ratio(self.px[method][ok], self.px[to][ok], self.seed)
        return out

    def rms(self, method: str) -> float:
        """The ranking figure of ``method``: its held-out RMS in :attr:`criterion` (inf when it
        failed on some held-out samples)."""
        err = self.errors[method]
        if not np.all(np.isfinite(err)):
            return float("inf")
        if self.criterion == "px":
            return float(np.sqrt(np.mean(self.px[method] ** 2)))
        return float(np.sqrt(np.mean(np.sum(err[:, :3] ** 2, axis=1)))) * 1e3

    def favoured(self) -> str:
        """The method with the lowest held-out RMS in :attr:`criterion` (ties to the refined)."""
        return min(self.errors, key=lambda m: (self.rms(m), m != REFINED))


def _bootstrap_rms(values: np.ndarray, seed: int) -> list[float]:
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, len(values), (N_BOOT, len(values)))
    boot = np.sqrt(np.mean(values[draws] ** 2, axis=1))
    return [float(v) for v in np.percentile(boot, [2.5, 97.5])]


def _bootstrap_ratio(before: np.ndarray, after: np.ndarray, seed: int) -> dict[str, Any]:
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, len(before), (N_BOOT, len(before)))
    boot = np.sqrt(
        np.sum(after[draws] ** 2, axis=1) / np.maximum(np.sum(before[draws] ** 2, axis=1), 1e-300)
    )
    ratio = float(np.sqrt(np.sum(after**2) / max(np.sum(before**2), 1e-300)))
    return {
        "after_over_before": ratio,
        "ci95": [float(v) for v in np.percentile(boot, [2.5, 97.5])],
    }


@dataclass(frozen=True)
class HandEye:
    """What :func:`handeye` found.

    Parameters
    ----------
    mode : {"eye_in_hand", "eye_to_hand", "robot_world"}
        Where the camera (or marker) is.
    handeye : (4, 4) ndarray of float
        ``X``: flange to camera (or marker; eye-to-hand: to the board), m.
    world : (4, 4) ndarray of float
        ``W``: the fixed frame (board, camera, world) from the robot's base, m.
    delivered : tuple of Delivered
        The transforms delivered in this mode, with standard deviations and what is not
        determined (see the module's docstring).
    exported : str or None
        Which estimate the files hold: ``"refined"``, a closed form the held-out samples favour
        beyond doubt, or None when refused (directions not determined and no guess to hold them).
    closed : tuple of ClosedForm
        Every closed-form method on all usable samples.
    selection : Selection
        The samples the closed forms used (indices into the usable samples).
    fit : FrameFit
        The refined estimate on all usable samples.
    ids : tuple of str
        Every sample's id.
    usable : (N,) ndarray of bool
        Samples with a measurement.
    rejected : dict of str to str
        Samples without one (image not posed), with the reason.
    outliers : dict of str to str
        Bad frames the refined fit left out, with the reason.
    findings : tuple of str
        What the motions leave undetermined or weak, in words.
    validation : HeldOut or None
        Held-out errors of every method (None: too few samples).
    verdict : Verdict
        ``code`` and ``text`` as for :func:`relcal.calibrate`, against the best closed form.
    source : str
        Where the flange poses came from: ``joints and the robot model`` or ``the logged
        flange poses``.
    settings : dict
        The options used.
    frames : dict of str to str
        The frame names of the exports (``base``, ``flange``, ``camera``, ``world``, ``marker``:
        defaults, overridden by ``frames:`` of dataset.yaml).
    camera : Camera or None
        With images, the intrinsics used (refined ones when refined).
    marker : Delivered or None
        Eye-to-hand: ``X``, the board on the flange (parent the flange, child the board), a
        by-product written to ``handeye.yaml`` (the guess ``relcal calibrate --handeye`` starts
        from); None in the other modes (``X`` is the delivered transform).
    """

    mode: str
    handeye: np.ndarray
    world: np.ndarray
    delivered: tuple[Delivered, ...]
    exported: str | None
    closed: tuple[ClosedForm, ...]
    selection: Selection
    fit: FrameFit
    ids: tuple[str, ...]
    usable: np.ndarray
    rejected: dict[str, str]
    outliers: dict[str, str]
    findings: tuple[str, ...]
    validation: HeldOut | None
    verdict: Verdict
    source: str
    settings: dict = field(default_factory=dict)
    frames: dict = field(default_factory=dict)
    camera: Any = None
    marker: Delivered | None = None

    def __repr__(self) -> str:
        from relcal._repr import short

        first = self.delivered[0]
        xyz, _ = tf.to_xyz_rpy(first.transform)
        return short(
            "HandEye",
            "",
            self.mode,
            f"{first.parent} -> {first.child} xyz "
            + " ".join(f"{v * 1e3:.1f}" for v in xyz)
            + " mm",
            f"verdict {self.verdict.code!r}",
        )

    def transform(self, key: str = "handeye") -> np.ndarray:
        """A delivered transform.

        Parameters
        ----------
        key : {"handeye", "world"}
            ``handeye`` (eye-to-hand: the camera in the base frame), or for robot-world
            ``world`` (the robot's base in the world frame).

        Returns
        -------
        (4, 4) ndarray of float
            The child frame in the parent frame, m.
        """
        for d in self.delivered:
            if d.key == key:
                return d.transform
        raise KeyError(key)


# --- the motions ---------------------------------------------------------------------------------


def repeat_groups(flange: np.ndarray) -> np.ndarray:
    """``(N,)`` group labels: flange poses within :data:`REPEAT_M` and :data:`REPEAT_RAD` of each
    other are one configuration recorded again (held out together)."""
    n = len(flange)
    label = np.arange(n)
    if n == 0:
        return label
    close_t = np.linalg.norm(flange[:, None, :3, 3] - flange[None, :, :3, 3], axis=-1) < REPEAT_M
    close = close_t & (rotation_angles(flange) < REPEAT_RAD)
    for i in range(n):  # union of each close pair
        for j in np.flatnonzero(close[i, i + 1 :]) + i + 1:
            a, b = label[i], label[j]
            if a != b:
                label[label == max(a, b)] = min(a, b)
    return np.unique(label, return_inverse=True)[1]


def folds_of(groups: np.ndarray, k: int, seed: int) -> np.ndarray:
    """``(N,)`` the fold of each sample (in canonical order): whole groups dealt in turn over ``k``
    folds after a seeded shuffle of the groups."""
    rng = np.random.default_rng(seed)
    names = np.unique(groups)
    order = rng.permutation(len(names))
    fold_of_group = np.empty(len(names), dtype=int)
    fold_of_group[order] = np.arange(len(names)) % k
    return fold_of_group[groups]


def motion_findings(flange: np.ndarray) -> tuple[list[str], np.ndarray | None]:
    """What the flange motions leave weak, in words, and the common rotation axis ``(3,)`` (in
    the flange frame) when every motion turns about one axis."""
    out: list[str] = []
    if len(flange) < 2:
        return out, None
    angles = rotation_angles(flange)
    largest = float(np.degrees(angles.max()))
    if largest < TINY_DEG:
        out.append(
            f"rotations too small: the largest rotation between two samples is {largest:.2f} "
            f"deg (below {TINY_DEG:g} deg): the hand-eye rotation and the translation it "
            "carries are barely determined; turn the flange by tens of degrees about two axes"
        )
    i, j = np.triu_indices(len(flange), 1)
    rel = tf.invert(flange[i]) @ flange[j]
    vec = tf.log_rotation(rel[:, :3, :3])  # axis times angle, in the flange frame
    big = np.linalg.norm(vec, axis=1) > np.radians(0.5)
    axis = None
    if big.sum() >= 1:
        s, vt = np.linalg.svd(vec[big], full_matrices=False)[1:]
        if s[0] > 0 and (len(s) < 2 or s[1] / s[0] < PARALLEL_RATIO):
            axis = vt[0] * np.sign(vt[0][np.argmax(np.abs(vt[0]))])
            out.append(
                "rotations about parallel axes: every motion turns about one axis (flange frame "
                f"direction {_direction(axis)}; the second axis carries {s[1] / s[0]:.1%} of it "
                "if any): the hand-eye translation along that axis is free (it trades with the "
                "fixed frame's); add rotations about another axis"
            )
    return out, axis


def _direction(v: np.ndarray) -> str:
    return "(" + ", ".join(f"{c:+.2f}" for c in v) + ")"


# --- delivered transforms ------------------------------------------------------------------------


def frame_names(dataset, mode: str | None = None) -> dict[str, str]:
    """The frame names of the exports for ``dataset`` in ``mode`` (default its own): ``base``,
    ``flange``, ``camera``, ``world``, ``marker``: relcal's defaults (a robot from a URDF: its
    chain's root and tip links for the base and the flange), overridden by ``frames:`` of
    dataset.yaml."""
    mode = mode or dataset.mode
    out = _frames_default(mode)
    chain = getattr(getattr(dataset, "model", None), "urdf", None)
    if chain is not None and getattr(dataset, "flange", None) is None:
        out.update(base=chain.root, flange=chain.tip)
    return {**out, **(getattr(dataset, "frames", None) or {})}


def _frames_default(mode: str) -> dict[str, str]:
    return {
        "base": "base_link",
        "flange": "tool0",
        "camera": "camera" if mode != "robot_world" else "sensor",
        "world": "world"
        if mode == "robot_world"
        else ("board" if mode == "eye_in_hand" else "camera"),
        "marker": "board" if mode == "eye_to_hand" else "marker",
    }


def _deliverables(
    mode: str, frames: dict[str, str], by_product: bool = False
) -> list[tuple[str, str, str, Any]]:
    """``(key, parent, child, function of (X, W) giving the transform)`` per delivered one (with
    ``by_product``, eye-to-hand: ``X``, the board on the flange)."""
    if by_product:
        return [("marker", frames["flange"], frames["marker"], lambda x, w: x)]
    if mode == "eye_to_hand":
        return [("handeye", frames["base"], frames["camera"], lambda x, w: tf.invert(w))]
    out = [("handeye", frames["flange"], frames["camera"], lambda x, w: x)]
    if mode == "robot_world":
        out.append(("world", frames["world"], frames["base"], lambda x, w: w))
    return out


def _jacobians(fn, x: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(6, 12)`` derivatives of (xyz, rpy) and of (parent-frame translation, parent-frame
    rotation vector) of ``fn(X exp(xi), W exp(omega))`` over the 12 perturbations."""
    ref = fn(x, w)
    _, rpy0 = tf.to_xyz_rpy(ref)
    step = 1e-7
    j_rpy = np.empty((6, 12))
    j_par = np.empty((6, 12))
    for i in range(12):
        cols = []
        for sign in (1.0, -1.0):
            d = np.zeros(12)
            d[i] = sign * step
            t = fn(x @ tf.from_vector(d[:6]), w @ tf.from_vector(d[6:]))
            xyz, rpy = tf.to_xyz_rpy(t)
            rot = tf.log_rotation(t[:3, :3] @ ref[:3, :3].T)
            cols.append((np.r_[xyz, rpy], np.r_[t[:3, 3], rot]))
        d_rpy = cols[0][0] - cols[1][0]
        d_rpy[3:] = (d_rpy[3:] + np.pi) % (2 * np.pi) - np.pi
        j_rpy[:, i] = d_rpy / (2 * step)
        j_par[:, i] = (cols[0][1] - cols[1][1]) / (2 * step)
    del rpy0
    return j_rpy, j_par


def _propagate(jac: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """``J cov J^T`` with NaN (held) parameters making every output they touch NaN."""
    nan = ~np.isfinite(np.diag(cov))
    out = jac @ np.nan_to_num(cov) @ jac.T
    if nan.any():
        touched = np.abs(jac[:, nan]).max(axis=1) > 1e-9
        out[touched, :] = np.nan
        out[:, touched] = np.nan
    return out


def frames_covariance(
    flange: np.ndarray,
    measured: np.ndarray,
    handeye: np.ndarray,
    world: np.ndarray,
    noise: np.ndarray | None = None,
) -> np.ndarray:
    """``(12, 12)`` covariance of ``(xi, omega)`` (as :attr:`FrameFit.covariance`) that the
    motions ``flange`` ``(N, 4, 4)`` give were each pose ``measured`` with the error covariance
    ``noise`` ``(6, 6)`` (m, rad, in the camera's or marker's frame; default
    :data:`NOMINAL_MM` and :data:`NOMINAL_DEG`: what the motions alone determine, whatever the
    measurements' noise). Directions the motions leave free get a variance of 10^12 times the
    best determined one's."""
    step = 1e-7
    jac = np.empty((6 * len(flange), 12))
    for i in range(12):
        sides = []
        for sign in (1.0, -1.0):
            d = np.zeros(12)
            d[i] = sign * step
            moved = (handeye @ tf.from_vector(d[:6]), world @ tf.from_vector(d[6:]))
            sides.append(sample_errors(flange, measured, *moved).ravel())
        jac[:, i] = (sides[0] - sides[1]) / (2 * step)
    if noise is None:
        noise = np.diag(np.r_[np.full(3, NOMINAL_MM * 1e-3), np.full(3, np.radians(NOMINAL_DEG))])
        noise = noise**2
    whiten = np.linalg.cholesky(np.linalg.inv(noise)).T  # whiten.T @ whiten = noise^-1
    jac = np.einsum("ij,njk->nik", whiten, jac.reshape(len(flange), 6, 12)).reshape(-1, 12)
    vals, vecs = np.linalg.eigh(jac.T @ jac)
    floor = 1e-12 * max(float(vals.max()), 1e-300)
    return (vecs / np.maximum(vals, floor)) @ vecs.T


def deliver(
    mode: str,
    fit: FrameFit,
    frames: dict[str, str],
    held_by_guess: bool = False,
    by_product: bool = False,
    motions: np.ndarray | None = None,
) -> tuple[Delivered, ...]:
    """The transforms of ``mode`` with their standard deviations and what is undetermined or
    weak (``by_product``: eye-to-hand's ``X``, the board on the flange). ``motions``: the
    covariance of :func:`frames_covariance` (its default noise), which tells a direction the
    motions leave free from a weak one; without it every direction above the limits is
    undetermined. A fit
    without any covariance (a closed form's) is delivered with unknown standard deviations."""
    out = []
    for key, parent, child, fn in _deliverables(mode, frames, by_product):
        t = fn(fit.handeye, fit.world)
        _, j_par = _jacobians(fn, fit.handeye, fit.world)
        par = _propagate(j_par, fit.covariance)
        std = np.sqrt(np.abs(np.diag(par)))
        if not np.isfinite(fit.covariance).any():
            out.append(Delivered(key, parent, child, t, std[:3], std[3:]))
            continue
        motion = None if motions is None else j_par @ motions @ j_par.T
        free, weak = [], []
        for block, unit, limit, what in (
            (slice(0, 3), 1e3, HOLD_MM, "translation"),
            (slice(3, 6), np.degrees(1.0), HOLD_DEG, "rotation"),
        ):
            sub = par[block, block]
            about = "along" if what == "translation" else "about"
            moved = j_par[block] @ fit.null_space  # how the deliverable moves along the null space
            if moved.size and np.abs(moved).max() > 1e-6:
                u, sv, _ = np.linalg.svd(moved, full_matrices=False)
                for e in u[:, sv > 1e-6 * max(sv.max(), 1e-300)].T:
                    e = e * np.sign(e[np.argmax(np.abs(e))])
                    free.append(
                        f"{what} of {parent} -> {child} {about} {_direction(e)} ({parent} frame):"
                        " not determined at all by these data (it trades with the fixed frame's)"
                    )
                continue
            if not np.all(np.isfinite(sub)):
                free.append(f"{what} of {parent} -> {child}: not determined by these data")
                continue
            val, vec = np.linalg.eigh(sub)
            for v, e in zip(val[::-1], vec.T[::-1], strict=True):
                sd = np.sqrt(max(v, 0.0)) * unit
                if sd <= limit:
                    continue
                e = e * np.sign(e[np.argmax(np.abs(e))])
                u = "mm" if what == "translation" else "deg"
                text = (
                    f"{what} of {parent} -> {child} {about} {_direction(e)} ({parent} frame):"
                    f" std {sd:.3g} {u}, above {limit:g} {u}"
                )
                motion_sd = np.inf if motion is None else np.sqrt(abs(e @ motion[block, block] @ e))
                if motion_sd * unit <= limit:
                    weak.append(f"{text} (the motions determine it; the measurements are noisy)")
                else:
                    free.append(text)
        free_dirs = () if held_by_guess else tuple(free)
        held_dirs = tuple(free) if held_by_guess else ()
        out.append(
            Delivered(key, parent, child, t, std[:3], std[3:], free_dirs, held_dirs, tuple(weak))
        )
    return tuple(out)


# --- the job -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Data:
    """The usable samples in canonical order: flange ``F``, measured ``C``, model and joints (for
    the pose fit), the images' corners (or None) and their camera."""

    order: np.ndarray  # indices into the dataset's samples
    flange: np.ndarray
    measured: np.ndarray
    model: Any
    q: np.ndarray
    corners: list[Corners] | None
    camera: Any


def _start(answers: list[ClosedForm], flange: np.ndarray, measured: np.ndarray, lever: float):
    """The closed form whose training samples fit best (median of position + lever x angle)."""
    best, score = None, np.inf
    for a in answers:
        if not a.ok:
            continue
        e = sample_errors(flange, measured, a.handeye, a.world)
        s = float(
            np.median(np.linalg.norm(e[:, :3], axis=1) + lever * np.linalg.norm(e[:, 3:], axis=1))
        )
        if s < score:
            best, score = a, s
    return best


def _refine(
    data: _Data,
    rows: np.ndarray,
    mode: str,
    start: tuple[np.ndarray, np.ndarray],
    refine_intrinsics: bool,
    reject: bool,
    progress: bool = False,
) -> FrameFit:
    """The refined fit on ``rows`` of ``data`` from ``start`` = (X, W)."""
    x0, w0 = start
    if data.corners is None:
        return fit_poses(data.model, data.q[rows], data.measured[rows], x0, w0, reject)
    return fit_images(
        data.flange[rows],
        [data.corners[i] for i in rows],
        data.camera,
        x0,
        w0,
        mode,
        refine_intrinsics,
        reject,
        progress,
    )


def _fallback_start(data: _Data, rows: np.ndarray, guess: np.ndarray | None):
    """A start when every closed form failed: the guess of dataset.yaml, else Park-Martin's."""
    from relcal.calibration.handeye import solve_handeye
    from relcal.calibration.handeye_closed import world_given

    f, c = data.flange[rows], data.measured[rows]
    x = guess if guess is not None else solve_handeye(f, c)
    return x, world_given(f, c, x)


def _lever(measured: np.ndarray) -> float:
    from relcal.calibration.measurement import board_lever

    return board_lever(measured)


def _fit_all(
    data: _Data,
    rows: np.ndarray,
    mode: str,
    methods: tuple[str, ...],
    refine_intrinsics: bool,
    reject: bool,
    guess: np.ndarray | None,
    progress: bool = False,
) -> tuple[list[ClosedForm], Selection, FrameFit]:
    f, c = data.flange[rows], data.measured[rows]
    selection = informative_samples(f, c)
    answers, selection = closed_forms(f, c, methods, selection)
    best = _start(answers, f, c, _lever(c))
    start = (best.handeye, best.world) if best is not None else _fallback_start(data, rows, guess)
    return answers, selection, _refine(data, rows, mode, start, refine_intrinsics, reject, progress)


def _validate(
    data: _Data,
    mode: str,
    methods: tuple[str, ...],
    folds: int,
    seed: int,
    refine_intrinsics: bool,
    reject: bool,
    guess: np.ndarray | None,
    progress: bool,
) -> HeldOut:
    from tqdm import tqdm

    n = len(data.order)
    groups = repeat_groups(data.flange)
    k = min(folds, len(np.unique(groups)))
    fold = folds_of(groups, k, seed)
    names = (REFINED, *methods)
    errors = {m: np.full((n, 6), np.nan) for m in names}
    px = {m: np.full(n, np.nan) for m in names} if data.corners is not None else None
    failures: dict[str, list[str]] = {m: [] for m in names}
    for f in tqdm(range(k), desc="cross-validating", unit="fold", disable=not progress):
        test, train = np.flatnonzero(fold == f), np.flatnonzero(fold != f)
        try:
            answers, _, fit = _fit_all(data, train, mode, methods, refine_intrinsics, reject, guess)
        except RelcalError as exc:
            failures[REFINED].append(f"fold {f + 1}: {exc}")
            continue
        found = {REFINED: (fit.handeye, fit.world, fit.camera or data.camera)}
        for a in answers:
            if a.ok:
                found[a.method] = (a.handeye, a.world, data.camera)
            else:
                failures[a.method].append(f"fold {f + 1}: {a.failure}")
        for m, (x, w, cam) in found.items():
            errors[m][test] = sample_errors(data.flange[test], data.measured[test], x, w)
            if px is not None:
                px[m][test] = reprojection_rms(
                    data.flange[test], [data.corners[i] for i in test], cam, x, w, mode
                )
    return HeldOut(
        samples=data.order,
        fold=fold,
        errors=errors,
        px=px,
        failures={m: v for m, v in failures.items() if v},
        n_folds=k,
        criterion="px" if px is not None else "position_mm",
        seed=seed,
    )


def _corners(dataset, m, usable: np.ndarray) -> list[Corners]:
    """Board points of the usable images (circle grids: the dots' perspective bias removed at
    each image's own pose, as the pose estimate does)."""
    import cv2

    from relcal.vision.detect import dot_bias

    out = []
    for i in usable:
        det = m.detections[i]
        img = det.image_points.astype(float)
        if det.board.type in ("circles", "acircles"):
            c = m.poses[i]
            t = c if dataset.mode == "eye_to_hand" else tf.invert(c)  # board in camera frame
            rvec = cv2.Rodrigues(t[:3, :3])[0]
            img = img - dot_bias(det.board, m.camera, rvec, t[:3, 3:], det.ids)
        out.append(Corners(det.object_points.astype(float), img))
    return out


def check_job(
    dataset, measurements, mode, methods, folds, seed, refine_intrinsics, reject, progress
) -> None:
    """The arguments of :func:`handeye`, checked before anything is measured."""
    from relcal.checks import check_choice, check_flag, check_number
    from relcal.data.dataset import MODES, check_dataset
    from relcal.data.imaging import check_measurements
    from relcal.errors import ArgumentError

    check_dataset(dataset)
    if measurements is not None:
        check_measurements(measurements, dataset)
    if mode is not None:
        check_choice(mode, "mode", MODES)
    if isinstance(methods, str) or not all(isinstance(m, str) for m in methods):
        raise ArgumentError(f"methods: expected a tuple of names from {', '.join(METHODS)}")
    for m in methods:
        check_choice(m, "methods", METHODS)
    check_number(folds, "folds", 2, integer=True)
    check_number(seed, "seed", 0, integer=True)
    if refine_intrinsics is not None:
        check_flag(refine_intrinsics, "refine_intrinsics")
    check_flag(reject, "reject")
    check_flag(progress, "progress")
    if dataset.measured not in ("image", "pose"):
        raise RelcalError(
            f"{dataset.spec_path or 'dataset'}: the samples measure "
            f"{'positions' if dataset.measured == 'position' else 'coincidences'}: a hand-eye "
            "transform needs poses (x, y, z, qx, qy, qz, qw, or roll, pitch, yaw) or images"
        )


def handeye(
    dataset,
    measurements=None,
    *,
    mode: str | None = None,
    methods: tuple[str, ...] = METHODS,
    folds: int = DEFAULT_FOLDS,
    seed: int = 0,
    refine_intrinsics: bool | None = None,
    reject: bool = True,
    progress: bool = False,
) -> HandEye:
    """Hand-eye calibration: every closed form, the refined estimate, held-out proof.

    Parameters
    ----------
    dataset : Dataset
        Joint angles with a robot model, or logged flange poses (columns ``fx`` .. ``fqw``),
        beside measured poses or images (:func:`relcal.load_dataset`).
    measurements : Measurements, optional
        The dataset's measurements (:func:`relcal.measure`), when already measured.
    mode : {"eye_in_hand", "eye_to_hand", "robot_world"}, optional
        Overrides the dataset's ``mode``: robot-world delivers the world frame too.
    methods : tuple of str
        Closed forms to run and score: of ``tsai``, ``park``, ``horaud``, ``andreff``,
        ``daniilidis`` (OpenCV's ``calibrateHandEye``), ``shah``, ``li``
        (``calibrateRobotWorldHandEye``).
    folds : int
        Folds of the cross-validation (at least 2; fewer when there are fewer distinct
        configurations).
    seed : int
        Seed of the folds and the bootstraps.
    refine_intrinsics : bool, optional
        With images: refine the intrinsics with the frames (default: when the dataset's camera
        is ``calibrate``).
    reject : bool
        Leave out bad frames (named in :attr:`HandEye.outliers`).
    progress : bool
        Progress bars (measuring images, the refits).

    Returns
    -------
    HandEye
        The delivered transform(s) with standard deviations, every method's held-out errors,
        the findings and the verdict.

    Raises
    ------
    ArgumentError
        An argument of the wrong type or value (naming it).
    RelcalError
        Samples that measure positions or coincidences, fewer than 4 usable samples, or samples
        that cannot be what they say (a unit, a quaternion order, a pose direction, rows out of
        step: :func:`~relcal.calibration.plausibility.check_handeye_dataset`, naming the fix).

    Examples
    --------
    >>> import numpy as np, relcal
    >>> from relcal import geometry as tf
    >>> model = relcal.get_robot("ur5e")
    >>> rng = np.random.default_rng(0)
    >>> q = np.radians([0, -90, 90, -90, -90, 0]) + rng.normal(0, 0.5, (20, 6))
    >>> x = tf.from_xyz_rpy(np.array([0.0, 0.05, 0.08]), np.radians([0, 0, 90]))
    >>> w = tf.from_xyz_rpy(np.array([0.6, 0.1, -0.3]), np.radians([180, 0, 0]))
    >>> poses = w @ relcal.fk(model, q) @ x  # camera poses in the board frame, no noise
    >>> result = relcal.handeye(relcal.Dataset.from_arrays(model, q, poses), folds=4)
    >>> [round(float(v), 3) + 0.0 for v in result.transform("handeye")[:3, 3] * 1e3]  # mm
    [0.0, 50.0, 80.0]
    >>> result.verdict.code, result.exported
    ('deploy', 'refined')
    """
    from relcal.calibration.plausibility import check_handeye_dataset
    from relcal.data.imaging import measure
    from relcal.robot.kinematics import fk

    check_job(
        dataset, measurements, mode, methods, folds, seed, refine_intrinsics, reject, progress
    )
    mode = mode or dataset.mode
    m = measurements if measurements is not None else measure(dataset, progress=progress)
    usable = np.flatnonzero(m.ok)
    if len(usable) < MIN_SAMPLES:
        raise RelcalError(
            f"{dataset.spec_path or 'dataset'}: {len(usable)} usable samples: a hand-eye needs at "
            f"least {MIN_SAMPLES} (many more to validate it)"
        )
    model, q = dataset.model, dataset.q
    if dataset.flange is not None:  # the logged poses, also beside joints and a robot model
        from relcal.data.flange import flange_chain

        model, q = flange_chain(dataset.flange)
    flange_all = fk(model, q) if dataset.flange is None else dataset.flange
    order = usable[canonical_order(flange_all[usable], m.poses[usable])]
    images = dataset.measured == "image"
    refine = bool(dataset.camera == "calibrate") if refine_intrinsics is None else refine_intrinsics
    data = _Data(
        order=order,
        flange=flange_all[order],
        measured=m.poses[order],
        model=model,
        q=q[order],
        corners=_corners(dataset, m, order) if images else None,
        camera=m.camera,
    )
    check_handeye_dataset(dataset, data.flange, data.measured, order, mode)
    rows = np.arange(len(order))
    guess = dataset.handeye
    answers, selection, fit = _fit_all(
        data, rows, mode, methods, refine and images, reject, guess, progress
    )
    findings, _axis = motion_findings(data.flange)
    frames = frame_names(dataset, mode)
    used = fit.used
    motions = frames_covariance(data.flange[used], data.measured[used], fit.handeye, fit.world)
    delivered = deliver(mode, fit, frames, motions=motions)
    held = False
    if any(d.undetermined for d in delivered) and guess is not None:
        if images:
            fit = _hold_images_at_guess(data, rows, mode, fit, guess, refine and images)
        else:
            fit = _hold_at_guess(data, rows, fit, guess)
        delivered = deliver(mode, fit, frames, held_by_guess=True, motions=motions)
        held = True
    validation = None
    if len(order) >= MIN_VALIDATED:
        validation = _validate(
            data, mode, methods, folds, seed, refine and images, reject, guess, progress
        )
    exported: str | None = REFINED
    undetermined = [u for d in delivered for u in d.undetermined]
    weak = [u for d in delivered for u in d.weak]
    if undetermined:
        exported = None
    elif validation is not None:
        exported = _exported(validation, answers)
    if exported not in (None, REFINED):
        chosen = next(a for a in answers if a.method == exported)
        replaced = FrameFit(
            chosen.handeye,
            chosen.world,
            np.full((12, 12), np.nan),
            fit.used,
            fit.outliers,
            True,
            fit.noise,
            fit.pixel_sigma,
            (),
            fit.camera,
        )
        delivered = deliver(mode, replaced, frames)
    marker = None
    if mode == "eye_to_hand":
        chosen_fit = fit if exported in (None, REFINED) else replaced
        marker = deliver(mode, chosen_fit, frames, held, by_product=True, motions=motions)[0]
    ids = dataset.ids
    verdict = handeye_verdict(
        validation, fit, exported, undetermined, held, guess is not None, weak
    )
    return HandEye(
        mode=mode,
        handeye=fit.handeye,
        world=fit.world,
        delivered=delivered,
        exported=exported,
        closed=tuple(answers),
        selection=Selection(
            order[selection.used], {int(order[k]): v for k, v in selection.left_out.items()}
        ),
        fit=fit,
        ids=ids,
        usable=m.ok.copy(),
        rejected={ids[i]: m.reasons[i] for i in np.flatnonzero(~m.ok)},
        outliers={ids[int(order[k])]: v for k, v in fit.outliers.items()},
        findings=tuple(findings),
        validation=validation,
        verdict=verdict,
        source=(
            "the logged flange poses"
            if dataset.flange is not None
            else "joints and the robot model"
        ),
        settings={
            "mode": mode,
            "methods": list(methods),
            "folds": folds,
            "seed": seed,
            "refine_intrinsics": bool(refine and images),
            "reject": reject,
            "held_at_guess": held,
        },
        frames=frames,
        camera=fit.camera or m.camera,
        marker=marker,
    )


def _exported(validation: HeldOut, answers: list[ClosedForm]) -> str:
    """The refined estimate, unless a closed form beats it on the held-out samples beyond doubt
    (the whole 95 % interval of refined over it above 1)."""
    key = "px" if validation.criterion == "px" else "position_mm"
    beaten = []
    for a in answers:
        if not a.ok or a.method in validation.failures:
            continue
        r = validation.ratio(a.method)
        if r and key in r and r[key]["ci95"][0] > 1.0:
            beaten.append((r[key]["after_over_before"], a.method))
    return max(beaten)[1] if beaten else REFINED


def _hold_at_guess(data: _Data, rows: np.ndarray, fit: FrameFit, guess: np.ndarray) -> FrameFit:
    """The pose fit again with ``X`` held near the guess of dataset.yaml by a prior of
    :data:`GUESS_MM` and :data:`GUESS_DEG` (maximum a posteriori): what the data determine stays
    theirs, what they leave free takes the guess."""
    from dataclasses import replace

    from relcal.calibration.handeye_fit import frames_of, frames_problem
    from relcal.calibration.identify import identify_lm
    from relcal.calibration.noise import Noise
    from relcal.calibration.uncertainty import pose_whitener

    keep = np.flatnonzero(fit.used)
    sub = rows[keep]
    problem = frames_problem(data.model, data.q[sub], data.measured[sub], guess, fit.world)
    whiten = pose_whitener(problem, Noise(covariance=fit.noise))
    std = np.r_[np.full(3, GUESS_MM * 1e-3), np.full(3, np.radians(GUESS_DEG)), np.full(6, np.inf)]
    prior = np.where(np.isfinite(std), 1.0 / std, 0.0)
    initial = np.r_[tf.to_vector(tf.invert(guess) @ fit.handeye), np.zeros(6)]
    from relcal.calibration.identifiability import analyse_problem

    ident = analyse_problem(problem)  # with the prior rows, all 12 are determined
    every = np.arange(problem.full_layout.size)
    ident = replace(ident, subset=every, rank=len(every), identifiable=np.ones(len(every), bool))
    result = identify_lm(
        problem,
        identifiability=ident,
        whiten=whiten,
        initial=initial,
        prior=prior,
        prior_std=std,
    )
    x, w = frames_of(problem, result)
    cov = result.covariance
    from relcal.calibration.handeye_fit import _reparametrise

    move = _reparametrise(guess, fit.world, x, w, result.params)
    cov = move @ np.nan_to_num(cov) @ move.T
    return replace(
        fit,
        handeye=x,
        world=w,
        covariance=cov,
        stopped=result.stopped,
        result=result,
        held=("handeye.* (prior: the guess of dataset.yaml)",),
    )


def _hold_images_at_guess(
    data: _Data, rows: np.ndarray, mode: str, fit: FrameFit, guess: np.ndarray, refine: bool
) -> FrameFit:
    """The image fit again on the images it kept, with ``X`` held near the guess of
    dataset.yaml by a prior of :data:`GUESS_MM` and :data:`GUESS_DEG` (maximum a posteriori,
    weighed against the pixels by the first fit's pixel noise)."""
    from dataclasses import replace

    keep = np.flatnonzero(fit.used)
    sub = rows[keep]
    std = np.r_[np.full(3, GUESS_MM * 1e-3), np.full(3, np.radians(GUESS_DEG))]
    held = fit_images(
        data.flange[sub],
        [data.corners[i] for i in sub],
        fit.camera or data.camera,
        fit.handeye,
        fit.world,
        mode,
        refine,
        reject=False,
        prior=(guess, std, max(fit.pixel_sigma or 0.0, 1e-3)),
    )
    return replace(
        held,
        used=fit.used,
        outliers=fit.outliers,
        held=("handeye.* (prior: the guess of dataset.yaml)",),
    )


def handeye_verdict(
    validation: HeldOut | None,
    fit: FrameFit,
    exported: str | None,
    undetermined: list[str],
    held: bool,
    has_guess: bool,
    weak: list[str] | None = None,
) -> Verdict:
    """The verdict (codes as :func:`relcal.calibration.verdict.verdict`): against the best
    closed form on the same held-out samples; ``collect more samples`` at best while directions
    are ``weak`` (:class:`Delivered`)."""
    if exported is None:
        fix = (
            "add motions that turn about other axes and by more"
            if has_guess
            else "give a guess (handeye: in dataset.yaml, from the mount drawing) to hold them, "
            "or add motions that turn about other axes and by more"
        )
        return Verdict(
            "do not deploy",
            f"do not deploy: the data leave {len(undetermined)} direction(s) undetermined "
            f"({undetermined[0]}); {fix}",
            None,
            None,
            0 if validation is None else len(validation.samples),
        )
    warnings: list[str] = []
    if weak:
        warnings.append(
            f"{len(weak)} direction(s) known only roughly ({weak[0]}): more samples, or "
            "measurements less noisy (a board filling more of the view, flatter, closer)"
        )
    if validation is None:
        return Verdict(
            "not validated",
            "not validated: too few samples to hold any out (at least "
            f"{MIN_VALIDATED}); measure it on a new session",
            None,
            None,
            0,
            tuple(warnings),
        )
    n = len(validation.samples)
    if n < MIN_HELD_OUT:
        warnings.append(
            f"the validation rests on {n} held-out samples (fewer than {MIN_HELD_OUT}): its "
            "intervals are rough"
        )
    if held:
        warnings.append(
            "directions the data leave free are held at the guess of dataset.yaml (handeye:)"
        )
    if not fit.converged:
        warnings.append("the refined fit did not converge (its gradient does not vanish)")
    key = validation.criterion
    unit = "px" if key == "px" else "mm"
    closed = [m for m in validation.errors if m != REFINED and np.isfinite(validation.rms(m))]
    ours = exported if exported is not None else REFINED
    mine = validation.rms(ours)
    if not closed:
        return Verdict(
            "collect more samples" if n < MIN_JUDGED or held else "deploy",
            f"held-out error {mine:.3f} {unit} on {n} samples; no closed form to compare with "
            "(all failed)",
            None,
            None,
            n,
            tuple(warnings),
        )
    best = min(closed, key=validation.rms)
    ratio = validation.ratio(best, to=ours) or {}
    r = ratio.get(key if key == "px" else "position_mm")
    factor = interval = None
    span = ""
    if r:
        factor = 1.0 / max(r["after_over_before"], 1e-300)
        lo, hi = r["ci95"]
        interval = (1.0 / max(hi, 1e-300), 1.0 / max(lo, 1e-300))
        span = f", 95% interval {times(interval[0])}..{times(interval[1])}"
    name = "the refined estimate" if ours == REFINED else TITLES[ours]
    compare = (
        f"{name}: held-out {mine:.3f} {unit} RMS on {n} samples against {validation.rms(best):.3f}"
        f" {unit} for the best closed form ({TITLES[best]}){span}"
    )
    if ours != REFINED:
        code = "deploy" if n >= MIN_JUDGED and not weak else "collect more samples"
        text = (
            f"{code}: the held-out samples favour {TITLES[ours]} over the refined estimate "
            f"({compare})"
        )
    elif n < MIN_JUDGED or held or weak or not fit.converged:
        code = "collect more samples"
        text = f"collect more samples: {compare}"
    elif interval is not None and interval[1] < 1.0:
        code = "do not deploy"
        text = f"do not deploy: worse than a closed form ({compare})"
    else:
        code = "deploy"
        text = f"deploy: {compare}"
    return Verdict(code, text, factor, interval, n, tuple(warnings))
