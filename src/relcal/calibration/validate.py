"""Validation on held-out samples: relative pose errors before and after calibration.

Errors are those of the problem's own formulation, evaluated on pairs of held-out samples with the
nominal parameters (before) and the identified ones (after).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from relcal.calibration.identify import Result
from relcal.calibration.measurement import PairStrategy, Problem, make_pairs, pair_errors

_KINDS = (("position_mm", slice(0, 3), 1e3), ("orientation_deg", slice(3, 6), 180 / np.pi))


def _norms(errors: np.ndarray, cols: slice, scale: float) -> np.ndarray:
    return np.linalg.norm(errors[:, cols], axis=1) * scale


def stats(errors: np.ndarray) -> dict[str, dict[str, float]]:
    """Mean, RMS, standard deviation, median, 95th percentile and maximum of the error norms,
    position in mm and orientation in degrees."""
    out = {}
    for key, cols, scale in _KINDS:
        norms = _norms(errors, cols, scale)
        if np.all(np.isnan(norms)) or len(norms) == 0:
            continue
        out[key] = {
            "mean": float(np.mean(norms)),
            "rms": float(np.sqrt(np.mean(norms**2))),
            "std": float(np.std(norms)),
            "median": float(np.median(norms)),
            "p95": float(np.percentile(norms, 95)),
            "max": float(np.max(norms)),
        }
    return out


def ratio_interval(
    pairs: np.ndarray,
    before: np.ndarray,
    after: np.ndarray,
    n_boot: int = 2000,
    seed: int = 0,
) -> dict[str, dict[str, float]]:
    """The ratio of RMS after to RMS before, with a 95 % interval from a paired bootstrap over
    the held-out *samples* (each pair counts as often as both its samples are drawn).

    Pairs share samples (``n`` samples make ``n (n - 1) / 2`` pairs), so resampling pairs would
    pretend far more independent evidence than there is.
    """
    samples, index = np.unique(pairs, return_inverse=True)
    i, j = index.reshape(pairs.shape).T
    n = len(samples)
    draws = np.random.default_rng(seed).integers(0, n, (n_boot, n))
    counts = np.zeros((n_boot, n))
    np.add.at(counts, (np.arange(n_boot)[:, None], draws), 1.0)

    def resampled(values: np.ndarray) -> np.ndarray:
        """``sum_p counts[i_p] counts[j_p] values_p`` per draw, via an ``(n, n)`` table."""
        table = np.zeros((n, n))
        np.add.at(table, (i, j), values)
        return np.einsum("bi,ij,bj->b", counts, table, counts)

    drawn = resampled(np.ones(len(pairs))) > 0  # draws with at least one pair
    out = {}
    for key, cols, scale in _KINDS:
        b2, a2 = _norms(before, cols, scale) ** 2, _norms(after, cols, scale) ** 2
        if np.all(np.isnan(b2)) or len(b2) == 0:
            continue
        boot = np.sqrt(resampled(a2)[drawn] / np.maximum(resampled(b2)[drawn], 1e-300))
        lo, hi = np.percentile(boot, [2.5, 97.5])
        ratio = np.sqrt(a2.sum() / max(b2.sum(), 1e-300))
        out[key] = {"after_over_before": float(ratio), "ci95": [float(lo), float(hi)]}
    return out


@dataclass(frozen=True)
class Validation:
    """Held-out errors before (nominal) and after (identified), per pair and summarised."""

    pairs: np.ndarray  # (P, 2) sample indices into the full data set
    before: np.ndarray  # (P, 6)
    after: np.ndarray  # (P, 6)

    def summary(self) -> dict:
        return {
            "n_pairs": len(self.pairs),
            "n_samples": len(np.unique(self.pairs)),
            "before": stats(self.before),
            "after": stats(self.after),
            "rms_ratio": ratio_interval(self.pairs, self.before, self.after),
        }

    def improvement(self) -> float:
        """Ratio of position RMS before to after."""
        b, a = stats(self.before), stats(self.after)
        return b["position_mm"]["rms"] / max(a["position_mm"]["rms"], 1e-300)


def subset(problem: Problem, samples: np.ndarray, pairing: PairStrategy = "all") -> Problem:
    """The problem restricted to some samples, re-paired among themselves."""
    samples = np.asarray(samples)
    return replace(
        problem,
        q=problem.q[samples],
        poses=problem.poses[samples],
        pairs=make_pairs(len(samples), pairing),
    )


def held_out(
    problem: Problem, result: Result, samples: np.ndarray, pairing: PairStrategy = "all"
) -> Validation:
    """Errors on pairs among ``samples`` (which the identification did not use)."""
    test = subset(problem, samples, pairing)
    zero = np.zeros_like(result.params)
    return Validation(
        pairs=np.asarray(samples)[test.pair_indices()],
        before=pair_errors(test, zero),
        after=pair_errors(test, result.params),
    )


def split(n_samples: int, fraction: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Random training and held-out sample indices (held-out share ``fraction``)."""
    order = np.random.default_rng(seed).permutation(n_samples)
    n_test = max(2, int(round(fraction * n_samples)))
    return np.sort(order[n_test:]), np.sort(order[:n_test])


def folds(n_samples: int, k: int, seed: int = 0) -> list[np.ndarray]:
    """``k`` disjoint held-out index sets covering all samples (shuffled with ``seed``)."""
    order = np.random.default_rng(seed).permutation(n_samples)
    return [np.sort(f) for f in np.array_split(order, k)]
