"""Writing a run's outputs as one unit: nothing lost, nothing half-written.

Every file a command writes goes through :func:`write_set`:

- A **folder** (``calibrate --out``, ``measure --out``, an imported or rendered dataset) is built
  in a temporary sibling folder (``.NAME.tmp-PID-*``), every file written and fsynced, then
  swapped into place in one atomic exchange. A folder that an earlier relcal run wrote (it holds
  ``.relcal-set.json``) is kept as ``<name>.prev/`` (one generation): the old set and the older
  ``.prev`` change places by atomic exchanges too, so at every moment ``NAME`` and ``NAME.prev``
  are each a whole set (the oldest one is deleted only once the new set and its record are in
  place). A dataset folder is never replaced (``replace="refuse"``). A non-empty folder relcal
  did not write is never touched.
- A **single file** (``--json``, ``--report``, ``plan --out``) is written to a temporary sibling
  and renamed over the old one (which is kept under a hard link until the run is complete). A
  device or FIFO (``/dev/stdout``, ``/dev/null``, a pipe) is written into, never replaced by a
  regular file; a symbolic link keeps pointing where it did.
- Nothing the run **read** is written over: readers call :func:`note_input`, and a destination
  that is an input, or a folder that holds one, is refused before anything is written.
- A **journal** (a registry record, :class:`Journal`) is written in the same transaction: it is
  prepared (inserted, not yet committed) before the renames and committed after them; if the
  commit fails the renames are undone, if a rename fails the record is rolled back.
- All destinations are checked before the first byte is staged, and all renames and the commit
  happen with SIGINT and SIGTERM held back, so an interrupted run leaves the old outputs or the
  new ones (with their record), whole; a refused or failed run leaves the disk as it was.
- **Leftovers.** Every temporary a run creates is locked (``flock``) by that run while it lives;
  a SIGKILL releases the lock, and the next run writing to the same place removes the
  temporaries nobody holds (and only those). Staging and the renames take a lock on the parent
  folder, so a cleanup never sees a live run between two of its steps.
- :func:`written` lists what this run has installed, so that a message after an interrupt says
  truthfully whether the new outputs are in place.
"""

from __future__ import annotations

import ctypes
import json
import os
import shutil
import signal
import stat
import tempfile
import uuid
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Literal, Protocol

from relcal.errors import RelcalError

MARKER = ".relcal-set.json"  # written into every output folder: run id and file list
_INPUTS: set[Path] = set()
_WRITTEN: list[str] = []  # what this run installed, in words (see :func:`written`)


def _real(path: str | Path) -> Path:
    return Path(os.path.realpath(os.path.abspath(path)))


def note_input(path: str | Path) -> None:
    """Record that this run read ``path`` (it is then never written over)."""
    _INPUTS.add(_real(path))


def inputs() -> frozenset[Path]:
    """The resolved paths read so far in this run."""
    return frozenset(_INPUTS)


@contextmanager
def tracking() -> Iterator[None]:
    """A fresh record of inputs for one run (the command line wraps each command in it)."""
    saved = set(_INPUTS)
    _INPUTS.clear()
    try:
        yield
    finally:
        _INPUTS.clear()
        _INPUTS.update(saved)


def written() -> list[str]:
    """What this run has installed so far, in words (``--out cal/ (run 3f2a...)``, ``registry
    run 7``): each entry is complete; empty when nothing was written."""
    return list(_WRITTEN)


def forget_written() -> None:
    """Start a new run's list of :func:`written` outputs (the command line calls it per command)."""
    _WRITTEN.clear()


class Journal(Protocol):
    """Something written in the same transaction as a set: a registry record.

    ``prepare`` writes it without making it visible (a database transaction begun and the row
    inserted) and may raise :class:`RelcalError`; ``commit`` makes it visible (raising if it
    cannot, then the set's renames are undone); ``rollback`` forgets a prepared write;
    ``describe`` says in words what was written (after ``commit``)."""

    def prepare(self) -> None: ...

    def commit(self) -> None: ...

    def rollback(self) -> None: ...

    def describe(self) -> str: ...


