"""Selection of K poses from a candidate pool: greedy forward selection, then optionally
Fedorov-style exchanges (swap a chosen pose for a candidate while the criterion improves)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from relcal.design.criteria import Information, criterion
from relcal.design.handeye import PairRule, excluded
from relcal.design.scoring import Scorer
from relcal.design.travel import (
    MAX_MOVE,
    Route,
    excess,
    joint_travel,
    route_excess,
    route_of,
    travel_order,
)
from relcal.robot.model import RobotModel


def greedy(
    info: Information,
    k: int,
    name: str,
    scorer: Scorer | None = None,
    rule: PairRule | None = None,
) -> np.ndarray:
    """Forward selection: add, one at a time, the candidate that maximises the criterion (and,
    with ``rule``, forms no pair it forbids with those chosen; fewer than ``k`` when none is
    left)."""
    scorer = scorer or Scorer(info)
    chosen: list[int] = []
    total = np.zeros(info.rows.shape[-1:] * 2)
    while len(chosen) < k and len(chosen) < len(info.rows):
        banned = excluded(rule, np.array(chosen, dtype=int))
        _, best = scorer.best(total, banned, name, len(chosen) + 1)
        if best < 0:
            break
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
    rule: PairRule | None = None,
) -> tuple[np.ndarray, int]:
    """Fedorov-style exchange: for each chosen pose, the swap with an unchosen candidate that
    improves the criterion most (with ``rule``: among those forming no pair it forbids with the
    others); passes until none improves. Returns the set and the swaps made."""
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
            banned = excluded(rule, chosen, np.delete(chosen, pos))
            value, best = scorer.best(base, banned, name, k)
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


NEAREST = 10  # candidates nearest the bound among which one is chosen when none is within it


def bounded_moves(
    model: RobotModel,
    pool: np.ndarray,
    info: Information,
    chosen: np.ndarray,
    name: str,
    max_move: float | None = MAX_MOVE,
    scorer: Scorer | None = None,
    max_rounds: int | None = None,
    rule: PairRule | None = None,
) -> tuple[np.ndarray, Route, int]:
    """The chosen poses in travel order, with no revolute joint moving more than ``max_move``
    (rad) between consecutive poses where the pool allows it.

    The route is :func:`relcal.design.travel.travel_order`'s; while a move exceeds the bound,
    one of its two poses is exchanged for the candidate of ``pool`` ``(P, n)`` within the bound
    of that pose's neighbours on the route that keeps the criterion ``name`` highest, and the
    route is made again (the exchange is kept only if the moves beyond the bound shrink). A move
    no exchange brings within the bound gets a candidate inserted between its poses, at most
    ``len(chosen) // 5`` in all (the plan then has more poses than asked). With ``rule``, no
    exchanged or inserted candidate forms a pair it forbids with the other poses. Returns the
    chosen indices in travel order (the route's ``order`` indexes them), the route and the
    number of exchanges."""
    scorer = scorer or Scorer(info)
    chosen = np.array(chosen)
    k = len(chosen)
    route = travel_order(model, pool[chosen], max_move)
    if max_move is None:
        return chosen[route.order], replace(route, order=np.arange(k)), 0
    exchanges = 0
    stuck: set[tuple[int, int]] = set()
    for _ in range(max_rounds if max_rounds is not None else 3 * k):
        ordered = chosen[route.order]
        over = excess(model, route.moves, max_move)
        moves = [t for t in np.argsort(-over) if over[t] > 0]
        moves = [t for t in moves if (ordered[t], ordered[t + 1]) not in stuck]
        if not moves:
            break
        t = int(moves[0])
        total = info.total(ordered)
        options = []
        for pos in (t, t + 1):
            neighbours = [ordered[p] for p in (pos - 1, pos + 1) if 0 <= p < k and p != pos]
            travel = joint_travel(model, pool, pool[neighbours])  # (P, m, n)
            beyond = excess(model, travel, max_move).sum(axis=1)  # (P,)
            now = beyond[ordered[pos]]
            base = total - info.total([ordered[pos]])
            # within the bound of both neighbours; else among the few that come nearest to it
            allowed = beyond <= 1e-12
            if not allowed[np.setdiff1d(np.arange(len(pool)), ordered)].any():
                free = np.setdiff1d(np.flatnonzero(beyond < now - 1e-9), ordered)
                allowed = np.zeros(len(pool), dtype=bool)
                allowed[free[np.argsort(beyond[free], kind="stable")[:NEAREST]]] = True
            banned = np.union1d(
                excluded(rule, ordered, np.delete(ordered, pos)), np.flatnonzero(~allowed)
            )
            if len(banned) >= len(pool):
                continue
            value, best = scorer.best(base, banned, name, k)
            if best >= 0:
                options.append((value, pos, best))
        before = route_excess(model, route)
        accepted = False
        for _value, pos, best in sorted(options, key=lambda o: -o[0]):
            trial = ordered.copy()
            trial[pos] = best
            kept = route_of(model, pool[trial], np.arange(k), max_move)
            fresh = travel_order(model, pool[trial], max_move)
            new = min((kept, fresh), key=lambda r: (route_excess(model, r), r.total))
            if route_excess(model, new) < before - 1e-12:
                chosen, route = trial, new
                exchanges += 1
                accepted = True
                break
        if not accepted:
            stuck.add((ordered[t], ordered[t + 1]))
    ordered = chosen[route.order]
    route = replace(route, order=np.arange(k))
    ordered, route = _bridges(model, pool, ordered, route, max_move, max(1, k // 5), rule)
    return ordered, route, exchanges


def _bridges(
    model: RobotModel,
    pool: np.ndarray,
    ordered: np.ndarray,
    route: Route,
    max_move: float,
    most: int,
    rule: PairRule | None = None,
) -> tuple[np.ndarray, Route]:
    """Up to ``most`` candidates of ``pool`` inserted into moves still beyond the bound, each
    the one nearest the bound from both ends (the plan then has more poses than asked; with
    ``rule``, none forming a pair it forbids with the others)."""
    for _ in range(most):
        over = excess(model, route.moves, max_move)
        if not (over > 0).any():
            break
        t = int(np.argmax(over))
        travel = joint_travel(model, pool, pool[ordered[t : t + 2]])  # (P, 2, n)
        beyond = excess(model, travel, max_move).sum(axis=1)
        beyond[excluded(rule, ordered)] = np.inf
        best = int(np.argmin(beyond))
        if not beyond[best] < over[t] - 1e-9:
            break
        trial = np.insert(ordered, t + 1, best)
        new = route_of(model, pool[trial], np.arange(len(trial)), max_move)
        if route_excess(model, new) >= route_excess(model, route) - 1e-12:
            break
        ordered, route = trial, new
    return ordered, route
