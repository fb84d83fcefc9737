"""Verification: a finished calibration applied to an independent session.

Held-out samples of the calibration's own session share its marker mounting, its board placement
and its day. A new session (days later, the board moved, the marker remounted) answers the
question a user asks before trusting a model: does it still predict better than the nominal
kinematics? The kinematics of both models are frozen; only what belongs to the session is
refitted, the same way for both:

- poses (``pose``): the hand-eye transform ``X`` (camera or marker mounting) and the world
  transform ``W`` (board or instrument placement); each held-out pose is predicted in the world
  frame, ``W F(q) X``, as calibrate validates;
- tracker points (``position``): the instrument-to-base transform ``T`` and the marker ``m``;
- coincidence samples (``coincidence``): the points of the groups (a new placement of the
  plate); the tool point belongs to the robot's tool, a re-seated ball is the same ball, so it
  stays the calibration's own (the calibrated model's and the baseline's each).

The nominal baseline is the session's nominal robot with the same nuisance refit: the best a user
gets without kinematic calibration, given this session's data. To keep the nuisance from
flattering either model on the samples it was fitted to, it is **cross-fitted**: the samples are
split into K folds, each fold's nuisance is fitted on the other folds' samples, and the fold is
evaluated with it (each sample: a pose in the world frame, a point, a coincidence).
Every sample's error is thus a prediction.

The verdict (:func:`assess`) compares the RMS error of both models with a paired bootstrap over
the session's samples (as :func:`validate.ratio_interval`), and the calibrated error with the
calibration's own held-out error (from its results document, bootstrapped over those samples):

- ``holds``: the 95 % interval of the ratio calibrated / baseline lies entirely below 1, and the
  error is not beyond doubt larger than at calibration;
- ``degraded``: it beats the baseline, but its error on this session exceeds the held-out error
  of the calibration with the whole 99 % interval of that ratio above 1 (the drift test's level;
  the robot, its mounting or the cell changed, or this session is noisier or reaches farther);
- ``inconclusive``: the interval of the ratio to the baseline spans 1: no evidence of
  improvement on this session;
- ``worse``: the whole interval lies above 1 (position, or orientation for pose data).

Only ``holds`` counts as success (exit status 0 of ``relcal verify``).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from relcal import geometry as tf
from relcal.calibration.handeye import solve_handeye, solve_instrument
from relcal.calibration.identify import calibrated_handeye, identify_lm
from relcal.calibration.measurement import (
    Problem,
    board_frame,
    board_guess,
    board_lever,
    pair_errors,
    tracker_frames,
)
from relcal.calibration.selection import plain_whiteners
from relcal.calibration.validate import rms_draws, stats
from relcal.checks import check_flag, check_number, check_path, check_seed
from relcal.errors import RelcalError
from relcal.limits import read_input
from relcal.robot.kinematics import Layout, fk
from relcal.robot.model import RobotModel

Kind = Literal["pose", "position", "coincidence"]
Verdict = Literal["holds", "degraded", "inconclusive", "worse"]

EMPTY = Layout((), (), ())  # no kinematic parameter is free: the nuisance alone is fitted
DEFAULT_FOLDS = 5
MIN_SAMPLES = 10  # fewer session samples: the intervals rest on little, said so
N_BOOT = 2000
# "degraded" needs the 99 % interval of the ratio to the calibration's own held-out error above 1
# (the drift test's level: at most about 0.5 % false alarms by design; the 95 % interval gave 7
# of 200 noise-only sessions of synthetic A465 and UR5e, from bootstraps of 8 held-out samples)
DEGRADED_LEVEL = 0.99
# A joint is outside the covered range when beyond it by more than the larger of these (a sample
# at the edge of the range is inside it).
RANGE_SLACK_RAD = np.radians(1.0)
RANGE_SLACK_M = 0.005
RANGE_SLACK_SHARE = 0.05  # of the covered span
EXIT_STATUS = {"holds": 0, "degraded": 1, "inconclusive": 1, "worse": 1}

NUISANCE = {
    "pose": "the hand-eye transform X (camera or marker mounting) and the world transform W "
    "(board or instrument placement)",
    "position": "the instrument-to-base transform T and the marker position m",
    "coincidence": "the point of each group",
}
FROZEN = {
    "pose": "the kinematics of both models",
    "position": "the kinematics of both models",
    "coincidence": "the kinematics and the tool point of both models (the robot's tool)",
}
FORMULATIONS = {
    "invariant": "pose",
    "board": "pose",
    "tracker": "position",
    "coincidence": "coincidence",
}


def session_kind(measured: str) -> Kind:
    """What a dataset's samples measure, as verification treats them (images give poses)."""
    if measured == "coincidence":
        return "coincidence"
    return "position" if measured == "position" else "pose"


# --- joint ranges --------------------------------------------------------------------------------


