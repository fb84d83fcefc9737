"""Which joint configurations a plan may use: candidates drawn as camera poses over the board,
solved by inverse kinematics, and kept when every constraint holds (:func:`check`): joint limits,
the whole board in view with a margin, distance and viewing angle, away from singularities,
clearance above the board, no self-collision and no collision with the cell's obstacles (capsules
about the links, :mod:`relcal.design.collision`, or the URDF's collision geometry), and a clear
line of sight from the camera to the board past the robot's own links
(:mod:`relcal.design.sight`).

On a Dask cluster the candidate batches are tasks; each batch draws from its own stream of the
seed (:func:`batch_seed`), so the pool does not depend on where or in which order batches run.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from relcal import geometry as tf
from relcal.cluster import prepare_worker
from relcal.design.cell import AnyCell, Cell
from relcal.design.collision import cell_collision, self_collision
from relcal.design.sight import in_image
from relcal.design.urdf_collision import urdf_geometry
from relcal.errors import RelcalError
from relcal.geometry import look_at
from relcal.robot.ik import inverse_condition, solve
from relcal.robot.kinematics import fk, forward_frames
from relcal.robot.model import RobotModel


@dataclass(frozen=True)
class Constraints:
    """What makes a configuration usable (lengths m, angles deg)."""

    margin_px: float = 40.0
    distance: tuple[float, float] = (0.25, 0.45)
    max_view_angle_deg: float = 40.0
    min_inverse_condition: float = 0.05
    clearance: float = 0.05
    length_scale: float = 0.5
    aim: float = 0.1  # sampled aim points within this fraction of the pattern size of its centre
    link_radius: float = 0.04  # m: capsules about the links' skeleton (0: no self-collision check)
    camera_radius: float = 0.04  # m: a sphere about the camera
    obstacles: tuple[tuple[float, ...], ...] = ()  # boxes (xmin, ymin, zmin, xmax, ymax, zmax), m
    sight_grid: int = 5  # sight lines per side of the pattern (0: no line-of-sight check)


def camera_poses(model: RobotModel, cell: Cell, q: np.ndarray) -> np.ndarray:
    """Camera poses ``(N, 4, 4)`` in the base frame with the nominal model."""
    return fk(model, q) @ cell.handeye


def image_points(cell: Cell, cameras: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels ``(N, 4, 2)`` of the pattern corners and their depths ``(N, 4)`` (m)."""
    corners = np.c_[cell.corners, np.ones(4)]  # (4, 4) homogeneous rows
    in_camera = tf.invert(cameras) @ cell.board_pose  # camera-from-board (N, 4, 4)
    pts = np.einsum("nij,kj->nki", in_camera, corners)[..., :3]
    z = pts[..., 2]
    safe = np.where(z > 1e-9, z, 1e-9)
    cam = cell.camera
    u = cam.fx * pts[..., 0] / safe + cam.cx
    v = cam.fy * pts[..., 1] / safe + cam.cy
    return np.stack([u, v], axis=-1), z


CONSTRAINTS = (
    "joint limits",
    "board in view",
    "distance",
    "viewing angle",
    "singularity",
    "clearance",
    "self-collision",
    "cell collision",
    "line of sight",
)  # the masks of :func:`check`, in its order


