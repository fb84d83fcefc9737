"""The coincidence measurement kind: a tool point seated again and again at the same unknown points.

A ball on the flange seated by hand in a socket, a touch-off on a fixed pin, a tool re-seated in a
fixture: every sample ``k`` of group ``g(k)`` puts the tool point ``t`` (in the robot's tip frame)
at the same point ``p_g`` of the world (the robot's base frame), which nobody measured. The
residual of sample ``k`` is (measured minus modelled, as everywhere in relcal)

    r_k = p_g(k) - F(q_k) t                                                       (3 rows)

and a known distance ``d_ab`` (standard deviation ``s_ab``) between two groups adds the row

    r_ab = (d_ab - |p_a - p_b|) * (sigma / s_ab)

with ``sigma`` the standard deviation of one sample's point (:attr:`Coincidence.seating`, or
``1 / problem.weights[0]`` when the rows are weighted), so that both kinds of rows are whitened
alike. Estimated with the kinematic parameters: the tool point (3 parameters ``tool_point.x`` ..,
added to its guess) and every group's point (``point[NAME].x`` .., added to their guesses).

Groups are named ``PLACEMENT/NAME`` (``front/hole_0``): a placement is one position of the plate
(of the fixture, of the pin); its groups share nothing with other placements' but the robot.

What such data cannot determine, named by :func:`explainer` from the identification Jacobian's
null space:

- a rigid motion of the robot base: every group point moves with it (nothing in the data is a
  fixed reference); a rotation about the line through the two points of a placement moves
  neither point;
- a change that moves the tool point by a constant amount in the tip frame: the tool point
  absorbs it (e.g. the last joint's offset along and about its axis);
- with no known distance, the scale: every length of the robot, the tool point and the points
  scaled together leaves every coincidence intact.
"""

from __future__ import annotations

import functools
from dataclasses import replace

import numpy as np

from relcal import geometry as tf
from relcal.calibration.measurement import FormulationHooks, Problem, register_formulation
from relcal.calibration.seated import SEATING as SEATING  # re-exported
from relcal.calibration.seated import Coincidence as Coincidence  # re-exported
from relcal.calibration.seated import placement_of as placement_of  # re-exported
from relcal.errors import RelcalError
from relcal.robot.kinematics import Layout, apply_errors, fk, make_layout, spatial_jacobian
from relcal.robot.model import RobotModel

POINT_COMPONENTS = ("x", "y", "z")
# A tool point guessed closer than this to the last joint's axis is judged on it: turning that
# joint moves it by less than the seating scatter, which cannot tell its offset from the axis.
AXIS_TOL = 1e-3
# Kinds of the parameters this measurement estimates besides the robot's.
TOOL_POINT = "tool_point"
POINT = "point"


def full_layout(layout: Layout, coincidence: Coincidence) -> Layout:
    """``layout`` followed by the tool point (``tool_point.x`` ..) and each group's point
    (``point[NAME].x`` ..), all in metres."""
    out = layout.extended(TOOL_POINT, POINT_COMPONENTS)
    names = tuple(f"{POINT}[{g}].{c}" for g in coincidence.names for c in POINT_COMPONENTS)
    count = len(names)
    return Layout(
        out.names + names,
        out.kinds + (POINT,) * count,
        out.index + tuple(range(3)) * coincidence.n_groups,
        out.prismatic,
    )


def coincidence_problem(
    model: RobotModel,
    q: np.ndarray,
    coincidence: Coincidence,
    layout: Layout | None = None,
    weights: np.ndarray | None = None,
) -> Problem:
    """The identification problem of coincidence samples at joints ``q`` ``(N, n)``."""
    q = np.asarray(q, dtype=float)
    if len(coincidence.index) != len(q):
        raise ValueError(f"{len(coincidence.index)} group indices for {len(q)} samples")
    return Problem(
        model=model,
        layout=make_layout(model) if layout is None else layout,
        q=q,
        poses=np.broadcast_to(np.eye(4), (len(q), 4, 4)),
        formulation="coincidence",
        measure="position",
        weights=None if weights is None else np.asarray(weights, dtype=float),
        coincidence=coincidence,
    )