@dataclass(frozen=True)
class JointRanges:
    """The range of each joint a calibration covered (its training samples), SI (rad, m)."""

    names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    prismatic: np.ndarray  # (n,) bool

    @classmethod
    def of(cls, model: RobotModel, q: np.ndarray) -> JointRanges:
        q = np.asarray(q, dtype=float)
        return cls(tuple(model.joint_names), q.min(axis=0), q.max(axis=0), model.prismatic.copy())

    def to_dict(self) -> dict:
        """The ``joint_ranges`` entry of a results document (SI units)."""
        return {
            "samples": "training",
            "joints": [
                {
                    "name": name,
                    "unit": "m" if self.prismatic[i] else "rad",
                    "lower": float(self.lower[i]),
                    "upper": float(self.upper[i]),
                }
                for i, name in enumerate(self.names)
            ],
        }

    @classmethod
    def from_dict(cls, doc: dict) -> JointRanges:
        joints = doc["joints"]
        return cls(
            tuple(j["name"] for j in joints),
            np.array([j["lower"] for j in joints], dtype=float),
            np.array([j["upper"] for j in joints], dtype=float),
            np.array([j["unit"] == "m" for j in joints], dtype=bool),
        )

    def slack(self) -> np.ndarray:
        """How far beyond the covered range a joint may go and still count as inside."""
        floor = np.where(self.prismatic, RANGE_SLACK_M, RANGE_SLACK_RAD)
        return np.maximum(floor, RANGE_SLACK_SHARE * (self.upper - self.lower))

    def excess(self, q: np.ndarray) -> np.ndarray:
        """``(N, n)``: how far each joint value lies beyond the covered range (0 inside)."""
        q = np.asarray(q, dtype=float)
        return np.maximum(np.maximum(self.lower - q, q - self.upper), 0.0)

    def outside(self, q: np.ndarray) -> np.ndarray:
        """``(N, n)`` bool: beyond the covered range by more than :meth:`slack`."""
        return self.excess(q) > self.slack()


# --- the calibration's own held-out errors -------------------------------------------------------


@dataclass(frozen=True)
class Reference:
    """The calibration's held-out errors on its own session (its results document), to compare a
    new session's errors with: per pair of held-out samples (per sample for points) the norms,
    position (m) in column 0 and rotation (rad) in column 3 of ``errors`` ``(P, 6)``. A
    reference known only by its RMS (:meth:`fixed`: a registry record) has no pairs; it is then
    taken as exact."""

    pairs: np.ndarray | None
    errors: np.ndarray | None
    rms: dict[str, float] | None = None  # mm, deg: for a fixed reference

    @property
    def n_samples(self) -> int | None:
        return None if self.pairs is None else len(np.unique(self.pairs))

    @classmethod
    def fixed(cls, position_mm: float, orientation_deg: float | None = None) -> Reference:
        rms = {"position_mm": float(position_mm)}
        if orientation_deg is not None:
            rms["orientation_deg"] = float(orientation_deg)
        return cls(None, None, rms)

    def draws(self, n_boot: int, seed: int) -> dict[str, np.ndarray]:
        """The RMS in each bootstrap draw over the reference's samples (constant if fixed)."""
        if self.pairs is None:
            return {k: np.full(n_boot, v) for k, v in (self.rms or {}).items()}
        return rms_draws(self.pairs, self.errors, n_boot, seed)

    def summary(self) -> dict[str, float]:
        """The RMS (mm, deg) per kind."""
        if self.pairs is None:
            return dict(self.rms or {})
        return {k: v["rms"] for k, v in stats(self.errors).items()}

    @classmethod
    def from_results(cls, doc: dict) -> Reference | None:
        """From ``validation.pairs`` of a results document, or for coincidence samples (held-out
        placements) from ``validation.samples``: each held-out sample's distance to its group's
        point (the points refitted on the held-out samples, kinematics and tool point frozen).
        None without held-out samples."""
        val = doc.get("validation") or {}
        rows = val.get("pairs") or []
        if not rows:
            return cls._from_samples(val.get("samples") or [])
        ids = {}
        pairs = np.array([[ids.setdefault(i, len(ids)) for i in r["ids"]] for r in rows], int)
        errors = np.full((len(rows), 6), np.nan)
        errors[:, 1:3] = 0.0
        errors[:, 0] = [
            np.nan if r["calibrated_mm"] is None else r["calibrated_mm"] / 1e3 for r in rows
        ]
        deg = [r.get("calibrated_deg") for r in rows]
        if all(d is not None for d in deg):
            errors[:, 3] = np.radians(deg)
            errors[:, 4:] = 0.0
        return cls(pairs, errors)

    @classmethod
    def _from_samples(cls, rows: list[dict]) -> Reference | None:
        """Per held-out sample ``calibrated_spread_mm`` (coincidence validation) as a reference
        of per-sample position errors (pairs ``(k, k)``); None without such samples."""
        spread = [r.get("calibrated_spread_mm") for r in rows if isinstance(r, dict)]
        if not spread or any(v is None for v in spread):
            return None
        k = np.arange(len(spread))
        errors = np.zeros((len(spread), 6))
        errors[:, 0] = np.asarray(spread, dtype=float) / 1e3
        errors[:, 3:] = np.nan  # no orientation is measured
        return cls(np.stack([k, k], axis=1), errors)


# --- the session's errors, nuisance cross-fitted -------------------------------------------------


def fold_indices(
    n: int, k: int, seed: int = 0, groups: np.ndarray | None = None
) -> list[np.ndarray]:
    """``k`` disjoint folds covering ``n`` samples (shuffled by ``seed``); with ``groups`` each
    group's samples are dealt over the folds in turn, so every fold's complement holds samples of
    every group with two or more."""
    rng = np.random.default_rng(seed)
    if groups is None:
        order = rng.permutation(n)
        return [np.sort(f) for f in np.array_split(order, k)]
    fold = np.empty(n, dtype=int)
    for g in np.unique(groups):
        members = rng.permutation(np.flatnonzero(groups == g))
        fold[members] = (np.arange(len(members)) + rng.integers(k)) % k
    return [np.flatnonzero(fold == f) for f in range(k)]


def max_folds(kind: Kind, n: int) -> int:
    """The most folds ``n`` samples allow: one sample a fold at most."""
    return n