def new_run_id() -> str:
    """A short random id stored in every file of one output set."""
    return uuid.uuid4().hex[:12]


Content = str | bytes | Callable[[Path], None]


@dataclass
class Folder:
    """A folder written as one unit: ``files`` maps a relative name to its text, bytes or a
    function writing that file; ``fill(folder)`` may write more (images)."""

    path: str | Path
    files: dict[str, Content] = field(default_factory=dict)
    what: str = "--out"  # the option or role named in messages
    replace: Literal["prev", "refuse"] = "prev"
    fill: Callable[[Path], None] | None = None
    run_id: str | None = None


@dataclass
class File:
    """A single file written as one unit."""

    path: str | Path
    content: str | bytes
    what: str = "--json"


def is_stream(path: str | Path) -> bool:
    """An existing device, FIFO or socket, or a path under /dev or /proc (``/dev/stdout``): written
    into, never replaced."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        return True
    return any(str(p).startswith(("/dev/", "/proc/")) for p in (Path(path), _real(path)))


def _nearest_existing(path: Path) -> Path:
    path = Path(os.path.abspath(path))
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def check_parent(path: str | Path, what: str) -> None:
    """The nearest existing ancestor of ``path`` must be a writable folder."""
    base = _nearest_existing(Path(path).parent)
    if not base.is_dir():
        raise RelcalError(f"{what} {path}: {base} is a file, not a folder")
    if not os.access(base, os.W_OK | os.X_OK):
        raise RelcalError(f"{what} {path}: cannot write in {base} (permission denied)")


def _is_set(folder: Path) -> bool:
    return (folder / MARKER).is_file()


def _is_input_inside(folder: Path) -> Path | None:
    real = _real(folder)
    for p in sorted(_INPUTS):
        if p == real or real in p.parents:
            return p
    return None


def check_folder(item: Folder) -> None:
    """Refuse a folder destination that is a file, holds an input, or is not relcal's own."""
    path = Path(item.path)
    what = f"{item.what} {path}"
    if is_stream(path):
        raise RelcalError(f"{what}: a device or pipe, not a folder; give a folder path")
    if path.exists() and not path.is_dir():
        raise RelcalError(f"{what}: exists and is a file, not a folder; give a folder path")
    check_parent(path, item.what)
    hit = _is_input_inside(path)
    if hit is not None:
        raise RelcalError(
            f"{what}: would overwrite {hit}, which this run reads; write the outputs elsewhere"
        )
    if path.is_dir() and any(path.iterdir()):
        if item.replace == "refuse":
            raise RelcalError(
                f"{what}: already exists and is not empty; relcal never replaces a dataset "
                "folder: choose a new folder or remove this one"
            )
        if not _is_set(path):
            raise RelcalError(
                f"{what}: exists, is not empty and was not written by relcal (no {MARKER}); "
                "choose a new or empty folder"
            )
        prev = _prev(path)
        if prev.exists() and not (prev.is_dir() and (_is_set(prev) or not any(prev.iterdir()))):
            raise RelcalError(
                f"{what}: {prev} (where the previous outputs are kept) exists and was not "
                "written by relcal; move it away"
            )


def check_file(item: File) -> None:
    """Refuse a file destination that is a folder, an input, or in an unwritable place."""
    path = Path(item.path)
    what = f"{item.what} {path}"
    if is_stream(path):
        if path.exists() and _real(path) in _INPUTS:
            raise RelcalError(f"{what}: this run reads it; write the output elsewhere")
        return
    if path.is_dir():
        raise RelcalError(f"{what}: is a folder; give a file name")
    if str(_real(path)).startswith(("/dev/", "/proc/")):
        raise RelcalError(f"{what}: no such device; relcal does not create files there")
    check_parent(path, item.what)
    if _real(path) in _INPUTS:
        raise RelcalError(
            f"{what}: would overwrite {_real(path)}, which this run reads; give another file"
        )


