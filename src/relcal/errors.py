"""The one exception type users see: a message naming the file, the field or line, and what was
expected. The command line prints it without a traceback and exits with status 2."""


class RelcalError(Exception):
    """Bad input or a problem relcal cannot solve, explained for a person."""


def require(module: str, extra: str, what: str):
    """Import the optional library ``module``, or raise a :class:`RelcalError` naming the extra
    that installs it (``pip install 'relcal[extra]'``); ``what`` names the feature needing it."""
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise RelcalError(
            f"{what} needs the Python module '{module}', which is not installed ({exc}); "
            f"install it with: pip install 'relcal[{extra}]'"
        ) from None


class ArgumentError(RelcalError, ValueError):
    """A Python API argument of the wrong type, shape or value (:mod:`relcal.checks`): a
    :class:`RelcalError` naming the argument, and a ``ValueError`` as Python code expects."""


_BIDI = dict.fromkeys([*range(0x202A, 0x202F), *range(0x2066, 0x206A), 0x200E, 0x200F, 0x061C])


def printable(text: object, limit: int | None = None) -> str:
    """Text that came from a file or a user, safe to show on a terminal or in a message:
    control characters (terminal escape sequences, carriage returns) and bidirectional
    overrides written as escapes, at most ``limit`` characters (with an ellipsis)."""
    out = []
    for ch in str(text):
        code = ord(ch)
        if (code < 32 and ch not in "\t\n") or 0x7F <= code < 0xA0 or code in _BIDI:
            out.append(ch.encode("unicode_escape").decode("ascii"))
        else:
            out.append(ch)
    shown = "".join(out)
    if limit is not None and len(shown) > limit:
        shown = shown[: max(limit - 3, 0)] + "..."
    return shown


def excerpt(text: object, limit: int = 40) -> str:
    """A short quoted excerpt of file text for a message (``'ninety'``), never more than
    ``limit`` characters of it, control characters escaped."""
    return "'" + printable(str(text).replace("\n", " "), limit) + "'"


# terminal-safe translation: C0 controls but tab, newline and carriage return (progress bars),
# DEL, C1 controls and bidirectional overrides shown as escapes
_TERMINAL = {
    code: chr(code).encode("unicode_escape").decode("ascii")
    for code in [*range(32), *range(0x7F, 0xA0), *_BIDI]
    if chr(code) not in "\t\n\r"
}


def terminal_safe(text: str) -> str:
    """``text`` with terminal control characters (escape sequences, bells, bidirectional
    overrides) written as visible escapes; tabs, newlines and carriage returns kept."""
    return text.translate(_TERMINAL)