PLAIN = np.diag(plain_whiteners(1)[0]).copy()  # rows of a relative pose: m, and 0.1 m/rad


@dataclass(frozen=True)
class Nuisance:
    """What one fit of a session's nuisance found, for the report: ``frames`` by name, SI
    (``handeye`` or ``instrument`` ``(4, 4)``, ``marker`` and ``tool_point`` ``(3,)``,
    ``group_points`` ``(G, 3)``; the documents serialize them)."""

    frames: dict[str, np.ndarray]
    converged: bool


def _pose_problem(model: RobotModel, q, poses, handeye) -> Problem:
    """A session's poses against ``W F(q) X`` with the kinematics frozen (the board formulation,
    as calibrate's default pairing): the nuisance ``X`` and ``W`` to fit."""
    weights = PLAIN.copy()
    weights[3:] = board_lever(poses)
    board = board_guess(fk(model, q), poses, handeye)
    return Problem(model, EMPTY, q, poses, "board", "pose", None, handeye, weights, board=board)


def _fit_pose(model: RobotModel, q, poses) -> tuple[tuple[np.ndarray, np.ndarray], bool]:
    """The hand-eye ``X`` and the world transform ``W`` fitted to poses with the kinematics
    frozen."""
    guess = solve_handeye(fk(model, q), poses)
    problem = _pose_problem(model, q, poses, guess)
    result = identify_lm(problem)
    world = board_frame(problem, result.params)
    return (calibrated_handeye(problem, result), world), bool(result.converged)


def _fit_points(model: RobotModel, q, points_poses) -> tuple[tuple[np.ndarray, np.ndarray], bool]:
    """``T`` and ``m`` fitted to points with the kinematics frozen."""
    instrument, marker = solve_instrument(fk(model, q), points_poses[:, :3, 3])
    problem = Problem(
        model,
        EMPTY,
        q,
        points_poses,
        "tracker",
        "position",
        instrument=instrument,
        marker=marker,
    )
    result = identify_lm(problem)
    return tracker_frames(problem, result.params), bool(result.converged)


def _tool_points(model: RobotModel, q: np.ndarray, tool_point: np.ndarray) -> np.ndarray:
    from relcal.calibration.coincidence import tool_points

    return tool_points(model, q, tool_point)


def _group_points(y: np.ndarray, groups: np.ndarray, n_groups: int) -> np.ndarray:
    """Each group's point: the mean of its samples' predicted points (NaN for an empty group)."""
    points = np.zeros((n_groups, 3))
    np.add.at(points, groups, y)
    count = np.bincount(groups, minlength=n_groups).astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        return points / count[:, None]


def _fold_errors(
    kind: Kind,
    model: RobotModel,
    q: np.ndarray,
    poses: np.ndarray | None,
    groups: np.ndarray | None,
    tool_point: np.ndarray | None,
    train: np.ndarray,
    test: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, bool]:
    """Pairs ``(P, 2)`` (sample indices) and errors ``(P, 6)`` of ``model`` on the ``test``
    samples, with the nuisance fitted on the ``train`` samples; and whether that fit converged."""
    if kind == "pose":  # each held-out pose predicted in the world frame
        (handeye, world), ok = _fit_pose(model, q[train], poses[train])
        predicted = world @ fk(model, q[test]) @ handeye
        errors = tf.to_vector(tf.invert(predicted) @ poses[test])
        return np.stack([test, test], axis=1), errors, ok
    if kind == "position":
        (instrument, marker), ok = _fit_points(model, q[train], poses[train])
        held = Problem(
            model,
            EMPTY,
            q[test],
            poses[test],
            "tracker",
            "position",
            instrument=instrument,
            marker=marker,
        )
        return np.stack([test, test], axis=1), pair_errors(held, np.zeros(9)), ok
    n_groups = int(groups.max()) + 1
    points = _group_points(_tool_points(model, q[train], tool_point), groups[train], n_groups)
    errors = np.full((len(test), 6), np.nan)
    errors[:, :3] = points[groups[test]] - _tool_points(model, q[test], tool_point)
    return np.stack([test, test], axis=1), errors, True


def _nuisance_all(
    kind: Kind,
    model: RobotModel,
    q: np.ndarray,
    poses: np.ndarray | None,
    groups: np.ndarray | None,
    tool_point: np.ndarray | None,
) -> Nuisance:
    """The nuisance fitted to every sample of the session (shown, never used for the errors)."""
    if kind == "pose":
        (handeye, world), ok = _fit_pose(model, q, poses)
        return Nuisance({"handeye": handeye, "world": world}, ok)
    if kind == "position":
        (instrument, marker), ok = _fit_points(model, q, poses)
        return Nuisance({"instrument": instrument, "marker": np.asarray(marker)}, ok)
    n_groups = int(groups.max()) + 1
    points = _group_points(_tool_points(model, q, tool_point), groups, n_groups)
    return Nuisance({"tool_point": np.asarray(tool_point, float), "group_points": points}, True)