def restricted(problem: Problem, samples: np.ndarray) -> Problem:
    """``problem`` on some of its samples (:meth:`Coincidence.restricted`)."""
    samples = np.asarray(samples, dtype=int)
    return replace(
        problem,
        q=problem.q[samples],
        poses=problem.poses[samples],
        coincidence=problem.coincidence.restricted(samples),
    )


def row_placements(problem: Problem) -> np.ndarray:
    """The placement of each residual row ``(3 N + D,)`` (indices into
    :meth:`Coincidence.placement_names`): a sample's three rows its group's, a known distance's
    row its first group's (a distance between two placements' groups is counted with the
    first)."""
    c = problem.coincidence
    lookup = {p: k for k, p in enumerate(c.placement_names())}
    of_group = np.array([lookup[p] for p in c.placements], dtype=int)
    samples = np.repeat(of_group[c.index], 3)
    return np.concatenate([samples, of_group[c.pairs[:, 0]]]).astype(int)


def split_params(problem: Problem, params: np.ndarray):
    """The model with the errors applied, the tool point ``(3,)`` and the group points
    ``(G, 3)`` at ``params``."""
    c = problem.coincidence
    n_geo = problem.layout.size
    params = np.asarray(params, dtype=float)
    model = apply_errors(problem.model, problem.layout, params[:n_geo])
    tool = c.tool_point + params[n_geo : n_geo + 3]
    points = c.points + params[n_geo + 3 :].reshape(-1, 3)
    return model, tool, points


def with_tool_point(model: RobotModel, tool_point: np.ndarray) -> RobotModel:
    """``model`` whose tool transform is moved by ``tool_point`` ``(3,)`` (m, in the tip frame),
    orientation unchanged: ``fk(with_tool_point(m, t), q)[:, :3, 3] == tool_points(m, q, t)``."""
    moved = np.eye(4)
    moved[:3, 3] = np.asarray(tool_point, dtype=float)
    return replace(model, tool=model.tool @ moved)


def tool_points(model: RobotModel, q: np.ndarray, tool_point: np.ndarray) -> np.ndarray:
    """The tool point in the base frame ``F(q_k) t`` ``(N, 3)``."""
    tip = fk(model, np.asarray(q, dtype=float))
    return tip[:, :3, :3] @ tool_point + tip[:, :3, 3]


def _row_factors(problem: Problem) -> tuple[float, np.ndarray]:
    """The factor of the sample rows and of each distance row (whitened alike)."""
    c = problem.coincidence
    if problem.weights is not None:
        sample = float(np.asarray(problem.weights, dtype=float)[0])
        return sample, 1.0 / c.stds
    return 1.0, c.seating / c.stds


def residuals(problem: Problem, params: np.ndarray, jacobian: bool = True):
    """Residuals ``(3 N + D,)`` (the sample rows, then the distance rows) and, if asked, their
    Jacobian ``(3 N + D, P)`` in relcal's sign (``r(p + dp) ~ r(p) - A dp``)."""
    c = problem.coincidence
    n_geo = problem.layout.size
    model, tool, points = split_params(problem, params)
    if jacobian and n_geo:
        tip, spatial = spatial_jacobian(model, problem.q, problem.layout)
    else:  # frames only (a baseline fit: nominal geometry), or no Jacobian
        tip, spatial = fk(model, problem.q), np.zeros((len(problem.q), 6, 0))
    y = tip[:, :3, :3] @ tool + tip[:, :3, 3]  # (N, 3)
    w_sample, w_dist = _row_factors(problem)
    r = (points[c.index] - y) * w_sample
    diff = points[c.pairs[:, 0]] - points[c.pairs[:, 1]]  # (D, 3)
    length = np.linalg.norm(diff, axis=1)
    r_dist = (c.lengths - length) * w_dist
    rows = np.concatenate([r.reshape(-1), r_dist])
    if not jacobian:
        return rows
    n, g = len(y), c.n_groups
    n_params = n_geo + 3 + 3 * g
    a = np.zeros((n, 3, n_params))
    # F -> exp(S) F moves the point by v + w x y = v - [y]x w; t -> t + dt by R_F dt;
    # p_g -> p_g + dp by -dp in the residual (+dp in the "modelled minus" sign of A, negated).
    a[:, :, :n_geo] = spatial[:, :3] - tf.skew(y) @ spatial[:, 3:]
    a[:, :, n_geo : n_geo + 3] = tip[:, :3, :3]
    cols = n_geo + 3 + 3 * c.index[:, None] + np.arange(3)  # (N, 3)
    a[np.arange(n)[:, None], np.arange(3), cols] = -1.0
    a *= w_sample
    a_dist = np.zeros((len(c.pairs), n_params))
    unit = diff / np.maximum(length, 1e-300)[:, None]
    for k, (i, j) in enumerate(c.pairs):
        a_dist[k, n_geo + 3 + 3 * i : n_geo + 6 + 3 * i] = unit[k] * w_dist[k]
        a_dist[k, n_geo + 3 + 3 * j : n_geo + 6 + 3 * j] = -unit[k] * w_dist[k]
    return rows, np.concatenate([a.reshape(-1, n_params), a_dist])