def check(
    model: RobotModel, cell: AnyCell, q: np.ndarray, constraints: Constraints
) -> dict[str, np.ndarray]:
    """Per constraint, a mask ``(N,)`` of configurations ``(N, n)`` that satisfy it (``N`` may
    be 0: every IK solution of a batch out of the limits). A fixed camera's cell
    (:class:`~relcal.design.cell.FixedCameraCell`): :func:`relcal.design.fixed.check`."""
    q = np.asarray(q, dtype=float).reshape(-1, model.n_joints)
    if not len(q):
        return {name: np.zeros(0, dtype=bool) for name in CONSTRAINTS}
    if cell.mode == "eye_to_hand":
        from relcal.design import fixed

        return fixed.check(model, cell, q, constraints)
    cameras = camera_poses(model, cell, q)
    pix, depth = image_points(cell, cameras)
    inside = in_image(cell.camera, pix, depth, constraints.margin_px)
    sight = cameras[:, :3, 3] - cell.center
    distance = np.linalg.norm(sight, axis=1)
    angle = np.degrees(np.arccos(np.clip(sight @ cell.normal / distance, -1.0, 1.0)))
    frames = forward_frames(model, q)[:, 2:, :3, 3]  # from the elbow on
    points = np.concatenate([frames, cameras[:, None, :3, 3]], axis=1)
    height = (points - cell.center) @ cell.normal
    lo, hi = constraints.distance
    masks = {
        "joint limits": np.all((q >= model.lower) & (q <= model.upper), axis=1),
        "board in view": inside,
        "distance": (distance >= lo) & (distance <= hi),
        "viewing angle": angle <= constraints.max_view_angle_deg,
        "singularity": inverse_condition(model, q, constraints.length_scale)
        >= constraints.min_inverse_condition,
        "clearance": (height >= constraints.clearance).all(axis=1),
    }
    rest = np.logical_and.reduce(list(masks.values()))
    masks.update(collisions(model, cell, q, constraints, rest))
    masks["line of sight"] = line_of_sight(model, cell, q, constraints, rest)
    return masks


def line_of_sight(
    model: RobotModel, cell: Cell, q: np.ndarray, constraints: Constraints, rest: np.ndarray
) -> np.ndarray:
    """Mask ``(N,)`` of configurations ``q`` whose camera sees the whole pattern past the
    robot's own links (:mod:`relcal.design.sight`): with the URDF's collision geometry where
    the chain has some, else capsules of ``link_radius`` about the skeleton. Checked only where
    ``rest`` holds (elsewhere True); always True with ``sight_grid`` 0."""
    from relcal.design.sight import sight_lines, skeleton_sight_free, urdf_sight_free

    ok = np.ones(len(q), dtype=bool)
    idx = np.flatnonzero(rest)
    if constraints.sight_grid <= 0 or not len(idx):
        return ok
    cameras = camera_poses(model, cell, q[idx])
    lines = sight_lines(cameras, cell.board_pose, cell.corners, max(constraints.sight_grid, 2))
    geometry = urdf_geometry(model)
    if geometry is not None:
        ok[idx] = urdf_sight_free(geometry, q[idx], lines)
    elif constraints.link_radius > 0:
        ok[idx] = skeleton_sight_free(model, q[idx], cell.handeye, lines, constraints.link_radius)
    return ok


def collisions(
    model: RobotModel, cell: Cell, q: np.ndarray, constraints: Constraints, rest: np.ndarray
) -> dict[str, np.ndarray]:
    """``self-collision`` and ``cell collision`` masks ``(N,)`` of configurations ``q``.

    From the URDF's collision geometry with python-fcl where the model comes from a URDF whose
    chain links have some (checked only where ``rest``, the other constraints, holds: the exact
    test costs more; elsewhere the masks are True), else from capsules about the kinematic
    skeleton (:mod:`relcal.design.collision`)."""
    radii = (constraints.link_radius, constraints.camera_radius)
    obstacles = np.array(constraints.obstacles, dtype=float).reshape(-1, 6)
    geometry = urdf_geometry(model) if max(radii) > 0 or len(obstacles) else None
    if geometry is not None:
        free, clear = np.ones(len(q), dtype=bool), np.ones(len(q), dtype=bool)
        idx = np.flatnonzero(rest)
        if max(radii) > 0:
            free[idx] = geometry.self_collision_free(q[idx])
        camera = camera_poses(model, cell, q[idx])[:, :3, 3]
        clear[idx] = geometry.cell_free(q[idx], camera, obstacles, constraints.camera_radius)
        return {"self-collision": free, "cell collision": clear}
    if max(radii) > 0:
        free = self_collision(model, q, cell.handeye, *radii)
    else:
        free = np.ones(len(q), dtype=bool)
    return {
        "self-collision": free,
        "cell collision": cell_collision(model, q, cell.handeye, obstacles, *radii),
    }


def feasible(
    model: RobotModel, cell: AnyCell, q: np.ndarray, constraints: Constraints
) -> np.ndarray:
    """Mask ``(N,)`` of configurations that satisfy every constraint."""
    masks = check(model, cell, q, constraints)
    return np.logical_and.reduce(list(masks.values()))