@dataclass(frozen=True)
class Verification:
    """A calibration's and the nominal baseline's errors on a new session, the nuisance
    cross-fitted (:func:`verify`). Pairs index :attr:`ids`; errors are position (m) and rotation
    (rad, NaN for points) per pair of samples of one fold (per sample for points and
    coincidence samples)."""

    kind: Kind
    ids: tuple[str, ...]
    q: np.ndarray  # (N, n) of the samples used
    folds: tuple[np.ndarray, ...]
    pairs: np.ndarray
    baseline: np.ndarray
    calibrated: np.ndarray
    seed: int
    nuisance: dict[str, Nuisance]  # "baseline", "calibrated": fitted to every sample (shown)
    identical: bool  # the calibrated model predicts the session as the nominal one does
    not_converged: int = 0  # nuisance fits (of 2 K) whose solver did not converge
    groups: tuple[str, ...] = ()  # coincidence: the group names
    skipped: tuple[str, ...] = ()  # samples not evaluated (a group with no other sample)

    @property
    def n_folds(self) -> int:
        return len(self.folds)

    @property
    def scheme(self) -> str:
        """How the nuisance was fitted, in words."""
        where = "each pose in the world frame" if self.kind == "pose" else "each sample"
        return (
            f"{self.n_folds}-fold cross-fitting: each fold evaluated ({where}) with "
            f"{NUISANCE[self.kind]} fitted on the other folds' samples"
        )


def check_same_robot(calibrated: RobotModel, nominal: RobotModel) -> None:
    """Refuse a calibration of another robot than the session's (joint count or names)."""
    if calibrated.n_joints != nominal.n_joints or tuple(calibrated.joint_names) != tuple(
        nominal.joint_names
    ):
        raise RelcalError(
            f"the calibration is of a {calibrated.n_joints}-joint robot (joints "
            f"{', '.join(calibrated.joint_names)}), the session's robot '{nominal.name}' has "
            f"{nominal.n_joints} (joints {', '.join(nominal.joint_names)}): another robot, or "
            "another chain of it (root and tip links)"
        )


def verify(
    calibrated: RobotModel,
    nominal: RobotModel,
    kind: Kind,
    ids: Sequence[str],
    q: np.ndarray,
    poses: np.ndarray | None = None,
    groups: Sequence[str] | None = None,
    tool_points: tuple[np.ndarray, np.ndarray] | None = None,
    folds: int = DEFAULT_FOLDS,
    seed: int = 0,
    progress: bool = False,
) -> Verification:
    """The errors of ``calibrated`` and of the ``nominal`` baseline on a session's samples
    ``q`` ``(N, n)`` (usable ones only) with ``poses`` ``(N, 4, 4)`` (measured poses, or points
    in the translation for ``position``) or coincidence ``groups`` (one name per sample; then
    ``tool_points`` = (calibrated, baseline) tool points in the tip frame, m), the session's
    nuisance cross-fitted over ``folds`` folds (fewer when the samples do not allow them)."""
    from tqdm import tqdm

    check_same_robot(calibrated, nominal)
    q = np.asarray(q, dtype=float)
    n = len(q)
    if kind == "coincidence":
        if groups is None or tool_points is None:
            raise RelcalError("coincidence samples need their groups and the tool points")
        from relcal.calibration.coincidence import group_indices

        index, names = group_indices(groups)
    else:
        index, names = None, ()
        if poses is None:
            raise RelcalError(f"{kind} samples need their measured poses")
    least = 3 if kind == "coincidence" else 4
    if n < least:
        raise RelcalError(
            f"the session has {n} usable samples: too few to refit its nuisance ({NUISANCE[kind]}) "
            "and evaluate on others"
        )
    k = max(2, min(folds, max_folds(kind, n)))
    parts = fold_indices(n, k, seed, index)
    tools = tool_points if tool_points is not None else (None, None)
    out, failed = {}, 0
    with tqdm(
        total=2 * k, disable=not progress, desc="verify", unit="fit", delay=1.0, leave=False
    ) as bar:
        for which, model, tool in (
            ("baseline", nominal, tools[1]),
            ("calibrated", calibrated, tools[0]),
        ):
            pairs, errors = [], []
            for test in parts:
                train = np.setdiff1d(np.arange(n), test)
                try:
                    p, e, ok = _fold_errors(kind, model, q, poses, index, tool, train, test)
                except RelcalError as exc:
                    raise RelcalError(
                        f"refitting the session's nuisance on {len(train)} samples: {exc}"
                    ) from None
                failed += not ok
                pairs.append(p)
                errors.append(e)
                bar.update(1)
            out[which] = (np.concatenate(pairs), np.concatenate(errors))
    pairs = out["baseline"][0]
    base, cal = out["baseline"][1], out["calibrated"][1]
    keep = np.all(np.isfinite(base[:, :3]) & np.isfinite(cal[:, :3]), axis=1)
    skipped = tuple(ids[i] for i in np.unique(pairs[~keep])) if not keep.all() else ()
    nuisance = {
        "baseline": _nuisance_all(kind, nominal, q, poses, index, tools[1]),
        "calibrated": _nuisance_all(kind, calibrated, q, poses, index, tools[0]),
    }
    if kind == "coincidence":  # the predicted tool points (a tool point may sit in a model)
        got = _tool_points(calibrated, q, tools[0]), _tool_points(nominal, q, tools[1])
        identical = bool(np.allclose(*got, atol=1e-12))
    else:
        identical = bool(np.allclose(fk(calibrated, q), fk(nominal, q), atol=1e-12))
    return Verification(
        kind=kind,
        ids=tuple(ids),
        q=q,
        folds=tuple(parts),
        pairs=pairs[keep],
        baseline=base[keep],
        calibrated=cal[keep],
        seed=seed,
        nuisance=nuisance,
        identical=identical,
        not_converged=failed,
        groups=tuple(names),
        skipped=skipped,
    )


# --- the verdict ---------------------------------------------------------------------------------


def _summary(errors: np.ndarray, draws: dict[str, np.ndarray]) -> dict:
    """:func:`validate.stats` of the error norms with the bootstrap interval of the RMS."""
    out = stats(errors)
    for key, boot in draws.items():
        if key in out:
            out[key]["ci95"] = _interval(boot)
    return out


