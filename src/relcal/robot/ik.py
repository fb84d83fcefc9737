"""Inverse kinematics: closed form for spherical-wrist 6R arms, damped least squares for any chain.

Targets are tool poses in the base frame, as returned by :func:`relcal.robot.kinematics.fk`: one
``(4, 4)`` matrix or a batch ``(N, 4, 4)``. Joint values are rad (revolute) or m (prismatic).

- :func:`solve_closed_form`: all (up to 8) solutions of a 6R standard-DH arm whose joints 2 and 3
  are parallel, whose joint 1 is not parallel to them, and whose last three axes meet in one point
  (A465, PUMA 560, IRB 120, ...). The wrist centre gives joints 1-3, the orientation joints 4-6.
- :func:`solve_numeric`: Levenberg-Marquardt on the pose error with the joint Jacobian, joints
  kept within their limits, batched over targets. Works for any chain.
- :func:`solve`: the closed-form branches (of the model, or of its idealised nominal when a
  calibrated model lost the spherical wrist) refined numerically, the branch nearest ``q_near``
  first; numeric from ``q_near`` and a few restarts when no closed form exists.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from relcal import geometry as tf
from relcal.errors import RelcalError
from relcal.robot.kinematics import Layout, fk, forward_frames, pose_jacobian
from relcal.robot.model import NONGEOMETRIC_KINDS, RobotModel

TWO_PI = 2.0 * np.pi
_LIMIT_SLACK = 1e-10  # rad or m a closed-form solution may sit outside a limit (then clipped)
_VERIFY_TOL = 1e-6  # m / rad: closed-form solutions reproducing the target worse are dropped


@dataclass(frozen=True)
class IKResult:
    """Joint solutions and how well they reach their targets.

    Attributes
    ----------
    q : (N, n) or (n,) joint values (rad, m), within the joint limits.
    converged : (N,) or scalar bool, both errors below their tolerances.
    position_error : (N,) or scalar, remaining tool position error (m).
    rotation_error : (N,) or scalar, remaining tool rotation error (rad).
    iterations : (N,) or scalar, numeric iterations used.
    """

    q: np.ndarray
    converged: np.ndarray
    position_error: np.ndarray
    rotation_error: np.ndarray
    iterations: np.ndarray

    def _squeeze(self) -> IKResult:
        return IKResult(*(np.asarray(v)[0] for v in vars(self).values()))


# --- helpers -----------------------------------------------------------------------------------


def wrap_angle(angle: np.ndarray) -> np.ndarray:
    """Angles wrapped to ``(-pi, pi]`` (rad), any shape."""
    return np.pi - np.mod(np.pi - np.asarray(angle, dtype=float), TWO_PI)


def nearest_equivalent(
    model: RobotModel, q: np.ndarray, reference: np.ndarray, slack: float = _LIMIT_SLACK
) -> np.ndarray:
    """Revolute joints shifted by whole turns into the limits, as near ``reference`` as possible.

    ``q`` and ``reference`` broadcast over ``(..., n)``. Prismatic joints are unchanged. Values
    within ``slack`` (rad) outside a limit are clipped onto it; entries with no turn inside the
    limits become NaN.
    """
    q = np.asarray(q, dtype=float)
    ref = np.broadcast_to(np.asarray(reference, dtype=float), q.shape)
    with np.errstate(invalid="ignore"):
        k_lo = np.ceil((model.lower - slack - q) / TWO_PI)
        k_hi = np.floor((model.upper + slack - q) / TWO_PI)
        k = np.clip(np.round((ref - q) / TWO_PI), k_lo, k_hi)
        shifted = np.clip(q + TWO_PI * k, model.lower, model.upper)
        shifted = np.where(k_lo > k_hi, np.nan, shifted)
    return np.where(model.prismatic, q, shifted)


def within_limits(model: RobotModel, q: np.ndarray, slack: float = 0.0) -> np.ndarray:
    """Mask ``(...)`` of joint vectors ``(..., n)`` inside ``[lower - slack, upper + slack]``."""
    q = np.asarray(q, dtype=float)
    return np.all((q >= model.lower - slack) & (q <= model.upper + slack), axis=-1)


def joint_layout(model: RobotModel) -> Layout:
    """A layout whose parameters are the joint variables (``theta_off`` or ``d`` of each joint).

    ``pose_jacobian`` with it is the usual geometric joint Jacobian, since a joint variable adds
    to ``theta_off`` (revolute) or ``d`` (prismatic).
    """
    kinds = tuple("d" if p else "theta_off" for p in model.prismatic)
    names = tuple(f"q[{i + 1}]" for i in range(model.n_joints))
    return Layout(names, kinds, tuple(range(model.n_joints)))


def _as_targets(target: np.ndarray) -> tuple[np.ndarray, bool]:
    target = np.asarray(target, dtype=float)
    if target.shape[-2:] != (4, 4) or target.ndim not in (2, 3):
        raise RelcalError(f"IK target must be a (4, 4) or (N, 4, 4) pose, got shape {target.shape}")
    return target.reshape(-1, 4, 4), target.ndim == 2


def _as_joints(model: RobotModel, q: np.ndarray, n_targets: int, what: str) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    if q.shape[-1:] != (model.n_joints,) or q.ndim > 2:
        raise RelcalError(
            f"{what} must have shape ({model.n_joints},) or (N, {model.n_joints}), got {q.shape}"
        )
    try:
        return np.broadcast_to(q.reshape(-1, model.n_joints), (n_targets, model.n_joints)).copy()
    except ValueError:
        raise RelcalError(f"{what} has {len(q)} rows for {n_targets} targets") from None


# --- structure tests ---------------------------------------------------------------------------


def _joint_axes(model: RobotModel, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points and unit directions ``(N, n, 3)`` of the joint axes, base frame."""
    frames = forward_frames(model, q)
    on_axis = frames[:, :-1] if model.convention == "dh" else frames[:, 1:]
    return on_axis[..., :3, 3], on_axis[..., :3, 2]


