"""The ``relcal`` command line. Subcommands live in :mod:`relcal.cli`.

Exit codes (:data:`EXIT_CODES`): 0 success; 1 the run finished but a check failed (a calibration
that did not converge: nothing written; an unreached target: marked in the outputs); 2 bad input,
a bad option or a refused or unwritable output (the message names the file or option), nothing
written; 3 internal error (a bug: please report it; ``RELCAL_DEBUG=1`` shows the traceback); 130
interrupted (SIGINT), 143 terminated (SIGTERM): the outputs are the previous ones, or the new
ones with their registry record, each whole, and the message says which.
"""

from __future__ import annotations

import os

# Small matrices dominate relcal's linear algebra; BLAS threads only add overhead to them (up to
# tens of times on 2 cores). Set before NumPy loads; a user's own setting wins.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import signal  # noqa: E402
import sys  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable, Sequence  # noqa: E402

from relcal.errors import RelcalError, printable  # noqa: E402

EXIT_CODES = {
    0: "ok",
    1: "finished, but a calibration did not converge (nothing written), a target was missed, "
    "or a verified calibration does not hold on the new session",
    2: "bad input, bad option or refused output (nothing written)",
    3: "internal error (please report; RELCAL_DEBUG=1 shows the traceback)",
    130: "interrupted (SIGINT)",
    143: "terminated (SIGTERM)",
}


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised like Ctrl-C so that staged outputs are cleaned up."""


# The signals this run received. A library may swallow the KeyboardInterrupt a signal raises
# (trimesh, imported lazily by yourdfpy, catches BaseException around its optional imports and
# fails later with an unrelated TypeError): the run still ends as interrupted, never as a bug.
_received: list[int] = []
# While main's handlers are installed; a deferred signal is re-delivered only then (the lock
# keeps a late re-delivery from reaching the caller's handlers once main has restored them).
_handling = False
_handling_lock = threading.Lock()
_REDELIVER_S = 0.05
_DEFER_AT_MOST_S = 3.0  # an import that hangs is still interrupted
_deferred_since: float | None = None  # when this run first deferred a signal


def _on_signal(signum, frame):
    _received.append(signum)
    if not _handling:  # a re-delivery main is already past: recorded, the run ends as interrupted
        return
    if _importing(frame) and _deferral_allowed():
        # Module initialisation is no place for an exception: a nanobind extension creating its
        # enums (manifold3d, under trimesh) aborts the process on one (SIGABRT, no cleanup),
        # and a half-run module body stays broken. The signal comes back once the import is done.
        threading.Timer(_REDELIVER_S, _redeliver, (signum,)).start()
        return
    raise _interruption(signum)


def _interruption(signum: int) -> type[KeyboardInterrupt]:
    return Terminated if signum == signal.SIGTERM else KeyboardInterrupt


def _deferral_allowed() -> bool:
    global _deferred_since
    if _deferred_since is None:
        _deferred_since = time.monotonic()
    return time.monotonic() - _deferred_since < _DEFER_AT_MOST_S


def _redeliver(signum: int) -> None:
    with _handling_lock:
        if _handling:
            # to the main thread itself, so that a sleep or a blocking read there wakes up
            signal.pthread_kill(threading.main_thread().ident, signum)


def _importing(frame) -> bool:
    """Whether ``frame`` runs inside an import (a module body, or importlib finding one)."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib._bootstrap"):
            return True
        frame = frame.f_back
    return False