def sample_camera_poses(
    cell: Cell, constraints: Constraints, count: int, rng: np.random.Generator
) -> np.ndarray:
    """Camera poses ``(count, 4, 4)`` over the spherical cap above the board: uniform over the
    cap's area up to the viewing angle, distance uniform in range, aim within ``aim`` of the
    pattern's size of its centre, roll uniform."""
    max_tilt = np.radians(constraints.max_view_angle_deg)
    cos_t = rng.uniform(np.cos(max_tilt), 1.0, count)
    sin_t = np.sqrt(1 - cos_t**2)
    az = rng.uniform(0, 2 * np.pi, count)
    rot = cell.board_pose[:3, :3] @ np.diag([1.0, 1.0, -1.0])  # z along the normal
    local = np.stack([sin_t * np.cos(az), sin_t * np.sin(az), cos_t], axis=1)
    dist = rng.uniform(*constraints.distance, count)
    eyes = cell.center + dist[:, None] * (local @ rot.T)
    size = np.ptp(cell.corners[:, :2], axis=0)
    offsets = rng.uniform(-1.0, 1.0, (count, 2)) * constraints.aim * size
    aims = cell.board_pose[:3, :3] @ np.c_[offsets, np.zeros(count)].T
    aims = cell.center + aims.T
    rolls = rng.uniform(-np.pi, np.pi, count)
    return np.stack([look_at(e, a, r) for e, a, r in zip(eyes, aims, rolls, strict=True)])


def random_joints(model: RobotModel, count: int, rng: np.random.Generator) -> np.ndarray:
    """Uniform joint values ``(count, n)`` within the limits (one turn where unlimited)."""
    lo = np.where(np.isfinite(model.lower), model.lower, -np.pi)
    hi = np.where(np.isfinite(model.upper), model.upper, np.pi)
    return rng.uniform(lo, hi, (count, model.n_joints))


def batch_seed(seed: int | np.random.SeedSequence, b: int) -> np.random.SeedSequence:
    """The random stream of candidate batch ``b``: child ``b`` of ``seed``'s sequence (what
    ``SeedSequence(seed).spawn(b + 1)[b]`` gives), so that a batch is the same wherever and in
    whatever order it is drawn."""
    root = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    return np.random.SeedSequence(
        root.entropy, spawn_key=(*root.spawn_key, b), pool_size=root.pool_size
    )


def candidate_batch(
    model: RobotModel,
    cell: AnyCell,
    constraints: Constraints,
    batch: int,
    seed: np.random.SeedSequence,
) -> tuple[np.ndarray, dict[str, int]]:
    """The feasible configurations ``(K, n)`` among ``batch`` sampled camera poses (a fixed
    camera's cell: board poses, :func:`relcal.design.fixed.sample_board_poses`) solved by IK
    from random starts drawn from ``seed``, and the rejections per constraint."""
    rng = np.random.default_rng(seed)
    if cell.mode == "eye_to_hand":
        from relcal.design.fixed import sample_board_poses

        flange = sample_board_poses(cell, constraints, batch, rng) @ tf.invert(cell.handeye)
    else:
        cams = sample_camera_poses(cell, constraints, batch, rng)
        flange = cams @ tf.invert(cell.handeye)
    sol = solve(model, flange, q_near=random_joints(model, batch, rng))
    ok = np.asarray(sol.converged, dtype=bool)
    rejected = {"ik": int((~ok).sum())}
    q = np.asarray(sol.q)[ok]
    masks = check(model, cell, q, constraints)
    for name, mask in masks.items():
        rejected[name] = int((~mask).sum())
    return q[np.logical_and.reduce(list(masks.values()))], rejected


MIN_YIELD = 0.02  # feasible configurations per sampled camera pose below which the search stops


def max_batches(count: int, batch: int, max_rounds: int) -> int:
    """Batches drawn at most for ``count`` candidates: enough at :data:`MIN_YIELD`, at least
    ``max_rounds``."""
    return max(max_rounds, int(np.ceil(count / (MIN_YIELD * batch))))


