"""Model selection: which parameters (and which row weighting) the data support, chosen by
cross-validated held-out error on the training samples.

Candidates range from the measurement frames alone (the hand-eye transform, a tracker's
instrument transform and marker, or a coincidence's tool point and group points: the baseline a
user gets without kinematic calibration) through the identifiable geometry to each family of
non-geometric terms. Every candidate and weighting is scored by K-fold cross-validation over
*samples* (a held-out fold's pairs are the pairs among its samples; pairs share samples, so
splitting pairs would leak; a tracker's points are one per sample, a coincidence's too, its known
distances always on the training side). The folds are refitted on the model linearised at a full
fit, ``r(p) ~ b - J p``: the errors are millimetres and tenths of a degree, so the second-order
terms are micrometres, and each fold costs one small normal-equation solve instead of a nonlinear
fit. A measurement kind linearises once at the geometric fit for every candidate
(:func:`score_candidates`), or each candidate at its own fit (:func:`score_each`).

The choice is conservative: the simplest candidate whose cross-validated error is within one
standard error of the best (paired over samples) wins, so a term is added only when it helps
clearly, and the hand-eye-only baseline is chosen when nothing helps.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from relcal.calibration.measurement import Problem, residuals
from relcal.calibration.noise import Noise, row_factors
from relcal.calibration.uncertainty import parameter_covariance
from relcal.robot.model import RobotModel, nongeometric_options, with_nongeometric

GEOMETRIC_KINDS = ("theta_off", "a", "d", "alpha", "beta", "base", "tool", "origin")
# Estimated with the robot, never exported: the hand-eye, a tracker's instrument transform and
# marker, a coincidence's tool point and group points.
FRAME_KINDS = ("handeye", "board", "instrument", "marker", "tool_point", "point")
PLAIN_ROTATION_WEIGHT = 0.1  # m/rad: rotation rows count like a 0.1 m lever arm
# Candidates without kinematic correction, by formulation: the hand-eye transform alone,
# (position-only data) the instrument transform and the marker alone, (coincidences) the tool
# point and the group points alone.
BASELINES = {
    "tracker": "instrument and marker only",
    "coincidence": "tool point and group points only",
}
BASELINE_CANDIDATES = ("hand-eye only", *BASELINES.values())


def family(kind: str) -> str:
    """The family of a parameter kind: ``frames`` (the hand-eye, a tracker's instrument
    transform and marker, a coincidence's tool point and group points), ``geometric`` or a
    non-geometric family (``harmonic_c`` and ``harmonic_s`` are one family ``harmonic``)."""
    if kind in FRAME_KINDS:
        return "frames"
    if kind in GEOMETRIC_KINDS:
        return "geometric"
    return kind.split("_")[0]


def baseline_name(problem: Problem) -> str:
    """The name of the candidate without kinematic correction (one of
    :data:`BASELINE_CANDIDATES`)."""
    return BASELINES.get(problem.formulation, BASELINE_CANDIDATES[0])


def geometric_columns(problem: Problem, subset: np.ndarray) -> np.ndarray:
    """The entries of ``subset`` that are frames or geometry (no non-geometric term)."""
    kinds = problem.full_layout.kinds
    keep = [c for c in subset if family(kinds[c]) in ("frames", "geometric")]
    return np.array(keep, dtype=int)


def candidate_model(model: RobotModel, nongeometric: str | Sequence[str]) -> RobotModel:
    """``model`` with the non-geometric families that model selection may choose switched on:
    ``"auto"`` every family the model can have (:func:`robot.model.nongeometric_options`),
    ``"none"`` only those the model file enables, or a list of families."""
    if nongeometric == "none":
        return model
    terms = nongeometric_options(model) if nongeometric == "auto" else tuple(nongeometric)
    return with_nongeometric(model, terms) if terms else model


@dataclass(frozen=True)
class Candidate:
    """A set of free parameters (indices into the full layout) and a row weighting."""

    name: str
    columns: np.ndarray  # (k,) int
    weighting: str  # "plain" (rotation rows x 0.1 m/rad) or "noise model" (learned 6x6)


WEIGHTINGS = ("plain", "noise model")


def candidates(
    problem: Problem, subset: np.ndarray, weightings: tuple[str, ...] = ("plain",)
) -> list[Candidate]:
    """Nested candidates within the identifiable ``subset``, simplest first, each under every
    weighting: the frames only (:func:`baseline_name`), + geometry, + each non-geometric family,
    + all of them."""
    kinds = problem.full_layout.kinds
    subset = np.asarray(subset, dtype=int)
    fam = np.array([family(kinds[i]) for i in subset])
    sets: list[tuple[str, np.ndarray]] = [(baseline_name(problem), subset[fam == "frames"])]
    base = subset[np.isin(fam, ("frames", "geometric"))]
    if len(base) > len(sets[0][1]):
        sets.append(("geometric", base))
    extra = [f for f in dict.fromkeys(fam) if f not in ("frames", "geometric")]
    for f in extra:
        sets.append((f"geometric + {f}", np.union1d(base, subset[fam == f])))
    if len(extra) > 1:
        sets.append(("geometric + " + " + ".join(extra), np.sort(subset)))
    return [
        Candidate(name, np.sort(cols), weighting) for name, cols in sets for weighting in weightings
    ]


@dataclass(frozen=True)
class Linearised:
    """Unweighted residuals as a linear function of the parameters: ``r(p) ~ b - J p``, one
    6-row block per measurement (a pair of samples, or a point of sample k ``(k, k)`` with zero
    rotation rows; a coincidence's known distance is one row of a block that belongs to no
    sample and is never held out, ``always``)."""

    b: np.ndarray  # (P, 6) translation m, rotation rad
    jac: np.ndarray  # (P, 6, Q)
    pairs: np.ndarray  # (P, 2) sample positions ((k, k) for a point of sample k)
    n_samples: int
    always: np.ndarray | None = None  # (P,) bool: blocks always on the training side


def linearise(problem: Problem, params: np.ndarray) -> Linearised:
    """The frame-invariant pose problem, a tracker's or a coincidence's point problem (with its
    known distances), linearised at ``params`` (its weights ignored)."""
    n = len(problem.q)
    if problem.formulation in ("tracker", "coincidence"):  # 3 rows per sample, no orientation
        r, a = residuals(replace(problem, weights=None, pair_weights=None), params)
        extra = len(r) - 3 * n  # one row per known distance
        b, jac = np.zeros((n + extra, 6)), np.zeros((n + extra, 6, a.shape[-1]))
        b[:n, :3], jac[:n, :3] = r[: 3 * n].reshape(n, 3), a[: 3 * n].reshape(n, 3, -1)
        b[n:, 0], jac[n:, 0] = r[3 * n :], a[3 * n :]
        pairs = np.repeat(np.r_[np.arange(n), np.zeros(extra, int)][:, None], 2, axis=1)
        always = np.r_[np.zeros(n, bool), np.ones(extra, bool)] if extra else None
        return Linearised(b + jac @ params, jac, pairs, n, always)
    plain = replace(problem, weights=None, pair_weights=None, measure="pose")
    pairs = plain.pair_indices()
    r, a = residuals(plain, params)
    r, a = r.reshape(len(pairs), 6), a.reshape(len(pairs), 6, -1)
    return Linearised(r + a @ params, a, pairs, n)


def plain_whiteners(n_pairs: int) -> np.ndarray:
    """The plain weighting ``(P, 6, 6)``: translation rows in m, rotation rows x 0.1 m/rad."""
    w = np.diag(np.r_[np.ones(3), np.full(3, PLAIN_ROTATION_WEIGHT)])
    return np.broadcast_to(w, (n_pairs, 6, 6))


def whitened(
    whiten: np.ndarray, jac: np.ndarray, b: np.ndarray, rows=None
) -> tuple[np.ndarray, np.ndarray]:
    """``whiten @ jac`` ``(P', 6, Q)`` and ``whiten @ b`` ``(P', 6)`` over the blocks ``rows``
    (default all) of ``whiten`` ``(P, 6, 6)``, ``jac`` ``(P, 6, Q)`` and ``b`` ``(P, 6)``; a
    diagonal whitening (:func:`~relcal.calibration.noise.row_factors`) scales the rows instead
    of multiplying blocks."""
    rows = slice(None) if rows is None else rows
    factors = row_factors(whiten)
    if factors is not None:  # C order, as the products give (sums over it keep their order)
        scaled = np.multiply(jac[rows], factors[:, None], order="C")
        return scaled, np.multiply(b[rows], factors, order="C")
    w = whiten[rows]
    return w @ jac[rows], np.einsum("pij,pj->pi", w, b[rows])


def solve_normal(normal: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """``normal^-1 rhs`` with Jacobi scaling (metres and radians differ by orders)."""
    d = np.sqrt(np.clip(np.diag(normal), 1e-300, None))
    return np.linalg.lstsq(normal / np.outer(d, d), rhs / d, rcond=1e-12)[0] / d


def fit(
    lin: Linearised,
    whiten: np.ndarray,
    columns: np.ndarray,
    rows=None,
    prior: np.ndarray | None = None,
) -> np.ndarray:
    """Weighted linear least squares over ``columns``; the full parameter vector ``(Q,)``.
    ``prior`` ``(Q,)``: prior-row weights (:func:`lin_prior`) of a maximum a posteriori fit."""
    rows = slice(None) if rows is None else rows
    jw = (whiten[rows] @ lin.jac[rows][:, :, columns]).reshape(-1, len(columns))
    bw = np.einsum("pij,pj->pi", whiten[rows], lin.b[rows]).reshape(-1)
    out = np.zeros(lin.jac.shape[-1])
    out[columns] = solve_normal(jw.T @ jw + _prior_normal(prior, columns), jw.T @ bw)
    return out


def _prior_normal(prior: np.ndarray | None, columns: np.ndarray) -> np.ndarray | float:
    """The prior rows' share ``diag(w^2)`` of the normal matrix over ``columns`` (0: none)."""
    if prior is None:
        return 0.0
    return np.diag(np.asarray(prior, float)[np.asarray(columns, int)] ** 2)


def lin_prior(
    lin: Linearised, whiten: np.ndarray, params: np.ndarray, std: np.ndarray
) -> np.ndarray | None:
    """The prior-row weights ``(Q,)`` of the linearised problem under the row whitening
    ``whiten`` ``(P, 6, 6)``: ``sqrt(c) s / std`` with ``s`` the robust level of the whitened
    rows at ``params`` and ``c`` the blocks' overcount (:mod:`relcal.calibration.priors`);
    None when no parameter has a prior."""
    from relcal.calibration.priors import noise_level, overcount, row_weights

    if not np.isfinite(np.asarray(std, float)).any():
        return None
    e = errors(lin, params)
    factors = row_factors(whiten)
    rows = e * factors if factors is not None else np.einsum("pij,pj->pi", whiten, e)
    noise = noise_level(rows)
    if noise <= 0:
        return None
    return row_weights(std, noise, overcount(len(lin.pairs), lin.n_samples))


def errors(lin: Linearised, params: np.ndarray, rows=None) -> np.ndarray:
    """Unweighted pair errors ``(P, 6)`` of the linear model at ``params``."""
    rows = slice(None) if rows is None else rows
    return lin.b[rows] - lin.jac[rows] @ params


@dataclass(frozen=True)
class Score:
    """A candidate's cross-validated held-out errors."""

    candidate: Candidate
    errors: np.ndarray  # (T, 6) over the held-out pairs of every fold
    per_sample: np.ndarray  # (n,) mean squared position error (m^2) of each sample's pairs

    @property
    def position_rms(self) -> float:
        return float(np.sqrt(np.mean(np.sum(self.errors[:, :3] ** 2, axis=1))))

    @property
    def orientation_rms(self) -> float:
        return float(np.sqrt(np.mean(np.sum(self.errors[:, 3:] ** 2, axis=1))))


def sample_folds(n_samples: int, k: int, seed: int) -> list[np.ndarray]:
    """``k`` disjoint held-out sets of sample positions (shuffled with ``seed``)."""
    order = np.random.default_rng(seed).permutation(n_samples)
    return [np.sort(f) for f in np.array_split(order, k)]


def score_candidates(
    lin: Linearised,
    whiteners: dict[str, np.ndarray],
    cands: list[Candidate],
    k: int = 5,
    seed: int = 0,
    prior: dict[str, np.ndarray | None] | None = None,
) -> list[Score]:
    """K-fold scores of every candidate: each fold's samples held out, the others refitted;
    ``prior``: per weighting, the prior-row weights of maximum a posteriori fits
    (:func:`lin_prior`; None: plain least squares). Only the weightings of ``cands`` are formed
    (``whiteners`` may hold more)."""
    held = {c.name + c.weighting: [] for c in cands}
    used = {c.weighting for c in cands}
    whiteners = {w: whiten for w, whiten in whiteners.items() if w in used}
    in_fold = np.zeros(lin.n_samples, dtype=int)
    for f, fold in enumerate(sample_folds(lin.n_samples, k, seed)):
        in_fold[fold] = f
    test_pairs = []
    for f in range(k):
        inside = in_fold[lin.pairs] == f
        train, test = ~inside.any(axis=1), inside.all(axis=1)
        if lin.always is not None:
            train, test = train | lin.always, test & ~lin.always
        test_pairs.append(np.flatnonzero(test))
        for weighting, whiten in whiteners.items():
            jw, bw = whitened(whiten, lin.jac, lin.b, train)
            jw, bw = jw.reshape(-1, lin.jac.shape[-1]), bw.reshape(-1)
            normal, rhs = jw.T @ jw, jw.T @ bw
            for c in cands:
                if c.weighting != weighting:
                    continue
                params = np.zeros(lin.jac.shape[-1])
                cols = c.columns
                w = None if prior is None else prior.get(weighting)
                params[cols] = solve_normal(
                    normal[np.ix_(cols, cols)] + _prior_normal(w, cols), rhs[cols]
                )
                held[c.name + c.weighting].append(errors(lin, params, test))
    pairs = lin.pairs[np.concatenate(test_pairs)]
    scores = []
    for c in cands:
        e = np.concatenate(held[c.name + c.weighting])
        sq = np.sum(e[:, :3] ** 2, axis=1)
        total = np.bincount(pairs.ravel(), np.repeat(sq, 2), minlength=lin.n_samples)
        count = np.bincount(pairs.ravel(), minlength=lin.n_samples)
        scores.append(Score(c, e, total / np.maximum(count, 1)))
    return scores


STANDARD_ERRORS = 2.0  # a more complex candidate must win by more than this many paired SE


def choose(scores: list[Score], n_se: float = STANDARD_ERRORS) -> tuple[int, str]:
    """Index of the chosen score and why: the simplest (first) candidate whose mean squared
    held-out position error is within ``n_se`` paired standard errors (over samples) of the
    best's. Two standard errors keep a family of terms that is not there out in about 98 % of
    data sets (one-sided), which is what a user must be able to trust."""
    mse = np.array([np.mean(s.per_sample) for s in scores])
    best = int(np.argmin(mse))
    for i, s in enumerate(scores[: best + 1]):
        diff = s.per_sample - scores[best].per_sample
        se = np.std(diff, ddof=1) / np.sqrt(len(diff)) if len(diff) > 1 else 0.0
        if i == best:
            return i, "lowest cross-validated held-out position error"
        if np.mean(diff) <= n_se * se:
            best_c = scores[best].candidate
            return i, (
                f"within {n_se:g} standard errors of the best ({best_c.name}, "
                f"{best_c.weighting}) and simpler"
            )
    return best, "lowest cross-validated held-out position error"


def choose_all(scores: list[Score]) -> tuple[int, str]:
    """Index of the candidate with the most parameters (under its best-scoring weighting) and
    why: ``--selection all``."""
    size = max(len(s.candidate.columns) for s in scores)
    largest = [k for k, s in enumerate(scores) if len(s.candidate.columns) == size]
    chosen = min(largest, key=lambda k: np.mean(scores[k].per_sample))
    return chosen, "all identifiable parameters (--selection all)"


def score_each(
    problem: Problem,
    fits: list,
    cands: list[Candidate],
    k: int,
    seed: int,
    std: np.ndarray | None = None,
) -> list[Score]:
    """K-fold scores of the candidates by :func:`score_candidates`, each candidate's folds
    refitted on ``problem`` linearised at its own fit to every training sample (``fits``, one
    :class:`~relcal.calibration.identify.Result` per candidate), in the plain weighting; ``std``
    ``(Q,)``: the priors' standard deviations (SI) of maximum a posteriori folds."""
    out = []
    for cand, result in zip(cands, fits, strict=True):
        lin = linearise(problem, result.params)
        plain = {"plain": plain_whiteners(len(lin.pairs))}
        prior = None
        if std is not None:
            prior = {"plain": lin_prior(lin, plain["plain"], result.params, std)}
        out.append(score_candidates(lin, plain, [cand], k, seed, prior)[0])
    return out


def _blocks(problem: Problem) -> np.ndarray:
    """The problem's row weighting as per-pair blocks ``(P, 6, 6)``."""
    if problem.pair_weights is not None:
        return problem.pair_weights
    w = np.ones(6) if problem.weights is None else problem.weights
    return np.broadcast_to(np.diag(w), (len(problem.pair_indices()), 6, 6))


def significant_columns(
    problem: Problem,
    ident,
    columns: np.ndarray,
    noise: Noise,
    params: np.ndarray,
    z_min: float = 3.0,
) -> np.ndarray:
    """``columns`` less the link parameters whose linearised estimate is below ``z_min``
    standard deviations (hand-eye components always stay), dropped until none is: ``--select
    conservative`` of the kinds that share one linearisation."""
    kinds = problem.full_layout.kinds
    cols = np.asarray(columns)
    lin = linearise(problem, params)
    while True:
        estimate = fit(lin, _blocks(problem), cols)
        unc = parameter_covariance(problem, noise, replace(ident, subset=cols), params=params)
        z = np.abs(estimate[unc.subset]) / np.maximum(unc.std[unc.subset], 1e-300)
        weak = [c for c, zc in zip(unc.subset, z, strict=True) if zc < z_min]
        weak = [c for c in weak if kinds[c] != "handeye"]
        if not weak:
            return cols
        cols = np.setdiff1d(cols, weak)


def significant_fit(problem: Problem, result, columns: np.ndarray, refit, z_min: float = 3.0):
    """``result`` (the fit of ``columns``) refitted by ``refit(columns)`` without the link
    parameters whose estimate is below ``z_min`` standard deviations (the frames always stay),
    until none is: ``--selection conservative`` of the kinds that fit every candidate."""
    kinds = problem.full_layout.kinds
    cols = np.asarray(columns)
    while True:
        z = np.abs(result.params) / np.where(np.isfinite(result.std), result.std, np.inf)
        weak = [c for c in cols if family(kinds[c]) != "frames" and z[c] < z_min]
        if not weak:
            return result
        cols = np.setdiff1d(cols, weak)
        result = refit(cols)


def bootstrap_std(
    lin: Linearised,
    whiten: np.ndarray,
    columns: np.ndarray,
    n_boot: int = 100,
    seed: int = 0,
    prior: np.ndarray | None = None,
) -> np.ndarray:
    """Standard deviations ``(Q,)`` of the linearised estimate over ``n_boot`` resamplings of the
    training *samples* (a pair counts as often as both its samples are drawn); NaN outside
    ``columns``. An independent check of the predicted standard deviations. ``prior``: the
    prior-row weights of a maximum a posteriori fit (:func:`lin_prior`), in every resampling."""
    rng = np.random.default_rng(seed)
    k = len(columns)
    jw, bw = whitened(whiten, lin.jac[:, :, columns], lin.b)  # (P, 6, k), (P, 6)
    gram = np.einsum("pra,prb->pab", jw, jw).reshape(len(jw), k * k)  # each pair's share
    rhs = np.einsum("pra,pr->pa", jw, bw)
    i, j = lin.pairs.T
    draws = rng.integers(0, lin.n_samples, (n_boot, lin.n_samples))
    counts = np.zeros((n_boot, lin.n_samples))
    np.add.at(counts, (np.arange(n_boot)[:, None], draws), 1.0)
    weights = counts[:, i] * counts[:, j]  # (B, P): a pair counts as often as both its samples
    weights = np.where(i == j, counts[:, i], weights)  # a sample's own measurement: as it
    normals, rhss = (weights @ gram).reshape(n_boot, k, k), weights @ rhs
    normals = normals + _prior_normal(prior, columns)
    draws = [solve_normal(n, r) for n, r in zip(normals, rhss, strict=True)]
    out = np.full(lin.jac.shape[-1], np.nan)
    out[columns] = np.std(draws, axis=0, ddof=1)
    return out