def _interrupt_noted() -> None:
    """Raise the interrupt a received signal stands for, if one was received."""
    if _received:
        raise _interruption(_received[-1])


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="relcal",
        description="Calibrate serial robot kinematics from relative camera measurements.",
        epilog="exit codes: " + "; ".join(f"{k} {v}" for k, v in EXIT_CODES.items()),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    from relcal import __version__
    from relcal.cli.common import register_all

    parser.add_argument("--version", action="version", version=f"relcal {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    register_all(sub)
    return parser


class _TerminalSafe:
    """A text stream whose writes are made terminal-safe (:func:`relcal.errors.terminal_safe`):
    text that came from files (ids, names, messages) cannot drive the terminal."""

    def __init__(self, stream) -> None:
        self._stream = stream

    def write(self, text: str) -> int:
        from relcal.errors import terminal_safe

        self._stream.write(terminal_safe(text))
        return len(text)

    def __getattr__(self, name: str):
        return getattr(self._stream, name)


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command; the one place where errors become messages and exit codes. Everything
    it prints is terminal-safe (control characters from files shown as escapes)."""
    streams = sys.stdout, sys.stderr
    sys.stdout, sys.stderr = _TerminalSafe(sys.stdout), _TerminalSafe(sys.stderr)
    try:
        return _main(argv)
    finally:
        sys.stdout, sys.stderr = streams


def _main(argv: Sequence[str] | None) -> int:
    sigs = (signal.SIGINT, signal.SIGTERM)
    in_main = _main_thread()
    previous = {s: signal.getsignal(s) for s in sigs} if in_main else {}
    global _deferred_since
    _received.clear()
    _deferred_since = None
    _set_handling(in_main)
    for s in previous:
        signal.signal(s, _on_signal)
    from relcal.outputset import forget_written

    forget_written()
    try:
        return _run(argv)
    except SystemExit as exc:  # argparse: --help (0) or a bad option (2, message printed)
        return exc.code if isinstance(exc.code, int) else 2
    except Terminated:
        print(f"relcal: terminated; {_what_was_written()}", file=sys.stderr)
        return 143
    except KeyboardInterrupt:
        print(f"relcal: interrupted; {_what_was_written()}", file=sys.stderr)
        return 130
    finally:
        _set_handling(False)
        for s, handler in previous.items():  # signal.signal first handles what is pending
            signal.signal(s, signal.SIG_DFL if handler is None else handler)


def _set_handling(on: bool) -> None:
    global _handling
    with _handling_lock:
        _handling = on


def _what_was_written() -> str:
    """The truth about the outputs after an interrupt: what this run installed (each whole,
    with its record), or that nothing was written."""
    from relcal.outputset import written

    done = written()
    if not done:
        return "nothing written (earlier outputs left as they were)"
    return (
        "already written, each whole: "
        + "; ".join(done)
        + " (the rest of the run, if any, was not done)"
    )


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def _run(argv: Sequence[str] | None) -> int:
    try:
        parser = build_parser()
        args = parser.parse_args(argv)  # light: see relcal.cli.common
        func: Callable[[argparse.Namespace], int] = args.func
        import numpy as np

        from relcal.cli.common import declare_run
        from relcal.outputset import tracking

        with tracking(), np.errstate(all="ignore"):
            declare_run(parser, args, list(sys.argv[1:] if argv is None else argv))
            code = func(args)
        _interrupt_noted()  # swallowed by a library: whatever was written is whole, and says so
        return code
    except (KeyboardInterrupt, SystemExit):
        raise
    except BaseException as exc:
        _interrupt_noted()  # a failure that followed a swallowed interrupt is the interrupt
        return _failure(exc)


def _failure(exc: BaseException) -> int:
    """Print the message of a failed command (not an interrupt); its exit code."""
    if isinstance(exc, RelcalError):
        print(f"relcal: error: {printable(exc)}", file=sys.stderr)
        return 2
    if isinstance(exc, BrokenPipeError):  # the reader of our output went away (``| head``)
        try:
            sys.stdout = open(os.devnull, "w")  # noqa: SIM115 - nothing more to print
        except OSError:
            pass
        return 141
    if isinstance(exc, OSError):
        where = f" {exc.filename}:" if exc.filename else ""
        print(f"relcal: error:{where} {exc.strerror or exc}; nothing written", file=sys.stderr)
        return 2
    if not isinstance(exc, Exception) or os.environ.get("RELCAL_DEBUG") == "1":
        raise exc
    # a bug: one line, the traceback only on request
    print(
        f"relcal: internal error: {type(exc).__name__}: {exc}; please report it "
        "(RELCAL_DEBUG=1 shows the traceback)",
        file=sys.stderr,
    )
    return 3


if __name__ == "__main__":
    sys.exit(main())