def sample_errors(problem: Problem, params: np.ndarray) -> np.ndarray:
    """Unweighted errors ``p_g(k) - F(q_k) t`` ``(N, 3)`` (m) of every sample."""
    model, tool, points = split_params(problem, params)
    return points[problem.coincidence.index] - tool_points(model, problem.q, tool)


def distance_errors(problem: Problem, params: np.ndarray) -> np.ndarray:
    """``|p_a - p_b| - d_ab`` ``(D,)`` (m) of the known distances at ``params``."""
    c = problem.coincidence
    _, _, points = split_params(problem, params)
    return np.linalg.norm(points[c.pairs[:, 0]] - points[c.pairs[:, 1]], axis=1) - c.lengths


# --- starting guesses ----------------------------------------------------------------------------


def initial_guess(
    model: RobotModel,
    q: np.ndarray,
    index: np.ndarray,
    n_groups: int,
    tool_point: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Starting guesses of the tool point ``(3,)`` (tip frame) and the group points ``(G, 3)``
    (base frame) at the nominal model.

    With ``tool_point`` given, each group's point is the mean of its samples' ``F(q_k) t``;
    otherwise ``R_k t - p_g(k) = -o_k`` (``F(q_k) = (R_k, o_k)``), linear in ``(t, p_1 ..
    p_G)``, is solved by least squares over every sample at once. A group needs samples at
    different orientations of the tip for that solve (the tool point is otherwise unseen).
    """
    index = np.asarray(index, dtype=int)
    tip = fk(model, np.asarray(q, dtype=float))
    rot, origin = tip[:, :3, :3], tip[:, :3, 3]
    if tool_point is None:
        n = len(index)
        lhs = np.zeros((n, 3, 3 + 3 * n_groups))
        lhs[:, :, :3] = rot
        cols = 3 + 3 * index[:, None] + np.arange(3)
        lhs[np.arange(n)[:, None], np.arange(3), cols] = -1.0
        sol, _, rank, _ = np.linalg.lstsq(lhs.reshape(-1, lhs.shape[-1]), -origin.reshape(-1))
        if rank < lhs.shape[-1]:
            raise RelcalError(
                "cannot guess the tool point: within a group the tip must take different "
                "orientations (or give tool: {xyz: [...]} in dataset.yaml)"
            )
        tool_point = sol[:3]
    tool_point = np.asarray(tool_point, dtype=float)
    y = rot @ tool_point + origin
    points = np.zeros((n_groups, 3))
    np.add.at(points, index, y)
    counts = np.bincount(index, minlength=n_groups)
    return tool_point, points / np.maximum(counts, 1)[:, None]


# --- what the data cannot see --------------------------------------------------------------------


def last_axis(model: RobotModel) -> tuple[np.ndarray, np.ndarray] | None:
    """The last joint's axis in the tip frame: a point on it and its unit direction (None for a
    prismatic last joint, which turns nothing)."""
    from relcal.robot.kinematics import forward_frames

    if model.prismatic[-1]:
        return None
    q0 = np.zeros((1, model.n_joints))
    frames = forward_frames(model, q0)[0]
    tip = fk(model, q0)[0]
    axis_frame = frames[-1] if model.convention != "dh" else frames[-2]
    rel = tf.invert(tip) @ axis_frame
    return rel[:3, 3], rel[:3, 2]


def axis_offset(model: RobotModel, tool_point: np.ndarray) -> float:
    """Distance (m) of the tool point (tip frame) from the last joint's axis (inf if none)."""
    axis = last_axis(model)
    if axis is None:
        return float("inf")
    point, direction = axis
    rel = np.asarray(tool_point, dtype=float) - point
    return float(np.linalg.norm(rel - (rel @ direction) * direction))


