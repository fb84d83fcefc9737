"""Pose planning: feasible joint configurations that see the whole board, and a selection of K of
them that makes the parameters as well determined as possible.

Candidates: camera poses are drawn over a spherical cap above the board (distance range, viewing
angle limit, random aim point near the centre and random roll about the optical axis), turned into
flange poses with the hand-eye guess and solved by inverse kinematics, each from a random joint
configuration so that every IK branch (elbow, wrist flip) appears. A candidate is kept when, with
the nominal model:

- the joints are within their limits;
- the pattern's four outer corners project inside the image with ``margin_px`` to spare
  (pinhole without distortion; the margin absorbs it), in front of the camera;
- the camera is ``distance`` away from the board centre, and the line of sight from the board
  centre makes at most ``max_view_angle_deg`` with the board normal;
- the configuration is away from singularities: the inverse condition number of the joint
  Jacobian (translation rows divided by ``length_scale``) is at least ``min_inverse_condition``;
- the joint frames from the elbow on and the camera stay ``clearance`` above the board plane.

Selection: each candidate's information (whitened per-pose Jacobian,
:func:`uncertainty.pose_rows`) is additive; the information of a set, with the unknown
board pose eliminated, is that of any connected pairing weighted by its full noise covariance (the
Cramer-Rao bound). Greedy forward selection, optionally followed by Fedorov-style exchanges (swap
a chosen pose for a candidate while the criterion improves), maximises the chosen criterion:

- ``O1`` .. ``O5``: the observability indices of the scaled information (column scales fixed from
  the whole candidate pool, so that sets compare), ``O1`` being D-optimality;
- ``A``: smallest trace of the scaled covariance;
- ``worst``: smallest worst-parameter standard deviation, angles counted as the displacement they
  cause ``length_scale`` away.

On a Dask cluster (``plan(client=...)``): the candidate batches are tasks (each batch draws from its
own stream of the seed, so the pool does not depend on where or in which order batches run), and
each greedy or exchange step scores the pool with one call per worker to an actor holding a shard
of the rows, sent once (:class:`Scorer`). Scores are computed in fixed blocks of pool indices in
both cases, so the plan is the same as in one process.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

import numpy as np

from relcal import geometry as tf
from relcal.calibration.identifiability import (
    DEFAULT_RCOND,
    Indices,
    analyse_problem,
    index_values,
    observability_indices,
)
from relcal.calibration.measurement import Formulation, Measure, Problem, camera_problem
from relcal.calibration.noise import Noise
from relcal.calibration.uncertainty import (
    Accuracy,
    Uncertainty,
    eliminate,
    pose_rows,
    predicted_accuracy,
)
from relcal.cluster import prepare_worker
from relcal.design.cell import Cell
from relcal.errors import RelcalError
from relcal.geometry import DEG, MM, look_at
from relcal.robot.ik import joint_layout, solve
from relcal.robot.kinematics import fk, forward_frames, pose_jacobian
from relcal.robot.model import RobotModel
from relcal.vision.boards import Board
from relcal.vision.camera import Camera

Criterion = Literal["O1", "O2", "O3", "O4", "O5", "A", "worst"]
CRITERIA: tuple[str, ...] = ("O1", "O2", "O3", "O4", "O5", "A", "worst")
Algorithm = Literal["greedy", "exchange"]
DEFAULT_NOISE = Noise(0.05 * MM, 0.01 * DEG, 0.001 * DEG)
_RIDGE = 1e-6  # added to the scaled information so that early greedy steps are defined


# --- the cell -------------------------------------------------------------------------------------


def parse_board(text: str) -> Board:
    """A chessboard from ``ROWSxCOLS@SQUARE`` (squares; ``SQUARE`` in m, or with ``mm``), e.g.
    ``7x10@0.02`` or ``7x10@20mm``, or a board YAML file (:func:`boards.load_board`)."""
    match = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*@\s*([0-9.eE+-]+)\s*(mm|m)?\s*", text)
    if match:
        rows, cols, size, unit = match.groups()
        try:
            spacing = float(size) * (1e-3 if unit == "mm" else 1.0)
            return Board(type="chessboard", rows=int(rows), columns=int(cols), spacing=spacing)
        except ValueError as exc:
            raise RelcalError(f"--board '{text}': {exc}") from None
    if Path(text).suffix in (".yaml", ".yml") or Path(text).exists():
        from relcal.vision.boards import load_board

        return load_board(text)
    raise RelcalError(
        f"--board '{text}': expected ROWSxCOLS@SQUARE (squares, metres or mm, e.g. 7x10@0.02) "
        "or a board YAML file"
    )


def parse_camera(text: str) -> Camera:
    """A camera from ``FX,FY,CX,CY,WIDTH,HEIGHT`` (px) or a camera YAML file."""
    parts = text.split(",")
    if len(parts) == 6:
        try:
            fx, fy, cx, cy = (float(v) for v in parts[:4])
            return Camera(fx=fx, fy=fy, cx=cx, cy=cy, width=int(parts[4]), height=int(parts[5]))
        except ValueError as exc:
            raise RelcalError(f"--camera '{text}': {exc}") from None
    from relcal.vision.camera import load_camera

    camera = load_camera(text)
    if camera.width is None or camera.height is None:
        raise RelcalError(f"{text}: the camera's image size (width, height) is needed to plan")
    return camera


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


# --- feasibility ----------------------------------------------------------------------------------


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


def inverse_condition(model: RobotModel, q: np.ndarray, length_scale: float) -> np.ndarray:
    """``s_min / s_max`` ``(N,)`` of the joint Jacobian with translation rows over
    ``length_scale`` (m): 0 at a singularity."""
    _, jac = pose_jacobian(model, q, joint_layout(model))
    jac = jac.copy()
    jac[:, :3] /= length_scale
    s = np.linalg.svd(jac, compute_uv=False)
    return s[:, -1] / s[:, 0]


def check(
    model: RobotModel, cell: Cell, q: np.ndarray, constraints: Constraints
) -> dict[str, np.ndarray]:
    """Per constraint, a mask ``(N,)`` of configurations ``(N, n)`` that satisfy it."""
    q = np.atleast_2d(q)
    cameras = camera_poses(model, cell, q)
    pix, depth = image_points(cell, cameras)
    cam, m = cell.camera, constraints.margin_px
    inside = (
        (depth > 0).all(axis=1)
        & (pix[..., 0] >= m).all(axis=1)
        & (pix[..., 0] <= cam.width - 1 - m).all(axis=1)
        & (pix[..., 1] >= m).all(axis=1)
        & (pix[..., 1] <= cam.height - 1 - m).all(axis=1)
    )
    sight = cameras[:, :3, 3] - cell.center
    distance = np.linalg.norm(sight, axis=1)
    angle = np.degrees(np.arccos(np.clip(sight @ cell.normal / distance, -1.0, 1.0)))
    frames = forward_frames(model, q)[:, 2:, :3, 3]  # from the elbow on
    points = np.concatenate([frames, cameras[:, None, :3, 3]], axis=1)
    height = (points - cell.center) @ cell.normal
    lo, hi = constraints.distance
    return {
        "joint limits": np.all((q >= model.lower) & (q <= model.upper), axis=1),
        "board in view": inside,
        "distance": (distance >= lo) & (distance <= hi),
        "viewing angle": angle <= constraints.max_view_angle_deg,
        "singularity": inverse_condition(model, q, constraints.length_scale)
        >= constraints.min_inverse_condition,
        "clearance": (height >= constraints.clearance).all(axis=1),
    }


def feasible(model: RobotModel, cell: Cell, q: np.ndarray, constraints: Constraints) -> np.ndarray:
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
    cell: Cell,
    constraints: Constraints,
    batch: int,
    seed: np.random.SeedSequence,
) -> tuple[np.ndarray, dict[str, int]]:
    """The feasible configurations ``(K, n)`` among ``batch`` sampled camera poses solved by IK
    from random starts drawn from ``seed``, and the rejections per constraint."""
    rng = np.random.default_rng(seed)
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
    cell: Cell,
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
        raise RelcalError(
            "no feasible configuration found: the board may be out of reach or the constraints "
            f"too tight (rejections: {rejected})"
        )
    return out, rejected


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


# --- information and criteria ---------------------------------------------------------------------


def selection_problem(
    model: RobotModel,
    cell: Cell,
    q: np.ndarray,
    formulation: Formulation = "invariant",
    measure: Measure = "pose",
) -> Problem:
    """The identification problem the plan is for (poses are the nominal camera poses)."""
    return camera_problem(model, q, cell.handeye, formulation, measure)


@dataclass(frozen=True)
class Information:
    """Per-candidate whitened Jacobians of the estimated parameters plus the nuisance (the board
    pose), and the fixed scales that make criteria of different sets comparable."""

    rows: np.ndarray  # (N, r, k + h)
    h: int
    subset: np.ndarray  # (k,) parameter indices (problem.full_layout)
    names: tuple[str, ...]  # full layout names
    is_angle: np.ndarray  # (P,)
    scale: np.ndarray  # (k,) column scales: RMS information per pose over the whole pool
    weights: np.ndarray  # (k,) length-equivalent factors (1 for m, length_scale for rad)
    identifiable: np.ndarray  # (P,)
    ridge: np.ndarray  # (k + h,) regularisation of the diagonal (early greedy steps)

    @property
    def k(self) -> int:
        return len(self.subset)

    def total(self, idx: np.ndarray) -> np.ndarray:
        """Summed information ``(k + h, k + h)`` of the candidates ``idx`` (nuisance kept)."""
        r = self.rows[np.asarray(idx, dtype=int)]
        return np.einsum("nri,nrj->ij", r, r)

    def of(self, idx: np.ndarray) -> np.ndarray:
        """Information ``(k, k)`` of the set ``idx`` with the nuisance eliminated."""
        return eliminate(self.total(idx), self.h)


def information(
    problem: Problem, noise: Noise, length_scale: float, rcond: float = DEFAULT_RCOND
) -> Information:
    """Per-pose information of the candidate problem's identifiable subset (judged on the whole
    pool with the relative rank tolerance)."""
    rows, h = pose_rows(problem, noise)
    layout = problem.full_layout
    ident = analyse_problem(problem, rcond)
    subset = ident.subset
    cols = np.r_[subset, np.arange(layout.size, layout.size + h)]
    sub = rows[:, :, cols]
    full = np.einsum("nri,nrj->ij", sub, sub)
    scale = np.sqrt(np.diag(eliminate(full, h)) / len(rows))
    nuisance = np.diag(full)[len(subset) :] / len(rows)
    angle = layout.is_angle()
    return Information(
        rows=sub,
        h=h,
        subset=subset,
        names=layout.names,
        is_angle=angle,
        scale=scale,
        weights=np.where(angle[subset], length_scale, 1.0),
        identifiable=ident.identifiable,
        ridge=_RIDGE * np.r_[scale**2, nuisance],
    )


def _from_variances(info: Information, var: np.ndarray, name: str) -> np.ndarray:
    if name == "worst":
        return -(np.sqrt(np.clip(var, 0, None)) * info.weights).max(axis=-1)
    return -np.sum(var * info.scale**2, axis=-1)  # A: trace of the scaled covariance


def criterion(info: Information, totals: np.ndarray, name: str, n_meas: int) -> np.ndarray:
    """Values to maximise ``(...,)`` of summed information ``(..., k + h, k + h)``."""
    if name not in CRITERIA:
        raise ValueError(f"unknown criterion '{name}': use one of {', '.join(CRITERIA)}")
    mats = eliminate(totals + np.diag(info.ridge), info.h)
    scaled = mats / np.outer(info.scale, info.scale)
    if name in ("worst", "A"):
        cov = np.linalg.inv(scaled) / np.outer(info.scale, info.scale)
        return _from_variances(info, np.diagonal(cov, axis1=-2, axis2=-1), name)
    s = np.sqrt(np.clip(np.linalg.eigvalsh(scaled), 1e-300, None))  # scaled singular values
    return index_values(s, name, n_meas)


_FAST = ("worst", "A", "O1")


def _prepare(info: Information, base: np.ndarray, name: str) -> tuple[np.ndarray, ...]:
    """What every candidate's score against the summed information ``base`` shares: ``(base,)``
    for the eigenvalue criteria, else the regularised matrix, its inverse and log-determinant."""
    if name not in _FAST:
        return (base,)
    reg = base + np.diag(info.ridge)
    return reg, np.linalg.inv(reg), np.linalg.slogdet(reg)[1]


def _scores(info: Information, prepared: tuple, rows: np.ndarray, name: str, n_meas: int):
    """Criterion ``(N,)`` of the prepared base plus each candidate's rows ``(N, r, Q)``.

    ``worst``, ``A`` and ``O1`` use rank-r updates of one inverse (Woodbury, determinant lemma):
    the top-left ``k x k`` block of the inverse of the full information is the covariance of the
    parameters with the nuisance eliminated. The others need eigenvalues of every candidate set.
    """
    if name not in _FAST:
        totals = prepared[0][None] + np.swapaxes(rows, -1, -2) @ rows
        return criterion(info, totals, name, n_meas)
    reg, inv, logdet_full = prepared
    v = rows @ inv  # (N, r, Q)
    small = np.eye(rows.shape[1]) + v @ np.swapaxes(rows, -1, -2)  # (N, r, r)
    k = info.k
    if name == "O1":
        _, logdet_small = np.linalg.slogdet(small)
        logdet = logdet_full + logdet_small
        if info.h:
            rh = rows[..., k:]
            nuis = reg[k:, k:] + np.swapaxes(rh, -1, -2) @ rh
            logdet = logdet - np.linalg.slogdet(nuis)[1]
        logdet = logdet - 2 * np.sum(np.log(info.scale))
        return np.exp(logdet / (2 * k)) / np.sqrt(n_meas)
    w = np.linalg.solve(small, v[..., :k])  # (N, r, k)
    var = np.diag(inv)[:k] - np.sum(v[..., :k] * w, axis=-2)
    return _from_variances(info, var, name)


def _values(info: Information, base: np.ndarray, add: np.ndarray, name: str, n_meas: int):
    """Criterion of ``base + rows[c]^T rows[c]`` for every candidate ``c`` in ``add``."""
    return _scores(info, _prepare(info, base, name), info.rows[add], name, n_meas)


BLOCK = 1024  # candidates scored at once: bounds the temporaries (a few MB)
# Fewest candidates worth a worker's scoring step (about 10 ms of work against an actor call's
# 2 ms and the client's 5 ms; the README has the measured numbers).
MIN_SHARD = 4096


def _block_best(
    info: Information,
    prepared: tuple,
    rows: np.ndarray,
    offset: int,
    excluded: np.ndarray,
    name: str,
    n_meas: int,
    block: int = BLOCK,
) -> tuple[float, int]:
    """``(value, index)`` of the best candidate among ``rows`` (pool indices from ``offset``)
    that is not ``excluded``, scored in blocks of ``block`` pool indices; ``(-inf, -1)`` if
    there is none. NaN scores count as -inf; ties go to the lowest index."""
    best, where = -np.inf, -1
    start = offset
    while start < offset + len(rows):
        stop = min((start // block + 1) * block, offset + len(rows))  # blocks align on the pool
        part = rows[start - offset : stop - offset]
        vals = np.asarray(_scores(info, prepared, part, name, n_meas))
        allowed = np.ones(stop - start, dtype=bool)
        allowed[excluded[(excluded >= start) & (excluded < stop)] - start] = False
        vals = np.where(allowed & ~np.isnan(vals), vals, -np.inf)
        i = int(np.argmax(vals))
        if allowed.any() and not allowed[i]:  # every allowed score is -inf
            i = int(np.argmax(allowed))
        if allowed.any() and (where < 0 or vals[i] > best):
            best, where = float(vals[i]), start + i
        start = stop
    return best, where


class Scorer:
    """Best candidate of a pool for a base information, in this process or on a Dask cluster.

    With ``client``, the pool's rows go once to the workers, one contiguous shard (whole blocks
    of ``block`` candidates, at least ``min_shard``, by default :data:`MIN_SHARD`) per worker
    held by a Dask actor, and
    each step asks every actor for its best ``(value, index)``. Actor calls go from this process
    to the workers directly: a task would pass the scheduler twice per step, tens of ms on a
    busy machine. The scores are computed block by block exactly as in this process, so the
    choice is the same; a pool too small for two shards is scored here. Should the cluster fail
    (a worker lost), the remaining steps run here, with the same result. Use as a context manager
    (it releases the actors)."""

    def __init__(
        self,
        info: Information,
        client=None,
        block: int | None = None,
        min_shard: int | None = None,
    ) -> None:
        self.info, self.client = info, client
        self.block = block = block or BLOCK
        self.n = len(info.rows)
        self._actors: list = []
        self._futures: list = []
        if client is None:
            return
        workers = list(client.scheduler_info().get("workers", {}))
        blocks = -(-self.n // block)
        shards = min(len(workers), blocks, self.n // (min_shard or MIN_SHARD))
        if shards < 2:
            self.client = None
            return
        parts = np.array_split(np.arange(blocks), shards)
        light = replace(info, rows=info.rows[:0])
        for part, worker in zip(parts, workers, strict=False):
            lo, hi = int(part[0]) * block, min(self.n, (int(part[-1]) + 1) * block)
            rows = client.scatter(info.rows[lo:hi], workers=[worker], hash=False)
            future = client.submit(
                _Shard, light, rows, lo, block, workers=[worker], actor=True, pure=False
            )
            self._futures.append(future)
            self._actors.append(future.result())
            rows.release()

    def best(self, base: np.ndarray, excluded: np.ndarray, name: str, n_meas: int):
        """``(value, index)`` of the candidate not in ``excluded`` that maximises the criterion
        of ``base`` plus its information."""
        prepared = _prepare(self.info, base, name)
        excluded = np.unique(np.asarray(excluded, dtype=int))
        if self._actors:
            try:
                calls = [a.best(prepared, excluded, name, n_meas) for a in self._actors]
                found = [vi for vi in (c.result() for c in calls) if vi[1] >= 0]
                return max(found, key=lambda vi: (vi[0], -vi[1]), default=(-np.inf, -1))
            except Exception as exc:  # a lost worker, a closed cluster: carry on here
                import warnings

                warnings.warn(f"scoring on the cluster failed ({exc}); scoring here", stacklevel=2)
                self.close()
        rows = self.info.rows
        return _block_best(self.info, prepared, rows, 0, excluded, name, n_meas, self.block)

    @property
    def remote_calls(self) -> list[int]:
        """Steps each actor has scored (empty in this process)."""
        return [a.calls for a in self._actors]

    @property
    def remote_seconds(self) -> list[tuple[float, float]]:
        """Wall and CPU time each actor has spent scoring, s (empty in this process)."""
        return [(a.seconds, a.cpu_seconds) for a in self._actors]

    def close(self) -> None:
        for future in self._futures:
            future.release()
        self._actors, self._futures = [], []

    def __enter__(self) -> Scorer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class _Shard:
    """A Dask actor: the rows ``(M, r, Q)`` of pool indices ``offset..offset + M`` and the pool's
    information without rows; :meth:`best` is one step's best candidate among them."""

    calls: int = 0  # steps scored (on the class: a Dask actor's proxy reads attributes it knows)
    seconds: float = 0.0  # wall time spent scoring them
    cpu_seconds: float = 0.0  # CPU time of the scoring thread

    def __init__(self, info: Information, rows: np.ndarray, offset: int, block: int) -> None:
        # a copy of its own: the received array lives in a network buffer, often unaligned
        # (NumPy's matmul then bypasses BLAS, slower and rounding differently) and read-only
        self.info, self.rows, self.offset, self.block = info, np.array(rows), offset, block

    def best(self, prepared, excluded, name: str, n_meas: int) -> tuple[float, int]:
        import time

        started, cpu = time.perf_counter(), time.thread_time()
        prepare_worker()
        info, rows = self.info, self.rows
        prepared = tuple(np.array(x) for x in prepared)  # aligned copies, as the rows
        found = _block_best(info, prepared, rows, self.offset, excluded, name, n_meas, self.block)
        self.calls += 1
        self.seconds += time.perf_counter() - started
        self.cpu_seconds += time.thread_time() - cpu
        return found