def wrist_miss(model: RobotModel) -> float:
    """How far (m) the axes of the last three joints are from meeting in one point.

    The largest distance of an axis from the point nearest to all three, over a few fixed
    configurations; ``inf`` when the axes are parallel or the chain is shorter than 3 joints.
    """
    n = model.n_joints
    if n < 3 or model.prismatic[-3:].any():
        return np.inf
    q = np.array([np.zeros(n), 0.3 + 0.1 * np.arange(n), -0.7 + 0.25 * np.arange(n)])
    points, dirs = _joint_axes(model, q)
    points, dirs = points[:, -3:], dirs[:, -3:]
    proj = np.eye(3) - dirs[..., :, None] * dirs[..., None, :]  # (N, 3, 3, 3)
    lhs, rhs = proj.sum(axis=1), np.einsum("nkij,nkj->ni", proj, points)
    if np.linalg.eigvalsh(lhs)[:, 0].min() < 1e-9:
        return np.inf
    centre = np.linalg.solve(lhs, rhs[..., None])[..., 0]
    miss = np.einsum("nkij,nkj->nki", proj, centre[:, None] - points)
    return float(np.linalg.norm(miss, axis=-1).max())


def has_spherical_wrist(model: RobotModel, tol: float = 1e-9) -> bool:
    """Whether the axes of the last three joints (revolute) meet in one point, within ``tol`` m."""
    return wrist_miss(model) <= tol


def _link_rotations(model: RobotModel) -> np.ndarray:
    """The constant part ``Rx(alpha_i) Ry(beta_i)`` of each joint transform, ``(n, 3, 3)``."""
    return tf.rot_x(model.alpha) @ tf.rot_y(model.beta)