def _interval(boot: np.ndarray, level: float = 0.95) -> list[float]:
    tail = 50 * (1 - level)
    return [float(v) for v in np.percentile(boot, [tail, 100 - tail])]


@dataclass(frozen=True)
class Assessment:
    """The numbers and the verdict of a :class:`Verification` (mm and degrees).

    ``baseline`` and ``calibrated``: :func:`validate.stats` of the error norms, each RMS with its
    95 % interval (``ci95``) from a bootstrap over the session's samples. ``ratio``: calibrated
    over baseline RMS, with its paired interval (the same draws). ``at_calibration``: the
    calibration's own held-out RMS (None without one) and ``ratio_to_calibration``: the session's
    calibrated RMS over it, with an interval from independent bootstraps of both sets of samples.
    ``samples``: per sample its fold and its errors under both models (for relative poses the RMS
    over the pairs it belongs to), and the joints outside the covered ranges."""

    baseline: dict
    calibrated: dict
    ratio: dict
    at_calibration: dict | None
    ratio_to_calibration: dict | None
    samples: list[dict]
    outside: list[dict]  # per joint outside the covered range: name, count, largest excess
    ranges_checked: bool
    warnings: tuple[str, ...]
    verdict: Verdict
    reason: str
    n_samples: int
    identical: bool = False
    notes: tuple[str, ...] = field(default=())

    @property
    def exit_status(self) -> int:
        return EXIT_STATUS[self.verdict]


def _per_sample(ver: Verification, outside: np.ndarray | None) -> list[dict]:
    """Each evaluated sample's fold and errors (relative poses: RMS over its pairs)."""
    fold_of = np.empty(len(ver.ids), dtype=int)
    for f, part in enumerate(ver.folds):
        fold_of[part] = f
    norms = {
        name: (
            np.linalg.norm(errors[:, :3], axis=1) * 1e3,
            np.degrees(np.linalg.norm(errors[:, 3:], axis=1)),
        )
        for name, errors in (("baseline", ver.baseline), ("calibrated", ver.calibrated))
    }
    rows = []
    for k in np.unique(ver.pairs):
        mine = (ver.pairs == k).any(axis=1)
        row: dict = {"id": ver.ids[k], "fold": int(fold_of[k]), "n_pairs": int(mine.sum())}
        for name, (mm, deg) in norms.items():
            row[f"{name}_mm"] = float(np.sqrt(np.mean(mm[mine] ** 2)))
            value = float(np.sqrt(np.mean(deg[mine] ** 2)))
            row[f"{name}_deg"] = value if np.isfinite(value) else None
        if outside is not None:
            row["outside_range"] = [int(j) for j in np.flatnonzero(outside[k])]
        rows.append(row)
    return rows


def assess(
    ver: Verification,
    reference: Reference | None = None,
    ranges: JointRanges | None = None,
    n_boot: int = N_BOOT,
    seed: int = 0,
) -> Assessment:
    """The errors of both models with their intervals, the comparison with the calibration's
    own held-out error (``reference``), the joints outside the calibration's covered ``ranges``,
    and the verdict (see the module's docstring)."""
    draws_b = rms_draws(ver.pairs, ver.baseline, n_boot, seed)
    draws_c = rms_draws(ver.pairs, ver.calibrated, n_boot, seed)  # the same draws
    baseline = _summary(ver.baseline, draws_b)
    calibrated = _summary(ver.calibrated, draws_c)
    ratio = {}
    for key in draws_c:
        rms_b, rms_c = baseline[key]["rms"], calibrated[key]["rms"]
        ratio[key] = {
            "after_over_before": rms_c / max(rms_b, 1e-300),
            "ci95": _interval(draws_c[key] / np.maximum(draws_b[key], 1e-300)),
        }
    at_cal = to_cal = None
    if reference is not None:
        ref_draws = reference.draws(n_boot, seed + 1)
        ref_rms = reference.summary()
        at_cal, to_cal = {}, {}
        for key, boot in ref_draws.items():
            if key not in draws_c:
                continue
            rms = ref_rms[key]
            at_cal[key] = {
                "rms": rms,
                "ci95": None if reference.pairs is None else _interval(boot),
                "n_samples": reference.n_samples,
            }
            m = min(len(boot), len(draws_c[key]))
            ratios = draws_c[key][:m] / np.maximum(boot[:m], 1e-300)
            to_cal[key] = {
                "ratio": calibrated[key]["rms"] / max(rms, 1e-300),
                "ci95": _interval(ratios),
                "ci99": _interval(ratios, DEGRADED_LEVEL),
            }
        at_cal, to_cal = at_cal or None, to_cal or None

    outside_mask = None if ranges is None else ranges.outside(ver.q)
    outside = []
    if outside_mask is not None:
        excess = ranges.excess(ver.q)
        used = np.unique(ver.pairs)
        for j in np.flatnonzero(outside_mask[used].any(axis=0)):
            beyond = excess[used, j][outside_mask[used, j]]
            outside.append(
                {
                    "joint": ranges.names[j],
                    "index": int(j),
                    "n_samples": int(outside_mask[used, j].sum()),
                    "largest_excess": float(beyond.max()),
                    "unit": "m" if ranges.prismatic[j] else "rad",
                    "covered": [float(ranges.lower[j]), float(ranges.upper[j])],
                }
            )
    samples = _per_sample(ver, outside_mask)
    n = len(samples)
    warnings = []
    if n < MIN_SAMPLES:
        warnings.append(
            f"the verification rests on {n} samples (fewer than {MIN_SAMPLES}): its intervals "
            "are wide; verify on more samples"
        )
    if ver.not_converged:
        warnings.append(
            f"{ver.not_converged} of {2 * ver.n_folds} nuisance fits did not converge (their "
            "errors are still shown)"
        )
    if ver.skipped:
        warnings.append(
            f"{len(ver.skipped)} sample(s) not evaluated (their group has no other sample to fit "
            f"its point): {', '.join(ver.skipped[:5])}"
        )
    if outside:
        warnings.append(
            f"{sum(o['n_samples'] for o in outside)} joint value(s) of this session lie outside "
            "the ranges the calibration covered ("
            + ", ".join(o["joint"] for o in outside)
            + "): the model is extrapolated there"
        )
    verdict, reason = _verdict(ratio, to_cal, at_cal, calibrated, baseline, ver.identical)
    return Assessment(
        baseline=baseline,
        calibrated=calibrated,
        ratio=ratio,
        at_calibration=at_cal,
        ratio_to_calibration=to_cal,
        samples=samples,
        outside=outside,
        ranges_checked=ranges is not None,
        warnings=tuple(warnings),
        verdict=verdict,
        reason=reason,
        n_samples=n,
        identical=ver.identical,
    )


