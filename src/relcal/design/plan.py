"""Pose planning: feasible joint configurations that see the whole board, a selection of K of them
that makes the parameters as well determined as possible, in an order a robot can run.

The pieces, one module each: candidates and the constraints they satisfy
(:mod:`relcal.design.feasibility`, :mod:`relcal.design.collision`), the information and the
criteria (:mod:`relcal.design.criteria`), scoring a pool here or on a Dask cluster
(:mod:`relcal.design.scoring`), greedy and exchange selection (:mod:`relcal.design.search`), the
travel order (:mod:`relcal.design.travel`) and the plan file (:mod:`relcal.design.planfile`).
:func:`plan` puts them together.

On a Dask cluster (``plan(client=...)``): the candidate batches are tasks (each batch draws from its
own stream of the seed, so the pool does not depend on where or in which order batches run), and
each greedy or exchange step scores the pool with one call per worker to an actor holding a shard
of the rows, sent once (:class:`~relcal.design.scoring.Scorer`). Scores are computed in fixed
blocks of pool indices in both cases, so the plan is the same as in one process.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from relcal._renamed import UNSET
from relcal.calibration.measurement import Formulation, Measure
from relcal.calibration.noise import Noise
from relcal.checks import check_choice, check_instance, check_number, check_seed
from relcal.design.cell import AnyCell, Cell, FixedCameraCell
from relcal.design.criteria import (
    CRITERIA,
    DEFAULT_NOISE,
    Criterion,
    Information,
    Quality,
    _values,
    criterion,
    information,
    quality,
    selection_problem,
)
from relcal.design.feasibility import Constraints, candidates, check, feasible
from relcal.design.handeye import PURPOSES, MotionQuality, PairRule, handeye_problem, motion_quality
from relcal.design.scoring import Scorer
from relcal.design.search import bounded_moves, exchange, greedy
from relcal.design.travel import MAX_MOVE, Route, travel_order
from relcal.errors import RelcalError
from relcal.robot.ik import inverse_condition
from relcal.robot.model import RobotModel, check_model

__all__ = [
    "CRITERIA",
    "DEFAULT_NOISE",
    "Constraints",
    "Criterion",
    "Information",
    "MotionQuality",
    "PlanResult",
    "Quality",
    "Route",
    "Scorer",
    "_values",
    "candidates",
    "check",
    "criterion",
    "exchange",
    "feasible",
    "greedy",
    "information",
    "inverse_condition",
    "plan",
    "quality",
    "selection_problem",
    "travel_order",
]

Algorithm = Literal["greedy", "exchange"]
ALGORITHMS = ("greedy", "exchange")
PLAN_FORMULATIONS = ("invariant", "published", "absolute", "tracker")  # coincidence: no plan


def check_plan(
    model: Any,
    cell: Any,
    n_poses: Any,
    constraints: Any,
    criterion: Any,
    algorithm: Any,
    n_candidates: Any,
    noise: Any,
    formulation: Any,
    measure: Any,
    random_sets: Any,
    n_validation: Any,
    seed: Any,
    purpose: Any = "calibrate",
) -> None:
    """The arguments of :func:`plan`, checked before any candidate is drawn."""
    check_model(model)
    check_instance(
        cell,
        (Cell, FixedCameraCell),
        "cell",
        "a Cell (relcal.Cell(), the board, camera and mount) or a FixedCameraCell (eye-to-hand)",
    )
    if constraints is not None:
        check_instance(
            constraints,
            Constraints,
            "constraints",
            "Constraints (relcal.design.feasibility.Constraints) or None",
        )
    check_choice(criterion, "criterion", CRITERIA)
    check_choice(algorithm, "algorithm", ALGORITHMS)
    check_instance(noise, Noise, "noise", "a Noise (relcal.Noise(position=, orientation=))")
    check_choice(formulation, "formulation", PLAN_FORMULATIONS)
    check_choice(measure, "measure", ("pose", "position"))
    relative = formulation in ("invariant", "published")
    check_number(n_poses, "n_poses", 2 if relative else 1, integer=True)
    check_number(n_candidates, "n_candidates", 1, integer=True)
    check_number(random_sets, "random_sets", 0, integer=True)
    check_number(n_validation, "n_validation", 0, integer=True)
    check_seed(seed)
    check_choice(purpose, "purpose", PURPOSES)
    if purpose == "handeye" and (formulation, measure) != ("invariant", "pose"):
        from relcal.errors import ArgumentError

        raise ArgumentError(
            f"purpose 'handeye' plans for the hand-eye transform of camera poses: formulation "
            f"'invariant' and measure 'pose' (got '{formulation}', '{measure}')"
        )


@dataclass(frozen=True)
class PlanResult:
    """A plan, the candidate pool it came from, and how it compares with random sets."""

    q: np.ndarray  # (K, n) in travel order, angles the equivalents the route reaches (rad, m)
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
    route: Route | None = None  # the plan's travel order and moves
    move_exchanges: int = 0  # poses exchanged to keep every move within the route's bound
    requested: int = 0  # poses asked for (``q`` has more when poses were added between moves)
    purpose: str = "calibrate"  # or "handeye": the criterion is of the hand-eye X alone
    motion: MotionQuality | None = None  # purpose "handeye": what the plan gives X
    random_motion: MotionQuality | None = None  # the same of the median random set
    mode: str = "eye_in_hand"  # or "eye_to_hand": a fixed camera, the board on the flange

    @property
    def random_median_worst(self) -> float:
        return float(np.median([r.worst[1] for r in self.random])) if self.random else np.nan

    @property
    def improvement(self) -> float:
        """Median worst std of the random sets over the plan's."""
        return self.random_median_worst / self.plan.worst[1]


