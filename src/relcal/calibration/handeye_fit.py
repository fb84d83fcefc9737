"""The refined hand-eye estimate: maximum likelihood of ``C_k = W F_k X``, kinematics frozen.

Poses (measured camera or marker poses): the skeleton's board formulation
(:mod:`relcal.calibration.measurement`) with no kinematic parameter free, so only the two frames
``X`` (``handeye.*``) and ``W`` (``board.*``) are estimated. A first fit weighs the rows plainly
(metres, and radians times the camera's distance from the board); the residuals then give the
noise model, a full 6x6 covariance of each pose's error in the camera's frame (translation and
rotation errors of a camera pose are strongly correlated), estimated robustly; samples whose
Mahalanobis distance is beyond the 99.9 % point of chi-square(6) are bad frames, named and left
out; the final fit is the noise-weighted one
(:func:`relcal.calibration.identify.identify_weighted`), whose covariance is the Cramer-Rao bound
of the learned noise.

Images: the board points' reprojection error over all images at once (:func:`fit_images`), the
camera intrinsics given or refined with the frames, a robust first pass to find bad frames.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np
import scipy.optimize

from relcal import geometry as tf
from relcal.calibration.identify import Result, calibrated_handeye, identify_lm, identify_weighted
from relcal.calibration.measurement import (
    Problem,
    board_frame,
    board_lever,
)
from relcal.calibration.noise import Noise, robust_scale
from relcal.calibration.selection import PLAIN_ROTATION_WEIGHT
from relcal.robot.kinematics import Layout
from relcal.robot.model import RobotModel

EMPTY = Layout((), (), ())  # no kinematic parameter free: the two frames alone
OUTLIER_LEVEL = 0.999  # chi-square(6) quantile beyond which a sample is a bad frame
OUTLIER_CHI2 = 22.457744484825323  # scipy.stats.chi2.ppf(OUTLIER_LEVEL, 6)
MAX_OUTLIER_SHARE = 0.25  # more would be the model's fault, not the frames'
FULL_NOISE_SAMPLES = 12  # fewer samples: an isotropic noise model (2 levels), not a full 6x6
NOISE_FLOOR = 1e-9  # m, rad: exact synthetic data still get a (tiny) noise model
FRAME_NAMES = tuple(f"handeye.{c}" for c in ("x", "y", "z", "rx", "ry", "rz")) + tuple(
    f"world.{c}" for c in ("x", "y", "z", "rx", "ry", "rz")
)


@dataclass(frozen=True)
class FrameFit:
    """The refined frames and what the fit saw.

    Parameters
    ----------
    handeye : (4, 4) ndarray of float
        ``X``: flange to camera (or marker), m.
    world : (4, 4) ndarray of float
        ``W``: the fixed frame (board, camera, world) from the robot's base, m.
    covariance : (12, 12) ndarray of float
        Of the 12-vector ``(xi, omega)`` with ``X exp(xi)``, ``W exp(omega)`` (translation m,
        rotation vector rad, each in the frame's own child frame); NaN rows and columns for
        directions the data did not determine (held at the start).
    used : (N,) ndarray of bool
        Samples the final fit used (bad frames left out).
    outliers : dict of int to str
        Samples left out as bad frames, with the reason.
    stopped : bool
        The solver's own stopping rule was met (see :attr:`converged`).
    noise : (6, 6) ndarray of float or None
        The learned pose noise covariance (m, rad): of each measured pose (camera frame),
        poses; of each image's pose beyond its pixels (the flange poses' own errors, a moving
        arm; :func:`image_pose_noise`), images.
    pixel_sigma : float or None
        The image noise per coordinate (px, measured with each image's pose freed), images
        only.
    held : tuple of str
        Frame directions (:data:`FRAME_NAMES`) held at the start because the data do not
        determine them.
    null_space : (12, k) ndarray of float
        Directions of the 12 perturbations the data do not determine at all (unit columns, SI):
        what a held parameter stands for, a combination of ``X`` and ``W``.
    camera : object
        The camera intrinsics used (refined ones when refined), images only.
    """

    handeye: np.ndarray
    world: np.ndarray
    covariance: np.ndarray
    used: np.ndarray
    outliers: dict[int, str]
    stopped: bool
    noise: np.ndarray | None = None
    pixel_sigma: float | None = None
    held: tuple[str, ...] = ()
    camera: object = None
    null_space: np.ndarray = field(default_factory=lambda: np.zeros((12, 0)))
    result: Result | None = field(default=None, repr=False, compare=False)

    @functools.cached_property
    def converged(self) -> bool:
        """The solver stopped by its rule and the gradient of the stated cost vanishes at the
        estimate (finite differences of the real residual, poses; the solver's own gradient
        test, images)."""
        if self.result is not None:
            return bool(self.result.converged)
        return self.stopped


def frames_problem(
    model: RobotModel, q: np.ndarray, measured: np.ndarray, handeye: np.ndarray, world: np.ndarray
) -> Problem:
    """The board formulation of ``C_k = W F(q_k) X`` with the kinematics frozen: 12 parameters,
    the perturbations of ``handeye`` and ``world``; rows weighted plainly (m, and rad times the
    camera's distance from the board)."""
    weights = np.r_[np.ones(3), np.full(3, max(board_lever(measured), PLAIN_ROTATION_WEIGHT))]
    return Problem(model, EMPTY, q, measured, "board", "pose", None, handeye, weights, board=world)


def sample_errors(
    flange: np.ndarray, measured: np.ndarray, handeye: np.ndarray, world: np.ndarray
) -> np.ndarray:
    """``(N, 6)``: each sample's error, the 6-vector (m, rad) of ``(W F_k X)^-1 C_k`` (in the
    frame of the predicted camera or marker)."""
    return tf.to_vector(tf.invert(world @ flange @ handeye) @ measured)


def learn_noise(errors: np.ndarray, n_params: int = 12) -> np.ndarray:
    """The covariance ``(6, 6)`` of a pose's error from the residuals ``(N, 6)`` of a fit of
    ``n_params`` parameters (the degrees of freedom counted); a full matrix from
    :data:`FULL_NOISE_SAMPLES` samples on, else isotropic translation and rotation levels."""
    n = len(errors)
    dof = max(n - n_params / 6.0, 1.0)
    if n >= FULL_NOISE_SAMPLES:
        cov = errors.T @ errors / dof
    else:
        t = np.sum(errors[:, :3] ** 2) / (3 * dof)
        r = np.sum(errors[:, 3:] ** 2) / (3 * dof)
        cov = np.diag([t, t, t, r, r, r])
    floor = np.diag(np.full(6, NOISE_FLOOR**2))
    return 0.5 * (cov + cov.T) + floor


def weight_inflation(n: int, n_params: int = 12) -> float:
    """How many times the covariance of a fit weighted by the noise :func:`learn_noise` learned
    from ``n`` samples understates the estimate's: the inverse of a covariance estimated with
    ``nu`` degrees of freedom in ``d`` dimensions overstates the true inverse by ``nu / (nu - d
    - 1)`` on average (Wishart), ``d = 6`` for the full matrix, ``d = 1`` per level (``3`` per
    sample) for the isotropic one. Without it, 12 samples printed standard deviations 1.7-2.1
    times smaller than the errors' spread."""
    dof = max(n - n_params / 6.0, 1.0)
    nu, d = (dof, 6) if n >= FULL_NOISE_SAMPLES else (3.0 * dof, 1)
    return nu / max(nu - d - 1.0, 1.0)


def bad_frames(errors: np.ndarray, n_params: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Samples whose errors ``(N, 6)`` are beyond the :data:`OUTLIER_LEVEL` point of
    chi-square(6) under the noise learned from the others (robust start: per-component scales),
    at most :data:`MAX_OUTLIER_SHARE` of them; ``(bad mask, squared Mahalanobis distances)``."""
    n = len(errors)
    limit = OUTLIER_CHI2
    scale = np.array([robust_scale(errors[:, j]) for j in range(6)])
    scale = np.maximum(scale, NOISE_FLOOR)
    d2 = np.sum((errors / scale) ** 2, axis=1)
    bad = d2 > limit
    for _ in range(5):
        if (~bad).sum() < 4:
            break
        cov = learn_noise(errors[~bad], n_params)
        d2 = np.einsum("ni,ij,nj->n", errors, np.linalg.pinv(cov), errors)
        new = d2 > limit
        if np.array_equal(new, bad):
            break
        bad = new
    if bad.sum() > MAX_OUTLIER_SHARE * n:  # too many to be bad frames: keep them all
        bad = np.zeros(n, dtype=bool)
    return bad, d2


def frames_of(problem: Problem, result: Result) -> tuple[np.ndarray, np.ndarray]:
    """``X`` and ``W`` of a fit of :func:`frames_problem`."""
    return calibrated_handeye(problem, result), board_frame(problem, result.params)


def fit_poses(
    model: RobotModel,
    q: np.ndarray,
    measured: np.ndarray,
    handeye: np.ndarray,
    world: np.ndarray,
    reject: bool = True,
) -> FrameFit:
    """The maximum-likelihood ``X`` and ``W`` of measured poses.

    Parameters
    ----------
    model : RobotModel
        The robot (or the pose chain of logged flange poses), kinematics frozen.
    q : (N, n) ndarray of float
        Joint values, rad (m for prismatic joints).
    measured : (N, 4, 4) ndarray of float
        ``C_k``, m.
    handeye, world : (4, 4) ndarray of float
        Starting ``X`` and ``W`` (a closed form's), m.
    reject : bool
        Leave out bad frames (see the module's docstring).

    Returns
    -------
    FrameFit
        The frames, their covariance (the learned noise's Cramer-Rao bound), the noise model and
        the samples left out.
    """
    n = len(q)
    problem = frames_problem(model, q, measured, handeye, world)
    first = identify_lm(problem)
    x1, w1 = frames_of(problem, first)
    flange = fk_of(model, q)
    errors = sample_errors(flange, measured, x1, w1)
    bad = bad_frames(errors)[0] if reject else np.zeros(n, dtype=bool)
    outliers = {}
    if bad.any():
        _, d2 = bad_frames(errors)
        for k in np.flatnonzero(bad):
            outliers[int(k)] = (
                f"{errors[k, :3].dot(errors[k, :3]) ** 0.5 * 1e3:.3f} mm, "
                f"{np.degrees(np.linalg.norm(errors[k, 3:])):.3f} deg off the fit of the others "
                f"(Mahalanobis distance {np.sqrt(d2[k]):.1f}, beyond the {OUTLIER_LEVEL:.1%} point)"
            )
        keep = ~bad
        problem = frames_problem(model, q[keep], measured[keep], x1, w1)
        x1, w1 = frames_of(problem, identify_lm(problem))
        errors = sample_errors(flange, measured, x1, w1)
    keep = ~bad
    noise = learn_noise(errors[keep])
    problem = frames_problem(model, q[keep], measured[keep], x1, w1)
    result = identify_weighted(problem, Noise(covariance=noise))
    x, w = frames_of(problem, result)
    cov = np.full((12, 12), np.nan)
    subset = result.identifiability.subset
    cov[np.ix_(subset, subset)] = result.covariance[np.ix_(subset, subset)]
    # the covariance is of perturbations at the start (x1, w1): carried to the estimate
    move = _reparametrise(x1, w1, x, w, result.params)
    cov = move @ np.nan_to_num(cov) @ move.T * weight_inflation(int(keep.sum()))
    held_mask = ~np.isin(np.arange(12), subset)
    cov[held_mask, :] = np.nan
    cov[:, held_mask] = np.nan
    return FrameFit(
        handeye=x,
        world=w,
        covariance=cov,
        used=keep,
        outliers=outliers,
        stopped=result.stopped,
        noise=noise,
        held=tuple(FRAME_NAMES[i] for i in np.flatnonzero(held_mask)),
        result=result,
        null_space=move
        @ np.asarray(result.identifiability.null_space, dtype=float).reshape(12, -1),
    )


def fk_of(model: RobotModel, q: np.ndarray) -> np.ndarray:
    from relcal.robot.kinematics import fk

    return fk(model, q)


def _reparametrise(
    x0: np.ndarray, w0: np.ndarray, x: np.ndarray, w: np.ndarray, params: np.ndarray
) -> np.ndarray:
    """``(12, 12)``: how perturbations at the start, ``X0 from_vector(p)`` (``X = X0
    from_vector(p_hat)``), map to perturbations at the estimate, ``X from_vector(v)``: with
    ``from_vector(p) = (exp(w), t)``, ``v_t = R(w_hat)^T (t - t_hat)`` and ``v_w = log(R(w_hat)^T
    R(w)) ~ J_r(w_hat) (w - w_hat)``."""
    del x0, w0, x, w
    out = np.zeros((12, 12))
    for block in (slice(0, 6), slice(6, 12)):
        p = params[block]
        b = block.start
        out[b : b + 3, b : b + 3] = tf.exp_rotation(p[3:]).T
        out[b + 3 : b + 6, b + 3 : b + 6] = tf.right_jacobian(p[3:])
    return out


# --- images --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Corners:
    """The board points found in one image: ``object_points`` ``(M, 3)`` (board frame, m) and
    ``image_points`` ``(M, 2)`` (px)."""

    object_points: np.ndarray
    image_points: np.ndarray


INTRINSIC_NAMES = ("fx", "fy", "cx", "cy")


def _camera_from_board(
    flange: np.ndarray, handeye: np.ndarray, world: np.ndarray, mode: str
) -> np.ndarray:
    """``(N, 4, 4)``: the board in the camera frame for each sample: ``(W F X)^-1`` when the
    camera is on the flange (eye-in-hand, robot-world), ``W F X`` when it is fixed."""
    c = world @ flange @ handeye
    return c if mode == "eye_to_hand" else tf.invert(c)


def _project(camera, transforms: np.ndarray, corners: list[Corners], intr=None) -> np.ndarray:
    """Reprojection residuals ``(sum M_k * 2,)`` (px) of every image's points."""
    import cv2

    k_mat, dist = camera.matrix.copy(), camera.dist.copy()
    if intr is not None:
        k_mat[0, 0], k_mat[1, 1], k_mat[0, 2], k_mat[1, 2] = intr[:4]
        dist = np.asarray(intr[4:], dtype=float)
    out = []
    for t, c in zip(transforms, corners, strict=True):
        rvec = cv2.Rodrigues(t[:3, :3])[0]
        uv, _ = cv2.projectPoints(c.object_points, rvec, t[:3, 3], k_mat, dist)
        out.append((uv.reshape(-1, 2) - c.image_points).ravel())
    return np.concatenate(out) if out else np.zeros(0)


def fit_images(
    flange: np.ndarray,
    corners: list[Corners],
    camera,
    handeye: np.ndarray,
    world: np.ndarray,
    mode: str,
    refine_intrinsics: bool = False,
    reject: bool = True,
    progress: bool = False,
    prior: tuple[np.ndarray, np.ndarray, float] | None = None,
) -> FrameFit:
    """The maximum-likelihood ``X`` and ``W`` (and intrinsics) of board images (maximum a
    posteriori with ``prior``).

    Parameters
    ----------
    flange : (N, 4, 4) ndarray of float
        ``F_k``, m.
    corners : list of Corners
        The board points found in each of the ``N`` images.
    camera : Camera
        The intrinsics (a start when refined).
    handeye, world : (4, 4) ndarray of float
        Starting ``X`` and ``W``, m.
    mode : {"eye_in_hand", "eye_to_hand", "robot_world"}
        Where the camera is (on the flange unless ``eye_to_hand``).
    refine_intrinsics : bool
        Refine focal lengths, principal point and distortion with the frames.
    reject : bool
        Leave out bad frames: a first pass with a robust (Huber) loss, then frames whose
        reprojection RMS is beyond 3 times the median and 1 px.
    progress : bool
        A progress bar over the solver's evaluations.
    prior : (guess, std, pixel_sigma), optional
        ``X`` held near ``guess`` ``(4, 4)`` with standard deviations ``std`` ``(6,)`` (m, rad,
        of ``guess^-1 X`` as a 6-vector): six residual rows ``pixel_sigma`` (px) times the
        deviation over ``std``, weighed against the pixels as their noise is. What the images
        determine stays theirs; what they leave free takes the guess.

    Returns
    -------
    FrameFit
        The frames, their covariance (of the least-squares estimate when each image's pixel
        errors are the pixel noise plus the image's pose error, both learned from the residuals:
        :func:`image_pose_noise`; ``s^2 (J^T J)^-1`` when the poses carry no error), the bad
        frames, the camera used.
    """
    from dataclasses import replace

    n = len(flange)
    dist0 = np.asarray(camera.distortion, dtype=float)
    if refine_intrinsics and len(dist0) == 0:
        dist0 = np.zeros(4)  # none given: k1, k2, p1, p2 refined from zero
    n_intr = (4 + len(dist0)) if refine_intrinsics else 0
    intr0 = np.r_[camera.fx, camera.fy, camera.cx, camera.cy, dist0] if n_intr else None

    def unpack(p: np.ndarray, keep: np.ndarray):
        x = handeye @ tf.from_vector(p[:6])
        w = world @ tf.from_vector(p[6:12])
        intr = intr0 + p[12:] if n_intr else None
        return _camera_from_board(flange[keep], x, w, mode), intr

    def pixels(p: np.ndarray, keep: np.ndarray) -> np.ndarray:
        t, intr = unpack(p, keep)
        return _project(camera, t, [c for c, k in zip(corners, keep, strict=True) if k], intr)

    def fun(p: np.ndarray, keep: np.ndarray) -> np.ndarray:
        if prior is None:
            return pixels(p, keep)
        guess, std, scale = prior
        held = tf.to_vector(tf.invert(guess) @ handeye @ tf.from_vector(p[:6]))
        return np.r_[pixels(p, keep), held / np.asarray(std, float) * scale]

    keep = np.ones(n, dtype=bool)
    p = np.zeros(12 + n_intr)
    outliers: dict[int, str] = {}
    bar = _bar(progress)
    try:
        if reject:
            sol = scipy.optimize.least_squares(
                lambda v: (bar.update(1), fun(v, keep))[1],
                p,
                method="trf",
                loss="huber",
                f_scale=1.0,
                x_scale="jac",
                max_nfev=200,
            )
            p = sol.x
            rms = _per_image_rms(pixels(p, keep), corners)
            limit = max(3.0 * float(np.median(rms)), 1.0)
            bad = rms > limit
            if 0 < bad.sum() <= MAX_OUTLIER_SHARE * n:
                for k in np.flatnonzero(bad):
                    outliers[int(k)] = (
                        f"reprojection RMS {rms[k]:.2f} px under the fit of all (above "
                        f"{limit:.2f} px: 3 times the median, 1 px at least)"
                    )
                keep = ~bad
        sol = scipy.optimize.least_squares(
            lambda v: (bar.update(1), fun(v, keep))[1],
            p,
            method="trf",
            x_scale="jac",
            max_nfev=200,
            xtol=1e-12,
            ftol=1e-12,
            gtol=1e-10,
        )
    finally:
        bar.close()
    p = sol.x
    r, jac = sol.fun, sol.jac
    info = jac.T @ jac
    scale_cols = np.sqrt(np.maximum(np.diag(info), 1e-300))
    vals, vecs = np.linalg.eigh(info / np.outer(scale_cols, scale_cols))
    null = vecs[:, vals < 1e-10 * vals.max()] / scale_cols[:, None]
    null = null[:12] / np.maximum(np.linalg.norm(null[:12], axis=0), 1e-300)
    x = handeye @ tf.from_vector(p[:6])
    w = world @ tf.from_vector(p[6:12])
    kept = [c for c, k in zip(corners, keep, strict=True) if k]
    intr = intr0 + p[12:] if n_intr else None
    n_pixels = sum(2 * len(c.image_points) for c in kept)
    noise = image_pose_noise(
        _camera_from_board(flange[keep], x, w, mode), kept, camera, intr, r[:n_pixels], mode
    )
    cov_all = _sandwich(jac, noise, kept)
    move = _reparametrise(handeye, world, x, w, p[:12])
    cov = move @ cov_all[:12, :12] @ move.T
    used_camera = camera
    if n_intr:
        v = intr0 + p[12:]
        used_camera = replace(
            camera, fx=v[0], fy=v[1], cx=v[2], cy=v[3], distortion=tuple(float(c) for c in v[4:])
        )
    grad = jac.T @ r
    scale = np.sqrt(np.maximum(np.diag(info), 1e-300))
    converged = (
        bool(sol.status > 0)
        and float(np.max(np.abs(grad) / scale)) <= 1e-6 * max(float(np.linalg.norm(r)), 1e-12) * 10
    )
    return FrameFit(
        handeye=x,
        world=w,
        covariance=cov,
        used=keep,
        outliers=outliers,
        stopped=converged,
        noise=noise.pose,
        pixel_sigma=noise.pixel_sigma,
        camera=used_camera,
        null_space=move @ null,
    )


@dataclass(frozen=True)
class ImageNoise:
    """The noise of an image fit: ``pixel_sigma`` (px per coordinate, measured after each image's
    own pose is freed), ``pose`` ``(6, 6)`` the covariance of each image's pose error beyond the
    pixels (m, rad, in the frame the chain's pose ends in: the camera's eye-in-hand, the
    board's eye-to-hand): what the flange poses, the robot's repeatability or a moving arm add,
    which the pixels of one image cannot show apart from the pose), and per image the pixel
    Jacobian ``(2 M_k, 6)`` of that pose."""

    pixel_sigma: float
    pose: np.ndarray
    pose_jacobians: tuple[np.ndarray, ...]


def image_pose_noise(
    transforms: np.ndarray,
    corners: list[Corners],
    camera,
    intr: np.ndarray | None,
    residuals: np.ndarray,
    mode: str,
) -> ImageNoise:
    """The pixel noise and the per-image pose noise of a fit whose board-in-camera transforms
    ``(N, 4, 4)`` left ``residuals`` ``(sum 2 M_k,)`` (px).

    Each image's residuals are split by a Gauss-Newton step of its own pose ``C_k exp(d_k)``
    (``C_k`` the chain's pose of the camera, eye-in-hand, or of the board, eye-to-hand): what
    is left is pixel noise (``sigma^2`` over ``sum 2 M_k - 6 N`` degrees of freedom); the steps
    ``d_k`` are pose errors plus the pose estimate's own noise ``sigma^2 (P_k^T P_k)^-1``, so
    the pose noise is the mean of ``d_k d_k^T`` less that, times ``N / (N - 2)`` (the 12 frame
    parameters fitted), projected on the positive semi-definite matrices."""
    jacobians, steps, own, left, count = [], [], [], 0.0, 0
    start = 0
    for t, c in zip(transforms, corners, strict=True):
        m2 = 2 * len(c.image_points)
        r = residuals[start : start + m2]
        start += m2
        jac = np.empty((m2, 6))
        h = np.r_[np.full(3, 1e-6), np.full(3, 1e-6)]
        for i in range(6):
            d = np.zeros(6)
            d[i] = h[i]
            plus = _project(camera, _moved(t, d, mode)[None], [c], intr)
            minus = _project(camera, _moved(t, -d, mode)[None], [c], intr)
            jac[:, i] = (plus - minus) / (2 * h[i])
        normal = jac.T @ jac
        step = -np.linalg.lstsq(jac, r, rcond=None)[0]
        rest = r + jac @ step
        left += float(rest @ rest)
        count += m2 - 6
        jacobians.append(jac)
        steps.append(step)
        own.append(np.linalg.pinv(normal))
    n = len(transforms)
    sigma2 = left / max(count, 1)
    pose = np.zeros((6, 6))
    if n > 2:
        d = np.array(steps)
        pose = (d.T @ d - sigma2 * np.sum(own, axis=0)) / (n - 2)
        vals, vecs = np.linalg.eigh(0.5 * (pose + pose.T))
        pose = (vecs * np.clip(vals, 0.0, None)) @ vecs.T
    return ImageNoise(float(np.sqrt(sigma2)), pose, tuple(jacobians))


def _moved(t: np.ndarray, d: np.ndarray, mode: str) -> np.ndarray:
    """The board-in-camera transform ``t`` when the chain's pose ``C`` moves to ``C exp(d)``:
    ``t = C`` eye-to-hand, ``t = C^-1`` otherwise."""
    step = tf.from_vector(d)
    return t @ step if mode == "eye_to_hand" else tf.invert(step) @ t


def _sandwich(jac: np.ndarray, noise: ImageNoise, corners: list[Corners]) -> np.ndarray:
    """The covariance of the least-squares estimate when each image's pixel errors have the
    covariance ``sigma^2 I + P_k S P_k^T`` (:class:`ImageNoise`): ``A^+ B A^+`` with ``A = J^T J``
    and ``B = sum_k J_k^T V_k J_k``."""
    info = jac.T @ jac  # pixel rows, then prior rows (of the pixels' noise by construction)
    a_inv = np.linalg.pinv(info, rcond=1e-12)
    b = noise.pixel_sigma**2 * info
    start = 0
    for c, p in zip(corners, noise.pose_jacobians, strict=True):
        m2 = 2 * len(c.image_points)
        jk = jac[start : start + m2]
        start += m2
        g = jk.T @ p  # (params, 6)
        b = b + g @ noise.pose @ g.T
    return a_inv @ b @ a_inv


def _per_image_rms(r: np.ndarray, corners: list[Corners]) -> np.ndarray:
    sizes = [len(c.image_points) for c in corners]
    out, start = [], 0
    for m in sizes:
        part = r[start : start + 2 * m].reshape(-1, 2)
        out.append(np.sqrt(np.mean(np.sum(part**2, axis=1))))
        start += 2 * m
    return np.array(out)


def reprojection_rms(
    flange: np.ndarray,
    corners: list[Corners],
    camera,
    handeye: np.ndarray,
    world: np.ndarray,
    mode: str,
) -> np.ndarray:
    """Each image's reprojection RMS ``(N,)`` (px) with the board placed by ``W F_k X``."""
    t = _camera_from_board(flange, handeye, world, mode)
    return _per_image_rms(_project(camera, t, corners), corners)


class _NoBar:
    def update(self, _n: int) -> None:
        pass

    def close(self) -> None:
        pass


def _bar(progress: bool):
    if not progress:
        return _NoBar()
    from tqdm import tqdm

    return tqdm(desc="refining", unit=" evaluations", leave=False)