def closed_form_problem(model: RobotModel, tol: float = 1e-9) -> str | None:
    """Why :func:`solve_closed_form` cannot handle ``model``, or None when it can."""
    if model.n_joints != 6 or model.prismatic.any():
        return f"it has {model.n_joints} joints; the closed form needs 6 revolute joints"
    if model.convention != "dh":
        return "it is in modified DH; the closed form is written for standard DH chains"
    miss = wrist_miss(model)
    if miss > tol:
        return (
            f"the axes of joints 4, 5 and 6 do not meet in one point (they miss by {miss:.3g} m, "
            f"tolerance {tol:.3g} m): no spherical wrist"
        )
    if max(abs(model.a[3]), abs(model.a[4]), abs(model.d[4])) > tol:
        return "the wrist offsets a[4], a[5] and d[5] are not zero"
    if abs(np.sin(model.alpha[1])) > tol or abs(np.sin(model.beta[1])) > tol:
        return "the axes of joints 2 and 3 are not parallel (alpha[2] or beta[2])"
    if np.hypot(*_link_rotations(model)[0][:2, 2]) < 1e-6:
        return "the axes of joints 1 and 2 are parallel"
    if abs(model.a[1]) < tol or np.hypot(*_forearm(model)[:2]) < tol:
        return "the upper arm or the forearm has zero length"
    return None


def check_closed_form(model: RobotModel, tol: float = 1e-9) -> None:
    """Raise :class:`RelcalError` unless ``model`` has the closed form of this module."""
    problem = closed_form_problem(model, tol)
    if problem is not None:
        raise RelcalError(
            f"robot '{model.name}' has no closed-form inverse kinematics: {problem}. "
            "Use relcal.robot.ik.solve or relcal.robot.ik.solve_numeric instead."
        )


def idealised(
    model: RobotModel, length_tol: float = 0.01, angle_tol: float = np.radians(2.0)
) -> RobotModel | None:
    """The nearby model with a closed form, or None.

    A calibrated arm keeps its nominal structure only approximately: this sets the wrist offsets
    ``a[4]``, ``a[5]``, ``d[5]`` and ``beta[2]`` to zero and ``alpha[2]`` to the nearest multiple
    of pi when they are within ``length_tol`` (m) and ``angle_tol`` (rad). Its solutions are good
    seeds for the numeric solver on the calibrated model.
    """
    if model.n_joints != 6 or model.convention != "dh" or model.prismatic.any():
        return None
    a, d, alpha, beta = model.a.copy(), model.d.copy(), model.alpha.copy(), model.beta.copy()
    snapped_alpha = np.round(alpha[1] / np.pi) * np.pi
    if max(abs(a[3]), abs(a[4]), abs(d[4])) > length_tol:
        return None
    if max(abs(alpha[1] - snapped_alpha), abs(beta[1])) > angle_tol:
        return None
    a[3] = a[4] = d[4] = beta[1] = 0.0
    alpha[1] = snapped_alpha
    ideal = model.with_values(a=a, d=d, alpha=alpha, beta=beta)
    return ideal if closed_form_problem(ideal) is None else None


# --- closed form -------------------------------------------------------------------------------


def _trig_roots(a: np.ndarray, b: np.ndarray, c: np.ndarray, slack: float) -> np.ndarray:
    """Both roots ``(..., 2)`` of ``a cos x + b sin x = c``; NaN where there is none.

    ``|c| / hypot(a, b)`` up to ``1 + slack`` counts as 1 (the double root). When
    ``a = b = c = 0`` every angle solves it; the roots 0 and pi are returned.
    """
    a, b, c = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (a, b, c)))
    r = np.hypot(a, b)
    free = (r < 1e-12) & (np.abs(c) < 1e-12)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = c / r
    ratio = np.where(np.abs(ratio) <= 1.0 + slack, np.clip(ratio, -1.0, 1.0), np.nan)
    roots = np.arctan2(b, a)[..., None] + np.arccos(ratio)[..., None] * np.array([1.0, -1.0])
    return np.where(free[..., None], np.array([0.0, np.pi]), roots)


def _forearm(model: RobotModel) -> np.ndarray:
    """Wrist centre in the frame after ``Rz(theta_3)`` of joint 3, minus ``d[3]`` (m)."""
    rc = _link_rotations(model)
    return np.array([model.a[2], 0.0, 0.0]) + rc[2] @ np.array([0.0, 0.0, model.d[3]])


