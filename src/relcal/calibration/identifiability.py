"""Which parameters relative data can identify, judged on the scaled identification Jacobian.

Columns are scaled to unit norm so that metres and radians compare; the rank tolerance is relative
to the largest singular value of the scaled matrix (DESIGN.md). Null-space directions are reduced
to sparse combinations and named in words: a rigid motion of the base, a change of the hand-eye
transform, offsets along parallel axes, or no effect at all.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
import scipy.linalg

from relcal import geometry as tf
from relcal.calibration.blas import one_blas_thread
from relcal.calibration.measurement import Problem, residuals
from relcal.deferred import Deferred, resolved_state
from relcal.errors import ArgumentError, RelcalError
from relcal.robot.kinematics import DISPLAY_UNITS, Layout, pose_jacobian
from relcal.robot.model import RobotModel, parallel_axes

DEFAULT_RCOND = 1e-6
HandEye = Literal["estimated", "known"]
INDEX_NAMES = ("O1", "O2", "O3", "O4", "O5")
# Frames estimated alongside the geometry (not part of the robot): hand-eye X, the board
# formulation's board transform W, the tracker formulation's instrument transform T and marker
# position m, the coincidence formulation's tool point and group points.
NUISANCE_KINDS = ("handeye", "board", "instrument", "marker", "tool_point", "point")
_INVOLVED = 1e-6  # a parameter with a larger share of a null vector is not identifiable alone


GENERIC_REASON = "no effect on the measurements at these poses"


def _generic_reason() -> str:
    return GENERIC_REASON


@dataclass(frozen=True)
class Combination:
    """An unidentifiable direction: ``sum(coefficients * parameters)`` has no effect on the data.

    ``why()`` names the reason; it is called when :attr:`reason` is first read (naming needs
    Jacobians at other poses, which most fits never ask for)."""

    names: tuple[str, ...]
    coefficients: tuple[float, ...]  # in SI units (m, rad)
    is_angle: tuple[bool, ...]
    units: tuple[str, ...] = ()  # SI units (Layout.units) when not all m or rad
    why: Callable[[], str] = field(default=_generic_reason, repr=False, compare=False)

    @functools.cached_property
    def reason(self) -> str:
        return self.why()

    def __getstate__(self) -> dict:
        """The reason named before pickling (the closure that names it does not pickle)."""
        return {**self.__dict__, "reason": self.reason, "why": None}

    def describe(self) -> str:
        """E.g. ``theta_off[6] +1 deg with a[6] +0.698 mm together: acts like ...``, in mm and
        deg, scaled so that the leading parameter (the first one not of the hand-eye transform)
        moves by one unit; terms below 0.1 % of the largest are left out of the text."""
        if len(self.names) == 1:
            return f"{self.names[0]}: {self.reason}"
        shown = np.array(
            [
                np.degrees(c) if a else c * 1e3
                for c, a in zip(self.coefficients, self.is_angle, strict=True)
            ]
        )
        shown_units = ["deg" if a else "mm" for a in self.is_angle]
        for k, unit in enumerate(self.units):
            if unit not in ("m", "rad"):  # scale, compliance
                shown[k] = self.coefficients[k] * DISPLAY_UNITS[unit][0]
                shown_units[k] = DISPLAY_UNITS[unit][1]
        lead = next((k for k, n in enumerate(self.names) if _kind(n) not in NUISANCE_KINDS), None)
        shown /= shown[lead] if lead is not None else np.abs(shown).max()
        big = np.abs(shown) >= 1e-3 * np.abs(shown).max()
        terms = [
            f"{n} {c:+.3g} {u}"
            for n, c, u, keep in zip(self.names, shown, shown_units, big, strict=True)
            if keep
        ]
        groups = {
            n.split("].")[0]
            for n, keep in zip(self.names, big, strict=True)
            if keep and _kind(n) == "point"
        }
        if len(groups) > 2:  # coincidence group points: how many, not each coordinate
            terms = [t for t in terms if _kind(t) != "point"] + [
                f"the points of {len(groups)} groups"
            ]
        return f"{' with '.join(terms)} together: {self.reason}"


def _kind(name: str) -> str:
    """The kind of a parameter from its name: ``handeye.tx`` -> ``handeye``, ``point[a/b].x`` ->
    ``point``."""
    return name.split(".")[0].split("[")[0]


@dataclass(frozen=True)
class Identifiability:
    """Singular values of the scaled Jacobian and what they imply (:func:`relcal.analyse_problem`).

    Parameters
    ----------
    singular_values : (P,) ndarray of float
        Singular values of the Jacobian with unit-norm columns, descending.
    column_norms : (P,) ndarray of float
        The norm of each Jacobian column (its scale, per unit of the parameter).
    rank : int
        Numerical rank: singular values above ``rcond`` times the largest.
    rcond : float
        The relative rank tolerance used.
    identifiable : (P,) ndarray of bool
        Parameters the data determine individually.
    subset : (rank,) ndarray of int
        Parameter indices chosen by QR with column pivoting: an identifiable subset.
    null_space : (P, P - rank) ndarray of float
        Unidentifiable directions in the parameters' SI units (m, rad), unit-norm columns.
    combinations : tuple of Combination
        The unidentifiable combinations, named, each with its reason.
    weak : tuple of Combination
        Of ``combinations``, those that varied poses would determine: weak data (a joint that
        barely moves), not a structural symmetry of the measurement.
    """

    singular_values: np.ndarray  # (P,), descending, of the unit-column Jacobian
    column_norms: np.ndarray  # (P,) scale of each column
    rank: int
    rcond: float
    identifiable: np.ndarray  # (P,) bool: determined individually by the data
    subset: np.ndarray  # (rank,) parameter indices chosen by QR with column pivoting
    # (P, P - rank) in original parameter units, columns unit-norm; both it and the combinations
    # may be given as functions of no arguments, computed on first read (a fit needs neither).
    null_space: np.ndarray = Deferred()
    combinations: tuple[Combination, ...] = Deferred()
    # Of ``combinations``, those that generic (varied) poses would determine: weak data, not a
    # structural symmetry (:func:`check_pose_set`).
    weak: tuple[Combination, ...] = ()

    __getstate__ = resolved_state

    @property
    def condition_number(self) -> float:
        """Ratio of the largest to the smallest kept singular value (inf at rank 0)."""
        s = self.singular_values
        return float(s[0] / s[self.rank - 1]) if self.rank else float("inf")


def scaled(jac: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit-norm columns and the norms. Columns at round-off level (below 1e-9 of the largest)
    have no effect: they keep norm 1 so that they stay (numerically) zero."""
    norms = np.linalg.norm(jac, axis=0)
    norms = np.where(norms > 1e-9 * norms.max(initial=0.0), norms, 1.0)
    return jac / norms, norms