def check(items: Iterable[Folder | File]) -> None:
    """Check every destination (and that no two are the same) without writing anything."""
    seen: dict[Path, str] = {}
    for item in items:
        (check_folder if isinstance(item, Folder) else check_file)(item)  # type: ignore[arg-type]
        real = _real(item.path)
        if real in seen and not is_stream(item.path):
            raise RelcalError(f"{item.what} {item.path}: also given as {seen[real]}")
        seen[real] = item.what
    folders = [(_real(i.path), i.what) for i in items if isinstance(i, Folder)]
    for item in items:
        real = _real(item.path)
        for folder, what in folders:
            if folder in real.parents:
                raise RelcalError(
                    f"{item.what} {item.path}: inside the output folder ({what} {folder}), "
                    "which is replaced as a whole; write it elsewhere"
                )


def check_apart(path: str | Path, what: str, items: Iterable[Folder | File]) -> None:
    """Refuse ``path`` (another file the run writes, such as its registry) when it is one of the
    output ``items``, or inside an output folder or its ``.prev`` (replaced as a whole)."""
    real = _real(path)
    for item in items:
        dest = _real(item.path)
        if real == dest:
            raise RelcalError(f"{what}: also given as {item.what} {item.path}; give another path")
        if isinstance(item, Folder) and (dest in real.parents or _prev(dest) in real.parents):
            raise RelcalError(
                f"{what}: inside the output folder ({item.what} {item.path}), which is replaced "
                "as a whole by every run; put it elsewhere"
            )


def _prev(path: Path) -> Path:
    return path.with_name(path.name + ".prev")


def _fsync_path(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _write_bytes(path: Path, content: str | bytes) -> None:
    data = content.encode() if isinstance(content, str) else content
    with open(path, "wb") as handle:
        handle.write(data)
        handle.flush()
        os.fsync(handle.fileno())


# ------------------------------------------------------------------ locks and stale temporaries


def _flock(fd: int, blocking: bool) -> bool:
    """An exclusive ``flock`` on ``fd``: True when held, False when another process holds it
    (non-blocking) or locks are not available here (then nothing is ever called stale)."""
    try:
        import fcntl
    except ImportError:  # not POSIX
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | (0 if blocking else fcntl.LOCK_NB))
    except OSError:
        return False
    return True


_HELD: dict[Path, int] = {}  # folders this process holds locked, and how many times
_OWN: dict[int, Path] = {}  # temporaries this process holds (:func:`_hold`), by descriptor


@contextmanager
def _folder_locks(folders: Iterable[Path]) -> Iterator[None]:
    """Exclusive locks on ``folders`` (sorted, so two runs never wait on each other in a cycle):
    held while temporaries are created or removed and while a set is renamed into place.
    Re-entrant within the process: a set written while another is being staged (the synthetic
    images of ``relcal simulate --images`` inside its output set) takes the locks it already
    holds again instead of waiting on itself (``flock`` on a second descriptor would)."""
    fds, taken = [], []
    try:
        for folder in sorted(set(folders)):
            key = Path(os.path.realpath(folder))
            if key in _OWN.values():  # a temporary of this run: held already
                continue
            if _HELD.get(key):
                _HELD[key] += 1
                taken.append(key)
                continue
            try:
                fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
            except OSError:
                continue
            fds.append(fd)
            _flock(fd, blocking=True)
            _HELD[key] = 1
            taken.append(key)
        yield
    finally:
        for key in taken:
            _HELD[key] -= 1
            if not _HELD[key]:
                del _HELD[key]
        for fd in fds:
            os.close(fd)