def greedy(info: Information, k: int, name: str, scorer: Scorer | None = None) -> np.ndarray:
    """Forward selection: add, one at a time, the candidate that maximises the criterion."""
    scorer = scorer or Scorer(info)
    chosen: list[int] = []
    total = np.zeros(info.rows.shape[-1:] * 2)
    while len(chosen) < k and len(chosen) < len(info.rows):
        _, best = scorer.best(total, np.array(chosen, dtype=int), name, len(chosen) + 1)
        chosen.append(best)
        total = total + info.total([best])
    return np.array(chosen)


def exchange(
    info: Information,
    chosen: np.ndarray,
    name: str,
    max_passes: int = 20,
    tol: float = 1e-9,
    scorer: Scorer | None = None,
) -> tuple[np.ndarray, int]:
    """Fedorov-style exchange: for each chosen pose, the swap with an unchosen candidate that
    improves the criterion most; passes until none improves. Returns the set and the swaps made."""
    scorer = scorer or Scorer(info)
    chosen = np.array(chosen)
    k = len(chosen)
    total = info.total(chosen)
    current = float(criterion(info, total, name, k))
    swaps = 0
    for _ in range(max_passes):
        improved = False
        for pos in range(k):
            base = total - info.total([chosen[pos]])
            value, best = scorer.best(base, chosen, name, k)
            if best < 0:
                return chosen, swaps
            if value > current + tol * abs(current):
                total = base + info.total([best])
                chosen[pos] = best
                current = value
                improved, swaps = True, swaps + 1
        if not improved:
            break
    return chosen, swaps