def _arm_angles(model: RobotModel, centre: np.ndarray, slack: float) -> np.ndarray:
    """Joint angles ``theta_1..3`` (incl. offsets) ``(N, 4, 3)`` placing the wrist centre.

    ``centre`` ``(N, 3)`` is in the frame before joint 1 (base removed). Branch order: shoulder
    (2) x elbow (2); NaN where the centre is out of reach (by more than ``slack``, relative).
    """
    rc = _link_rotations(model)
    normal = rc[0][:, 2]  # axis 2 in the frame of joint 1 before Rz(theta_1)
    s2 = np.cos(model.alpha[1])  # +-1: joints 2 and 3 parallel or antiparallel
    fore = _forearm(model)
    height = model.d[1] + s2 * (model.d[2] + fore[2])  # wrist centre along axis 2
    px, py, pz = centre.T
    link1 = np.array([model.a[0], 0.0, model.d[0]])
    th1 = _trig_roots(
        normal[0] * px + normal[1] * py,
        normal[0] * py - normal[1] * px,
        height + normal @ link1 - normal[2] * pz,
        slack,
    )  # (N, 2)
    rot1 = tf.rot_z(th1) @ rc[0]  # (N, 2, 3, 3)
    origin1 = tf.rot_z(th1) @ link1
    local = np.einsum("nbji,nbj->nbi", rot1, centre[:, None] - origin1)  # R1^T (p - o1)
    x, y = local[..., 0], local[..., 1]
    a2, length = model.a[1], np.hypot(fore[0], fore[1])
    phi = np.arctan2(s2 * fore[1], fore[0])
    with np.errstate(invalid="ignore"):
        cos_psi = (x**2 + y**2 - a2**2 - length**2) / (2 * a2 * length)
        cos_psi = np.where(np.abs(cos_psi) <= 1 + slack, np.clip(cos_psi, -1, 1), np.nan)
        psi = np.arccos(cos_psi)[..., None] * np.array([1.0, -1.0])  # (N, 2, 2)
    th2 = np.arctan2(y, x)[..., None] - np.arctan2(length * np.sin(psi), a2 + length * np.cos(psi))
    th3 = s2 * (psi - phi)
    th1 = np.broadcast_to(th1[..., None], th2.shape)
    return np.stack([th1, th2, th3], axis=-1).reshape(len(centre), 4, 3)


def _wrist_angles(
    model: RobotModel, arm: np.ndarray, flange_rot: np.ndarray, slack: float
) -> np.ndarray:
    """Joint angles ``theta_4..6`` ``(N, 4, 2, 3)`` for arm angles ``(N, 4, 3)``.

    Solves ``Rz(t4) R4 Rz(t5) R5 Rz(t6) = R3^T R_flange R6^T`` with ``Ri = Rx(alpha_i) Ry(beta_i)``:
    the third row/column gives ``t5`` (two roots), then ``t4`` aligns the wrist axis 6 and ``t6``
    is what remains. At a wrist singularity ``t4`` is taken as 0.
    """
    rc = _link_rotations(model)
    rot3 = (
        tf.rot_z(arm[..., 0])
        @ rc[0]
        @ tf.rot_z(arm[..., 1])
        @ rc[1]
        @ tf.rot_z(arm[..., 2])
        @ rc[2]
    )
    m = np.swapaxes(rot3, -1, -2) @ flange_rot[:, None] @ rc[5].T  # (N, 4, 3, 3)
    u, v = rc[3][2], rc[4][:, 2]  # R4^T e_z and R5 e_z
    th5 = _trig_roots(
        u[0] * v[0] + u[1] * v[1], u[1] * v[0] - u[0] * v[1], m[..., 2, 2] - u[2] * v[2], slack
    )  # (N, 4, 2)
    w = (rc[3] @ tf.rot_z(th5)) @ v  # axis 6 after joints 5, 6, before Rz(t4): (N, 4, 2, 3)
    mz = m[..., :, 2][:, :, None]
    th4 = np.arctan2(mz[..., 1], mz[..., 0]) - np.arctan2(w[..., 1], w[..., 0])
    singular = np.hypot(w[..., 0], w[..., 1]) < 1e-12
    th4 = np.where(singular, 0.0, th4)
    partial = tf.rot_z(th4) @ rc[3] @ tf.rot_z(th5) @ rc[4]
    rest = np.swapaxes(partial, -1, -2) @ m[:, :, None]
    th6 = np.arctan2(rest[..., 1, 0], rest[..., 0, 0])
    return np.stack([th4, th5, th6], axis=-1)