def judged_tool_point(model: RobotModel, tool_point: np.ndarray) -> np.ndarray:
    """The tool point identifiability is judged at: on the last joint's axis when the guess is
    within :data:`AXIS_TOL` of it (a ball centred on the flange), else the guess."""
    axis = last_axis(model)
    if axis is None or axis_offset(model, tool_point) >= AXIS_TOL:
        return np.asarray(tool_point, dtype=float)
    point, direction = axis
    rel = np.asarray(tool_point, dtype=float) - point
    return point + (rel @ direction) * direction


def consistent(problem: Problem, iterations: int = 30, tol: float = 1e-12) -> Problem:
    """``problem`` with each sample's joints nudged (minimum-norm Gauss-Newton steps, usually a
    fraction of a degree) so that the nominal model puts the tool point exactly on its group's
    point guess: where identifiability is judged. A tool point guessed within :data:`AXIS_TOL`
    of the last joint's axis is moved onto it (:func:`judged_tool_point`).

    The symmetries of this kind (a rigid motion of the base with all the points, a scaling of
    every length) leave the cost unchanged but turn or scale the residuals, so at real data,
    whose nominal points scatter by millimetres, the Jacobian sees them as weakly determined
    (singular values of the order of the scatter over the reach, 1e-3 and more: far above any
    rank tolerance). At consistent data they are exact null directions, as they are in truth."""
    from relcal.robot.ik import joint_layout

    c = problem.coincidence
    model, tool, points = split_params(problem, np.zeros(problem.full_layout.size))
    tool = judged_tool_point(model, tool)
    joints = joint_layout(model)
    q = np.array(problem.q, dtype=float)
    target = points[c.index]
    for _ in range(iterations):
        tip, spatial = spatial_jacobian(model, q, joints)
        y = tip[:, :3, :3] @ tool + tip[:, :3, 3]
        err = target - y
        if np.abs(err).max() < tol:
            break
        jp = spatial[:, :3] - tf.skew(y) @ spatial[:, 3:]  # (N, 3, n)
        q = q + (np.linalg.pinv(jp) @ err[:, :, None])[:, :, 0]
    return replace(problem, q=q, coincidence=replace(c, tool_point=tool))