def travel_order(q: np.ndarray) -> np.ndarray:
    """An order of configurations ``(K, n)`` for the controller: nearest neighbour in joint space
    (largest joint move) from the one nearest the zero position. The Cramer-Rao bound does not
    depend on the order."""
    left = list(range(len(q)))
    order = [left.pop(int(np.argmin(np.abs(q).max(axis=1))))]
    while left:
        step = np.abs(q[left] - q[order[-1]]).max(axis=1)
        order.append(left.pop(int(np.argmin(step))))
    return np.array(order)


# --- evaluating a set -----------------------------------------------------------------------------


@dataclass(frozen=True)
class Quality:
    """Predicted quality of a set of poses (noise-weighted estimator, Cramer-Rao bound)."""

    uncertainty: Uncertainty
    worst: tuple[str, float]  # parameter and its length-equivalent std (m)
    worst_length: tuple[str, float]  # largest std among lengths (m)
    worst_angle: tuple[str, float]  # largest std among angles (rad)
    median: float  # median length-equivalent std (m)
    indices: Indices
    accuracy: Accuracy | None = None


def quality(
    info: Information,
    idx: np.ndarray,
    problem: Problem | None = None,
    q_validation: np.ndarray | None = None,
) -> Quality:
    """Standard deviations, observability indices and (with the pool's ``problem`` and validation
    poses) the predicted accuracy of the set ``idx`` of candidates."""
    mat = info.of(idx)
    cov = np.linalg.inv(mat / np.outer(info.scale, info.scale)) / np.outer(info.scale, info.scale)
    cov = 0.5 * (cov + cov.T)
    unc = Uncertainty(
        names=info.names,
        is_angle=info.is_angle,
        subset=info.subset,
        crb=cov,
        least_squares=None,
        estimator="weighted",
        identifiable=info.identifiable,
    )
    std = np.sqrt(np.diag(cov))
    eq = std * info.weights
    names = [info.names[p] for p in info.subset]
    angle = info.is_angle[info.subset]

    def worst_of(mask: np.ndarray) -> tuple[str, float]:
        if not mask.any():
            return "-", float("nan")
        k = int(np.argmax(np.where(mask, std, -np.inf)))
        return names[k], float(std[k])

    s = np.sqrt(np.clip(np.linalg.eigvalsh(mat / np.outer(info.scale, info.scale)), 0, None))
    acc = None
    if problem is not None and q_validation is not None:
        acc = predicted_accuracy(problem, unc, q_validation)
    return Quality(
        uncertainty=unc,
        worst=(names[int(np.argmax(eq))], float(eq.max())),
        worst_length=worst_of(~angle),
        worst_angle=worst_of(angle),
        median=float(np.median(eq)),
        indices=observability_indices(s, len(idx)),
        accuracy=acc,
    )