def _verdict(
    ratio: dict, to_cal: dict | None, at_cal: dict | None, cal: dict, base: dict, identical: bool
) -> tuple[Verdict, str]:
    """The verdict and its reason in words (see the module's docstring)."""
    pos = ratio["position_mm"]
    lo, hi = pos["ci95"]
    text = (
        f"position RMS {cal['position_mm']['rms']:.3f} mm against the baseline's "
        f"{base['position_mm']['rms']:.3f} mm (x{pos['after_over_before']:.2f}, 95% interval "
        f"{lo:.2f}..{hi:.2f})"
    )
    degraded = ""
    if to_cal is not None and to_cal["position_mm"]["ci99"][0] > 1.0:
        t = to_cal["position_mm"]
        degraded = (
            f"its error on this session is x{t['ratio']:.2f} its held-out error at calibration "
            f"({at_cal['position_mm']['rms']:.3f} mm; 99% interval {t['ci99'][0]:.2f}.."
            f"{t['ci99'][1]:.2f}, entirely above 1): the robot, its mounting or the cell changed "
            "since (or this session is noisier or reaches farther); recalibrate"
        )
    if identical:
        if degraded:
            return (
                "degraded",
                "the calibration is the nominal kinematics (no correction); " + degraded,
            )
        return "holds", (
            "the calibration exported the nominal kinematics (no correction); "
            f"on this session it predicts as at calibration (position RMS "
            f"{cal['position_mm']['rms']:.3f} mm)"
        )
    worse = [k for k, r in ratio.items() if r["ci95"][0] > 1.0]
    if worse:
        what = " and ".join("orientation" if k == "orientation_deg" else "position" for k in worse)
        return "worse", (
            f"worse than the nominal model on this session in {what} beyond doubt: {text}; "
            "do not use it"
        )
    if hi >= 1.0:
        return "inconclusive", (
            f"no evidence of improvement on this session: {text}, the interval spans 1; verify "
            "on more samples"
        )
    if degraded:
        return "degraded", f"better than the nominal model ({text}), but {degraded}"
    return "holds", f"better than the nominal model: {text}"


# --- a calibration output folder -----------------------------------------------------------------