def explainer(problem: Problem):
    """A function naming why a null-space direction (in parameter units) of a coincidence
    problem leaves the data unchanged (the ``explain`` of
    :func:`relcal.calibration.identifiability.analyse`)."""
    c = problem.coincidence
    n_geo = problem.layout.size
    layout = full_layout(problem.layout, c)
    offset = axis_offset(problem.model, c.tool_point)  # of the guess

    @functools.cache
    def nominal() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Tip poses, spatial twists of the geometry and the tool points, at the nominal model
        and the samples nudged onto their points (:func:`consistent`), where the analysis is."""
        judged = consistent(problem)
        tool = judged.coincidence.tool_point
        tip, spatial = spatial_jacobian(problem.model, judged.q, problem.layout)
        return tip, spatial, tip[:, :3, :3] @ tool + tip[:, :3, 3]

    def fitted(motion: np.ndarray, basis: np.ndarray) -> tuple[np.ndarray, float]:
        """Least-squares coefficients of ``motion`` ``(N, 3)`` on ``basis`` ``(N, 3, K)`` and the
        share of ``motion`` they leave unexplained."""
        lhs = basis.reshape(-1, basis.shape[-1])
        coef = np.linalg.lstsq(lhs, motion.reshape(-1), rcond=None)[0]
        scale = np.abs(motion).max()
        miss = np.abs(lhs @ coef - motion.reshape(-1)).max() / scale if scale > 0 else 0.0
        return coef, float(miss)

    def two_point_line() -> str:
        """With one placement of two groups: the line through their points (a rotation of the
        base about it moves neither)."""
        places = c.placement_names()
        if len(places) == 1 and c.n_groups == 2:
            return (
                f"; with one placement of two groups even a rotation about the line through "
                f"{c.names[0]} and {c.names[1]} moves neither point"
            )
        return ""

    def on_axis() -> bool:
        return offset < AXIS_TOL

    def explain(v: np.ndarray) -> str:
        involved = np.flatnonzero(np.abs(v) > 1e-6 * np.abs(v).max())
        kinds = {layout.kinds[i] for i in involved}
        tip, spatial, y = nominal()
        geometric = v[:n_geo]
        dt = v[n_geo : n_geo + 3]
        twist = spatial @ geometric  # (N, 6) at the base origin
        motion = twist[:, :3] + np.cross(twist[:, 3:], y)  # the tool point's, base frame
        if kinds <= {POINT, TOOL_POINT}:
            return "no samples determine these points"
        if kinds == {"d"} and len(involved) > 1:
            joints = sorted({layout.index[i] + 1 for i in involved})
            return (
                f"translations along parallel axes of joints {', '.join(map(str, joints))}: "
                "only their sum is identifiable (Hayati's beta cures it)"
            )
        # what the terms would move on their own (their sum may cancel)
        terms = spatial[:, :3] * geometric - tf.skew(y) @ (spatial[:, 3:] * geometric)
        scale = max(np.abs(terms).max(), np.abs(dt).max() if dt.size else 0.0)
        if np.abs(motion).max() < 1e-12 and len(involved) == 1:
            return "does not move the tool point (orientation is not measured)"
        # Where the points go: the tool point's motion plus the tool point change, per sample.
        points_moved = motion + tip[:, :3, :3] @ dt
        n = len(y)
        rigid = np.concatenate([np.broadcast_to(np.eye(3), (n, 3, 3)), -tf.skew(y)], axis=-1)
        in_tip = tip[:, :3, :3]  # a constant change in the tip frame
        _, miss = fitted(motion, in_tip)
        if miss < 1e-6:
            return (
                "moves the tool point by a constant amount in the tip frame: the tool point "
                "absorbs it"
            )
        if np.abs(points_moved).max() < 1e-6 * max(scale, 1e-300):  # the terms cancel
            if not on_axis():
                return "linearly dependent at these poses: vary the poses or fix one of them"
            n = problem.model.n_joints
            return (
                f"the tool point lies on joint {n}'s axis (its guess {offset * 1e3:.2g} mm from "
                f"it): turning joint {n} does not move it, so it is a point of link "
                f"{n - 1} whose place these parameters describe together (only orientation "
                "data, or a tool point off that axis, would separate them)"
            )
        _, miss = fitted(points_moved, rigid)
        if miss < 1e-6:
            return (
                "acts as a rigid motion of the robot base: every group point moves with it "
                f"(coincidences hold no fixed reference{two_point_line()})"
            )
        similar = np.concatenate([rigid, y[:, :, None]], axis=-1)
        coef, miss = fitted(points_moved, similar)
        if miss < 1e-6 and abs(coef[-1]) > 0:
            return (
                "scales every length together (robot, tool point and the points' spacing): "
                "with no known distance between groups the data fix shapes, not sizes "
                "(give distances: in dataset.yaml)"
            )
        return "linearly dependent at these poses: vary the poses or fix one of them"

    return explain


# --- from a dataset ------------------------------------------------------------------------------


def group_indices(groups) -> tuple[np.ndarray, tuple[str, ...]]:
    """Each sample's group index ``(N,)`` and the group names, in order of first appearance."""
    names = tuple(dict.fromkeys(groups))
    lookup = {n: g for g, n in enumerate(names)}
    return np.array([lookup[g] for g in groups], dtype=int), names


