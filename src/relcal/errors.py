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