def plan(
    model: RobotModel,
    cell: AnyCell,
    n_poses: int = 30,
    constraints: Constraints | None = None,
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
    *,
    max_move: float | None = MAX_MOVE,
    purpose: str = "calibrate",
    k: int = UNSET,
) -> PlanResult:
    """Plan ``n_poses`` poses: candidates, selection, and the comparison with random sets.

    The plan is compared with ``random_sets`` random feasible sets of as many candidates
    (predicted standard deviations and accuracy on ``n_validation`` other feasible poses).

    With ``client`` (a ``distributed.Client``) the candidate batches and the scoring of the
    candidates at every greedy and exchange step run as tasks on its cluster; the plan is the
    same as in this process (each candidate batch has its own random stream from ``seed``).

    Parameters
    ----------
    model : RobotModel
        The nominal robot.
    cell : Cell or FixedCameraCell
        The board, where it is, the camera and its mount (:class:`~relcal.design.cell.Cell`),
        or the fixed camera, where it is, and the board on the flange
        (:class:`~relcal.design.cell.FixedCameraCell`, eye-to-hand: candidates put the board in
        front of the camera, and the criteria are of ``X``, the flange-from-board, and of the
        board-in-camera poses ``C_k = W F_k X`` a calibration measures).
    n_poses : int
        Number of poses to plan.
    constraints : Constraints, optional
        What makes a configuration usable (board in view, distance, view angle, joint margins,
        collisions); the defaults of :class:`relcal.design.feasibility.Constraints`.
    criterion : {"worst", "A", "O1", "O2", "O3", "O4", "O5"}
        What the selection optimises: the worst predicted standard deviation, or an
        observability index.
    algorithm : {"exchange", "greedy"}
        Greedy selection alone, or followed by exchanges.
    n_candidates : int
        Feasible candidate configurations to select from.
    noise : Noise
        Measurement noise the predicted standard deviations are computed with (m, rad).
    formulation : {"invariant", "published", "absolute", "tracker"}
        The identification formulation the plan is for.
    measure : {"pose", "position"}
        Position and orientation, or position only.
    random_sets : int
        Random feasible sets of ``n_poses`` candidates compared with the plan.
    n_validation : int
        Other feasible poses on which predicted accuracy is computed.
    seed : int
        Seed of the candidates and the random sets.
    client : distributed.Client, optional
        A Dask client to run the candidate batches and the scoring on.
    max_move : float or None
        Largest travel of any revolute joint between consecutive poses (rad; default 120 deg,
        None: no bound): the route keeps within it, and where no order can, a pose of a longer
        move is exchanged for the best candidate within the bound of its neighbours
        (:func:`relcal.design.search.bounded_moves`).
    purpose : {"calibrate", "handeye"}
        What the poses are for: a kinematic calibration (the criterion over the identifiable
        geometric parameters and the hand-eye), or the hand-eye transform ``X`` alone
        (:mod:`relcal.design.handeye`: the criterion over ``X``'s six components with the
        kinematics known, and no two poses turning near 180 deg from each other or barely
        moving); then :attr:`PlanResult.motion` holds ``X``'s predicted standard deviations
        and the spread of the rotation axes.
    k : int
        Deprecated name of ``n_poses`` (a DeprecationWarning; removed in relcal 0.2).

    Returns
    -------
    PlanResult
        The planned configurations ``q`` ``(n_poses, n_joints)`` in travel order (rad, m), their
        predicted quality and that of the random sets.

    Raises
    ------
    ArgumentError
        An argument of the wrong type or value (a robot name for ``model``, an unknown
        ``algorithm``, ``criterion``, ``formulation`` or ``measure``, ``n_poses`` below 2 for a
        relative formulation, a negative count or seed), before any candidate is drawn.
    RelcalError
        Fewer feasible candidates than ``n_poses + n_validation``.

    Examples
    --------
    >>> import relcal
    >>> result = relcal.plan(
    ...     relcal.get_robot("a465"), relcal.Cell(), n_poses=12, n_candidates=300, random_sets=3,
    ...     n_validation=10,
    ... )
    >>> result.q.shape
    (12, 6)
    """
    import time

    from relcal._renamed import renamed

    k = renamed("plan", "k", k, "n_poses", n_poses, 30)
    check_plan(
        model, cell, k, constraints, criterion, algorithm, n_candidates, noise, formulation,
        measure, random_sets, n_validation, seed, purpose,
    )  # fmt: skip
    constraints = constraints or Constraints()
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
    rule = None
    if purpose == "handeye":
        problem = handeye_problem(model, pool, cell.handeye)
        rule = PairRule.of(model, pool)
    else:
        problem = selection_problem(model, cell, pool, formulation, measure)
    info = information(problem, noise, constraints.length_scale)
    if purpose == "handeye" and info.k < 6:
        raise RelcalError(
            f"the {len(pool)} feasible candidates determine only {info.k} of the hand-eye's 6 "
            "components (their rotations turn about one axis): widen --max-angle or the joint "
            "limits"
        )
    with Scorer(info, client) as scorer:
        chosen = greedy(info, k, criterion, scorer, rule)
        if len(chosen) < k:
            raise RelcalError(
                f"only {len(chosen)} of {len(pool)} feasible candidates for {k} poses form no "
                "pair turning near 180 deg or barely moving; draw more candidates or ask for "
                "fewer poses"
            )
        swaps = 0
        if algorithm == "exchange":
            chosen, swaps = exchange(info, chosen, criterion, scorer=scorer, rule=rule)
        chosen, route, bridged = bounded_moves(
            model, pool, info, chosen, criterion, max_move, scorer=scorer, rule=rule
        )
    plan_quality = quality(info, chosen, problem, q_val)
    sets = [rng.choice(len(pool), len(chosen), replace=False) for _ in range(random_sets)]
    randoms = tuple(quality(info, idx, problem, q_val) for idx in sets)
    random_q = motion = random_motion = None
    if sets:
        median = int(np.argsort([r.worst[1] for r in randoms])[len(sets) // 2])
        random_q = travel_order(model, pool[sets[median]], max_move).q
    if purpose == "handeye":
        fixed = None
        if cell.mode == "eye_to_hand":
            fixed = (cell.camera_pose, noise.pose_covariance())
        motion = motion_quality(model, route.q, cell.handeye, plan_quality.uncertainty.crb, fixed)
        if sets:
            crb = randoms[median].uncertainty.crb
            random_motion = motion_quality(model, random_q, cell.handeye, crb, fixed)
    return PlanResult(
        q=route.q,
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
        route=route,
        move_exchanges=bridged,
        requested=k,
        purpose=purpose,
        motion=motion,
        random_motion=random_motion,
        mode=cell.mode,
    )
