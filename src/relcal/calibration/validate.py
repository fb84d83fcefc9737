"""Validation on held-out samples: errors before and after calibration.

For poses and points (:class:`Validation`) the errors are those of the problem's own formulation,
evaluated on pairs of held-out samples (relative poses) or on each held-out sample (absolute
points) with the nominal parameters and the frame guesses, the baseline fit and the identified
one. For coincidences (:class:`PlacementValidation`) whole placements are held out: a new plate
position is the honest test; the kinematics and the tool point are frozen and the held-out
placement's group points refitted (:func:`spread_of`), and the errors are the spread of the
predicted points of each group and the error of the known distances.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, replace

import numpy as np

from relcal.calibration.coincidence import Coincidence, split_params, tool_points
from relcal.calibration.identify import Result
from relcal.calibration.measurement import (
    PairStrategy,
    Problem,
    capped_pairs,
    make_pairs,
    pair_errors,
)
from relcal.calibration.noise import robust_scale
from relcal.robot.model import RobotModel

_KINDS = (("position_mm", slice(0, 3), 1e3), ("orientation_deg", slice(3, 6), 180 / np.pi))
#: Formulations whose measurements are single samples (pairs ``(k, k)``): absolute poses, poses
#: against the board (world) transform, tracker points.
PER_SAMPLE = ("absolute", "board", "tracker")


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


RESAMPLE_CHUNK = 2**21  # numbers of one chunk of the bootstrap's per-pair weights (16 MB)

#: The last ``(key, (resampled, drawn))`` of :func:`_resampler`: one calibration's documents
#: bootstrap the same held-out pairs several times (the validation, the verdict, each exported
#: file), and the draws depend on the pairs, ``n_boot`` and the seed alone. One entry, kept only
#: when its draw counts ``(n_boot, n)`` take at most ``RESAMPLE_KEEP_BYTES``.
_LAST_RESAMPLER: tuple = ()
RESAMPLE_KEEP_BYTES = 2**25  # 32 MB: the counts of 2000 draws of up to 8000 samples


def _resampler(pairs: np.ndarray, n_boot: int, seed: int, units: np.ndarray | None = None):
    """The paired bootstrap over the *samples* of ``pairs`` ``(P, 2)``: a function mapping a value
    per pair ``(P,)`` to its sum in each of ``n_boot`` draws (a pair counts as often as both its
    samples are drawn; per-sample values, pairs ``(k, k)``, once per draw of their sample), and
    the mask of draws holding at least one pair. With ``units`` (a label per sample index, e.g.
    the configuration of :func:`~relcal.calibration.coverage.configuration_clusters`), whole
    units are drawn: the repeats of one configuration are one piece of evidence. The same
    pairs, units, ``n_boot`` and ``seed`` give the same function (the last one is reused)."""
    global _LAST_RESAMPLER
    pairs = np.ascontiguousarray(pairs)
    digest = hashlib.blake2b(pairs.tobytes(), digest_size=16)
    if units is not None:
        digest.update(np.ascontiguousarray(units[np.unique(pairs)], dtype=np.int64).tobytes())
    key = (pairs.shape, pairs.dtype.str, digest.digest(), int(n_boot), seed)
    last = _LAST_RESAMPLER
    if last and last[0] == key:
        return last[1]
    made = _make_resampler(pairs, n_boot, seed, units)
    n = len(np.unique(pairs))
    if n_boot * n * _count_dtype(n).itemsize <= RESAMPLE_KEEP_BYTES:
        _LAST_RESAMPLER = (key, made)
    return made


def _count_dtype(n: int) -> np.dtype:
    """The smallest unsigned integer type that holds any count of ``n`` draws (at most ``n``)."""
    for dtype in (np.uint8, np.uint16, np.uint32):
        if n <= np.iinfo(dtype).max:
            return np.dtype(dtype)
    return np.dtype(np.uint64)


def _draw_counts(n: int, n_boot: int, seed: int) -> np.ndarray:
    """``(n_boot, n)``: how often each of ``n`` samples is drawn in each of ``n_boot`` draws of
    ``n`` samples with replacement (:func:`_count_dtype`: whole numbers, exact as floats)."""
    draws = np.random.default_rng(seed).integers(0, n, (n_boot, n))
    flat = (np.arange(n_boot)[:, None] * n + draws).ravel()
    counts = np.bincount(flat, minlength=n_boot * n).reshape(n_boot, n)
    return counts.astype(_count_dtype(n))


def _make_resampler(pairs: np.ndarray, n_boot: int, seed: int, units: np.ndarray | None = None):
    """:func:`_resampler`, built. Its function also takes several values per pair ``(P, k)``
    and returns ``(n_boot, k)``: the draws' per-pair weights ``counts[i] counts[j]`` are formed
    once per chunk of draws for all ``k`` columns (forming them is what costs)."""
    samples, index = np.unique(pairs, return_inverse=True)
    i, j = index.reshape(pairs.shape).T
    per_sample = bool(np.all(i == j))
    n = len(samples)
    if units is None:
        counts = _draw_counts(n, n_boot, seed)
    else:  # each sample counts as often as its unit is drawn
        _, unit = np.unique(np.asarray(units)[samples], return_inverse=True)
        counts = _draw_counts(int(unit.max()) + 1, n_boot, seed)[:, unit]

    chunk = max(1, min(n_boot, RESAMPLE_CHUNK // max(len(pairs), 1)))

    def resampled(values: np.ndarray) -> np.ndarray:
        """``sum_p counts[i_p] counts[j_p] values_p`` per draw: ``O(n_boot P)`` time, draws
        taken a chunk at a time (an ``(n, n)`` table would cost ``n_boot n^2``)."""
        columns = np.ascontiguousarray(values.reshape(len(values), -1).T)  # one row per value
        if per_sample:
            c = counts.astype(float)
            out = np.stack([c @ np.bincount(i, v, minlength=n) for v in columns], axis=1)
        else:
            out = np.empty((n_boot, len(columns)))
            for start in range(0, n_boot, chunk):
                c = counts[start : start + chunk].astype(float)
                weights = c[:, i] * c[:, j]
                for k, v in enumerate(columns):
                    out[start : start + chunk, k] = weights @ v
        return out.reshape((n_boot, *values.shape[1:]))

    return resampled, resampled(np.ones(len(pairs))) > 0


def ratio_interval(
    pairs: np.ndarray,
    before: np.ndarray,
    after: np.ndarray,
    n_boot: int = 2000,
    seed: int = 0,
    units: np.ndarray | None = None,
) -> dict[str, dict[str, float]]:
    """The ratio of RMS after to RMS before, with a 95 % interval from a paired bootstrap over
    the held-out *samples* (each pair counts as often as both its samples are drawn), or over
    their ``units`` (configurations) when given.

    Pairs share samples (``n`` samples make ``n (n - 1) / 2`` pairs), so resampling pairs would
    pretend far more independent evidence than there is; repeats of one configuration share its
    kinematic error, so resampling them one by one would too. Per-sample errors come as pairs
    ``(k, k)`` and count once per draw of their sample.
    """
    resampled, drawn = _resampler(pairs, n_boot, seed, units)
    kinds = []
    for key, cols, scale in _KINDS:
        b2, a2 = _norms(before, cols, scale) ** 2, _norms(after, cols, scale) ** 2
        if not (np.all(np.isnan(b2)) or len(b2) == 0):
            kinds.append((key, a2, b2))
    if not kinds:
        return {}
    sums = resampled(np.stack([v for _, a2, b2 in kinds for v in (a2, b2)], axis=1))[drawn]
    out = {}
    for k, (key, a2, b2) in enumerate(kinds):
        boot = np.sqrt(sums[:, 2 * k] / np.maximum(sums[:, 2 * k + 1], 1e-300))
        lo, hi = np.percentile(boot, [2.5, 97.5])
        ratio = np.sqrt(a2.sum() / max(b2.sum(), 1e-300))
        out[key] = {"after_over_before": float(ratio), "ci95": [float(lo), float(hi)]}
    return out


def rms_draws(
    pairs: np.ndarray,
    errors: np.ndarray,
    n_boot: int = 2000,
    seed: int = 0,
    units: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """The RMS error norms (mm, deg) in each draw of the paired bootstrap over the samples of
    ``pairs`` (or their ``units``) that :func:`ratio_interval` uses (the same draws for the same
    ``seed``), per kind (``position_mm``, ``orientation_deg``; kinds without values left out)."""
    resampled, drawn = _resampler(pairs, n_boot, seed, units)
    kinds = []
    for key, cols, scale in _KINDS:
        e2 = _norms(errors, cols, scale) ** 2
        if not (len(e2) == 0 or np.all(np.isnan(e2))):
            kinds.append((key, e2))
    columns = [np.ones(len(pairs))] + [e2 for _, e2 in kinds]
    sums = resampled(np.stack(columns, axis=1))[drawn]
    return {key: np.sqrt(sums[:, k + 1] / sums[:, 0]) for k, (key, _) in enumerate(kinds)}


def rms_interval(
    pairs: np.ndarray,
    errors: np.ndarray,
    n_boot: int = 2000,
    seed: int = 0,
    units: np.ndarray | None = None,
) -> dict[str, list[float]]:
    """The 95 % interval of the RMS error norms (mm, deg) by :func:`rms_draws`."""
    return {
        key: [float(v) for v in np.percentile(boot, [2.5, 97.5])]
        for key, boot in rms_draws(pairs, errors, n_boot, seed, units).items()
    }


@dataclass(frozen=True)
class Validation:
    """Held-out errors ``(P, 6)`` (position m, rotation rad) per held-out sample (``pairs``
    ``(k, k)``: each pose predicted in the world frame, each point in the instrument's) or per
    pair of held-out samples (relative poses).

    ``guess``: nominal kinematics with the frame guesses. ``baseline``: nominal kinematics with
    the frames (hand-eye, world, instrument) fitted on the training samples, the best a user gets
    without kinematic calibration (None where there is none, e.g. a simulation that knows the
    truth). ``calibrated``: the chosen model. Every ratio is relative to :attr:`before`, the
    baseline when there is one. ``units``: the configuration of every sample of the data set
    (:func:`~relcal.calibration.coverage.configuration_clusters`), which the bootstrap draws
    whole (None: each sample its own); ``what``: how the evidence is named (``poses``,
    ``points``, ``pairs of poses``).
    """

    pairs: np.ndarray  # (P, 2) sample indices into the full data set
    guess: np.ndarray
    calibrated: np.ndarray
    baseline: np.ndarray | None = None
    # held-out samples that fit badly under every model (:func:`held_out_outliers`), left out
    # of the pairs above
    outliers: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    units: np.ndarray | None = None
    what: str | None = None  # None: named by the formulation (verdict.held_out_what)

    @property
    def samples(self) -> np.ndarray:
        """The held-out samples the errors rest on (sorted dataset indices)."""
        return np.unique(self.pairs)

    @property
    def n_configurations(self) -> int:
        """The distinct configurations among :attr:`samples`."""
        if self.units is None:
            return len(self.samples)
        return len(np.unique(self.units[self.samples]))

    def interval(self, before: np.ndarray, after: np.ndarray) -> dict[str, dict[str, float]]:
        """:func:`ratio_interval` of two of this validation's error arrays, drawn as its
        :attr:`units` say."""
        return ratio_interval(self.pairs, before, after, units=self.units)

    @property
    def before(self) -> np.ndarray:
        return self.guess if self.baseline is None else self.baseline

    @property
    def after(self) -> np.ndarray:
        return self.calibrated

    def improvement(self) -> float:
        """Position RMS of the baseline over that of the calibrated model."""
        b, a = stats(self.before), stats(self.after)
        return b["position_mm"]["rms"] / max(a["position_mm"]["rms"], 1e-300)

    def rms(self, which: str) -> float:
        """The held-out position RMS (mm) of ``before`` or ``calibrated``: what the verdict on
        a calibration compares."""
        return stats(getattr(self, which))["position_mm"]["rms"]

    def ratio(self) -> dict[str, float | list[float]]:
        """``{"after_over_before", "ci95"}`` of the position RMS (:func:`ratio_interval`)."""
        return self.interval(self.before, self.calibrated)["position_mm"]


def pooled(validations: list):
    """Several validations (e.g. the folds of a cross-validation) as one."""
    if validations and isinstance(validations[0], PlacementValidation):
        return PlacementValidation(
            tuple(p for v in validations for p in v.placements),
            pooled_spread([v.baseline for v in validations]),
            pooled_spread([v.calibrated for v in validations]),
            np.concatenate([v.samples for v in validations]),
        )
    has_baseline = all(v.baseline is not None for v in validations)
    return Validation(
        pairs=np.concatenate([v.pairs for v in validations]),
        guess=np.concatenate([v.guess for v in validations]),
        calibrated=np.concatenate([v.calibrated for v in validations]),
        baseline=np.concatenate([v.baseline for v in validations]) if has_baseline else None,
        outliers=np.concatenate([v.outliers for v in validations]).astype(int),
        units=validations[0].units,  # the data set's configurations, the same in every fold
        what=validations[0].what,
    )


def subset(
    problem: Problem,
    samples: np.ndarray,
    pairing: PairStrategy = "all",
    max_pairs: int | None = None,
) -> Problem:
    """The problem restricted to some samples, re-paired among themselves; all pairs capped at
    ``max_pairs`` drawn at random (:func:`~relcal.calibration.measurement.capped_pairs`)."""
    samples = np.asarray(samples)
    if problem.formulation in PER_SAMPLE:
        pairs = problem.pairs  # each sample its own measurement
    elif pairing == "all" and max_pairs is not None:
        pairs = capped_pairs(len(samples), max_pairs)
    else:
        pairs = make_pairs(len(samples), pairing)
    return replace(problem, q=problem.q[samples], poses=problem.poses[samples], pairs=pairs)


def _scores(problem: Problem, params: np.ndarray, samples, partners, sigma=None):
    """Each sample's median error against ``partners`` (pairs ``(k, j)``; per-pose
    formulations: its own error), in units of ``sigma`` (default: robust levels of these
    errors); and ``sigma``."""
    samples, partners = np.asarray(samples), np.asarray(partners)
    if problem.formulation in PER_SAMPLE:
        errors = pair_errors(subset(problem, samples), params)[:, None, :]
    else:
        # every (sample, partner) but a sample with itself, sample by sample
        slot, where = np.divmod(np.arange(len(samples) * len(partners)), len(partners))
        other = samples[slot] != partners[where]
        slot, where = slot[other], where[other]
        pairs = np.stack([samples[slot], partners[where]], axis=1).astype(int)
        per = pair_errors(replace(problem, pairs=pairs), params)
        errors = np.full((len(samples), len(partners), 6), np.nan)
        errors[slot, where] = per
    if sigma is None:
        flat = errors.reshape(-1, 6)
        flat = flat[np.isfinite(flat[:, :3]).all(axis=1)]
        sigma = np.ones(6)
        for cols in (slice(0, 3), slice(3, 6)):
            values = flat[:, cols].ravel()
            values = values[np.isfinite(values)]
            if values.size:
                sigma[cols] = max(robust_scale(values), 1e-12)
    norms = np.sqrt(np.nansum((errors / sigma) ** 2, axis=2))
    norms[np.isnan(errors).all(axis=2)] = np.nan
    return np.nanmedian(norms, axis=1), sigma


def held_out_outliers(
    problem: Problem,
    models: list[np.ndarray],
    samples: np.ndarray,
    train: np.ndarray,
    threshold: float = 10.0,
    partners: int = 50,
    seed: int = 0,
) -> np.ndarray:
    """The held-out ``samples`` that fit badly under *every* model in ``models`` (parameter
    vectors: the calibrated one and the baseline), by the rule that finds training outliers at
    twice its threshold: a sample's median error against training samples, as a robust z-score
    among the training samples' own, above ``threshold`` (10; a wrong row, an inverted pose or a
    mistyped joint, scores in the hundreds; a real sample that is merely the worst of a set
    stays below). A sample the calibrated model merely extrapolates to still fits the baseline,
    so it is never called an outlier: validation cannot be flattered that way."""
    samples, train = np.asarray(samples), np.asarray(train)
    if len(samples) == 0 or len(train) < 4:
        return np.zeros(0, dtype=int)
    rng = np.random.default_rng(seed)
    chosen = train if len(train) <= partners else np.sort(rng.choice(train, partners, False))
    flagged = np.ones(len(samples), dtype=bool)
    for params in models:
        own, sigma = _scores(problem, params, chosen, chosen)
        theirs, _ = _scores(problem, params, samples, chosen, sigma)
        own = own[np.isfinite(own)]
        if own.size < 4:
            return np.zeros(0, dtype=int)
        centre = np.median(own)
        spread = max(robust_scale(own), 1e-12)
        flagged &= (theirs - centre) > threshold * spread
    return samples[flagged]


def held_out(
    problem: Problem,
    result: Result,
    samples: np.ndarray,
    pairing: PairStrategy = "all",
    baseline: Result | None = None,
    train: np.ndarray | None = None,
    max_pairs: int | None = None,
    *,
    guess: np.ndarray | None = None,
    units: np.ndarray | None = None,
) -> Validation:
    """Errors on pairs among ``samples`` (which the identification did not use), or on each
    sample alone (as pairs ``(k, k)``) for the per-sample formulations (:data:`PER_SAMPLE`), of
    the nominal model with the frame guesses (``guess``, parameters; default zeros), the
    ``baseline`` fit (if given) and ``result``.

    With the ``train`` samples, held-out samples that fit badly under both the calibrated model
    and the baseline (:func:`held_out_outliers`) are left out of the pairs and listed in
    ``outliers``, as outliers among the training samples are left out of the fit (while at
    least 2 held-out samples remain). ``max_pairs``: at most that many of the pairs, drawn at
    random (a large held-out set: the statistics stay linear in the samples). ``units``: the
    configuration of each sample of ``problem`` (:attr:`Validation.units`)."""
    samples = np.asarray(samples)
    outliers = np.zeros(0, dtype=int)
    if train is not None:
        models = [result.params] + ([baseline.params] if baseline is not None else [])
        outliers = held_out_outliers(problem, models, samples, train)
        if len(samples) - len(outliers) >= 2:
            samples = np.setdiff1d(samples, outliers)
    test = subset(problem, samples, pairing, max_pairs)
    if problem.formulation in PER_SAMPLE:
        pairs = np.stack([samples, samples], axis=1)
        what = "poses" if problem.formulation == "board" else "points"
    else:
        pairs = samples[test.pair_indices()]
        what = "pairs of poses"
    return Validation(
        pairs=pairs,
        guess=pair_errors(test, np.zeros_like(result.params) if guess is None else guess),
        calibrated=pair_errors(test, result.params),
        baseline=None if baseline is None else pair_errors(test, baseline.params),
        outliers=outliers,
        units=units,
        what=what,
    )


def split_units(units: np.ndarray, fraction: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Training and held-out indices of samples grouped in ``units`` ``(N,)`` (labels 0 .. m-1:
    the configurations of :func:`~relcal.calibration.coverage.configuration_clusters`), whole
    units held out: a random share ``fraction`` of the units (seeded), at least 2 samples, at
    least one unit left for training. With one sample per unit, a random share of the samples."""
    units = np.asarray(units, dtype=int)
    n_units = int(units.max()) + 1
    order = np.random.default_rng(seed).permutation(n_units)
    reached = np.cumsum(np.bincount(units, minlength=n_units)[order])
    n_take = max(int(round(fraction * n_units)), int(np.searchsorted(reached, 2)) + 1)
    held = np.isin(units, order[: min(n_take, n_units - 1)])
    return np.flatnonzero(~held), np.flatnonzero(held)