@dataclass(frozen=True)
class CalibrationFiles:
    """What ``relcal calibrate`` wrote and ``verify`` reads: the model file (loaded as a user
    loads it) and the results document."""

    folder: Path
    model: RobotModel
    results: dict
    # why model.yaml is not the file the calibration validated (hand-edited since), else None
    changed: str | None = None

    def covered_ranges(self) -> tuple[JointRanges | None, str]:
        """The joint ranges the calibration covered and where they come from: its results
        document, or (an older document without them) its training samples read again from its
        dataset folder; None, with the reason, when neither is available."""
        doc = self.results.get("joint_ranges")
        if doc:
            return JointRanges.from_dict(doc), "results.json"
        root, train = self.results.get("dataset"), self.results.get("train_ids")
        if not root or not train:
            return None, "results.json records no joint ranges and no training samples"
        from relcal.data.dataset import load_dataset

        try:
            dataset = load_dataset(root)
        except RelcalError as exc:
            return None, (
                "results.json records no joint ranges (an older relcal) and its dataset cannot be "
                f"read again ({exc})"
            )
        where = {sid: k for k, sid in enumerate(dataset.ids)}
        rows = [where[i] for i in train if i in where]
        if len(rows) != len(train):
            return None, f"the training samples of results.json are not all in {root} any more"
        ranges = JointRanges.of(dataset.model, dataset.q[rows])
        return ranges, f"the training samples in {root} (results.json records no joint ranges)"

    @property
    def reference(self) -> Reference | None:
        """The held-out error at calibration; None when model.yaml was changed since (that
        error is of another file: comparing with it would blame the robot for the edit)."""
        if self.changed is not None:
            return None
        return Reference.from_results(self.results)

    @property
    def tool_points(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(calibrated, baseline) tool points of a coincidence calibration (tip frame, m):
        ``tool_point_xyz_m`` and ``baseline_tool_point_xyz_m`` of the results document (None
        unless it has both: the baseline's own tool point, fitted with the nominal kinematics,
        is what the baseline is verified with)."""
        tool = self.results.get("tool_point_xyz_m")
        base = self.results.get("baseline_tool_point_xyz_m")
        if tool is None or base is None:
            return None
        if self.results.get("tool_point_in_model"):  # model.yaml's tool ends at the tool point
            tool = np.zeros(3)
        return np.asarray(tool, dtype=float), np.asarray(base, dtype=float)


def load_calibration(folder: str | Path) -> CalibrationFiles:
    """``model.yaml`` and ``results.json`` of a calibration output folder."""
    from relcal.outputset import note_input
    from relcal.robot.model import load_model

    folder = Path(folder)
    if not folder.is_dir():
        raise RelcalError(
            f"{folder}: not a calibration folder (expected the output folder of relcal calibrate, "
            "with model.yaml and results.json, or a registry run id with --registry)"
        )
    missing = [f for f in ("model.yaml", "results.json") if not (folder / f).is_file()]
    if missing:
        raise RelcalError(
            f"{folder}: no {' and no '.join(missing)}: not the output folder of relcal calibrate"
        )
    path = folder / "results.json"
    note_input(path)
    try:
        results = json.loads(read_input(path, "text"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise RelcalError(f"{path}: cannot read: {exc}") from None
    if not isinstance(results, dict):
        raise RelcalError(f"{path}: not a relcal results document")
    model = load_model(folder / "model.yaml")
    record = model_file_record(folder / "model.yaml", results)
    changed = None
    if record is not None and not record["matches"]:
        changed = (
            f"{folder / 'model.yaml'} was changed since the calibration (its SHA-256 is not the "
            "one results.json records for the file it validated): the numbers here are of the "
            "edited file, and its held-out error at calibration is unknown, so a difference is "
            "no sign of a change of the robot; verify the file relcal wrote (or recalibrate)"
        )
    return CalibrationFiles(folder, model, results, changed)


def model_file_record(model_path: Path, results: dict) -> dict | None:
    """What ``results`` (a results document of ``relcal calibrate``) records for the model file
    at ``model_path``: ``{"position_rms_mm", "n_samples", "matches"}``, ``matches`` False when
    the file's SHA-256 (after the run's comment line) is not the recorded one (the file was
    changed since); None without such a record (an older or another document)."""
    import hashlib

    from relcal.calibration.artifacts import RUN_ID_PREFIX

    try:
        entry = {f["file"]: f for f in results["artifacts"]["files"]}["model.yaml"]
        data = read_input(model_path, "yaml")
    except (OSError, KeyError, TypeError):
        return None
    if data.startswith(RUN_ID_PREFIX.encode()):
        data = data.split(b"\n", 1)[1] if b"\n" in data else b""
    held = entry.get("held_out") or {}
    return {
        "position_rms_mm": held.get("position_rms_mm"),
        "n_samples": held.get("n_samples"),
        "matches": hashlib.sha256(data).hexdigest() == entry.get("sha256"),
    }


def check_session(
    calibration: Any, dataset: Any, measurements: Any, folds: Any, seed: Any, progress: Any
) -> None:
    """The arguments of :func:`verify_session`, checked before anything is read."""
    from relcal.data.dataset import check_dataset
    from relcal.data.imaging import check_measurements

    if not isinstance(calibration, CalibrationFiles):
        check_path(
            calibration,
            "calibration",
            "a calibration folder (the --out folder of relcal calibrate, or "
            "relcal.write_calibration's) or load_calibration(folder)",
        )
    check_dataset(dataset)
    if measurements is not None:
        check_measurements(measurements, dataset)
    check_number(folds, "folds", 2, integer=True)
    check_seed(seed)
    check_flag(progress, "progress")


def check_session_inputs(dataset, measurements) -> None:
    """The input gate of ``calibrate`` on a session to verify
    (:meth:`~relcal.calibration.kinds.MeasurementKind.check_data` of its kind): joint readings
    beyond the limits, absurd magnitudes, measurements that are not this robot's in this joint
    order and unit (another arm, a wrong unit) and a board moved during the session are refused
    here as they are before a calibration, naming the likely cause. Every entry point of
    ``verify`` (the command, :func:`verify_session`) calls it."""
    from relcal.calibration.kinds.dispatch import kind_of

    kind_of(dataset, measurements).check_data()


def verify_session(
    calibration: CalibrationFiles | str | Path,
    dataset,
    measurements=None,
    folds: int = DEFAULT_FOLDS,
    seed: int = 0,
    progress: bool = False,
) -> tuple[Verification, Assessment]:
    """A finished calibration verified on a new session: does it still hold?

    :func:`verify` on the session's usable samples, with the session's own robot as the nominal
    baseline, then :func:`assess` with the calibration's own held-out error (when it measures
    what the session does) and the joint ranges it covered.

    Parameters
    ----------
    calibration : CalibrationFiles, str or Path
        The output folder of ``relcal calibrate`` or :func:`relcal.write_calibration` (or
        :func:`load_calibration` of it).
    dataset : Dataset
        The new session (:func:`relcal.load_dataset`).
    measurements : Measurements, optional
        Its measurements (:func:`relcal.measure`), when its images are already measured.
    folds : int
        Folds of the cross-fitted refit of the session's nuisance transforms.
    seed : int
        Seed of the folds and bootstraps.
    progress : bool
        Progress bars (measuring images; the refits when they take over a second).

    Returns
    -------
    verification : Verification
        Every sample's errors under the calibrated model and the session's nominal model.
    assessment : Assessment
        The numbers (mm, degrees, with 95 % intervals) and the verdict (``verdict``,
        ``reason``).

    Raises
    ------
    ArgumentError
        ``calibration`` not a folder path or :class:`CalibrationFiles`, ``dataset`` not a
        :class:`~relcal.Dataset` (a folder path: load it first), ``measurements`` not those of
        ``dataset``, ``folds`` below 2 or not whole, ``seed`` not whole, ``progress`` not a bool
        (checked before anything is read).
    RelcalError
        Not a calibration folder (no ``model.yaml`` or ``results.json``, or unreadable), a
        session of a robot with other joints, session data that the checks before a calibration
        refuse (joint readings beyond the limits, absurd magnitudes, measurements that are not
        this robot's in this joint order and unit:
        :meth:`~relcal.calibration.kinds.MeasurementKind.check_data`), a session that holds the
        calibration's own training samples, or too few usable samples (below 4; 3 for
        coincidence data) to refit the session's nuisance transforms.

    Examples
    --------
    A calibration written to a folder, verified on a session (here the half of the samples it
    did not use, to keep the example short and self-contained; a real check uses a session
    recorded after the calibration, and the calibration's own training samples are refused):

    >>> import tempfile, relcal
    >>> from relcal.data.order import take
    >>> dataset = relcal.load_dataset("examples/tiago-pro-poses")  # from the repository root
    >>> cal = relcal.calibrate(dataset, holdout=0.5, nongeometric="none")
    >>> out = tempfile.mkdtemp() + "/cal"
    >>> files = relcal.write_calibration(cal, out)
    >>> session = take(cal.dataset, cal.test)
    >>> verification, assessment = relcal.verify_session(out, session)
    >>> assessment.verdict, assessment.n_samples
    ('holds', 24)
    """
    from relcal.data.imaging import measure

    check_session(calibration, dataset, measurements, folds, seed, progress)
    files = calibration if isinstance(calibration, CalibrationFiles) else None
    files = files or load_calibration(calibration)
    if measurements is None:
        measurements = measure(dataset, progress=progress)
    usable, repeated = session_gate(files.results, dataset, measurements)
    kind = session_kind(dataset.measured)
    ver = verify(
        files.model,
        dataset.model,
        kind,
        [dataset.ids[i] for i in usable],
        dataset.q[usable],
        None if kind == "coincidence" else measurements.poses[usable],
        None if dataset.groups is None else [dataset.groups[i] for i in usable],
        files.tool_points,
        folds=folds,
        seed=seed,
        progress=progress,
    )
    settings = files.results.get("settings") or {}
    same = FORMULATIONS.get(settings.get("formulation")) == kind
    reference = files.reference if same else None
    assessment = assess(ver, reference, files.covered_ranges()[0], seed=seed)
    if files.changed is not None:  # said first: the edit, not the robot, is the news
        assessment = replace(assessment, warnings=(files.changed, *assessment.warnings))
    if repeated:
        assessment = replace(assessment, warnings=(*assessment.warnings, repeated))
    return ver, assessment


def session_gate(results: dict | None, dataset, measurements) -> tuple[np.ndarray, str | None]:
    """Every check of a session before it is verified, for every entry point (the command,
    :func:`verify_session`): the input gate of ``calibrate`` (:func:`check_session_inputs`),
    then the calibration's own training samples refused (:func:`check_new_session`, with
    ``results``, its results document; None for a calibration rebuilt from a registry record,
    which records no samples). Returns the usable samples' indices and the warning about
    repeated training configurations (None when there is none)."""
    check_session_inputs(dataset, measurements)
    usable = np.flatnonzero(measurements.ok)
    return usable, check_new_session(results, dataset, measurements, usable)


def check_new_session(
    results: dict | None, dataset, measurements, usable: np.ndarray
) -> str | None:
    """Refuse a session that holds samples of the calibration's own training set (its joints
    and measurement again: verifying on the data it was fitted to says nothing); return a
    warning when the session's configurations repeat training configurations (a new
    measurement there shows the model only where it was fitted), else None. ``results`` is the
    calibration's results document (its ``training`` entry; None: nothing to compare)."""
    from scipy.spatial import cKDTree

    from relcal.calibration.coverage import SAME_M, SAME_RAD
    from relcal.data.order import sample_digests

    training = (results or {}).get("training") or {}
    ids = [dataset.ids[i] for i in usable]
    digests = training.get("digests") or []
    if digests:
        groups = None if dataset.groups is None else [dataset.groups[i] for i in usable]
        poses = None if dataset.measured == "coincidence" else measurements.poses[usable]
        own = np.isin(sample_digests(dataset.q[usable], poses, groups), digests)
        if own.any():
            named = ", ".join(ids[k] for k in np.flatnonzero(own)[:5])
            where = dataset.spec_path or "the session"
            raise RelcalError(
                f"{where}: {int(own.sum())} of the session's {len(ids)} samples are the "
                "calibration's own "
                f"training samples (the same joints and measurement: {named}"
                f"{', ...' if own.sum() > 5 else ''}): verifying on the data a model was fitted "
                "to says nothing of a new session; verify on a session recorded after the "
                "calibration (its held-out samples were already validated by relcal calibrate)"
            )
    configurations = np.asarray(training.get("configurations") or [], dtype=float)
    model = dataset.model
    if configurations.ndim != 2 or configurations.shape[1] != model.n_joints:
        return None
    scale = np.where(model.prismatic, SAME_M, SAME_RAD)
    near, _ = cKDTree(configurations / scale).query(dataset.q[usable] / scale, p=np.inf)
    repeats = near <= 1.0
    if not repeats.any():
        return None
    return (
        f"{int(repeats.sum())} of the session's {len(ids)} samples repeat configurations of the "
        "calibration's training set (joints within 0.5 deg): there the session shows the model "
        "where it was fitted, not elsewhere; verify at other configurations too"
    )
