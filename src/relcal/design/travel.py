"""The order a robot runs a plan's poses in, and which of the equivalent angles it goes to.

A revolute joint whose range spans more than a turn (a UR's +-360 deg) reaches the same
configuration at ``q`` and ``q +- 2 pi``: the plan picks, per joint and along the route, the
equivalents within the limits that make the joint's travel least (a shortest path through the
equivalents, joint by joint). The route is a nearest-neighbour tour improved by 2-opt on the cost
of a move, the largest joint travel (the time of a synchronised joint move at the joints' common
speed), summed over the route. The Cramer-Rao bound of a set does not depend on its order or on
which equivalent is used: the kinematics are the same.

A bound on the travel of any revolute joint in one move (:data:`MAX_MOVE`, 120 deg by default)
keeps each move short and safe for a camera's cable: a move beyond it costs
:data:`PENALTY` times its excess on top of its travel, in the order and in the choice of
equivalents alike, so the route keeps within the bound wherever an order can, and otherwise
exceeds it as little as it can (:attr:`Route.over`; :func:`relcal.design.plan.plan` then adds
poses between).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from relcal.robot.model import RobotModel

TWO_PI = 2 * np.pi
MAX_MOVE = np.radians(120.0)  # rad: default bound on one revolute joint's travel in one move
PENALTY = 100.0  # cost per rad of travel beyond the bound


@dataclass(frozen=True)
class Route:
    """A travel order and its joint values.

    ``order`` ``(K,)`` indexes the input configurations; ``q`` ``(K, n)`` holds them in that order
    with the chosen equivalents (rad, m); ``moves`` ``(K - 1, n)`` the absolute joint travel of
    each move."""

    order: np.ndarray
    q: np.ndarray
    moves: np.ndarray
    max_move: float | None = None  # rad: the bound on a revolute joint's travel in one move
    prismatic: np.ndarray | None = None  # (n,) bool: joints the bound does not apply to

    @property
    def over(self) -> np.ndarray:
        """``(M, 2)`` (move index, joint index) of every revolute move beyond :attr:`max_move`."""
        if self.max_move is None or not len(self.moves):
            return np.zeros((0, 2), dtype=int)
        revolute = np.ones(self.moves.shape[1], bool) if self.prismatic is None else ~self.prismatic
        return np.argwhere((self.moves > self.max_move + 1e-9) & revolute)

    @property
    def longest(self) -> tuple[int, int, float]:
        """``(move index, joint index, travel)`` of the longest single joint travel (rad, m)."""
        if not len(self.moves):
            return 0, 0, 0.0
        k, j = np.unravel_index(int(np.argmax(self.moves)), self.moves.shape)
        return int(k), int(j), float(self.moves[k, j])

    @property
    def total(self) -> float:
        """Sum over the moves of the largest joint travel (rad, m)."""
        return float(self.moves.max(axis=1).sum()) if len(self.moves) else 0.0


def equivalents(model: RobotModel, q: np.ndarray) -> np.ndarray:
    """The values ``(K, n, 3)`` of each joint equivalent to ``q`` ``(K, n)``: ``q - 2 pi``, ``q``,
    ``q + 2 pi``, NaN where outside the limits or the joint is prismatic. ``q`` itself is kept even
    outside the limits (the caller checks limits)."""
    shifts = np.array([-TWO_PI, 0.0, TWO_PI])
    out = q[..., None] + shifts
    outside = (out < model.lower[:, None] - 1e-12) | (out > model.upper[:, None] + 1e-12)
    outside[..., 1] = False
    outside |= model.prismatic[:, None] & (shifts != 0)
    return np.where(outside, np.nan, out)


def joint_travel(model: RobotModel, q: np.ndarray, other: np.ndarray | None = None) -> np.ndarray:
    """``(K, L, n)`` smallest travel of each joint between configurations ``q`` ``(K, n)`` and
    ``other`` ``(L, n)`` (default ``q``), over their equivalents (rad, m)."""
    eq = equivalents(model, q)  # (K, n, 3)
    eo = eq if other is None else equivalents(model, other)
    diff = np.abs(eq[:, None, :, :, None] - eo[None, :, :, None, :])  # (K, L, n, 3, 3)
    return np.nanmin(diff.reshape(*diff.shape[:3], 9), axis=-1)


def move_costs(model: RobotModel, q: np.ndarray) -> np.ndarray:
    """``(K, K)`` cost of moving between two configurations: the largest over joints of the
    smallest travel between any of their equivalents."""
    return joint_travel(model, q).max(axis=-1)


def excess(model: RobotModel, travel: np.ndarray, max_move: float | None) -> np.ndarray:
    """Summed travel of the revolute joints beyond ``max_move`` in each move of ``travel``
    ``(..., n)`` (rad); zeros without a bound."""
    if max_move is None:
        return np.zeros(travel.shape[:-1])
    over = np.where(model.prismatic, 0.0, np.maximum(travel - max_move, 0.0))
    return over.sum(axis=-1)


def nearest_neighbour(cost: np.ndarray, start: int) -> list[int]:
    """A path through every node from ``start``, each step to the nearest unvisited node."""
    left = [i for i in range(len(cost)) if i != start]
    order = [start]
    while left:
        step = cost[order[-1], left]
        order.append(left.pop(int(np.argmin(step))))
    return order


def two_opt(cost: np.ndarray, order: list[int], max_passes: int = 50) -> list[int]:
    """Improve an open path by reversing segments while that shortens it (first improvement)."""
    order = list(order)
    n = len(order)
    for _ in range(max_passes):
        improved = False
        for i in range(1, n - 1):
            for j in range(i + 1, n):
                a, b = order[i - 1], order[i]
                c = order[j]
                d = order[j + 1] if j + 1 < n else None
                before = cost[a, b] + (cost[c, d] if d is not None else 0.0)
                after = cost[a, c] + (cost[b, d] if d is not None else 0.0)
                if after < before - 1e-12:
                    order[i : j + 1] = order[i : j + 1][::-1]
                    improved = True
        # the path's first node may also move: reverse a prefix
        for j in range(1, n - 1):
            if cost[order[0], order[j + 1]] < cost[order[j], order[j + 1]] - 1e-12:
                order[: j + 1] = order[: j + 1][::-1]
                improved = True
        if not improved:
            break
    return order


def unwrap(model: RobotModel, q: np.ndarray, max_move: float | None = None) -> np.ndarray:
    """Per joint, the equivalents of ``q`` ``(K, n)`` (in route order) that make the joint's
    summed travel least (each move beyond ``max_move`` costing :data:`PENALTY` times its excess
    on top): a shortest path through at most three values per pose, starting from the
    equivalent nearest zero."""
    eq = equivalents(model, q)  # (K, n, 3)
    k, n, _ = eq.shape
    out = q.copy()
    for j in range(n):
        options = eq[:, j, :]
        bound = None if model.prismatic[j] else max_move
        cost = np.where(np.isnan(options[0]), np.inf, np.abs(options[0]))  # start near zero
        back = np.zeros((k, 3), dtype=int)
        for t in range(1, k):
            step = np.abs(options[t][:, None] - options[t - 1][None, :])  # (3 now, 3 before)
            if bound is not None:
                step = step + PENALTY * np.maximum(step - bound, 0.0)
            total = np.where(np.isnan(step), np.inf, step) + cost[None, :]
            back[t] = np.argmin(total, axis=1)
            cost = np.where(np.isnan(options[t]), np.inf, total.min(axis=1))
        choice = int(np.argmin(cost))
        for t in range(k - 1, -1, -1):
            out[t, j] = options[t, choice]
            choice = back[t, choice]
    return out


def path_cost(cost: np.ndarray, order) -> float:
    """Summed cost of the moves of an open path."""
    order = np.asarray(order)
    return float(cost[order[:-1], order[1:]].sum()) if len(order) > 1 else 0.0


def route_of(
    model: RobotModel, q: np.ndarray, order: np.ndarray, max_move: float | None = MAX_MOVE
) -> Route:
    """The route through ``q`` ``(K, n)`` in the given ``order``, its equivalents by
    :func:`unwrap`."""
    order = np.asarray(order, dtype=int)
    ordered = unwrap(model, q[order], max_move)
    return Route(order, ordered, np.abs(np.diff(ordered, axis=0)), max_move, model.prismatic)


def route_excess(model: RobotModel, route: Route) -> float:
    """Summed travel of revolute joints beyond the route's bound over its moves (rad)."""
    return float(excess(model, route.moves, route.max_move).sum()) if len(route.moves) else 0.0