def make_coincidence(
    model: RobotModel,
    q: np.ndarray,
    groups,
    distances=(),
    tool_point: np.ndarray | None = None,
    seating: float = SEATING,
) -> Coincidence:
    """The :class:`Coincidence` of samples at joints ``q`` ``(N, n)`` in ``groups`` (a name per
    sample), with known ``distances`` ``(group_a, group_b, distance_m, std_m)`` among them
    (others are left out), the tool point guess (None: solved, :func:`initial_guess`) and the
    group points guessed at the nominal model."""
    index, names = group_indices(groups)
    tool, points = initial_guess(model, q, index, len(names), tool_point)
    lookup = {n: g for g, n in enumerate(names)}
    kept = [d for d in distances if d[0] in lookup and d[1] in lookup]
    return Coincidence(
        index=index,
        names=names,
        points=points,
        tool_point=tool,
        pairs=np.array([[lookup[a], lookup[b]] for a, b, _, _ in kept], dtype=int).reshape(-1, 2),
        lengths=np.array([d for _, _, d, _ in kept], dtype=float),
        stds=np.array([s for _, _, _, s in kept], dtype=float),
        seating=seating,
    )


def dataset_problem(dataset, samples: np.ndarray | None = None, weights=None) -> Problem:
    """The coincidence problem of ``dataset``'s samples (all by default), guesses at the nominal
    model (the tool point from ``tool:`` in dataset.yaml, else solved)."""
    if dataset.groups is None:
        raise RelcalError(f"{dataset.spec_path}: not coincidence samples (no group column)")
    samples = np.arange(len(dataset.q)) if samples is None else np.asarray(samples, dtype=int)
    q = dataset.q[samples]
    groups = [dataset.groups[k] for k in samples]
    c = make_coincidence(dataset.model, q, groups, dataset.distances, dataset.tool_point)
    return coincidence_problem(dataset.model, q, c, weights=weights)


# --- plausibility -------------------------------------------------------------------------------


SPREAD_LIMIT = 0.03  # m: RMS spread of a group under the nominal model beyond any real robot's
DISTANCE_LIMIT = (0.2, 0.005)  # share of a known distance and m: wrong pair or wrong distance


def check_plausible(problem: Problem, baseline_params: np.ndarray, source: str = "") -> None:
    """Refuse what cannot be coincidences of this robot, naming the likely cause, from the
    baseline fit (nominal geometry, the tool point and the group points fitted): a group whose
    samples the nominal robot does not bring near one point (another robot, another joint order,
    a tip link that is not the tool point's), or a known distance far from the one between the
    points the nominal robot reaches (a wrong pair of groups, another plate's distance)."""
    c = problem.coincidence
    where = f"{source}: " if source else ""
    model, tool, points = split_params(problem, baseline_params)
    y = tool_points(model, problem.q, tool)
    spread = np.linalg.norm(y - points[c.index], axis=1)
    per_group = np.sqrt(
        np.bincount(c.index, spread**2, c.n_groups)
        / np.maximum(np.bincount(c.index, minlength=c.n_groups), 1)
    )
    worst = int(np.argmax(per_group))
    if per_group[worst] > SPREAD_LIMIT:
        raise RelcalError(
            f"{where}the nominal robot puts the samples of group {c.names[worst]} "
            f"{per_group[worst] * 1e3:.0f} mm RMS apart (calibration corrects millimetres, not "
            "centimetres): are the joints this robot's, in its joint order and unit, and is the "
            "chain's tip link at the tool point?"
        )
    share, floor = DISTANCE_LIMIT
    found = np.linalg.norm(points[c.pairs[:, 0]] - points[c.pairs[:, 1]], axis=1)
    for (i, j), want, got in zip(c.pairs, c.lengths, found, strict=True):
        if abs(got - want) > max(share * want, floor):
            raise RelcalError(
                f"{where}distance {c.names[i]} to {c.names[j]}: {want * 1e3:g} mm given, "
                f"{got * 1e3:.1f} mm between the points the nominal robot reaches: a wrong pair "
                "of groups, or another plate's distance?"
            )


def nuisance_columns(problem: Problem) -> np.ndarray:
    """The tool point and group point columns of ``problem.full_layout``."""
    return np.arange(problem.layout.size, problem.full_layout.size)


def _problem_layout(problem: Problem) -> Layout:
    """:func:`full_layout` of a coincidence problem."""
    return full_layout(problem.layout, problem.coincidence)


register_formulation(
    "coincidence",
    FormulationHooks(
        full_layout=_problem_layout,
        residuals=residuals,
        sample_errors=sample_errors,
        row_clusters=row_placements,
    ),
)
