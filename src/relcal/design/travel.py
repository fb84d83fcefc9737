"""The order a robot runs a plan's poses in, and which of the equivalent angles it goes to.

A revolute joint whose range spans more than a turn (a UR's +-360 deg) reaches the same
configuration at ``q`` and ``q +- 2 pi``: the plan picks, per joint and along the route, the
equivalents within the limits that make the joint's travel least (a shortest path through the
equivalents, joint by joint). The route is a nearest-neighbour tour improved by 2-opt on the cost
of a move, the largest joint travel (the time of a synchronised joint move at the joints' common
speed), summed over the route. The Cramer-Rao bound of a set does not depend on its order or on
which equivalent is used: the kinematics are the same.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from relcal.robot.model import RobotModel

TWO_PI = 2 * np.pi


@dataclass(frozen=True)
class Route:
    """A travel order and its joint values.

    ``order`` ``(K,)`` indexes the input configurations; ``q`` ``(K, n)`` holds them in that order
    with the chosen equivalents (rad, m); ``moves`` ``(K - 1, n)`` the absolute joint travel of
    each move."""

    order: np.ndarray
    q: np.ndarray
    moves: np.ndarray

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


def move_costs(model: RobotModel, q: np.ndarray) -> np.ndarray:
    """``(K, K)`` cost of moving between two configurations: the largest over joints of the
    smallest travel between any of their equivalents."""
    eq = equivalents(model, q)  # (K, n, 3)
    diff = np.abs(eq[:, None, :, :, None] - eq[None, :, :, None, :])  # (K, K, n, 3, 3)
    per_joint = np.nanmin(diff.reshape(*diff.shape[:3], 9), axis=-1)
    return per_joint.max(axis=-1)


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


def unwrap(model: RobotModel, q: np.ndarray) -> np.ndarray:
    """Per joint, the equivalents of ``q`` ``(K, n)`` (in route order) that make the joint's
    summed travel least: a shortest path through at most three values per pose, starting from
    the equivalent nearest zero."""
    eq = equivalents(model, q)  # (K, n, 3)
    k, n, _ = eq.shape
    out = q.copy()
    for j in range(n):
        options = eq[:, j, :]
        cost = np.where(np.isnan(options[0]), np.inf, np.abs(options[0]))  # start near zero
        back = np.zeros((k, 3), dtype=int)
        for t in range(1, k):
            step = np.abs(options[t][:, None] - options[t - 1][None, :])  # (3 now, 3 before)
            total = np.where(np.isnan(step), np.inf, step) + cost[None, :]
            back[t] = np.argmin(total, axis=1)
            cost = np.where(np.isnan(options[t]), np.inf, total.min(axis=1))
        choice = int(np.argmin(cost))
        for t in range(k - 1, -1, -1):
            out[t, j] = options[t, choice]
            choice = back[t, choice]
    return out


def travel_order(model: RobotModel, q: np.ndarray) -> Route:
    """The route through configurations ``q`` ``(K, n)`` (rad, m): nearest neighbour from the one
    nearest the zero position, then 2-opt, then the equivalents that make each joint's travel
    least (:func:`unwrap`)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if len(q) == 0:
        return Route(np.zeros(0, dtype=int), q, np.zeros((0, q.shape[1])))
    cost = move_costs(model, q)
    start = int(np.argmin(np.abs(q).max(axis=1)))
    order = np.array(two_opt(cost, nearest_neighbour(cost, start)))
    ordered = unwrap(model, q[order])
    return Route(order, ordered, np.abs(np.diff(ordered, axis=0)))