STARTS = 8  # nearest-neighbour tours tried (from the pose nearest zero and evenly spread others)


def travel_order(model: RobotModel, q: np.ndarray, max_move: float | None = MAX_MOVE) -> Route:
    """The route through configurations ``q`` ``(K, n)`` (rad, m): nearest-neighbour tours from
    the one nearest the zero position and a few others, each improved by 2-opt, the shortest
    kept; then the equivalents that make each joint's travel least (:func:`unwrap`). A move of a
    revolute joint beyond ``max_move`` (rad; None: no bound) costs :data:`PENALTY` times its
    excess on top of its travel, so the route keeps within the bound where an order can."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if len(q) == 0:
        return Route(
            np.zeros(0, dtype=int), q, np.zeros((0, q.shape[1])), max_move, model.prismatic
        )
    travel = joint_travel(model, q)
    cost = travel.max(axis=-1) + PENALTY * excess(model, travel, max_move)
    first = int(np.argmin(np.abs(q).max(axis=1)))
    starts = [first] + [s for s in np.linspace(0, len(q) - 1, STARTS).astype(int) if s != first]
    best = None
    for start in dict.fromkeys(starts):
        order = two_opt(cost, nearest_neighbour(cost, int(start)))
        if best is None or path_cost(cost, order) < path_cost(cost, best) - 1e-12:
            best = order
    return route_of(model, q, np.array(best), max_move)
