"""Checks of the Python API's arguments (in the manner of pytransform3d's ``check_*``): a wrong
type, shape or value is a :class:`RelcalError` naming the argument, what it got, what was
expected and the likely cause, raised where the API is entered (``Problem``, ``calibrate``,
``fk``, ``apply_errors``, ...), never a NumPy broadcast error or an IndexError from deep inside.

Each ``check_*`` returns the value converted (a float or int array of the checked shape).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from relcal.errors import ArgumentError, excerpt


def describe(value: Any) -> str:
    """What ``value`` is, in a few words, for a message: ``str '/data/ds'``, ``an array of
    shape (3, 6)``, ``None``."""
    if value is None:
        return "None"
    if isinstance(value, np.ndarray):
        return f"an array of shape {value.shape} ({value.dtype})"
    if isinstance(value, str | Path):
        return f"{type(value).__name__} {excerpt(value, 60)}"
    if isinstance(value, list | tuple):
        shape = np.shape(value) if _regular(value) else None
        return f"a {type(value).__name__} of {len(value)} items" + (
            f" (shape {shape})" if shape and len(shape) > 1 else ""
        )
    if isinstance(value, int | float | bool):
        return f"{type(value).__name__} {value!r}"
    return f"a {type(value).__module__}.{type(value).__qualname__}"


def _regular(value: Any) -> bool:
    try:
        np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return False
    return True


def check_instance(value: Any, cls: type | tuple[type, ...], name: str, expected: str) -> Any:
    """``value`` must be an instance of ``cls``; ``expected`` says what, with how to get one."""
    if not isinstance(value, cls):
        raise ArgumentError(f"{name}: expected {expected}, got {describe(value)}")
    return value


def check_choice(value: Any, name: str, choices: Iterable[str]) -> str:
    """``value`` must be one of ``choices`` (strings)."""
    choices = tuple(choices)
    if not isinstance(value, str) or value not in choices:
        raise ArgumentError(
            f"{name}: unknown {describe(value)}; expected one of "
            + ", ".join(repr(c) for c in choices)
        )
    return value


def check_number(
    value: Any,
    name: str,
    low: float | None = None,
    high: float | None = None,
    *,
    low_open: bool = False,
    high_open: bool = False,
    integer: bool = False,
) -> float | int:
    """A finite number (``integer``: a whole one) within ``[low, high]`` (ends open if asked)."""
    kind = "a whole number" if integer else "a number"
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise ArgumentError(f"{name}: expected {kind}, got {describe(value)}")
    if integer and not float(value).is_integer():
        raise ArgumentError(f"{name}: expected {kind}, got {value!r}")
    if not np.isfinite(value):
        raise ArgumentError(f"{name}: expected a finite number, got {value!r}")
    below = low is not None and (value <= low if low_open else value < low)
    above = high is not None and (value >= high if high_open else value > high)
    if below or above:
        lo = "" if low is None else f"{'(' if low_open else '['}{low:g}"
        hi = "" if high is None else f"{high:g}{')' if high_open else ']'}"
        span = f"in {lo or '(-inf'}, {hi or 'inf)'}"
        raise ArgumentError(f"{name}: expected {kind} {span}, got {value!r}")
    return int(value) if integer else float(value)


def check_array(
    value: Any,
    name: str,
    shape: Sequence[int | None],
    *,
    dtype: type = float,
    finite: bool = True,
    hint: str = "",
) -> np.ndarray:
    """``value`` as an array of ``shape`` (``None``: any length on that axis), every entry
    finite unless ``finite=False``; ``hint`` names the likely cause of a wrong shape."""
    want = (
        "("
        + ", ".join("N" if s is None else str(s) for s in shape)
        + ("," if len(shape) == 1 else "")
        + ")"
    )
    try:
        arr = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError):
        raise ArgumentError(
            f"{name}: expected numbers of shape {want}, got {describe(value)}"
            + (f"; {hint}" if hint else "")
        ) from None
    if arr.ndim != len(shape) or any(
        s is not None and n != s for n, s in zip(arr.shape, shape, strict=False)
    ):
        raise ArgumentError(
            f"{name}: expected shape {want}, got {describe(value)}" + (f"; {hint}" if hint else "")
        )
    if finite and arr.size and not np.isfinite(arr).all():
        ok = np.isfinite(arr).reshape(arr.shape[0], -1).all(axis=1) if arr.ndim else np.array([0])
        bad = np.flatnonzero(~ok)
        what = "entries" if arr.ndim <= 1 else "rows" if arr.ndim == 2 else "items"
        raise ArgumentError(
            f"{name}: {bad.size} of {len(ok)} {what} are not finite (NaN or infinite), the first "
            f"{name}[{int(bad[0])}]; missing or failed measurements? leave those samples out"
        )
    return arr


def check_transform(value: Any, name: str) -> np.ndarray:
    """A homogeneous transform ``(4, 4)`` with finite entries."""
    return check_array(value, name, (4, 4), hint="expected a 4x4 homogeneous transform")


def check_joints(q: Any, n_joints: int, name: str = "q", model: str = "") -> np.ndarray:
    """Joint values ``(N, n_joints)`` (a single ``(n_joints,)`` configuration is one row)."""
    if isinstance(q, np.ndarray) and q.dtype == float and q.ndim == 2 and q.shape[1] == n_joints:
        if np.isfinite(q).all():  # the common case, fast: fk is a hot path
            return q
    try:
        arr = np.asarray(q, dtype=float)
    except (TypeError, ValueError):
        arr = q
    if isinstance(arr, np.ndarray) and arr.ndim == 1:
        arr = arr[None, :]
    of = f" of the {n_joints}-joint robot{f' {model!r}' if model else ''}"
    return check_array(
        arr,
        name,
        (None, n_joints),
        hint=f"one row per configuration, one column per joint{of} (rad, m for prismatic)",
    )


def check_pairs(pairs: Any, n_poses: int, name: str = "pairs") -> np.ndarray:
    """Index pairs ``(P, 2)`` of poses, each index in ``[0, n_poses)`` and the two different."""
    arr = check_array(
        pairs, name, (None, 2), hint="one row (i, j) per pair, e.g. make_pairs(N, 'all')"
    )
    if arr.size and not np.all(arr == np.round(arr)):
        raise ArgumentError(f"{name}: expected whole-number indices, got fractions")
    idx = arr.astype(int)
    if idx.size:
        bad = np.flatnonzero((idx < 0).any(axis=1) | (idx >= n_poses).any(axis=1))
        if bad.size:
            k = int(bad[0])
            raise ArgumentError(
                f"{name}[{k}] = ({idx[k, 0]}, {idx[k, 1]}): an index out of range for {n_poses} "
                f"poses (0 to {n_poses - 1}); {bad.size} pair(s) are; pairs made for another set "
                "of poses?"
            )
        same = np.flatnonzero(idx[:, 0] == idx[:, 1])
        if same.size:
            k = int(same[0])
            raise ArgumentError(
                f"{name}[{k}] = ({idx[k, 0]}, {idx[k, 1]}): a pose paired with itself carries no "
                "relative motion"
            )
    return idx


def check_vector(value: Any, name: str, size: int, what: str) -> np.ndarray:
    """A vector of ``size`` finite entries; ``what`` says which entries (the layout's names)."""
    return check_array(
        value,
        name,
        (size,),
        hint=f"one value per entry of {what}",
    )


MEASURES = ("position", "pose")


def check_problem(problem) -> dict[str, Any]:
    """The checked and converted fields of a :class:`relcal.calibration.measurement.Problem`
    (called by its ``__post_init__``)."""
    from typing import get_args

    from relcal.calibration.measurement import Formulation  # the one list of formulations
    from relcal.robot.kinematics import Layout

    p = "Problem"
    check_model(problem.model, f"{p}.model")
    check_instance(problem.layout, Layout, f"{p}.layout", "a Layout (relcal.make_layout(model))")
    check_choice(problem.formulation, f"{p}.formulation", get_args(Formulation))
    check_choice(problem.measure, f"{p}.measure", MEASURES)
    model = problem.model
    out: dict[str, Any] = {}
    q = out["q"] = check_joints(problem.q, model.n_joints, f"{p}.q", model.name)
    n = len(q)
    poses = out["poses"] = check_array(
        problem.poses,
        f"{p}.poses",
        (n, 4, 4),
        finite=False,
        hint=f"one 4x4 measured pose per row of q ({n})",
    )
    # a pose that is wholly NaN is a sample without a measurement (a rejected frame): allowed
    # in a problem as long as no measurement uses it (:func:`check_measured`); a partly finite
    # pose, or no finite pose at all, is wrong data
    finite = np.isfinite(poses).reshape(n, -1)
    partial = np.flatnonzero(finite.any(axis=1) & ~finite.all(axis=1))
    if partial.size or (n and not finite.any()):
        bad = np.flatnonzero(~finite.all(axis=1))
        raise ArgumentError(
            f"{p}.poses: {bad.size} of {n} items are not finite (NaN or infinite), the first "
            f"{p}.poses[{int(bad[0])}]; missing or failed measurements? leave those samples out"
        )
    if problem.pairs is not None:
        out["pairs"] = check_pairs(problem.pairs, n, f"{p}.pairs")
    pairs = len(out["pairs"]) if problem.pairs is not None else max(n - 1, 0)
    if problem.formulation in ("published", "invariant") and pairs == 0:
        raise ArgumentError(
            f"{p}: no pairs of poses ({n} poses); relative measurements need 2 or more"
        )
    out["handeye"] = check_transform(problem.handeye, f"{p}.handeye")
    out["instrument"] = check_transform(problem.instrument, f"{p}.instrument")
    out["board"] = check_transform(problem.board, f"{p}.board")
    out["marker"] = check_vector(problem.marker, f"{p}.marker", 3, "the marker position x, y, z")
    if problem.weights is not None:
        out["weights"] = check_array(
            problem.weights, f"{p}.weights", (6,), hint="one factor per residual row (t, r)"
        )
    if problem.pair_weights is not None:
        per = n if problem.formulation in ("absolute", "tracker", "board") else pairs
        out["pair_weights"] = check_array(
            problem.pair_weights,
            f"{p}.pair_weights",
            (per, 6, 6),
            hint="one 6x6 whitening block per measurement",
        )
    return out


def check_errors(errors: Any, layout, name: str = "errors") -> np.ndarray:
    """A parameter vector of ``layout`` (``apply_errors``): one finite value per entry."""
    from relcal.robot.kinematics import Layout

    check_instance(layout, Layout, "layout", "a Layout (relcal.make_layout(model))")
    size = layout.size
    names = ", ".join(layout.names[:4]) + (", ..." if size > 4 else "")
    return check_array(
        errors,
        name,
        (size,),
        hint=f"one value per parameter of the layout ({size}: {names}; m and rad); a vector "
        "made for another layout or model?",
    )


def check_dataset(dataset: Any, name: str = "dataset") -> Any:
    """A loaded :class:`relcal.data.dataset.Dataset` (a folder path is loaded first)."""
    from relcal.data.dataset import Dataset

    if isinstance(dataset, str | Path):
        raise ArgumentError(
            f"{name}: expected a Dataset, got {describe(dataset)}: load the folder first, "
            f"relcal.load_dataset({str(dataset)!r})"
        )
    return check_instance(dataset, Dataset, name, "a Dataset (relcal.load_dataset(folder))")


def check_calibrate(
    dataset: Any,
    measurements: Any,
    holdout: Any,
    seed: Any,
    pairing: Any,
    method: Any,
    loss: Any,
    holdout_ids: Any,
    select_folds: Any,
    selection: Any,
) -> None:
    """The arguments of :func:`relcal.calibrate`."""
    from relcal.data.imaging import Measurements

    check_dataset(dataset)
    if measurements is not None:
        check_instance(
            measurements, Measurements, "measurements", "Measurements (relcal.measure(dataset))"
        )
        if len(measurements.ok) != len(dataset.ids):
            raise ArgumentError(
                f"measurements: {len(measurements.ok)} samples, the dataset has "
                f"{len(dataset.ids)}: measured from another dataset?"
            )
    check_number(holdout, "holdout", 0, 1, high_open=True)
    check_number(seed, "seed", integer=True)
    check_choice(pairing, "pairing", ("auto", "consecutive", "star", "all", "board"))
    check_choice(method, "method", ("lm", "published"))
    check_choice(loss, "loss", ("linear", "huber", "cauchy", "soft_l1"))
    check_choice(selection, "selection", ("cv", "conservative", "all"))
    check_number(select_folds, "select_folds", 2, integer=True)
    if holdout_ids is not None:
        if isinstance(holdout_ids, str) or not all(isinstance(i, str) for i in holdout_ids):
            raise ArgumentError(
                f"holdout_ids: expected a list of sample ids (strings), got "
                f"{describe(holdout_ids)}"
                + ("; a single id is ['s1'], not 's1'" if isinstance(holdout_ids, str) else "")
            )


def check_model(model: Any, name: str = "model") -> Any:
    """A :class:`relcal.robot.model.RobotModel`."""
    from relcal.robot.model import RobotModel

    if isinstance(model, str | Path):
        raise ArgumentError(
            f"{name}: expected a RobotModel, got {describe(model)}: load it first, "
            f"relcal.get_robot({str(model)!r})"
        )
    return check_instance(model, RobotModel, name, "a RobotModel (relcal.get_robot('a465'))")


def check_measured(problem) -> None:
    """Every pose a measurement of ``problem`` uses is finite (``identify``): a sample without a
    measurement (a wholly NaN pose) may sit in a problem, not in its pairs."""
    n = len(problem.q)
    if problem.formulation in ("absolute", "tracker"):
        used = np.arange(n)
    else:
        used = np.unique(problem.pair_indices())
    finite = np.isfinite(problem.poses[used]).reshape(len(used), -1).all(axis=1)
    if not finite.all():
        bad = used[~finite]
        raise ArgumentError(
            f"Problem.poses: {bad.size} of the {len(used)} poses the measurements use are not "
            f"finite, the first Problem.poses[{int(bad[0])}]; leave samples without a "
            "measurement out of the pairs"
        )