def unit_folds(units: np.ndarray, k: int, seed: int = 0) -> list[np.ndarray]:
    """``k`` disjoint held-out index sets of whole ``units`` covering all samples (the units
    shuffled with ``seed``); with one sample per unit, ``k`` folds of the samples."""
    units = np.asarray(units, dtype=int)
    order = np.random.default_rng(seed).permutation(int(units.max()) + 1)
    return [np.flatnonzero(np.isin(units, part)) for part in np.array_split(order, k)]


def split(n_samples: int, fraction: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Random training and held-out sample indices (held-out share ``fraction``)."""
    return split_units(np.arange(n_samples), fraction, seed)


def folds(n_samples: int, k: int, seed: int = 0) -> list[np.ndarray]:
    """``k`` disjoint held-out index sets covering all samples (shuffled with ``seed``)."""
    return unit_folds(np.arange(n_samples), k, seed)


def error_norms(errors: np.ndarray) -> dict[str, np.ndarray]:
    """Per-pair (or per-point) error norms of ``errors`` ``(P, 6)``: ``position`` (m) and
    ``orientation`` (rad; absent when orientation was not measured, i.e. all NaN)."""
    out = {"position": np.linalg.norm(errors[:, :3], axis=1)}
    rotation = np.linalg.norm(errors[:, 3:], axis=1)
    if len(rotation) and not np.all(np.isnan(rotation)):
        out["orientation"] = rotation
    return out


# --- coincidences: held-out placements -----------------------------------------------------------


@dataclass(frozen=True)
class Spread:
    """Coincidence errors on samples the fit did not use, the group points refitted there (a new
    placement's points are unknown: a nuisance of the new session) with the kinematics and the
    tool point frozen.

    ``spread`` ``(N,)``: distance (m) of each sample's predicted point from its group's mean
    point; ``distance`` ``(D,)``: ``|p_a - p_b| - d_ab`` (m) between the refitted points of each
    known distance among the held-out groups.
    """

    spread: np.ndarray
    distance: np.ndarray
    groups: np.ndarray  # (N,) group of each sample (into names)
    names: tuple[str, ...]

    def summary(self) -> dict[str, dict[str, float] | None]:
        """``{"spread_mm": {"rms", "max"}, "distance_error_mm": {"rms", "max"} or None}``."""

        def summarised(values: np.ndarray) -> dict[str, float] | None:
            if len(values) == 0:
                return None
            mm = np.abs(values) * 1e3
            return {"rms": float(np.sqrt(np.mean(mm**2))), "max": float(mm.max())}

        spread, distance = summarised(self.spread), summarised(self.distance)
        return {"spread_mm": spread, "distance_error_mm": distance}

    def as_errors(self) -> np.ndarray:
        """The spread as per-sample position errors ``(N, 6)`` (m; rotation NaN), for what
        summarises pair or point errors."""
        out = np.full((len(self.spread), 6), np.nan)
        out[:, :3] = 0.0
        out[:, 0] = self.spread
        return out

    def per_group(self) -> dict[str, dict[str, float]]:
        """``{group: {"n", "rms_mm", "max_mm"}}`` of the spread."""
        out = {}
        for g, name in enumerate(self.names):
            mm = self.spread[self.groups == g] * 1e3
            if len(mm):
                out[name] = {
                    "n": int(len(mm)),
                    "rms_mm": float(np.sqrt(np.mean(mm**2))),
                    "max_mm": float(mm.max()),
                }
        return out


def spread_of(
    model: RobotModel, q: np.ndarray, coincidence: Coincidence, tool_point: np.ndarray
) -> Spread:
    """The spread of the predicted points per group and the error of the known distances on
    samples ``q`` of ``coincidence``'s groups, predicted by ``model`` with ``tool_point``; each
    group's point refitted as the mean of its samples' predicted points (the least-squares
    point of the coincidence rows alone: the distance is what is checked, not imposed)."""
    y = tool_points(model, q, tool_point)
    index = coincidence.index
    points = np.zeros((coincidence.n_groups, 3))
    np.add.at(points, index, y)
    points /= np.maximum(np.bincount(index, minlength=coincidence.n_groups), 1)[:, None]
    spread = np.linalg.norm(y - points[index], axis=1)
    pairs = coincidence.pairs
    distance = (
        np.linalg.norm(points[pairs[:, 0]] - points[pairs[:, 1]], axis=1) - coincidence.lengths
    )
    return Spread(spread, distance, index, coincidence.names)


def pooled_spread(parts: list[Spread]) -> Spread:
    """Several held-out evaluations (the placements left out in turn) as one."""
    names: list[str] = []
    groups = []
    for part in parts:
        groups.append(part.groups + len(names))
        names += list(part.names)
    return Spread(
        np.concatenate([p.spread for p in parts]),
        np.concatenate([p.distance for p in parts]),
        np.concatenate(groups) if groups else np.zeros(0, int),
        tuple(names),
    )


@dataclass(frozen=True)
class PlacementValidation:
    """Held-out placements: the baseline (nominal geometry, the tool point and the group points
    fitted to the training samples) and the calibrated model evaluated on them with their group
    points refitted (:func:`spread_of`). ``samples``: the held-out sample indices, in the order
    of the spreads. ``outliers``: always none (a held-out placement is validated whole; its
    points are refitted, so no sample of it is judged against the training samples)."""

    placements: tuple[str, ...]
    baseline: Spread
    calibrated: Spread
    samples: np.ndarray
    outliers: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))

    @property
    def before(self) -> Spread:
        return self.baseline

    def summary(self) -> dict:
        """``{"baseline": {...}, "calibrated": {...}}`` of :meth:`Spread.summary`."""
        return {"baseline": self.baseline.summary(), "calibrated": self.calibrated.summary()}

    def improvement(self) -> float:
        """Spread RMS of the baseline over that of the calibrated model."""
        return self.rms("before") / max(self.rms("calibrated"), 1e-300)

    def rms(self, which: str) -> float:
        """The held-out spread RMS (mm) of ``before`` or ``calibrated``."""
        return getattr(self, which).summary()["spread_mm"]["rms"]

    def ratio(self) -> dict[str, float | list[float]]:
        """``{"after_over_before", "ci95"}`` of the spread RMS, the interval from a bootstrap
        over the held-out samples (:func:`ratio_interval`)."""
        pairs = np.stack([self.samples, self.samples], axis=1)

        ratio = ratio_interval(pairs, self.baseline.as_errors(), self.calibrated.as_errors())
        return ratio["position_mm"]


def held_out_placements(
    problem: Problem,
    params: np.ndarray,
    baseline: np.ndarray,
    q: np.ndarray,
    coincidence: Coincidence,
    samples: np.ndarray,
) -> PlacementValidation:
    """The coincidence validation of the fits ``params`` and ``baseline`` of ``problem`` (the
    training samples) on held-out samples at joints ``q`` of the groups of ``coincidence``
    (dataset indices ``samples``): the kinematics and the tool point frozen, the held-out group
    points refitted."""
    out = []
    for p in (baseline, params):
        model, tool, _ = split_params(problem, p)
        out.append(spread_of(model, q, coincidence, tool))
    places = coincidence.placement_names()
    return PlacementValidation(places, out[0], out[1], np.asarray(samples, dtype=int))
