"""Checks of the Python API's arguments (in the manner of pytransform3d's ``check_*``): a wrong
type, shape or value is a :class:`RelcalError` naming the argument, what it got, what was
expected and the likely cause, raised where the API is entered (``Problem``, ``calibrate``,
``fk``, ``apply_errors``, ...), never a NumPy broadcast error or an IndexError from deep inside.

Each ``check_*`` returns the value converted (a float or int array of the checked shape).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from os import PathLike
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


def real_array(value: Any, name: str, dtype: type = float) -> np.ndarray:
    """``value`` as an array of ``dtype``; complex numbers are refused naming ``name`` unless
    every imaginary part is zero (NumPy would drop them with a warning only: a joint value
    ``0.3+0.1j`` is not a reading). Other conversions fail as NumPy's do (TypeError,
    ValueError), for the caller's message."""
    arr = np.asarray(value)
    if np.iscomplexobj(arr):
        imag = np.abs(arr.imag)
        if np.any(imag != 0):
            k = np.unravel_index(int(np.argmax(imag != 0)), arr.shape) if arr.ndim else ()
            at = f"{name}[{', '.join(str(int(i)) for i in k)}]" if k else name
            raise ArgumentError(
                f"{at} = {arr[k] if k else arr}: complex, expected real numbers "
                f"({int(np.count_nonzero(imag))} of {arr.size} with an imaginary part); a "
                "computation upstream produced complex values (a square root or logarithm of a "
                "negative number?): take the real values only where that is meant"
            )
        arr = arr.real
    return np.asarray(arr, dtype=dtype)


def check_instance(value: Any, cls: type | tuple[type, ...], name: str, expected: str) -> Any:
    """``value`` must be an instance of ``cls``; ``expected`` says what, with how to get one."""
    if not isinstance(value, cls):
        raise ArgumentError(f"{name}: expected {expected}, got {describe(value)}")
    return value


def check_path(value: Any, name: str, expected: str) -> Path:
    """``value`` as a :class:`~pathlib.Path`: a ``str`` or an ``os.PathLike``; ``expected``
    says which file or folder (``"a dataset folder"``)."""
    if isinstance(value, str | PathLike) and not isinstance(value, bytes):
        text = os.fspath(value)
        if isinstance(text, str) and text.strip():  # (Path("") is ".": the working folder)
            return Path(text)
    raise ArgumentError(f"{name}: expected {expected} (a str or Path), got {describe(value)}")


def check_flag(value: Any, name: str) -> bool:
    """``value`` must be ``True`` or ``False`` (a NumPy bool too)."""
    if not isinstance(value, bool | np.bool_):
        raise ArgumentError(f"{name}: expected True or False, got {describe(value)}")
    return bool(value)


def check_names(
    value: Any, name: str, choices: Iterable[str], example: str, *, empty: bool = False
) -> tuple[str, ...]:
    """A list of strings, each one of ``choices`` (a bare string is refused: ``example`` shows
    the list spelling, e.g. ``"['plain']"``); an empty list only with ``empty``."""
    choices = tuple(choices)
    if isinstance(value, str) or not isinstance(value, Iterable):
        single = f"; a single one is {example}, not {value!r}" if isinstance(value, str) else ""
        raise ArgumentError(
            f"{name}: expected a list of names (one or more of "
            + ", ".join(repr(c) for c in choices)
            + f"), got {describe(value)}{single}"
        )
    names = tuple(value)
    if not names and not empty:
        raise ArgumentError(
            f"{name}: expected one or more of " + ", ".join(repr(c) for c in choices) + ", got none"
        )
    for k, item in enumerate(names):
        if not isinstance(item, str) or item not in choices:
            raise ArgumentError(
                f"{name}[{k}]: unknown {describe(item)}; expected one of "
                + ", ".join(repr(c) for c in choices)
            )
    return names


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
    if isinstance(value, int | np.integer):  # a Python int may exceed every float and int64
        if not -(2**63) <= value < 2**63:
            raise ArgumentError(
                f"{name}: {value!r} is out of range for a whole number here (at most 2**63 - 1 "
                "in size)"
            )
    elif not np.isfinite(value):
        raise ArgumentError(f"{name}: expected a finite number, got {value!r}")
    if integer and not float(value).is_integer():
        raise ArgumentError(f"{name}: expected {kind}, got {value!r}")
    below = low is not None and (value <= low if low_open else value < low)
    above = high is not None and (value >= high if high_open else value > high)
    if below or above:
        lo = "" if low is None else f"{'(' if low_open else '['}{low:g}"
        hi = "" if high is None else f"{high:g}{')' if high_open else ']'}"
        span = f"in {lo or '(-inf'}, {hi or 'inf)'}"
        raise ArgumentError(f"{name}: expected {kind} {span}, got {value!r}")
    return int(value) if integer else float(value)


SEED_MAX = 2**63 - 1  # seeds fit a signed 64-bit integer (NumPy takes any size; files do not)


def check_seed(value: Any, name: str = "seed") -> int:
    """A random seed: a whole number from 0 to :data:`SEED_MAX` (NumPy refuses negative seeds
    deep inside, with a message that does not name the argument)."""
    if isinstance(value, int | np.integer) and not isinstance(value, bool) and value > SEED_MAX:
        raise ArgumentError(f"{name}: expected a seed from 0 to 2**63 - 1, got {value!r}")
    return int(check_number(value, name, 0, integer=True))


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
        arr = real_array(value, name, dtype)
    except ArgumentError:
        raise
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
        arr = real_array(q, name)
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
