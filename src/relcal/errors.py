"""The one exception type users see: a message naming the file, the field or line, and what was
expected. The command line prints it without a traceback and exits with status 2."""


class RelcalError(Exception):
    """Bad input or a problem relcal cannot solve, explained for a person."""