def _rank_and_involved(s: np.ndarray, vt: np.ndarray, rcond: float) -> tuple[int, np.ndarray]:
    """Numerical rank from singular values ``s`` and the mask of parameters with a share of the
    null space (rows of ``vt`` beyond the rank), both in scaled coordinates."""
    rank = int(np.sum(s > rcond * (s[0] if len(s) else 0.0)))
    return rank, np.linalg.norm(vt[rank:], axis=0) > _INVOLVED


def _triangular(matrix: np.ndarray) -> np.ndarray:
    """The triangular QR factor ``R`` of ``matrix`` (``R^T R = matrix^T matrix``): what the SVD
    and the column pivoting below need of a tall matrix, at a fraction of its size."""
    matrix = np.asarray(matrix, dtype=float)
    if not matrix.size:
        return np.linalg.qr(matrix, mode="r")
    factored, _, _, info = scipy.linalg.lapack.dgeqrf(matrix)  # LAPACK itself: no wrapper costs
    if info:
        raise np.linalg.LinAlgError(f"QR factorisation failed (LAPACK info {info})")
    return np.triu(factored[: min(matrix.shape)])


_TIE = 1e-6  # columns whose pivoting norms agree this closely are taken in their order


def _pivot_order(matrix: np.ndarray) -> np.ndarray:
    """The column order ``(P,)`` of QR with column pivoting of ``matrix`` ``(M, P)`` (LAPACK's
    ``dgeqp3``), columns whose norms tie to within :data:`_TIE` taken in their order.

    Symmetries make exact ties (two parameters that the data see alike, such as the offsets of
    a curved symmetry): LAPACK breaks them by round-off, so that a change in the last digit of
    the Jacobian (another BLAS, another order of the same products) swapped which of two
    equivalent parameters a calibration estimated and which it held. A relative preference of
    ``_TIE`` for earlier columns decides them the same way every time; it is far above the
    round-off of the norms LAPACK updates (about 1e-8 relative) and far below any real
    difference between columns.
    """
    matrix = np.asarray(matrix, dtype=float)
    n = matrix.shape[1]
    if not matrix.size:
        return np.arange(n)
    earlier = 1.0 + _TIE * np.arange(n - 1, -1, -1) / max(n - 1, 1)
    return scipy.linalg.lapack.dgeqp3(matrix * earlier)[1] - 1  # 1-based


