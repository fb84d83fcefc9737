"""Selection of K poses from a candidate pool: greedy forward selection, then optionally
Fedorov-style exchanges (swap a chosen pose for a candidate while the criterion improves)."""

from __future__ import annotations

import numpy as np

from relcal.design.criteria import Information, criterion
from relcal.design.scoring import Scorer


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