def _closed_form_batch(
    model: RobotModel, targets: np.ndarray, approximate: bool = False
) -> np.ndarray:
    """Joint values ``(N, 8, 6)`` (not wrapped, limits ignored; NaN rows where unreachable).

    Branch order: shoulder x elbow x wrist flip. Rows that do not reproduce their target within
    1e-6 m / rad are NaN too, unless ``approximate``: then targets slightly out of reach (5 %
    in the cosines) get the nearest stretched configuration, to seed a nearby calibrated model.
    """
    slack = 0.05 if approximate else 1e-9
    flange = tf.invert(model.base) @ targets @ tf.invert(model.tool)
    rc6 = _link_rotations(model)[5]
    last = rc6.T @ np.array([model.a[5], 0.0, model.d[5]])
    centre = flange[:, :3, 3] - flange[:, :3, :3] @ last
    arm = _arm_angles(model, centre, slack)  # (N, 4, 3)
    wrist = _wrist_angles(model, arm, flange[:, :3, :3], slack)  # (N, 4, 2, 3)
    arm = np.broadcast_to(arm[:, :, None], wrist.shape)
    theta = np.concatenate([arm, wrist], axis=-1).reshape(len(targets), 8, 6)
    q = theta - model.theta_off
    return q if approximate else _drop_wrong(model, q, targets)


