"""Measurement models: residuals and their Jacobians for absolute and relative pose data.

Residuals follow ``r ~ A (p_true - p)``: measured minus modelled, so a Gauss-Newton step is
``dp = pinv(A) r``. Three formulations:

- ``absolute``: tool pose in the base frame; ``r_k = (p_meas - p_model, rotvec(R_meas R_model^T))``.
- ``published`` (Lu & Hayes): ``r_ij = r_j - r_i`` with the absolute errors in the base frame; the
  board position cancels, its orientation must be known (the measured poses are base-aligned).
- ``invariant``: ``M_ij = C_i^-1 C_j`` against ``X^-1 F_i^-1 F_j X``; residual = 6-vector of
  ``model^-1 measured`` (in the camera frame). The board frame ``W`` cancels entirely; the hand-eye
  transform ``X`` is estimated with the geometry (6 extra parameters ``handeye.*``).
- ``board``: each camera pose ``C_k`` against ``W F(q_k) X``, with the board-from-base transform
  ``W`` (6 parameters ``board.*``, a small motion ``W0 exp(omega)`` of the guess) estimated with
  the geometry and the hand-eye ``X``; residual = 6-vector of ``(W F_k X)^-1 C_k`` (camera frame).
  ``N`` residual blocks instead of the ``N (N - 1) / 2`` of all pairs, carrying the same
  information (``W`` takes what relative measurements cancel; see
  ``docs/explanation/relative-formulation.md``): what large data sets use.
- ``tracker``: points measured by an instrument (laser tracker reflector, mocap marker) whose
  frame ``T`` relative to the robot base is unknown: ``r_k = p_meas - T F(q_k) m`` (3 rows), with
  ``T`` (6 parameters ``instrument.*``, a small motion ``T0 exp(xi)`` of the guess) and the marker
  position ``m`` in the flange frame (3 parameters ``marker.*``, added to the guess) estimated with
  the geometry. ``T`` absorbs whatever moves the base rigidly, ``m`` whatever moves the flange
  point by a constant amount in the flange frame.
- ``coincidence``: a tool point seated again and again at unknown points (a ball in the sockets
  of a plate, a touch-off pin): ``r_k = p_g(k) - F(q_k) t`` per sample, with the tool point ``t``
  and each group's point ``p_g`` estimated with the geometry, plus a row per known distance
  between groups (:mod:`relcal.calibration.coincidence`, which ``problem.coincidence`` describes).

``measure="position"`` keeps the 3 translation rows of each measurement, ``"pose"`` all 6.
"""

from __future__ import annotations

import copy
import functools
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Literal, get_args

import numpy as np

from relcal import geometry as tf
from relcal._renamed import UNSET
from relcal.checks import (
    check_array,
    check_choice,
    check_joints,
    check_pairs,
    check_transform,
    check_vector,
)
from relcal.errors import ArgumentError, RelcalError
from relcal.limits import AUTO_ALL_PAIRS as AUTO_ALL_PAIRS  # re-exported
from relcal.limits import resolve_pairing as resolve_pairing
from relcal.robot.kinematics import (
    Layout,
    check_errors,
    check_layout,
    errors_applied,
    fk,
    make_layout,
    pose_jacobian,
    spatial_jacobian,
)
from relcal.robot.model import RobotModel, check_model

if TYPE_CHECKING:
    from relcal.calibration.seated import Coincidence

MARKER_COMPONENTS = ("x", "y", "z")  # the tracker formulation's marker position, m

Formulation = Literal["absolute", "published", "invariant", "board", "tracker", "coincidence"]
Measure = Literal["position", "pose"]
PairStrategy = Literal["consecutive", "star", "all", "board", "auto"]
PAIRINGS = ("auto", "all", "consecutive", "star", "board")  # the choices a user has
VALIDATION_PAIRS = 10_000  # pairs of held-out samples validated above AUTO_ALL_PAIRS (random)


def sample_pairs(n_samples: int) -> np.ndarray:
    """``(k, k)`` ``(N, 2)``: each sample its own measurement (the board formulation)."""
    idx = np.arange(n_samples)
    return np.stack([idx, idx], axis=1)