# --- the plan -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PlanResult:
    """A plan, the candidate pool it came from, and how it compares with random sets."""

    q: np.ndarray  # (K, n) in travel order
    criterion: str
    algorithm: str
    swaps: int
    n_candidates: int
    rejected: dict[str, int]
    plan: Quality
    random: tuple[Quality, ...]  # random feasible sets of the same size
    seconds: float
    names: tuple[str, ...] = field(default=())
    random_q: np.ndarray | None = None  # (K, n) the random set with the median worst std

    @property
    def random_median_worst(self) -> float:
        return float(np.median([r.worst[1] for r in self.random])) if self.random else np.nan

    @property
    def improvement(self) -> float:
        """Median worst std of the random sets over the plan's."""
        return self.random_median_worst / self.plan.worst[1]


def plan(
    model: RobotModel,
    cell: Cell,
    k: int = 30,
    constraints: Constraints = Constraints(),
    criterion: Criterion = "worst",
    algorithm: Algorithm = "exchange",
    n_candidates: int = 2000,
    noise: Noise = DEFAULT_NOISE,
    formulation: Formulation = "invariant",
    measure: Measure = "pose",
    random_sets: int = 20,
    n_validation: int = 50,
    seed: int = 0,
    client=None,
) -> PlanResult:
    """Plan ``k`` poses: candidates, selection, and the comparison with ``random_sets`` random
    feasible sets of ``k`` candidates (predicted standard deviations and accuracy on
    ``n_validation`` other feasible poses).

    With ``client`` (a ``distributed.Client``) the candidate batches and the scoring of the
    candidates at every greedy and exchange step run as tasks on its cluster; the plan is the
    same as in this process (each candidate batch has its own random stream from ``seed``).
    """
    import time

    start = time.perf_counter()
    pool_seed, sets_seed = np.random.SeedSequence(seed).spawn(2)
    rng = np.random.default_rng(sets_seed)
    pool, rejected = candidates(
        model, cell, constraints, n_candidates + n_validation, pool_seed, client=client
    )
    if len(pool) < k + n_validation:
        raise RelcalError(
            f"only {len(pool)} feasible candidates for {k} poses and {n_validation} validation "
            f"poses; relax the constraints or ask for fewer poses (rejections: {rejected})"
        )
    q_val, pool = pool[:n_validation], pool[n_validation:]
    problem = selection_problem(model, cell, pool, formulation, measure)
    info = information(problem, noise, constraints.length_scale)
    if algorithm not in ("greedy", "exchange"):
        raise ValueError(f"unknown algorithm '{algorithm}': use greedy or exchange")
    with Scorer(info, client) as scorer:
        chosen = greedy(info, k, criterion, scorer)
        swaps = 0
        if algorithm == "exchange":
            chosen, swaps = exchange(info, chosen, criterion, scorer=scorer)
    chosen = chosen[travel_order(pool[chosen])]
    plan_quality = quality(info, chosen, problem, q_val)
    sets = [rng.choice(len(pool), k, replace=False) for _ in range(random_sets)]
    randoms = tuple(quality(info, idx, problem, q_val) for idx in sets)
    random_q = None
    if sets:
        middle = sets[int(np.argsort([r.worst[1] for r in randoms])[len(sets) // 2])]
        random_q = pool[middle][travel_order(pool[middle])]
    return PlanResult(
        q=pool[chosen],
        criterion=criterion,
        algorithm=algorithm,
        swaps=swaps,
        n_candidates=len(pool),
        rejected=rejected,
        plan=plan_quality,
        random=randoms,
        seconds=time.perf_counter() - start,
        names=problem.full_layout.names,
        random_q=random_q,
    )