def _drop_wrong(model: RobotModel, q: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """``q`` ``(N, K, n)`` with NaN rows where FK misses the target by more than 1e-6."""
    n_targets, k, n = q.shape
    ok = ~np.isnan(q).any(axis=-1)
    flat = np.where(ok[..., None], q, 0.0).reshape(-1, n)
    poses = fk(model, flat)
    err_all = tf.pose_error(np.repeat(targets, k, axis=0), poses).reshape(n_targets, k, 6)
    err = np.where(ok, np.abs(err_all).max(axis=-1), np.inf)
    return np.where((err <= _VERIFY_TOL)[..., None], q, np.nan)


def _unique_rows(q: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    keep: list[np.ndarray] = []
    for row in q:
        if all(np.abs(wrap_angle(row - other)).max() > tol for other in keep):
            keep.append(row)
    return np.array(keep).reshape(-1, q.shape[-1])


def solve_closed_form(
    model: RobotModel, target: np.ndarray, *, respect_limits: bool = True, tol: float = 1e-9
) -> np.ndarray:
    """All inverse kinematics solutions of a 6R spherical-wrist arm, shape ``(K, 6)``, K <= 8.

    Parameters
    ----------
    model : standard-DH 6R chain whose joints 2 and 3 are parallel and whose last three axes meet
        in one point (any base, tool, theta offsets, link lengths and offsets otherwise).
    target : ``(4, 4)`` tool pose in the base frame (m).
    respect_limits : keep only solutions within the joint limits; a joint is wrapped to
        ``(-pi, pi]``, or shifted by a whole turn when only that lies within its limits. When
        False every solution is returned, wrapped to ``(-pi, pi]``.
    tol : tolerance (m) of the structure test, see :func:`closed_form_problem`.

    Returns
    -------
    ``(K, 6)`` joint vectors (rad), duplicates removed; ``K = 0`` when the pose is out of reach.

    Raises
    ------
    RelcalError
        When the model has no spherical wrist or not the arm structure above.
    """
    check_closed_form(model, tol)
    targets, single = _as_targets(target)
    if not single:
        raise RelcalError("solve_closed_form takes one (4, 4) target; loop or use solve()")
    q = wrap_angle(_closed_form_batch(model, targets)[0])
    if respect_limits:
        q = nearest_equivalent(model, q, np.zeros(6))
    return _unique_rows(q[~np.isnan(q).any(axis=-1)])


# --- numeric -----------------------------------------------------------------------------------


def _converged(err: np.ndarray, position_tol: float, rotation_tol: float) -> np.ndarray:
    pos, rot = np.linalg.norm(err[:, :3], axis=1), np.linalg.norm(err[:, 3:], axis=1)
    return (pos <= position_tol) & (rot <= rotation_tol)


def _lm_step(
    model: RobotModel, q: np.ndarray, err: np.ndarray, damping: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Damped Gauss-Newton step ``(N, n)`` and its predicted decrease of ``|e|^2`` ``(N,)``.

    Solves ``(J^T J + mu I) dq = J^T e`` with ``mu = |e|^2 / 2 + lambda`` (Sugihara's damping keeps
    far-away steps short). Joints at a limit whose step points outwards are held (active set).
    """
    _, jac = pose_jacobian(model, q, joint_layout(model))
    mu = 0.5 * np.einsum("ni,ni->n", err, err) + damping
    free = np.ones(q.shape, dtype=bool)
    for _ in range(2):
        jac_free = jac * free[:, None, :]
        jt = np.swapaxes(jac_free, -1, -2)
        grad = (jt @ err[..., None])[..., 0]
        lhs = jt @ jac_free + mu[:, None, None] * np.eye(model.n_joints)
        step = np.linalg.solve(lhs, grad[..., None])[..., 0]
        blocked = ((q <= model.lower) & (step < 0)) | ((q >= model.upper) & (step > 0))
        if not blocked.any():
            break
        free &= ~blocked
    predicted = np.einsum("ni,ni->n", step, grad + mu[:, None] * step)
    return step, predicted


def solve_numeric(
    model: RobotModel,
    target: np.ndarray,
    seed: np.ndarray,
    *,
    position_tol: float = 1e-10,
    rotation_tol: float = 1e-10,
    max_iter: int = 100,
    damping: float = 1e-3,
) -> IKResult:
    """Levenberg-Marquardt inverse kinematics for any chain, batched over targets.

    Each iteration takes the damped step (joints held at a limit they push against), clips the
    joints into their limits and keeps the step if the squared pose error decreased; ``damping``
    follows Nielsen's gain-ratio rule. Redundant chains get the damped minimum-change step.

    Parameters
    ----------
    model : any serial chain.
    target : ``(4, 4)`` or ``(N, 4, 4)`` tool poses in the base frame.
    seed : ``(n,)`` or ``(N, n)`` starting joint values (clipped into the limits first).
    position_tol, rotation_tol : convergence thresholds on the tool error (m, rad).
    max_iter : iteration cap per target.
    damping : initial Levenberg-Marquardt damping (m^2).

    Returns
    -------
    :class:`IKResult`, unbatched when ``target`` is ``(4, 4)``.
    """
    targets, single = _as_targets(target)
    q = np.clip(_as_joints(model, seed, len(targets), "seed"), model.lower, model.upper)
    err = tf.pose_error(targets, fk(model, q))
    cost = np.einsum("ni,ni->n", err, err)
    lam = np.full(len(targets), float(damping))
    grow = np.full(len(targets), 2.0)
    iters = np.zeros(len(targets), dtype=int)
    done = _converged(err, position_tol, rotation_tol)
    for _ in range(max_iter):
        act = np.flatnonzero(~done & (lam < 1e12))
        if act.size == 0:
            break
        step, predicted = _lm_step(model, q[act], err[act], lam[act])
        trial = np.clip(q[act] + step, model.lower, model.upper)
        trial_err = tf.pose_error(targets[act], fk(model, trial))
        trial_cost = np.einsum("ni,ni->n", trial_err, trial_err)
        gain = (cost[act] - trial_cost) / np.maximum(predicted, 1e-300)
        better = trial_cost < cost[act]
        idx = act[better]
        q[idx], err[idx], cost[idx] = trial[better], trial_err[better], trial_cost[better]
        shrink = np.maximum(1 / 3, 1 - (2 * np.clip(gain, 0, 1) - 1) ** 3)
        lam[act] = np.where(better, np.maximum(lam[act] * shrink, 1e-12), lam[act] * grow[act])
        grow[act] = np.where(better, 2.0, grow[act] * 2)
        iters[act] += 1
        done[act] = _converged(err[act], position_tol, rotation_tol)
    result = IKResult(
        q=q,
        converged=done,
        position_error=np.linalg.norm(err[:, :3], axis=1),
        rotation_error=np.linalg.norm(err[:, 3:], axis=1),
        iterations=iters,
    )
    return result._squeeze() if single else result


# --- combined ----------------------------------------------------------------------------------


def _closed_form_model(model: RobotModel, seed_model: RobotModel | None) -> RobotModel | None:
    """The model whose closed form seeds ``model``: itself, ``seed_model``, or its idealisation.
    A model with non-geometric terms is never its own exact closed form: its geometry's branches
    are effective joint values, close to but not the readings, so they only seed."""
    if closed_form_problem(model) is None:
        if not model.has_nongeometric_values():
            return model
        if seed_model is None:
            return replace(model, **{k: None for k in NONGEOMETRIC_KINDS})
    if seed_model is not None:
        if seed_model.n_joints != model.n_joints:
            raise RelcalError(
                f"seed model '{seed_model.name}' has {seed_model.n_joints} joints, "
                f"'{model.name}' has {model.n_joints}"
            )
        return seed_model if closed_form_problem(seed_model) is None else idealised(seed_model)
    return idealised(model)


def _random_seeds(model: RobotModel, count: int, n_targets: int) -> np.ndarray:
    """Deterministic seeds ``(n_targets, count, n)`` spread over the limits (one turn at most)."""
    lo = np.where(model.prismatic, model.lower, np.maximum(model.lower, -np.pi))
    hi = np.where(model.prismatic, model.upper, np.minimum(model.upper, np.pi))
    lo, hi = np.where(np.isfinite(lo), lo, -1.0), np.where(np.isfinite(hi), hi, 1.0)
    rng = np.random.default_rng(0)
    return rng.uniform(lo, hi, size=(n_targets, count, model.n_joints))


def _branch_seeds(
    model: RobotModel, source: RobotModel, targets: np.ndarray, reference: np.ndarray
) -> np.ndarray:
    """Seeds ``(N, K, n)`` from the closed form of ``source`` (NaN rows unused).

    Exact branches (``source is model``) need no other seed; ``reference`` is kept only for
    targets without a branch within the limits. Branches of an idealised model may sit slightly
    outside the limits (0.05 rad) and are clipped in, and ``reference`` is always a seed.
    """
    first = reference[:, None]
    exact = source is model
    branches = _closed_form_batch(source, targets, approximate=not exact)
    branches = nearest_equivalent(model, branches, first, _LIMIT_SLACK if exact else 0.05)
    if exact:
        none = np.isnan(branches).any(axis=-1).all(axis=-1)
        first = np.where(none[:, None, None], first, np.nan)
    return np.concatenate([first, branches], axis=1)


def _refine(model: RobotModel, targets: np.ndarray, seeds: np.ndarray, options: dict) -> IKResult:
    """:func:`solve_numeric` from seeds ``(N, K, n)`` (NaN rows skipped); fields ``(N, K, ...)``.

    Skipped seeds come back as NaN joints, not converged, with infinite errors.
    """
    used = ~np.isnan(seeds).any(axis=-1)
    res = solve_numeric(
        model, np.broadcast_to(targets[:, None], (*used.shape, 4, 4))[used], seeds[used], **options
    )
    fields = {"q": np.full(seeds.shape, np.nan), "converged": np.zeros(used.shape, dtype=bool)}
    fields |= {"position_error": np.full(used.shape, np.inf)}
    fields |= {"rotation_error": np.full(used.shape, np.inf)}
    fields |= {"iterations": np.zeros(used.shape, dtype=int)}
    for name, value in fields.items():
        value[used] = getattr(res, name)
    return IKResult(**fields)


def _nearest_converged(model: RobotModel, res: IKResult, reference: np.ndarray) -> IKResult:
    """Per target, the converged candidate of ``res`` ``(N, K, ...)`` nearest ``reference``.

    Joints are first shifted by whole turns (within limits) towards ``reference`` ``(N, n)``.
    Without a converged candidate, the one with the smallest error is taken.
    """
    ref = np.broadcast_to(reference[:, None], res.q.shape)
    q = nearest_equivalent(model, res.q, ref)
    dist = np.linalg.norm(q - ref, axis=-1)
    score = np.where(res.converged, dist, 1e6 + res.position_error + res.rotation_error)
    pick = (np.arange(len(q)), np.argmin(score, axis=1))
    fields = {name: np.asarray(value)[pick] for name, value in vars(res).items()}
    return IKResult(**(fields | {"q": q[pick]}))


def _replace_rows(result: IKResult, rows: np.ndarray, other: IKResult) -> IKResult:
    """``result`` with ``rows`` taken from ``other`` where ``other`` converged."""
    take = rows[other.converged]
    fields = {}
    for name, value in vars(result).items():
        value = np.array(value)
        value[take] = getattr(other, name)[other.converged]
        fields[name] = value
    return IKResult(**fields)


def solve(
    model: RobotModel,
    target: np.ndarray,
    q_near: np.ndarray | None = None,
    *,
    seed_model: RobotModel | None = None,
    restarts: int = 8,
    position_tol: float = 1e-10,
    rotation_tol: float = 1e-10,
    max_iter: int = 100,
) -> IKResult:
    """Inverse kinematics of any chain: the converged solution nearest ``q_near``.

    Seeds are the closed-form branches of ``model`` when it has a closed form (every solution
    within limits is among them, so nothing else is tried). Otherwise ``q_near`` and, when
    available, the branches of ``seed_model`` or of the idealised ``model`` (a calibrated arm
    whose wrist is no longer exactly spherical, see :func:`idealised`); targets still unsolved
    get ``restarts`` deterministic random seeds. Seeds are refined by :func:`solve_numeric` on
    ``model``; among converged results the one nearest ``q_near`` (after whole-turn shifts within
    limits) is returned, else the one with the smallest error.

    Parameters
    ----------
    model : the chain to invert (nominal or calibrated).
    target : ``(4, 4)`` or ``(N, 4, 4)`` tool poses in the base frame (m).
    q_near : ``(n,)`` or ``(N, n)`` preferred joint values; default zeros clipped to the limits.
    seed_model : a model with a closed form (e.g. the nominal one) whose branches seed ``model``.
    restarts : random seeds per target when there is no closed form.
    position_tol, rotation_tol, max_iter : see :func:`solve_numeric`.

    Returns
    -------
    :class:`IKResult`, unbatched when ``target`` is ``(4, 4)``.
    """
    targets, single = _as_targets(target)
    near = np.clip(np.zeros(model.n_joints), model.lower, model.upper) if q_near is None else q_near
    reference = _as_joints(model, near, len(targets), "q_near")
    options = dict(position_tol=position_tol, rotation_tol=rotation_tol, max_iter=max_iter)
    source = _closed_form_model(model, seed_model)
    if source is None:
        seeds = reference[:, None]
    else:
        seeds = _branch_seeds(model, source, targets, reference)
    result = _nearest_converged(model, _refine(model, targets, seeds, options), reference)
    retry = np.flatnonzero(~result.converged)
    if source is not model and retry.size and restarts > 0:
        seeds = _random_seeds(model, restarts, retry.size)
        again = _refine(model, targets[retry], seeds, options)
        result = _replace_rows(result, retry, _nearest_converged(model, again, reference[retry]))
    return result._squeeze() if single else result


def inverse_condition(model: RobotModel, q: np.ndarray, length_scale: float) -> np.ndarray:
    """``s_min / s_max`` ``(N,)`` of the joint Jacobian with translation rows over
    ``length_scale`` (m): 0 at a singularity."""
    _, jac = pose_jacobian(model, q, joint_layout(model))
    jac = jac.copy()
    jac[:, :3] /= length_scale
    s = np.linalg.svd(jac, compute_uv=False)
    return s[:, -1] / s[:, 0]
