"""Short ``repr`` texts for the public result types: what a person looks at in a REPL or a
notebook (sizes, names, the verdict), never whole arrays."""

from __future__ import annotations

from collections.abc import Callable


def short(kind: str, title: str, *parts: str | Callable[[], str]) -> str:
    """``<kind title: part, part, ...>``; a callable part is evaluated and left out if it
    raises (a repr must never fail)."""
    shown = []
    for part in parts:
        if callable(part):
            try:
                part = part()
            except Exception:  # noqa: BLE001 - a repr shows what it can
                continue
        if part:
            shown.append(part)
    head = f"{kind} {title}".strip()
    return f"<{head}: {', '.join(shown)}>" if shown else f"<{head}>"


def plural(n: int, what: str) -> str:
    """``1 sample``, ``3 samples``."""
    return f"{n} {what}" if n == 1 else f"{n} {what}s"
