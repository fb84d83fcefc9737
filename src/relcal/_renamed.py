"""Keywords of the Python API renamed to the command line's name for the same concept
(docs/reference/names.md): the old keyword keeps working for one release, with a
DeprecationWarning that names the new one."""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any

from relcal.errors import ArgumentError


class _Unset:
    """The default of a renamed keyword: "not given" (None may be a meaningful value)."""

    def __repr__(self) -> str:
        return "<not given>"


UNSET: Any = _Unset()
REMOVED_IN = "0.2"


def renamed(
    function: str,
    old: str,
    old_value: Any,
    new: str,
    new_value: Any,
    new_default: Any,
    convert: Callable[[Any], Any] = lambda value: value,
) -> Any:
    """The value of keyword ``new``, taking the deprecated keyword ``old`` when it was given.

    Parameters
    ----------
    function : str
        The function's public name, for the messages (``calibrate``).
    old, new : str
        The deprecated keyword and the one that replaces it.
    old_value, new_value : object
        What the caller passed (``UNSET`` when ``old`` was not given).
    new_default : object
        The default of ``new``: a ``new_value`` other than it counts as given.
    convert : callable
        The old keyword's value as a value of the new one (``lambda v: not v`` for a keyword
        whose sense is reversed).

    Returns
    -------
    object
        ``new_value``, or ``convert(old_value)`` when the old keyword was given.

    Raises
    ------
    ArgumentError
        Both keywords given with values that disagree.
    """
    if isinstance(new_default, bool):  # a flag: checked before ``convert`` (``not``) sees it
        from relcal.checks import check_flag

        check_flag(new_value, new)
        if old_value is not UNSET:
            check_flag(old_value, old)
    if old_value is UNSET:
        return new_value
    value = convert(old_value)
    warnings.warn(
        f"relcal.{function}({old}=...) is deprecated and will be removed in relcal {REMOVED_IN}: "
        f"use {new}={value!r}",
        DeprecationWarning,
        stacklevel=3,
    )
    try:
        differ = bool(new_value != value)
    except (TypeError, ValueError):  # arrays and other values without one truth
        differ = True
    if new_value is not new_default and differ:
        raise ArgumentError(
            f"{function}: {old}={old_value!r} and {new}={new_value!r} disagree; give only {new} "
            f"({old} is its deprecated name)"
        )
    return value
