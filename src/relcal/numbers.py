"""Numbers written as text (CSV cells, command-line options, plan files) read strictly.

Python's ``float`` reads more than a table or an option should: ``4_1.67`` is 41.67 (digit
separators), ``' 1 '`` is 1, ``'infinity'`` is inf. A typo there is silently a wrong number, so
every number relcal reads from text goes through :func:`parse_number`: a decimal number
(``-0.5``, ``12``, ``.5``, ``1e-3``) and nothing else, and a refusal that says the likely cause
(an underscore, a decimal comma, several values in one cell: a file separated by tabs or spaces
read with another separator, a value that is not finite). Imports nothing heavy: the command
line's option types use it.
"""

from __future__ import annotations

import math
import re

NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


class NotANumber(ValueError):
    """A text that is not a decimal number; ``str(exc)`` says what was expected and why not."""


def parse_number(text: str) -> float:
    """The finite float that ``text`` writes (surrounding spaces allowed), else
    :class:`NotANumber` with the likely cause."""
    stripped = text.strip()
    if NUMBER.fullmatch(stripped):
        value = float(stripped)
        if math.isfinite(value):
            return value
        raise NotANumber(f"{stripped!r} is too large to be a number here (overflows)")
    raise NotANumber(why_not(stripped))


def why_not(text: str) -> str:
    """Why ``text`` is not a decimal number, in words for a message."""
    shown = repr(text if len(text) <= 40 else text[:37] + "...")
    if not text:
        return "expected a number, got an empty field"
    if "_" in text and NUMBER.fullmatch(text.replace("_", "")):
        return (
            f"expected a number, got {shown}: an underscore inside a number (Python would read "
            f"{text.replace('_', '')}); a typo or a digit separator? write the digits alone"
        )
    if "\t" in text or (" " in text and all(NUMBER.fullmatch(p) for p in text.split())):
        return (
            f"expected one number, got {shown}: several values in one field, separated by "
            "tabs or spaces; is the file separated by tabs or spaces while its header (or the "
            "format) uses another separator? use one separator throughout"
        )
    if "," in text and NUMBER.fullmatch(text.replace(",", ".", 1)):
        return f"expected a number, got {shown}: a decimal comma? write 0.5, not 0,5"
    if text.lower().lstrip("+-") in ("inf", "infinity", "nan"):
        return f"expected a finite number, got {shown}"
    return f"expected a number, got {shown}"


NOISE_LIMITS = (1000.0, 180.0, 180.0)  # mm, deg, deg: beyond them no pose or joint means much


def noise_numbers(text: str) -> list[float]:
    """The levels of a ``POS_MM,ORI_DEG[,JOINT_DEG]`` noise text (standard deviations in mm and
    degrees, the joints' 0 when not given), each read by :func:`parse_number`, else
    :class:`NotANumber` naming the field and the likely cause: a negative level, or one beyond
    1000 mm or 180 deg (metres in micrometres? a level in the wrong field?)."""
    parts = text.split(",")
    if not 2 <= len(parts) <= 3:
        raise NotANumber(f"2 or 3 numbers separated by commas, got {len(parts)}")
    values = []
    for name, part, limit, unit in zip(
        ("POS_MM", "ORI_DEG", "JOINT_DEG"), parts, NOISE_LIMITS, ("mm", "deg", "deg"), strict=False
    ):
        try:
            value = parse_number(part)
        except NotANumber as exc:
            raise NotANumber(f"{name}: {exc}") from None
        if not 0 <= value <= limit:
            raise NotANumber(
                f"{name}: {value:.4g} {unit}: expected a standard deviation from 0 to {limit:g} "
                f"{unit}"
                + (" (a noise level cannot be negative)" if value < 0 else "; a wrong unit?")
            )
        values.append(value)
    return values + [0.0] * (3 - len(values))