def _singular(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Singular values and right singular vectors ``(s, vt)`` of ``matrix``, from the SVD of its
    triangular QR factor: the same values, about half the cost for tall matrices (no ``U``)."""
    _, s, vt = np.linalg.svd(_triangular(matrix), full_matrices=False)
    return s, vt


def identifiable_mask(jac: np.ndarray, rcond: float = DEFAULT_RCOND) -> np.ndarray:
    """The ``identifiable`` mask of :func:`analyse` alone (one SVD, no QR or null-space naming)."""
    unit, _ = scaled(jac)
    return ~_rank_and_involved(*_singular(unit), rcond)[1]


def sparse_basis(
    null: np.ndarray, tol: float = 1e-9, preference: np.ndarray | None = None
) -> np.ndarray:
    """A sparse basis of the span of ``null`` ``(P, k)``: each column led by its own pivot parameter
    (chosen by QR with column pivoting, so the pivots are well conditioned), unit-norm columns.
    ``preference`` ``(P,)`` weighs the pivot choice: a parameter weighted 0.01 leads a column only
    when the others cannot."""
    k = null.shape[1]
    weight = np.ones(len(null)) if preference is None else preference
    piv = _pivot_order(null.T * weight)
    basis = np.linalg.solve(null.T[:, piv[:k]], null.T)  # identity in the pivot columns
    basis[np.abs(basis) < tol] = 0.0
    basis = basis[np.argsort(piv[:k])]  # ordered by pivot parameter
    return (basis / np.linalg.norm(basis, axis=1, keepdims=True)).T


def pivot_weights(layout: Layout) -> np.ndarray:
    """How strongly each parameter is preferred into the identifiable subset: the hand-eye
    transform first (estimated whole, so the link parameters it absorbs stay at nominal), then
    the geometry, then non-geometric terms (a term that duplicates a geometric parameter at these
    poses is the one left out)."""
    frames = NUISANCE_KINDS  # estimated whole where they can be
    geometric = ("theta_off", "a", "d", "alpha", "beta", "base", "tool", "origin")
    return np.array([10.0 if k in frames else 1.0 if k in geometric else 0.1 for k in layout.kinds])


def analyse(
    jac: np.ndarray,
    layout: Layout,
    rcond: float = DEFAULT_RCOND,
    explain=None,
) -> Identifiability:
    """Rank, identifiable subset and named null-space combinations of a Jacobian ``(M, P)``.

    ``explain(vector) -> str``, if given, names why a null-space direction (in parameter units)
    does not change the data; otherwise the generic reason is used.
    """
    unit, norms = scaled(jac)
    tri = _triangular(unit)
    _, s, vt = np.linalg.svd(tri, full_matrices=False)
    rank, involved = _rank_and_involved(s, vt, rcond)
    # The hand-eye transform is estimated whole where it can be: the link parameters it absorbs
    # (the leads of the combinations) stay at nominal, so the exported model changes only what
    # the data determine. Column pivoting sees only the columns' inner products, which the
    # triangular factor keeps.
    piv = _pivot_order(tri * pivot_weights(layout))
    named = functools.cache(lambda: _named_null_space(vt[rank:].T, norms, layout, explain))
    return Identifiability(
        singular_values=s,
        column_norms=norms,
        rank=rank,
        rcond=rcond,
        identifiable=~involved,
        subset=np.sort(piv[:rank]),
        null_space=lambda: named()[0],
        combinations=lambda: named()[1],
    )


def _named_null_space(
    null_scaled: np.ndarray, norms: np.ndarray, layout: Layout, explain
) -> tuple[np.ndarray, tuple[Combination, ...]]:
    """The null space ``(P, k)`` given in scaled coordinates, as a sparse basis in parameter
    units (unit-norm columns) and as named combinations (see :func:`analyse`)."""
    if not null_scaled.shape[1]:
        return np.zeros((len(norms), 0)), ()
    # Each combination led by a geometric parameter where possible: "theta_off[2] with a change
    # of X" reads better than a hand-eye component with several link parameters.
    hand_eye = np.array([kind in NUISANCE_KINDS for kind in layout.kinds])
    sparse = sparse_basis(null_scaled, preference=np.where(hand_eye, 1e-2, 1.0))
    null = sparse / norms[:, None]  # back to parameter units
    null /= np.linalg.norm(null, axis=0)
    angle, units = layout.is_angle(), layout.units()
    combos = []
    for v_scaled, v in zip(sparse.T, null.T, strict=True):
        idx = np.flatnonzero(np.abs(v_scaled) > 1e-6)
        combos.append(
            Combination(
                names=tuple(layout.names[i] for i in idx),
                coefficients=tuple((v[idx] / np.abs(v[idx]).max()).tolist()),
                is_angle=tuple(bool(angle[i]) for i in idx),
                units=tuple(units[i] for i in idx),
                why=functools.partial(explain, v) if explain else _generic_reason,
            )
        )
    return null, tuple(combos)


# --- a problem's identifiability ---------------------------------------------------------------


def explainer(problem: Problem):
    """A function naming why a null-space direction (parameter units) leaves the data unchanged."""
    if problem.formulation == "coincidence":
        from relcal.calibration.coincidence import explainer as coincidence_explainer

        return coincidence_explainer(problem)
    model, layout = problem.model, problem.full_layout
    n_geo = problem.layout.size

    @functools.cache
    def jacobians() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The parameters' effect on the tool at the nominal model ``(N, 6, P)``: at the tool
        point in the base frame, as a spatial twist (about the base origin) and as a body twist
        (in the tool frame). Computed on the first explanation only (problems without a null
        space never need them), so that each explanation is a few matrix-vector products."""
        tip, jac = pose_jacobian(model, problem.q, problem.layout)
        spatial = jac.copy()
        spatial[:, :3] += tf.skew(tip[:, :3, 3]) @ jac[:, 3:]  # v_0 = v_tip - w x tip
        body = tf.rotate_twist(np.swapaxes(tip[:, :3, :3], -1, -2), jac)
        return jac, spatial, body

    @functools.cache
    def elsewhere() -> np.ndarray:
        """The pose Jacobian at 20 other configurations (fixed seed), inside the limits."""
        lo = np.where(np.isfinite(model.lower), model.lower, -np.pi)
        hi = np.where(np.isfinite(model.upper), model.upper, np.pi)
        q = np.random.default_rng(0).uniform(lo, hi, (20, model.n_joints))
        return pose_jacobian(model, q, problem.layout)[1]

    def still(jac: np.ndarray, geometric: np.ndarray) -> float:
        """How little the combination moves the tool, relative to what its terms could."""
        scale = np.abs(jac).max(axis=(0, 1)) @ np.abs(geometric)
        return float(np.abs(jac @ geometric).max() / scale) if scale > 0 else 0.0

    def same_motion(geometric: np.ndarray) -> bool:
        """Whether the combination leaves the tool as still at other poses as at these (a
        redundancy of the parametrisation, as in URDF origins, not of the chosen poses)."""
        here, there = still(jacobians()[0], geometric), still(elsewhere(), geometric)
        return there < DEFAULT_RCOND and there <= max(10 * here, 1e-9)

    def constant(twists: np.ndarray) -> bool:
        scale = np.abs(twists).max()
        return scale > 0 and np.abs(twists - twists.mean(axis=0)).max() < 1e-6 * scale

    def explain(v: np.ndarray) -> str:
        involved = np.flatnonzero(np.abs(v) > 1e-6 * np.abs(v).max())
        kinds = {layout.kinds[i] for i in involved}
        jac, spatial, body = jacobians()
        geometric = v[:n_geo]
        motion = jac @ geometric  # (N, 6): tip velocity and angular velocity, base frame
        positions = problem.formulation == "board" and problem.measure == "position"
        if kinds == {"handeye"} and positions:  # the hand-eye's rotation (its shift moves them)
            return "turns the camera about its own centre, which camera positions do not see"
        if len(involved) == 1 and np.abs(motion).max() < 1e-12:
            return "has no effect on the tool pose"
        if kinds == {"d"} and len(involved) > 1:
            joints = sorted({layout.index[i] + 1 for i in involved})
            return (
                f"translations along parallel axes of joints {', '.join(map(str, joints))}: "
                "only their sum is identifiable (Hayati's beta cures it)"
            )
        if problem.formulation == "tracker":
            if constant(spatial @ geometric) or kinds <= {"instrument"}:
                return (
                    "acts as a rigid motion of the robot base: the instrument-to-base "
                    "transform T absorbs it"
                )
            moved = body[:, :3] @ geometric + np.cross(body[:, 3:] @ geometric, problem.marker)
            if len(involved) == 1 and np.abs(moved).max() < 1e-12:
                return "does not move the marker point (a tracker measures no orientation)"
            if constant(moved):
                return "moves the marker by a constant amount in the flange frame: m absorbs it"
            return "linearly dependent at these poses: vary the poses or fix one of them"
        if "handeye" not in kinds and constant(spatial @ geometric):
            if problem.formulation == "board":
                return "acts as a rigid motion of the robot base: the board transform W absorbs it"
            return "acts as a rigid motion of the robot base: cancels in relative measurements"
        if "handeye" in kinds or constant(body @ geometric):
            if problem.formulation in ("invariant", "board"):
                return "acts like a change of the hand-eye transform X, which absorbs it"
            return "acts like a change of the tool transform"
        if same_motion(geometric):
            return (
                "the same motion described twice (e.g. a joint's zero offset and its origin's "
                "rotation about the joint axis), at any pose: only their sum is identifiable"
            )
        return "linearly dependent at these poses: vary the poses or fix one of them"

    return explain


@one_blas_thread
def analyse_problem(
    problem: Problem,
    rcond: float = DEFAULT_RCOND,
    jac: np.ndarray | None = None,
    handeye: HandEye = "estimated",
) -> Identifiability:
    """Identifiability of ``problem`` at its nominal model (all errors zero).

    ``jac``: the identification Jacobian there, if the caller has it already. With
    ``handeye="known"`` the hand-eye columns of the frame-invariant formulation are left out (the
    transform is taken as given; the board formulation estimates it with the board transform,
    always). A coincidence problem is judged at its samples nudged onto their
    group points (:func:`relcal.calibration.coincidence.consistent`; ``jac`` is not used).

    Parameters
    ----------
    problem : Problem
        The identification problem.
    rcond : float
        Relative rank tolerance, 0 < rcond < 1: singular values of the column-scaled Jacobian
        below ``rcond`` times the largest count as zero.
    jac : (R, P) ndarray of float, optional
        The identification Jacobian at the nominal model (R residual rows, P parameters).
    handeye : {"estimated", "known"}
        Whether the hand-eye transform is estimated with the robot parameters (``known``: the
        frame-invariant, published and absolute formulations).

    Returns
    -------
    Identifiability
        Rank, identifiable parameters, a subset to identify and the named unidentifiable
        combinations.

    Raises
    ------
    ArgumentError
        ``problem`` not a :class:`Problem`, ``rcond`` outside (0, 1), an unknown ``handeye``,
        ``handeye="known"`` for the board formulation.

    Examples
    --------
    >>> import relcal
    >>> sim = relcal.simulate(relcal.get_robot("a465"), n_poses=20, seed=0)
    >>> ana = relcal.analyse_problem(sim.problem)
    >>> ana.rank, len(ana.singular_values)
    (22, 24)
    >>> ana.combinations[0].names
    ('d[1]',)
    """
    from relcal.checks import check_choice, check_instance, check_number

    check_instance(problem, Problem, "problem", "a Problem")
    check_number(rcond, "rcond", 0, 1, low_open=True, high_open=True)
    check_choice(handeye, "handeye", ("estimated", "known"))
    if handeye == "known" and problem.formulation == "board":
        raise ArgumentError(
            "handeye 'known' (--handeye known): the board formulation estimates the hand-eye "
            "transform X with the board transform W (as a calibration does); take X as known "
            "with pairs of poses (pairing 'all', 'consecutive' or 'star'), or estimate it"
        )
    if problem.formulation == "coincidence":
        from relcal.calibration.coincidence import consistent

        _, jac = residuals(consistent(problem), np.zeros(problem.full_layout.size))
    if jac is None:
        _, jac = residuals(problem, np.zeros(problem.full_layout.size))
    else:
        from relcal.checks import check_array

        jac = check_array(
            jac,
            "jac",
            (None, problem.full_layout.size),
            hint="the identification Jacobian of this problem at zero errors, one column per "
            "parameter of problem.full_layout (or leave jac out)",
        )
    layout = problem.full_layout
    if handeye == "known" and problem.formulation == "invariant":
        layout = problem.layout
        jac = jac[:, : layout.size]
    return analyse(jac, layout, rcond, explainer(problem))


def check_pose_set(
    problem: Problem, source: str, seed: int = 0, refuse: bool = True
) -> Identifiability:
    """Identifiability at the problem's poses, with the combinations they leave undetermined
    that generic poses would determine (the structural null space of this robot and
    formulation) as its ``weak`` ones. With ``refuse``, an error if there are any, naming what
    they miss; without, the caller decides (:func:`weak_families`). ``source`` names the data
    in the message (e.g. the dataset file)."""
    ident = analyse_problem(problem)
    if problem.formulation == "coincidence":  # generic poses seat no tool point in a group
        return ident
    rng = np.random.default_rng(seed)
    model = problem.model
    lo = np.where(np.isfinite(model.lower), model.lower, -np.pi)
    hi = np.where(np.isfinite(model.upper), model.upper, np.pi)
    generic = rng.uniform(lo, hi, (max(30, len(problem.q)), model.n_joints))
    reference = analyse_problem(
        replace(
            problem, q=generic, poses=np.broadcast_to(np.eye(4), (len(generic), 4, 4)), pairs=None
        )
    )
    if ident.rank < reference.rank:
        known = {c.names for c in reference.combinations}
        weak = tuple(c for c in ident.combinations if c.names not in known)
        if refuse:
            raise RelcalError(
                f"{source}: the poses identify only {ident.rank} of the {reference.rank} "
                "parameter combinations that varied poses would; vary the joints more. Not "
                "determined by these poses: "
                + "; ".join([c.describe() for c in weak] or ["(mixed combinations)"])
            )
        return replace(ident, weak=weak or ident.combinations[: reference.rank - ident.rank])
    return ident


def identifiable_at(
    problem: Problem, params: np.ndarray, ident: Identifiability, jac: np.ndarray | None = None
) -> np.ndarray:
    """Parameters identifiable both at the nominal model and at the estimate.

    Exact symmetries (base motion, hand-eye absorption) are curved in parameter space: a parameter
    outside the nominal null space can still drift along it at second order, which the null space
    at the estimate reveals. ``jac``: the Jacobian at ``params`` if the caller has it.
    """
    if jac is None:
        _, jac = residuals(problem, params)
    return ident.identifiable & identifiable_mask(jac, ident.rcond)


def n_measurements(problem: Problem) -> int:
    """Poses (absolute) or pairs (relative formulations)."""
    if problem.formulation == "absolute":
        return len(problem.q)
    return len(problem.pair_indices())


# --- observability indices and parallel axes ----------------------------------------------------


@dataclass(frozen=True)
class Indices:
    """Observability indices O1..O5 (see the module docstring) and the condition number."""

    O1: float
    O2: float
    O3: float
    O4: float
    O5: float
    condition_number: float


def index_values(singular_values: np.ndarray, name: str, n_measurements: int) -> np.ndarray:
    """Observability index ``name`` (O1..O5) of singular values ``(..., L)`` (any order, all
    positive) of full-column-rank scaled Jacobians, one value per leading index."""
    s = np.asarray(singular_values, dtype=float)
    low, high = s.min(axis=-1), s.max(axis=-1)
    if name == "O1":
        return np.exp(np.mean(np.log(s), axis=-1)) / np.sqrt(n_measurements)
    if name == "O2":
        return low / high
    if name == "O3":
        return low
    if name == "O4":
        return low**2 / high
    if name == "O5":
        return 1.0 / np.sum(1.0 / s, axis=-1)
    raise ValueError(f"unknown observability index '{name}': use one of {', '.join(INDEX_NAMES)}")


def observability_indices(singular_values: np.ndarray, n_measurements: int) -> Indices:
    """Indices from the singular values ``(L,)`` of a full-column-rank scaled Jacobian."""
    s = np.asarray(singular_values, dtype=float)
    if len(s) == 0 or s.min() <= 0:
        return Indices(0.0, 0.0, 0.0, 0.0, 0.0, float("inf"))
    values = {name: float(index_values(s, name, n_measurements)) for name in INDEX_NAMES}
    return Indices(**values, condition_number=float(s.max() / s.min()))


@dataclass(frozen=True)
class ParallelPair:
    """Consecutive joint axes parallel within the tolerance, and what standard DH makes of them."""

    joints: tuple[int, int]  # 1-based
    angle_deg: float  # angle between the axes at the nominal geometry
    hayati: bool  # the model already has Hayati's beta for this pair
    misalignment_deg: float = 0.0  # for the demonstration below
    std_d: tuple[float, float] | None = None  # std of both d's (m) with that misalignment


def parallel_pairs(model: RobotModel, tol_deg: float = 1.0) -> list[ParallelPair]:
    """Consecutive axes parallel within ``tol_deg`` (:func:`robot.model.parallel_axes`, the test
    that the Hayati choice uses too)."""
    parallel, angles = parallel_axes(model, tol_deg)
    first = 1 if model.convention == "dh" else 0  # 1-based first joint of the pair, less j
    return [
        ParallelPair(
            (j + first, j + first + 1), float(np.degrees(angles[j])), bool(model.hayati[j])
        )
        for j in map(int, np.flatnonzero(parallel))
    ]