def capped_pairs(n_samples: int, max_pairs: int, seed: int = 0) -> np.ndarray:
    """All ``n (n - 1) / 2`` index pairs ``(P, 2)`` of ``n_samples`` samples, or, when there are
    more than ``max_pairs``, that many distinct ones drawn at random (seeded, sorted): per-pair
    statistics of a large set at a bounded cost, never quadratic."""
    total = n_samples * (n_samples - 1) // 2
    if total <= max_pairs:
        return make_pairs(n_samples, "all")
    rng = np.random.default_rng(seed)
    codes = np.zeros(0, dtype=np.int64)
    while len(codes) < max_pairs:  # draw (i, j) with i < j, keep distinct
        i = rng.integers(0, n_samples, 2 * max_pairs)
        j = rng.integers(0, n_samples, 2 * max_pairs)
        lo, hi = np.minimum(i, j), np.maximum(i, j)
        codes = np.unique(np.r_[codes, (lo * n_samples + hi)[lo != hi]])
    codes = np.sort(rng.choice(codes, max_pairs, replace=False))
    return np.stack([codes // n_samples, codes % n_samples], axis=1)


@dataclass(frozen=True)
class FormulationHooks:
    """What a formulation whose math lives in its own module supplies to :class:`Problem`
    (``coincidence``: :mod:`relcal.calibration.coincidence`, which registers them when it is
    imported, as it is to build the :class:`~relcal.calibration.coincidence.Coincidence` its
    problems carry). Imports go one way: that module imports this one, never the reverse.

    ``full_layout(problem)``: the parameter layout with the formulation's nuisance parameters;
    ``residuals(problem, params, jacobian)``: the residual ``(M,)`` and its Jacobian
    ``(M, P)`` (or None), as :func:`residuals`; ``sample_errors(problem, params)``: the
    position error of each sample ``(N, 3)``, m; ``row_clusters(problem)``: the cluster of each
    residual row ``(M,)`` when rows are correlated within clusters (optional).
    """

    full_layout: Callable[[Problem], Layout]
    residuals: Callable[..., tuple[np.ndarray, np.ndarray | None]]
    sample_errors: Callable[[Problem, np.ndarray], np.ndarray]
    # the cluster of each residual row (rows of one cluster share errors: their covariance is
    # scaled by the clusters' design effect), or None: independent rows
    row_clusters: Callable[[Problem], np.ndarray] | None = None


_FORMULATIONS: dict[str, FormulationHooks] = {}


def register_formulation(name: str, hooks: FormulationHooks) -> None:
    """Register the hooks of formulation ``name`` (a module defining a formulation calls this
    when it is imported)."""
    _FORMULATIONS[name] = hooks


def formulation_hooks(name: str) -> FormulationHooks:
    """The registered hooks of formulation ``name``.

    Raises
    ------
    RelcalError
        No module registered ``name`` (its problem was not built through its module).
    """
    try:
        return _FORMULATIONS[name]
    except KeyError:
        raise RelcalError(
            f"formulation {name!r}: its module is not loaded (build its problem through it, "
            "e.g. relcal.calibration.coincidence.coincidence_problem)"
        ) from None


def row_clusters(problem: Problem) -> np.ndarray | None:
    """The cluster of each residual row ``(M,)`` of ``problem`` when its formulation's rows are
    correlated within clusters (coincidence: the placements), else None (independent rows)."""
    hooks = _FORMULATIONS.get(problem.formulation)
    if hooks is None or hooks.row_clusters is None:
        return None
    return hooks.row_clusters(problem)


def make_pairs(
    n_poses: int,
    pairing: PairStrategy = "consecutive",
    reference: int = 0,
    *,
    strategy: PairStrategy = UNSET,
) -> np.ndarray:
    """Index pairs of poses that form relative measurements.

    Parameters
    ----------
    n_poses : int
        Number of poses ``n`` (0 or more).
    pairing : {"consecutive", "star", "all", "board", "auto"}
        Consecutive ``(k, k+1)``, a star around ``reference``, all ``n (n - 1) / 2`` pairs, or
        ``board``: each pose alone, ``(k, k)`` (compared with the board, not with another
        pose); ``auto`` is resolved first (:func:`resolve_pairing`). The command line's
        ``--pairing``.
    reference : int
        The centre of the star, ``0 <= reference < n_poses``.
    strategy : {"consecutive", "star", "all"}
        Deprecated name of ``pairing`` (a DeprecationWarning; removed in relcal 0.2).

    Returns
    -------
    (P, 2) ndarray of int
        The pairs ``(i, j)``, ``i`` first.

    Raises
    ------
    ArgumentError
        ``n_poses`` negative or not whole, ``reference`` out of range, an unknown pairing.
    RelcalError
        All pairs of so many poses that they would not fit the memory limit
        (``RELCAL_MAX_MEMORY_MB``, :mod:`relcal.limits`).

    Examples
    --------
    >>> import relcal
    >>> relcal.make_pairs(4, "consecutive").tolist()
    [[0, 1], [1, 2], [2, 3]]
    >>> relcal.make_pairs(4, "all").shape
    (6, 2)
    """
    from relcal._renamed import renamed
    from relcal.checks import check_number

    strategy = renamed("make_pairs", "strategy", strategy, "pairing", pairing, "consecutive")
    n_poses = check_number(n_poses, "n_poses", 0, integer=True)
    strategy = resolve_pairing(strategy, n_poses)
    idx = np.arange(n_poses)
    if strategy == "star" and n_poses and not 0 <= reference < n_poses:
        check_number(reference, "reference", 0, n_poses - 1, integer=True)
    if strategy == "consecutive":
        return np.stack([idx[:-1], idx[1:]], axis=1)
    if strategy == "star":
        others = idx[idx != reference]
        return np.stack([np.full_like(others, reference), others], axis=1)
    if strategy == "all":
        from relcal.limits import check_memory

        pairs = n_poses * (n_poses - 1) // 2
        check_memory(  # the upper-triangle mask (1 byte per entry) and two copies of the pairs
            n_poses**2 + 32.0 * pairs,
            f"make_pairs: n_poses={n_poses:,} with pairing 'all' ({pairs:,} pairs)",
            "use pairing 'board' (one measurement per pose, the information of all pairs) or "
            "'consecutive'",
        )
        i, j = np.triu_indices(n_poses, k=1)
        return np.stack([i, j], axis=1)
    if strategy == "board":
        return sample_pairs(n_poses)
    from relcal.checks import check_choice

    check_choice(strategy, "pairing", PAIRINGS)
    raise AssertionError("unreachable")


def per_sample_median(values: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """Each sample's median of ``values`` ``(P,)`` over the measurements ``pairs`` ``(P, 2)`` that
    involve it (a pair ``(k, k)`` once), NaN for a sample in none; ``(max index + 1,)``. One
    sort, ``O(P log P)``: no pass over all pairs per sample."""
    pairs = np.asarray(pairs, dtype=int)
    n = int(pairs.max()) + 1
    other = pairs[:, 1] != pairs[:, 0]
    sample = np.r_[pairs[:, 0], pairs[other, 1]]
    value = np.r_[values, values[other]]
    order = np.lexsort((value, sample))
    sample, value = sample[order], value[order]
    start = np.searchsorted(sample, np.arange(n), "left")
    count = np.searchsorted(sample, np.arange(n), "right") - start
    out = np.full(n, np.nan)
    has = count > 0
    lo = start[has] + (count[has] - 1) // 2
    hi = start[has] + count[has] // 2
    out[has] = 0.5 * (value[lo] + value[hi])
    return out


@dataclass(frozen=True)
class Problem:
    """An identification problem: nominal model, which parameters, and the measurements.

    ``q`` ``(N, n)`` joint values; ``poses`` ``(N, 4, 4)`` measured poses: tool poses in a
    base-aligned frame (absolute, published) or camera poses in the board frame (invariant,
    board). ``handeye`` is the flange-from-camera guess ``X`` used by the invariant and board
    formulations (for the others the measured pose is the tool pose: put the camera in
    ``model.tool``); ``board`` the board-from-base guess ``W`` of the board formulation.

    Parameters
    ----------
    model : RobotModel
        The nominal robot.
    layout : Layout
        The robot parameters to identify (:func:`relcal.make_layout` of ``model``).
    q : (N, n_joints) array_like of float
        Joint values in rad (m for prismatic joints).
    poses : (N, 4, 4) array_like of float
        Measured poses (m): tool poses in a base-aligned frame (``absolute``, ``published``),
        camera poses in the board frame (``invariant``), tracker points in the translation
        column (``tracker``); identity placeholders for ``coincidence`` (unused).
    formulation : {"invariant", "board", "published", "absolute", "tracker", "coincidence"}
        How measurements are compared with the model: relative motions ``C_i^-1 C_j`` with the
        hand-eye estimated, each camera pose against ``W F(q) X`` with the board transform ``W``
        estimated too, the published base-frame differences (Lu & Hayes), absolute poses,
        points of a tracker, or coincident tool points.
    measure : {"pose", "position"}
        Position and orientation (6 rows per measurement), or position only (3 rows).
    pairs : (P, 2) array_like of int or None
        Index pairs of the relative formulations; None means consecutive pairs.
    handeye : (4, 4) array_like of float
        Flange-from-camera guess ``X`` of the ``invariant`` and ``board`` formulations (m).
    weights : (6,) array_like of float or None
        Per-row factors of each 6-row residual, e.g. ``1/sigma`` of translation and rotation.
    pair_weights : (P, 6, 6) array_like of float or None
        Per-measurement whitening blocks applied after ``weights`` (a learned noise model).
    instrument : (4, 4) array_like of float
        ``tracker``: guess of the instrument-from-base transform (m).
    marker : (3,) array_like of float
        ``tracker``: guess of the marker position in the tool frame (m).
    coincidence : Coincidence or None
        ``coincidence``: the groups, their point guesses and the known distances.
    board : (4, 4) array_like of float
        ``board``: guess of the board-from-base transform ``W`` (m).

    Raises
    ------
    ArgumentError
        An unknown formulation, poses that are not ``(N, 4, 4)`` or not finite, a pair index out
        of range or a pose paired with itself, a hand-eye that is not 4x4 (naming the argument).
    """

    model: RobotModel
    layout: Layout
    q: np.ndarray
    poses: np.ndarray
    formulation: Formulation = "invariant"
    measure: Measure = "pose"
    pairs: np.ndarray | None = None
    handeye: np.ndarray = field(default_factory=lambda: np.eye(4))
    weights: np.ndarray | None = None  # (6,) per-row factors, e.g. 1/sigma of (t, r) rows
    # (P, 6, 6) per-measurement whitening blocks (pose measurements), applied after ``weights``:
    # a learned noise model's inverse Cholesky factors (:func:`noise.pair_whiteners`).
    pair_weights: np.ndarray | None = None
    instrument: np.ndarray = field(default_factory=lambda: np.eye(4))  # tracker: guess of T
    marker: np.ndarray = field(default_factory=lambda: np.zeros(3))  # tracker: guess of m (m)
    coincidence: Coincidence | None = None  # coincidence: groups, guesses, known distances
    board: np.ndarray = field(default_factory=lambda: np.eye(4))  # board: guess of W

    def __repr__(self) -> str:
        from relcal._repr import plural, short

        pairs = "" if self.pairs is None else plural(len(self.pairs), "pair")
        extra = self.full_layout.size - self.layout.size
        return short(
            "Problem",
            "",
            f"robot {self.model.name!r}",
            plural(len(self.q), "sample"),
            pairs,
            f"{self.formulation} formulation, {self.measure}",
            f"{self.layout.size} parameters" + (f" + {extra} nuisance" if extra else ""),
        )

    def __post_init__(self) -> None:
        """Arguments checked where the API is entered (:func:`check_problem`):
        a wrong shape, a non-finite pose or an unknown formulation is a RelcalError naming it."""
        for name, value in check_problem(self).items():
            object.__setattr__(self, name, value)

    @functools.cached_property
    def full_layout(self) -> Layout:
        """The parameter layout including the hand-eye 6-vector when it is estimated (or, for the
        tracker formulation, the instrument 6-vector and the marker 3-vector)."""
        if self.formulation == "invariant":
            return self.layout.extended("handeye")
        if self.formulation == "board":
            return self.layout.extended("handeye").extended("board")
        if self.formulation == "tracker":
            return self.layout.extended("instrument").extended("marker", MARKER_COMPONENTS)
        if self.formulation == "coincidence":
            return formulation_hooks(self.formulation).full_layout(self)
        return self.layout

    @property
    def rows_per_measurement(self) -> int:
        """Residual rows per measurement: 3 for points and positions, 6 for poses."""
        point = self.formulation in ("tracker", "coincidence")
        return 3 if self.measure == "position" or point else 6

    def pair_indices(self) -> np.ndarray:
        """The pose index pairs of the relative measurements.

        Returns
        -------
        (P, 2) ndarray of int
            ``pairs``, consecutive pairs when not given, or ``(k, k)`` per sample for the
            board formulation (each pose compared with the board).
        """
        if self.formulation == "board":
            return sample_pairs(len(self.q))
        if self.pairs is not None:
            return np.asarray(self.pairs, dtype=int)
        return make_pairs(len(self.q))

    @functools.cached_property
    def measured_motions(self) -> np.ndarray:
        """The measured relative transforms ``C_i^-1 C_j`` ``(P, 4, 4)`` of the pairs (formed
        once: every evaluation of the residuals needs them)."""
        return tf.relative(self.poses, self.pair_indices())

    def n_residuals(self) -> int:
        """Number of residual rows of the problem.

        Returns
        -------
        int
            Rows over all measurements: per pair, per pose or per point times
            :attr:`rows_per_measurement`, plus one per known distance of coincidence data.
        """
        if self.formulation == "coincidence":  # 3 rows per sample, 1 per known distance
            return 3 * len(self.q) + len(self.coincidence.lengths)
        per_pose = self.formulation in ("absolute", "tracker", "board")
        count = len(self.q) if per_pose else len(self.pair_indices())
        return count * self.rows_per_measurement


def derived(problem: Problem, **changes: Any) -> Problem:
    """``replace(problem, **changes)`` without the argument checks, for internal changes that
    keep a checked problem valid (a sub-layout of its model, weights dropped, another
    measure). The measured motions, formed once per problem, carry over when the poses, pairs
    and formulation stay."""
    out = copy.copy(problem)
    cache = out.__dict__
    cache.pop("full_layout", None)
    if {"poses", "pairs", "formulation"} & changes.keys():
        cache.pop("measured_motions", None)
    for name, value in changes.items():
        object.__setattr__(out, name, value)
    return out


def unweighted(problem: Problem) -> Problem:
    """``problem`` without its row and pair weights (itself when it has none): the residuals in
    their own units (m, rad)."""
    if problem.weights is None and problem.pair_weights is None:
        return problem
    return derived(problem, weights=None, pair_weights=None)


def camera_pairing(formulation: Formulation, pairing: PairStrategy, n_poses: int) -> str:
    """The pairing that ``pairing`` stands for with ``n_poses`` camera poses measured for
    ``formulation`` (``auto`` resolved by :func:`resolve_pairing`), checked.

    Parameters
    ----------
    formulation : {"invariant", "published", "absolute"}
        What the measured poses are: camera poses in the board frame (``invariant``), or tool
        poses in a base-aligned frame.
    pairing : {"auto", "all", "consecutive", "star", "board"}
        The choice (the command line's ``--pairing``).
    n_poses : int
        Number of poses.

    Returns
    -------
    str
        ``all``, ``consecutive``, ``star`` or ``board``.

    Raises
    ------
    ArgumentError
        An unknown pairing, or ``board`` (asked for, or ``auto`` above
        :data:`AUTO_ALL_PAIRS` poses) with poses that are not in the board frame: only the
        frame-invariant data have a board frame to fit.
    """
    check_choice(pairing, "pairing", PAIRINGS)
    used = resolve_pairing(pairing, n_poses, formulation)
    if used == "board" and formulation != "invariant":
        asked = "'board'" if pairing == "board" else f"'auto' ({n_poses} poses: board)"
        raise ArgumentError(
            f"pairing {asked}: the board formulation compares each camera pose with a fitted "
            "board frame, so it needs camera poses in the board frame: formulation 'invariant' "
            f"(--formulation invariant), not {formulation!r}; or pair the poses ('all', "
            "'consecutive' or 'star')"
        )
    return used


def camera_problem(
    model: RobotModel,
    q: np.ndarray,
    handeye: np.ndarray,
    formulation: Formulation = "invariant",
    measure: Measure = "pose",
    pairing: PairStrategy = "consecutive",
    poses: np.ndarray | None = None,
    board: np.ndarray | None = None,
) -> Problem:
    """The identification problem of camera poses ``(N, 4, 4)`` at joints ``q`` ``(N, n)`` for a
    camera mounted by the flange-from-camera ``handeye``: estimated with the geometry from that
    guess (frame-invariant, and the board formulation, which ``pairing`` ``board`` asks for:
    :func:`camera_pairing`), or folded into the tool (published, absolute). Without ``poses``,
    the nominal camera poses (the Jacobian does not depend on them). ``board``: the board
    formulation's guess of the board-from-base ``W`` ``(4, 4)``, by default
    :func:`board_guess` from the nominal flange poses and ``poses`` (as a calibration starts)."""
    used = camera_pairing(formulation, pairing, len(q))
    x = handeye
    ident_model = model
    if formulation != "invariant":
        ident_model, x = replace(model, tool=model.tool @ handeye), np.eye(4)
    if poses is None:
        poses = fk(ident_model, q) @ x
    if used == "board":
        if board is None:
            board = board_guess(fk(ident_model, q), poses, x)
        return Problem(
            ident_model, make_layout(model), q, poses, "board", measure, None, x, board=board
        )
    return Problem(
        model=ident_model,
        layout=make_layout(model),
        q=q,
        poses=poses,
        formulation=formulation,
        measure=measure,
        pairs=make_pairs(len(q), used),
        handeye=x,
    )


def split_params(problem: Problem, params: np.ndarray) -> tuple[RobotModel, np.ndarray]:
    """The model with the geometric errors applied, and the hand-eye transform ``X``."""
    n_geo = problem.layout.size
    model = errors_applied(problem.model, problem.layout, params[:n_geo])
    handeye = problem.handeye
    if problem.formulation in ("invariant", "board"):
        handeye = handeye @ tf.from_vector(params[n_geo : n_geo + 6])
    return model, handeye


def board_frame(problem: Problem, params: np.ndarray) -> np.ndarray:
    """The board-from-base transform ``W`` ``(4, 4)`` of the board formulation at ``params``
    (``problem.board`` moved by the ``board.*`` 6-vector)."""
    n_geo = problem.layout.size
    return problem.board @ tf.from_vector(params[n_geo + 6 : n_geo + 12])


def board_guess(tip: np.ndarray, poses: np.ndarray, handeye: np.ndarray) -> np.ndarray:
    """A guess of the board-from-base ``W`` ``(4, 4)`` from flange poses ``F_k`` and camera
    poses ``C_k`` ``(N, 4, 4)`` and the hand-eye ``X``: the median of ``C_k (F_k X)^-1``
    (translations and rotation matrices element by element, the rotation projected on SO(3)),
    so that a few wrong samples (an inverted pose, a bad detection) do not move the start the
    solver refines."""
    each = poses @ tf.invert(tip @ handeye)
    finite = np.isfinite(each).all(axis=(1, 2))
    each = each[finite] if finite.any() else each
    rotation = np.median(each[:, :3, :3], axis=0)
    u, _, vt = np.linalg.svd(rotation)
    out = np.eye(4)
    out[:3, :3] = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    out[:3, 3] = np.median(each[:, :3, 3], axis=0)
    return out


def fit_world(
    model: RobotModel, handeye: np.ndarray, q: np.ndarray, poses: np.ndarray
) -> np.ndarray:
    """The world (board) transform ``W`` ``(4, 4)`` that best places the measured poses ``C_k``
    ``(N, 4, 4)`` at ``W F(q_k) X`` with the kinematics ``model`` and the hand-eye ``X`` held:
    the board formulation's plain least squares (rotation rows times :func:`board_lever`) over
    ``W`` alone, from :func:`board_guess`. What a fit in which ``W`` cancels (relative poses)
    implies for the world frame."""
    from scipy.optimize import least_squares

    board = board_guess(fk(model, q), poses, handeye)
    rows = np.r_[np.ones(3), np.full(3, board_lever(poses))]
    problem = Problem(
        model, Layout((), (), ()), q, poses, "board", "pose", None, handeye, board=board,
        weights=rows,
    )  # fmt: skip

    def cost(w: np.ndarray) -> np.ndarray:
        return residuals(problem, np.r_[np.zeros(6), w], jacobian=False)

    def jac(w: np.ndarray) -> np.ndarray:
        return residuals(problem, np.r_[np.zeros(6), w])[1][:, 6:]

    w = least_squares(cost, np.zeros(6), jac=jac, method="lm", xtol=1e-14, ftol=1e-14).x
    return board_frame(problem, np.r_[np.zeros(6), w])


def world_of(problem: Problem, params: np.ndarray) -> np.ndarray:
    """The world (board) transform ``W`` ``(4, 4)`` of a pose fit ``params`` of ``problem``: the
    fit's own (board formulation), or, for a relative fit in which ``W`` cancels, the one that
    best places ``problem``'s poses with the fit's kinematics and hand-eye (:func:`fit_world`)."""
    if problem.formulation == "board":
        return board_frame(problem, params)
    model, handeye = split_params(problem, params)
    return fit_world(model, handeye, problem.q, problem.poses)


def world_errors(
    problem: Problem,
    params: np.ndarray,
    model: RobotModel,
    q: np.ndarray,
    poses: np.ndarray,
) -> np.ndarray:
    """Errors ``(N, 6)`` (m, rad) of poses ``(N, 4, 4)`` at joints ``q`` predicted in the world
    frame, ``W F(q) X`` with ``model``'s kinematics and the frames ``W`` (:func:`world_of`) and
    ``X`` of the fit ``params`` of the pose problem ``problem``: the translation and rotation
    vector of ``(W F X)^-1 C``, whose norms are the world-frame position and angle errors."""
    world = world_of(problem, params)
    _, handeye = split_params(problem, params)
    return tf.to_vector(tf.invert(world @ fk(model, q) @ handeye) @ poses)


def board_lever(poses: np.ndarray) -> float:
    """The median distance (m) of the cameras ``(N, 4, 4)`` (poses in the board frame) from the
    board's origin; 0.1 m at least."""
    return max(float(np.median(np.linalg.norm(poses[:, :3, 3], axis=1))), 0.1)


def residuals(
    problem: Problem, params: np.ndarray, jacobian: bool = True, model_jacobian: bool = False
):
    """Residual vector ``(M,)`` and, if asked, its Jacobian ``A`` ``(M, P)`` at ``params``.

    Measurements are stacked measurement by measurement (3 or 6 rows each). ``A`` is the exact
    derivative of the residual (``r(p + dp) ~ r(p) - A dp``); with ``model_jacobian`` it is that
    of the modelled measurement instead, i.e. the residual's where the residual vanishes: what
    the Fisher information and the propagation of measurement noise use (the noise lives in the
    tangent space at the true measurement). Both give the same gradient ``A^T r``.
    """
    params = np.asarray(params, dtype=float)
    if params.shape != (problem.full_layout.size,) or not np.isfinite(params).all():
        check_errors(params, problem.full_layout, "params")  # raises, naming what is wrong
    if problem.formulation == "tracker":
        return _tracker(problem, params, jacobian)
    if problem.formulation == "coincidence":
        return formulation_hooks(problem.formulation).residuals(problem, params, jacobian)
    model, handeye = split_params(problem, params)
    if jacobian and problem.formulation in ("invariant", "board"):
        tip, jac = spatial_jacobian(model, problem.q, problem.layout)
    elif jacobian:
        tip, jac = pose_jacobian(model, problem.q, problem.layout)
    else:
        tip, jac = fk(model, problem.q), None
    rows = problem.rows_per_measurement
    if problem.formulation == "invariant":
        n_geo = problem.layout.size
        r, a = _invariant(problem, tip, jac, handeye, params[n_geo : n_geo + 6], model_jacobian)
    elif problem.formulation == "board":
        n_geo = problem.layout.size
        r, a = _board(problem, tip, jac, handeye, params[n_geo : n_geo + 12], model_jacobian)
    else:
        r, a = tf.pose_error(problem.poses, tip), jac
        if jacobian and not model_jacobian:  # log(R_e exp(-w)) ~ log(R_e) - J_r^-1(log R_e) w
            a = a.copy()
            a[:, 3:] = tf.right_jacobian_inverse(r[:, 3:]) @ a[:, 3:]
        if problem.formulation == "published":
            i, j = problem.pair_indices().T
            r, a = r[j] - r[i], (a[j] - a[i] if jacobian else None)
    if problem.weights is not None:
        r = r * problem.weights
        a = a * problem.weights[:, None] if jacobian else None
    if problem.pair_weights is not None:
        w = problem.pair_weights
        r = np.einsum("pij,pj->pi", w, r)
        a = w @ a if jacobian else None
    r = r[:, :rows].reshape(-1)
    return (r, a[:, :rows].reshape(-1, a.shape[-1])) if jacobian else r


def _invariant(
    problem: Problem,
    tip: np.ndarray,
    spatial: np.ndarray | None,
    handeye: np.ndarray,
    handeye_params: np.ndarray,
    model_jacobian: bool = False,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Residuals ``(P, 6)`` and Jacobian ``(P, 6, n_geo + 6)`` of the frame-invariant form, the
    latter if the spatial twists of the parameters (:func:`spatial_jacobian`) are given (with
    ``model_jacobian``, that of the modelled motion: see :func:`residuals`);
    ``handeye = problem.handeye @ from_vector(handeye_params)``."""
    i, j = problem.pair_indices().T
    camera = tip @ handeye  # F X
    inverse = tf.invert(camera)[j]  # (F_j X)^-1
    model_rel_inv = inverse @ camera[i]  # (X^-1 F_i^-1 F_j X)^-1
    r = tf.to_vector(model_rel_inv @ problem.measured_motions)
    if spatial is None:
        return r, None
    n_geo = spatial.shape[-1]
    # F_k -> exp(S_k) F_k makes X^-1 F_i^-1 F_j X -> model_rel exp(Ad((F_j X)^-1) (S_j - S_i));
    # X -> X exp(xi) makes it model_rel exp(xi - Ad(model_rel^-1) xi). The residual moves by its
    # tangent T (residual_tangent; the identity for the model's Jacobian) times these body
    # motions: T Ad and T (I - Ad) are formed per pair, 6 x 6, before the one wide product.
    # With Ad((R, p)) = [[R, [p] R], [0, R]] and T = [[I, -[t]], [0, J]]:
    # T Ad = [[R, [p - t] R], [0, J R]], T (I - Ad) = [[I - R, -[t] - [p - t] R], [0, J (I - R)]].
    t = np.zeros((len(i), 3)) if model_jacobian else r[:, :3]
    turn = None if model_jacobian else tf.right_jacobian_inverse(-r[:, 3:])
    rot, shift = inverse[:, :3, :3], inverse[:, :3, 3]
    to_pair = np.zeros((len(i), 6, 6))
    to_pair[:, :3, :3] = rot
    to_pair[:, :3, 3:] = tf.skew(shift - t) @ rot
    to_pair[:, 3:, 3:] = rot if turn is None else turn @ rot
    out = np.empty((len(i), 6, n_geo + 6))
    np.matmul(to_pair, spatial[j] - spatial[i], out=out[:, :, :n_geo])
    rot, shift = model_rel_inv[:, :3, :3], model_rel_inv[:, :3, 3]
    fixed = np.eye(3) - rot
    moved = np.zeros((len(i), 6, 6))
    moved[:, :3, :3] = fixed
    moved[:, :3, 3:] = -tf.skew(t) - tf.skew(shift - t) @ rot
    moved[:, 3:, 3:] = fixed if turn is None else turn @ fixed
    if np.any(handeye_params):  # per unit change of the 6-vector, not of a motion on top
        moved = (moved.reshape(-1, 6) @ tf.vector_tangent(handeye_params)).reshape(moved.shape)
    out[:, :, n_geo:] = moved
    return r, out


def _board(
    problem: Problem,
    tip: np.ndarray,
    spatial: np.ndarray | None,
    handeye: np.ndarray,
    frame_params: np.ndarray,
    model_jacobian: bool = False,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Residuals ``(N, 6)`` of the board formulation, the 6-vectors of ``(W F_k X)^-1 C_k``, and
    (given the spatial twists ``(N, 6, n_geo)`` of the parameters) their Jacobian
    ``(N, 6, n_geo + 12)``, or with ``model_jacobian`` that of the modelled pose ``W F_k X`` as
    a body motion (camera frame); ``frame_params``: the ``handeye.*`` and ``board.*`` 6-vectors.

    ``F_k -> exp(S_k) F_k`` and ``W -> W exp(omega)`` move ``W F_k X`` by the body twists
    ``Ad((F_k X)^-1) S_k`` and ``Ad((F_k X)^-1) omega``; ``X -> X exp(xi)`` by ``xi``.

    Position-only measurements (``problem.measure == "position"``) compare the camera's position
    in the frame of the measured camera, ``R_C^T (t_C - t_model)``: the rotation of ``X`` turns
    the camera about its own centre, and has no effect on it at all (in the modelled camera's
    frame, ``(W F X)^-1 C``'s translation, it would turn the residual vector without changing its
    length: a direction of the cost that the Jacobian away from the optimum shows as
    determined). Its Jacobian is ``R_C^T R_model`` times the body motion's translation rows,
    which is the model's at the optimum.
    """
    handeye_params, board_params = frame_params[:6], frame_params[6:12]
    world = problem.board @ tf.from_vector(board_params)
    camera = tip @ handeye  # F X
    modelled = world @ camera
    r = tf.to_vector(tf.invert(modelled) @ problem.poses)
    position = problem.measure == "position"
    if position:
        measured = problem.poses[:, :3, :3]
        turn = np.swapaxes(measured, -1, -2) @ modelled[:, :3, :3]  # R_C^T R_model
        shift = problem.poses[:, :3, 3] - modelled[:, :3, 3]
        r[:, :3] = np.einsum("nji,nj->ni", measured, shift)
    if spatial is None:
        return r, None
    n_geo = spatial.shape[-1]
    to_camera = tf.adjoint(tf.invert(camera))  # (N, 6, 6): base twists -> camera body twists
    out = np.empty((len(r), 6, n_geo + 12))
    out[:, :, :n_geo] = to_camera @ spatial
    out[:, :, n_geo : n_geo + 6] = np.eye(6)
    out[:, :, n_geo + 6 :] = to_camera
    if np.any(handeye_params):  # per unit change of the 6-vectors, not of a motion on top
        out[:, :, n_geo : n_geo + 6] = tf.vector_tangent(handeye_params)
    if np.any(board_params):
        out[:, :, n_geo + 6 :] = to_camera @ tf.vector_tangent(board_params)
    if model_jacobian:
        return r, out
    if position:  # the rotation rows are not used
        out[:, :3] = turn @ out[:, :3]
        return r, out
    return r, residual_tangent(r) @ out


def residual_tangent(r: np.ndarray) -> np.ndarray:
    """``(P, 6, 6)``: how the residual 6-vector ``r = (t, phi)`` of ``E = model^-1 measured``
    moves when the model moves by a body motion ``delta = (v, w)`` (``E -> exp(-delta) E``):
    ``dr = -[[I, -[t]x], [0, J_l^-1(phi)]] delta``. The identity where the residual vanishes;
    on real data (millimetres and degrees left) the identity would put the stationary point of
    the solver's gradient off the cost's minimum."""
    out = np.zeros((len(r), 6, 6))
    out[:, :3, :3] = np.eye(3)
    out[:, :3, 3:] = -tf.skew(r[:, :3])
    out[:, 3:, 3:] = tf.right_jacobian_inverse(-r[:, 3:])
    return out


def pair_errors(problem: Problem, params: np.ndarray) -> np.ndarray:
    """Per-pair (or per-pose for ``absolute``) errors ``(P, 6)``: position (m), rotation (rad).

    With position-only measurements the rotation columns are NaN.
    """
    if problem.formulation == "coincidence":  # per sample, the distance rows left out
        r = formulation_hooks(problem.formulation).sample_errors(problem, params)
        return np.concatenate([r, np.full_like(r, np.nan)], axis=1)
    # Points: 3 rows per sample, no orientation (tracker points, and the board formulation's
    # positions, which are compared in the measured camera's frame).
    board_positions = problem.formulation == "board" and problem.measure == "position"
    if problem.formulation == "tracker" or board_positions:
        r = residuals(unweighted(problem), params, jacobian=False).reshape(-1, 3)
        return np.concatenate([r, np.full_like(r, np.nan)], axis=1)
    plain = derived(problem, measure="pose", weights=None, pair_weights=None)
    r = residuals(plain, params, jacobian=False).reshape(-1, 6)
    if problem.measure == "position":
        r[:, 3:] = np.nan
    return r


def tracker_frames(problem: Problem, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Instrument-from-base transform ``T`` ``(4, 4)`` and marker position ``m`` ``(3,)`` (flange
    frame, m) of the tracker formulation at ``params``."""
    n_geo = problem.layout.size
    instrument = problem.instrument @ tf.from_vector(params[n_geo : n_geo + 6])
    return instrument, problem.marker + params[n_geo + 6 : n_geo + 9]


def _tracker(problem: Problem, params: np.ndarray, jacobian: bool):
    """Residuals ``(3 N,)`` ``p_meas - T F(q) m`` and, if asked, the Jacobian ``(3 N, P)`` of the
    modelled point ``T F(q) m`` with respect to the parameters (``r ~ A (p_true - p)``)."""
    n_geo = problem.layout.size
    model = errors_applied(problem.model, problem.layout, params[:n_geo])
    instrument, marker = tracker_frames(problem, params)
    if jacobian and n_geo:
        tip, spatial = spatial_jacobian(model, problem.q, problem.layout)
    elif jacobian:  # frames only (the baseline fit: nominal geometry)
        tip, spatial = fk(model, problem.q), np.zeros((len(problem.q), 6, 0))
    else:
        tip, spatial = fk(model, problem.q), None
    point = tip[:, :3, :3] @ marker + tip[:, :3, 3]  # F m in the base frame (N, 3)
    rot = instrument[:3, :3]
    r = problem.poses[:, :3, 3] - (point @ rot.T + instrument[:3, 3])
    weights = None if problem.weights is None else np.asarray(problem.weights, float)[:3]
    if weights is not None:
        r = r * weights
    if not jacobian:
        return r.reshape(-1)
    # F -> exp(S) F moves the point by v + w x y; T -> T exp(xi) by R_T (v_xi + w_xi x y);
    # m -> m + dm by R_T R_F dm.
    skew = tf.skew(point)  # (N, 3, 3): [y]x, so w x y = -[y]x w
    geo = spatial[:, :3] - skew @ spatial[:, 3:]
    inst = np.concatenate([np.broadcast_to(np.eye(3), skew.shape), -skew], axis=-1)
    if np.any(params[n_geo : n_geo + 6]):  # per unit change of T's 6-vector
        inst = inst @ tf.vector_tangent(params[n_geo : n_geo + 6])
    mark = tip[:, :3, :3]
    a = rot @ np.concatenate([geo, inst, mark], axis=-1)  # (N, 3, P)
    if weights is not None:
        a = a * weights[:, None]
    return r.reshape(-1), a.reshape(-1, a.shape[-1])


MEASURES = ("position", "pose")


def check_problem(problem) -> dict[str, Any]:
    """The checked and converted fields of a :class:`relcal.calibration.measurement.Problem`
    (called by its ``__post_init__``)."""
    p = "Problem"
    check_model(problem.model, f"{p}.model")
    check_layout(problem.layout, problem.model, f"{p}.layout")
    check_choice(problem.formulation, f"{p}.formulation", get_args(Formulation))
    check_choice(problem.measure, f"{p}.measure", MEASURES)
    model = problem.model
    out: dict[str, Any] = {}
    q = out["q"] = check_joints(problem.q, model.n_joints, f"{p}.q", model.name)
    n = len(q)
    poses = out["poses"] = check_array(
        problem.poses,
        f"{p}.poses",
        (n, 4, 4),
        finite=False,
        hint=f"one 4x4 measured pose per row of q ({n})",
    )
    # a pose that is wholly NaN is a sample without a measurement (a rejected frame): allowed
    # in a problem as long as no measurement uses it (:func:`check_measured`); a partly finite
    # pose, or no finite pose at all, is wrong data
    finite = np.isfinite(poses).reshape(n, -1)
    partial = np.flatnonzero(finite.any(axis=1) & ~finite.all(axis=1))
    if partial.size or (n and not finite.any()):
        bad = np.flatnonzero(~finite.all(axis=1))
        raise ArgumentError(
            f"{p}.poses: {bad.size} of {n} items are not finite (NaN or infinite), the first "
            f"{p}.poses[{int(bad[0])}]; missing or failed measurements? leave those samples out"
        )
    if problem.formulation == "coincidence" and problem.coincidence is None:
        raise ArgumentError(
            f"{p}.coincidence: expected the groups and distances (a Coincidence) of the "
            "coincidence formulation, got None; build the problem with "
            "relcal.calibration.coincidence.coincidence_problem"
        )
    if problem.pairs is not None:
        out["pairs"] = check_pairs(problem.pairs, n, f"{p}.pairs")
    pairs = len(out["pairs"]) if problem.pairs is not None else max(n - 1, 0)
    if problem.formulation in ("published", "invariant") and pairs == 0:
        raise ArgumentError(
            f"{p}: no pairs of poses ({n} poses); relative measurements need 2 or more"
        )
    out["handeye"] = check_transform(problem.handeye, f"{p}.handeye")
    out["instrument"] = check_transform(problem.instrument, f"{p}.instrument")
    out["board"] = check_transform(problem.board, f"{p}.board")
    out["marker"] = check_vector(problem.marker, f"{p}.marker", 3, "the marker position x, y, z")
    if problem.weights is not None:
        out["weights"] = check_array(
            problem.weights, f"{p}.weights", (6,), hint="one factor per residual row (t, r)"
        )
    if problem.pair_weights is not None:
        per = n if problem.formulation in ("absolute", "tracker", "board") else pairs
        out["pair_weights"] = check_array(
            problem.pair_weights,
            f"{p}.pair_weights",
            (per, 6, 6),
            hint="one 6x6 whitening block per measurement",
        )
    return out


def check_measured(problem) -> None:
    """Every pose a measurement of ``problem`` uses is finite (``identify``): a sample without a
    measurement (a wholly NaN pose) may sit in a problem, not in its pairs."""
    n = len(problem.q)
    if problem.formulation in ("absolute", "tracker"):
        used = np.arange(n)
    else:
        used = np.unique(problem.pair_indices())
    finite = np.isfinite(problem.poses[used]).reshape(len(used), -1).all(axis=1)
    if not finite.all():
        bad = used[~finite]
        raise ArgumentError(
            f"Problem.poses: {bad.size} of the {len(used)} poses the measurements use are not "
            f"finite, the first Problem.poses[{int(bad[0])}]; leave samples without a "
            "measurement out of the pairs"
        )