def _hold(path: Path) -> int | None:
    """Open and lock ``path`` (a temporary of this run) for as long as the run lives: a lock
    that a SIGKILL releases, which is how the next run knows the temporary is stale."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return None
    _flock(fd, blocking=False)
    _OWN[fd] = Path(os.path.realpath(path))
    return fd


def _release(fd: int) -> None:
    """Close a descriptor of :func:`_hold` (its lock goes with it)."""
    _OWN.pop(fd, None)
    os.close(fd)


_RANDOM = r"[a-z0-9_]{8}"  # tempfile's random part


def _temporaries(item: Folder | File) -> list[Path]:
    """The temporaries a relcal run writing ``item`` may have left beside it, by their exact
    name patterns: ``.NAME.tmp-PID-XXXXXXXX`` folders (staged sets, old sets on their way out;
    ``.NAME.tmp-XXXXXXXX`` from relcal before 0.2) and ``.NAME.XXXXXXXX.tmp`` files."""
    import re

    path = Path(os.path.abspath(item.path))
    name = re.escape(path.name)
    pattern = re.compile(rf"\.{name}\.tmp-(?:\d+-)?{_RANDOM}(?:-older)?|\.{name}\.{_RANDOM}\.tmp")
    try:
        entries = list(os.scandir(path.parent))
    except OSError:
        return []
    return sorted(path.parent / e.name for e in entries if pattern.fullmatch(e.name))


def _is_stale(path: Path) -> bool:
    """A temporary that no live process holds (its lock can be taken)."""
    try:
        fd = os.open(path, os.O_RDONLY | (os.O_DIRECTORY if path.is_dir() else 0))
    except OSError:
        return False
    try:
        return _flock(fd, blocking=False)
    finally:
        os.close(fd)


def remove_stale(*items: Folder | File) -> list[Path]:
    """Remove the temporaries that killed runs left beside ``items`` (those no live process
    holds; call with the parent folders locked); the paths removed."""
    removed = []
    for item in items:
        if is_stream(item.path):
            continue
        for tmp in _temporaries(item):
            if tmp.is_symlink() or not _is_stale(tmp):
                continue
            if tmp.is_dir():
                shutil.rmtree(tmp, ignore_errors=True)
            else:
                tmp.unlink(missing_ok=True)
            if not tmp.exists():
                removed.append(tmp)
    return removed


# --------------------------------------------------------------------------------- staging


def _stage_folder(item: Folder, holds: list[int]) -> Path:
    path = Path(os.path.abspath(item.path))
    with _folder_locks([path.parent]):  # created and locked before any cleanup can see it
        tmp = Path(tempfile.mkdtemp(dir=path.parent, prefix=f".{path.name}.tmp-{os.getpid()}-"))
        fd = _hold(tmp)
    if fd is not None:
        holds.append(fd)
    try:
        _fill_folder(tmp, item)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return tmp


def _fill_folder(tmp: Path, item: Folder) -> None:
    os.chmod(tmp, 0o777 & ~_umask())
    for name, content in item.files.items():
        target = tmp / name
        target.parent.mkdir(parents=True, exist_ok=True)
        if callable(content):
            content(target)
        else:
            _write_bytes(target, content)
    if item.fill is not None:
        item.fill(tmp)
    written_files = sorted(str(p.relative_to(tmp)) for p in tmp.rglob("*") if p.is_file())
    manifest = {
        "run_id": item.run_id or new_run_id(),
        "files": written_files,
        "written_utc": datetime.now(UTC).isoformat(timespec="seconds"),
    }
    _write_bytes(tmp / MARKER, json.dumps(manifest, indent=2) + "\n")
    for p in tmp.rglob("*"):
        if p.is_file():
            _fsync_path(p)
    for d in [tmp, *(p for p in tmp.rglob("*") if p.is_dir())]:
        _fsync_path(d)


def _temp_file(path: Path) -> Path:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    return Path(tmp)


def _stage_file(item: File, holds: list[int]) -> Path | None:
    if is_stream(item.path):
        return None  # written at commit time
    path = _real(item.path)  # a symbolic link keeps pointing at the file, which is replaced
    path.parent.mkdir(parents=True, exist_ok=True)
    with _folder_locks([path.parent]):
        tmp = _temp_file(path)
        fd = _hold(tmp)
    if fd is not None:
        holds.append(fd)
    try:
        _write_bytes(tmp, item.content)
        os.chmod(tmp, 0o666 & ~_umask())
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return tmp


# --------------------------------------------------------------------------------- commit

_RENAME_EXCHANGE = 2


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux renameat2); False where it is not available."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    at_fdcwd = -100
    if fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    return False


Undo = list[Callable[[], object]]


def _commit_folder(tmp: Path, item: Folder, undo: Undo, trash: list[Path]) -> None:
    """Put the staged set ``tmp`` in place; the current set becomes ``.prev`` and the older
    ``.prev`` goes to ``trash`` (deleted once the run is complete). ``undo`` gets, step by step,
    what puts everything back."""
    path = Path(os.path.abspath(item.path))
    prev = _prev(path)
    if path.is_dir() and any(path.iterdir()):
        if _exchange(tmp, path):  # new set in place; tmp holds the old one
            undo.append(lambda: _exchange(tmp, path))
            if prev.exists():
                if not _exchange(tmp, prev):  # the old set is .prev; tmp holds the older one
                    raise OSError(f"cannot exchange {tmp} and {prev}")
                undo.append(lambda: _exchange(tmp, prev))
                trash.append(tmp)
            else:
                os.rename(tmp, prev)
                undo.append(lambda: os.rename(prev, tmp))
        else:  # no atomic exchange here: three renames (the folder is missing for a moment)
            if prev.exists():
                aside = Path(f"{tmp}-older")
                os.rename(prev, aside)
                undo.append(lambda: os.rename(aside, prev))
                trash.append(aside)
            os.rename(path, prev)
            undo.append(lambda: os.rename(prev, path))
            os.rename(tmp, path)
            undo.append(lambda: os.rename(path, tmp))
    else:
        if path.is_dir():
            path.rmdir()
            undo.append(path.mkdir)
        os.rename(tmp, path)
        undo.append(lambda: os.rename(path, tmp))
    _fsync_path(path.parent)


def _write_stream(item: File) -> None:
    data = item.content.encode() if isinstance(item.content, str) else item.content
    with open(item.path, "wb") as handle:  # a device or pipe: written into
        handle.write(data)


def _commit_file(tmp: Path, item: File, undo: Undo, trash: list[Path]) -> None:
    """Rename the staged file over the destination; the old file stays reachable under a hard
    link (in ``trash``) until the run is complete, so ``undo`` can put it back."""
    path = _real(item.path)
    backup = None
    if path.is_file():
        backup = _temp_file(path)
        backup.unlink()
        try:
            os.link(path, backup)
        except OSError:  # no hard links here: a copy
            shutil.copy2(path, backup)
        trash.append(backup)
    os.replace(tmp, path)
    if backup is not None:
        undo.append(lambda: os.replace(backup, path))
    else:
        undo.append(path.unlink)
    _fsync_path(path.parent)


def _undo(undo: Undo) -> str | None:
    """Run ``undo`` backwards; None, or what could not be put back."""
    for step in reversed(undo):
        try:
            step()
        except OSError as exc:
            return str(exc)
    undo.clear()
    return None


@contextmanager
def _signals_held() -> Iterator[None]:
    """SIGINT and SIGTERM held back until the block is done, then delivered.

    In the main thread the Python handlers are swapped for ones that only note the signal (a
    signal mask alone covers one thread, and Python runs its handlers in the main thread
    whichever thread the kernel picked); the mask also keeps a default SIGTERM from killing the
    process mid-rename. The noted signals are raised again once the block is done.
    """
    import threading

    sigs = (signal.SIGINT, signal.SIGTERM)
    masked = hasattr(signal, "pthread_sigmask")
    old_mask = signal.pthread_sigmask(signal.SIG_BLOCK, set(sigs)) if masked else None
    caught: list[int] = []
    swapped = threading.current_thread() is threading.main_thread()
    old = {s: signal.signal(s, lambda n, f: caught.append(n)) for s in sigs} if swapped else {}
    try:
        yield
    finally:
        if masked:
            signal.pthread_sigmask(signal.SIG_SETMASK, old_mask)  # pending ones land in caught
        for s, handler in old.items():
            signal.signal(s, signal.SIG_DFL if handler is None else handler)
        for n in dict.fromkeys(caught):
            signal.raise_signal(n)


def _missing_parents(items: Iterable[Folder | File]) -> list[Path]:
    """Folders that staging ``items`` will create, deepest first."""
    missing: set[Path] = set()
    for item in items:
        parent = Path(os.path.abspath(item.path)).parent
        while not parent.exists() and parent != parent.parent:
            missing.add(parent)
            parent = parent.parent
    return sorted(missing, key=lambda p: len(p.parts), reverse=True)


@contextmanager
def _naming(item: Folder | File) -> Iterator[None]:
    """An operating-system error while writing ``item`` as a message naming it."""
    try:
        yield
    except OSError as exc:
        raise RelcalError(
            f"{item.what} {item.path}: cannot write: {exc.strerror or exc}"
            + ("" if isinstance(item, File) and is_stream(item.path) else "; nothing written")
        ) from None


def _describe(item: Folder | File) -> str:
    if isinstance(item, Folder):
        return f"{item.what} {item.path}" + (f" (run {item.run_id})" if item.run_id else "")
    return f"{item.what} {item.path}"


def write_set(*items: Folder | File, journal: Journal | None = None) -> list[Path]:
    """Write ``items`` as one unit, with ``journal`` (a registry record) in the same
    transaction (see the module docstring); return the paths written.

    Every destination is checked first (:class:`RelcalError` if one is refused, with nothing
    written), stale temporaries of killed runs beside them are removed, everything is staged in
    locked temporary siblings, streams are written, the journal is prepared, then all renames
    and the journal's commit happen with SIGINT and SIGTERM held back. A failed rename rolls the
    journal back and undoes the renames before it; a failed commit undoes every rename. On any
    failure the staged files are removed and the disk is as it was.
    """
    check(items)
    files = [i for i in items if not is_stream(i.path)]
    created = _missing_parents(files)  # removed again if the write fails
    staged: list[tuple[Folder | File, Path | None]] = []
    holds: list[int] = []
    undo: Undo = []
    trash: list[Path] = []
    prepared = committed = False
    try:
        for item in files:
            with _naming(item):
                Path(os.path.abspath(item.path)).parent.mkdir(parents=True, exist_ok=True)
        parents = [Path(os.path.abspath(i.path)).parent for i in files]
        with _folder_locks(parents):
            remove_stale(*files)
        for item in items:
            with _naming(item):
                if isinstance(item, Folder):
                    staged.append((item, _stage_folder(item, holds)))
                else:
                    staged.append((item, _stage_file(item, holds)))
        # streams first: a full disk or a closed pipe stops the run before any rename
        for item, tmp in staged:
            if tmp is None:
                with _naming(item):
                    _write_stream(item)  # type: ignore[arg-type]
        if journal is not None:
            journal.prepare()
            prepared = True
        with _signals_held(), _folder_locks(parents):
            try:
                for item, tmp in staged:
                    if tmp is None:
                        continue
                    with _naming(item):
                        if isinstance(item, Folder):
                            _commit_folder(tmp, item, undo, trash)
                        else:
                            _commit_file(tmp, item, undo, trash)
                if journal is not None:
                    try:
                        journal.commit()
                    except RelcalError as exc:
                        left = ", ".join(str(i.path) for i in files)
                        raise RelcalError(
                            f"{exc}; nothing written ({left} left as they were)"
                        ) from None
                committed = True
            except BaseException:
                failed = _undo(undo)
                if failed is not None:
                    raise RelcalError(
                        "the outputs could not be put back after a failed write ("
                        f"{failed}); check {', '.join(str(i.path) for i in files)}"
                    ) from None
                raise
            _WRITTEN.extend(_describe(i) for i in items)
            if journal is not None:
                _WRITTEN.append(journal.describe())
            staged, created = [], []
    finally:
        if committed:  # the oldest set and replaced files: no longer needed (even if a held
            for old in trash:  # signal is being delivered)
                if old.is_dir():
                    shutil.rmtree(old, ignore_errors=True)
                else:
                    old.unlink(missing_ok=True)
        if prepared and not committed:
            try:
                journal.rollback()  # type: ignore[union-attr]
            except Exception:  # noqa: BLE001 - the write's own error is the one to report
                pass
        for _, tmp in staged:
            if tmp is None:
                continue
            if tmp.is_dir():
                shutil.rmtree(tmp, ignore_errors=True)
            else:
                tmp.unlink(missing_ok=True)
        for fd in holds:
            _release(fd)
        for folder in created:
            try:
                folder.rmdir()
            except OSError:
                pass
    return [Path(i.path) for i in items]