def candidates(
    model: RobotModel,
    cell: AnyCell,
    constraints: Constraints,
    count: int,
    seed: int | np.random.SeedSequence = 0,
    batch: int = 400,
    max_rounds: int = 20,
    client=None,
) -> tuple[np.ndarray, dict[str, int]]:
    """Up to ``count`` feasible configurations ``(K, n)`` and, per constraint, how many IK
    solutions it rejected (``ik`` counts camera poses out of reach).

    Batches of ``batch`` camera poses, batch ``b`` drawn from its own stream
    (:func:`batch_seed`), are kept in order until ``count`` are found; the search gives up after
    ``max_rounds`` batches without any, or after :func:`max_batches`. With ``client`` (a
    ``distributed.Client``) the batches run as tasks on its cluster; the pool and the counts
    (of the batches used) are the same as in this process.
    """
    limit = max_batches(count, batch, max_rounds)
    if client is None:
        results = (
            candidate_batch(model, cell, constraints, batch, batch_seed(seed, b))
            for b in range(limit)
        )
    else:
        results = _dask_batches(client, (model, cell, constraints), batch, seed, limit)
    kept: list[np.ndarray] = []
    rejected: dict[str, int] = {}
    total = 0
    try:
        for b, (good, counts) in enumerate(results):
            for name, n in counts.items():
                rejected[name] = rejected.get(name, 0) + n
            kept.append(good)
            total += len(good)
            if total >= count or (total == 0 and b + 1 >= max_rounds):
                break
    finally:
        close = getattr(results, "close", None)
        if close is not None:
            close()  # cancels the batches still running on the cluster
    out = np.concatenate(kept)[:count] if total else np.zeros((0, model.n_joints))
    if len(out) == 0:
        where = (
            "the poses in front of the fixed camera (--distance from it) may be out of the arm's "
            "reach (move --camera-pose, or check --handeye, the board on the flange)"
            if cell.mode == "eye_to_hand"
            else "the board may be out of reach"
        )
        raise RelcalError(
            f"no feasible configuration found: {where} or the constraints too tight "
            f"(rejections: {rejected}){_narrow_joints(model)}"
        )
    return out, rejected


def _narrow_joints(model: RobotModel) -> str:
    """A hint naming the joints whose limits leave them (almost) no motion."""
    width = np.asarray(model.upper, float) - np.asarray(model.lower, float)
    narrow = [
        f"{name} ({w:.3g} m)" if model.prismatic[i] else f"{name} ({np.degrees(w):.3g} deg)"
        for i, (name, w) in enumerate(zip(model.joint_names, width, strict=True))
        if w < (1e-3 if model.prismatic[i] else np.radians(1.0))
    ]
    if not narrow:
        return ""
    return (
        "; joints that can hardly move between their limits: "
        + ", ".join(narrow)
        + " (a zero-width or nearly zero-width limit, from --limits or the robot file: widen it)"
    )


def _batch_task(context, batch: int, seeds: list[np.random.SeedSequence]):
    """A Dask task: candidate batches, one per seed, with the scattered ``(model, cell,
    constraints)``."""
    import copy

    prepare_worker()
    context = copy.deepcopy(context)  # aligned arrays of its own (see _Shard)
    return [candidate_batch(*context, batch, seed) for seed in seeds]


TASK_SECONDS = 0.25  # s: the work of one Dask task of candidate batches (its overhead: a few ms)


def _dask_batches(client, context: tuple, batch: int, seed, limit: int):
    """Results of batches ``0, 1, ...`` in order: the first here (it times a batch), the rest
    as Dask tasks of about :data:`TASK_SECONDS` of batches each on ``client``'s cluster, the
    context scattered once, two tasks per worker in flight (those left when the caller stops
    are cancelled)."""
    import time

    from relcal.cluster import n_workers

    started = time.perf_counter()
    yield candidate_batch(*context, batch, batch_seed(seed, 0))
    per_task = int(np.clip(TASK_SECONDS / max(time.perf_counter() - started, 1e-3), 1, 16))
    shared = client.scatter(context, broadcast=True, hash=False)
    ahead = 2 * n_workers(client)
    starts = range(1, limit, per_task)
    futures: list = []
    try:
        for i in range(len(starts)):
            while len(futures) < min(len(starts), i + ahead):
                lo = starts[len(futures)]
                seeds = [batch_seed(seed, b) for b in range(lo, min(limit, lo + per_task))]
                futures.append(client.submit(_batch_task, shared, batch, seeds, pure=False))
            yield from futures[i].result()
            futures[i] = None
    finally:
        client.cancel([f for f in futures if f is not None])
