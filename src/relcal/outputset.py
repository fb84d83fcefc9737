"""Writing a run's outputs as one unit: nothing lost, nothing half-written.

Every file a command writes goes through :func:`write_set`:

- A **folder** (``calibrate --out``, ``measure --out``, an imported or rendered dataset) is built
  in a temporary sibling folder, every file written and fsynced, then swapped into place in one
  rename. A folder that an earlier relcal run wrote (it holds ``.relcal-set.json``) is kept as
  ``<name>.prev/`` (one generation; the older one is deleted); a dataset folder is never replaced
  (``replace="refuse"``). A non-empty folder relcal did not write is never touched.
- A **single file** (``--json``, ``--report``, ``plan --out``) is written to a temporary sibling
  and renamed over the old one. A device or FIFO (``/dev/stdout``, ``/dev/null``, a pipe) is
  written into, never replaced by a regular file; a symbolic link keeps pointing where it did.
- Nothing the run **read** is written over: readers call :func:`note_input`, and a destination
  that is an input, or a folder that holds one, is refused before anything is written.
- All destinations are checked before the first byte is staged, and all renames happen together
  with SIGINT and SIGTERM held back, so an interrupted run leaves the old outputs or the new ones,
  whole; a refused or failed run leaves the disk as it was.
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
from typing import Literal

from relcal.errors import RelcalError

MARKER = ".relcal-set.json"  # written into every output folder: run id and file list
_INPUTS: set[Path] = set()


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


def _stage_folder(item: Folder) -> Path:
    path = Path(os.path.abspath(item.path))
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=path.parent, prefix=f".{path.name}.tmp-"))
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
    written = sorted(str(p.relative_to(tmp)) for p in tmp.rglob("*") if p.is_file())
    manifest = {
        "run_id": item.run_id or new_run_id(),
        "files": written,
        "written_utc": datetime.now(UTC).isoformat(timespec="seconds"),
    }
    _write_bytes(tmp / MARKER, json.dumps(manifest, indent=2) + "\n")
    for p in tmp.rglob("*"):
        if p.is_file():
            _fsync_path(p)
    for d in [tmp, *(p for p in tmp.rglob("*") if p.is_dir())]:
        _fsync_path(d)


def _stage_file(item: File) -> Path | None:
    if is_stream(item.path):
        return None  # written at commit time
    path = _real(item.path)  # a symbolic link keeps pointing at the file, which is replaced
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        _write_bytes(Path(tmp), item.content)
        os.chmod(tmp, 0o666 & ~_umask())
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return Path(tmp)


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


def _commit_folder(tmp: Path, item: Folder) -> None:
    path = Path(os.path.abspath(item.path))
    if path.is_dir() and any(path.iterdir()):
        prev = _prev(path)
        if prev.exists():
            shutil.rmtree(prev)
        if _exchange(tmp, path):  # the new set in place in one step; tmp holds the old one
            os.rename(tmp, prev)
        else:
            os.rename(path, prev)
            os.rename(tmp, path)
    else:
        if path.is_dir():
            path.rmdir()
        os.rename(tmp, path)
    _fsync_path(path.parent)


def _commit_file(tmp: Path | None, item: File) -> None:
    if tmp is None:
        data = item.content.encode() if isinstance(item.content, str) else item.content
        with open(item.path, "wb") as handle:  # a device or pipe: written into
            handle.write(data)
        return
    path = _real(item.path)
    os.replace(tmp, path)
    _fsync_path(path.parent)


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


def write_set(*items: Folder | File) -> list[Path]:
    """Write ``items`` as one unit (see the module docstring); return the paths written.

    Every destination is checked first (:class:`RelcalError` if one is refused, with nothing
    written), everything is staged in temporary siblings, then all are renamed into place with
    SIGINT and SIGTERM held back. On any failure the staged files are removed.
    """
    check(items)
    staged: list[tuple[Folder | File, Path | None]] = []
    created = _missing_parents(items)  # removed again if the write fails
    try:
        for item in items:
            with _naming(item):
                if isinstance(item, Folder):
                    staged.append((item, _stage_folder(item)))
                else:
                    staged.append((item, _stage_file(item)))
        # streams first: a full disk or a closed pipe stops the run before any rename
        staged.sort(key=lambda pair: pair[1] is not None)
        with _signals_held():
            for item, tmp in staged:
                with _naming(item):
                    if isinstance(item, Folder):
                        _commit_folder(tmp, item)  # type: ignore[arg-type]
                    else:
                        _commit_file(tmp, item)
            staged, created = [], []
    finally:
        for _, tmp in staged:
            if tmp is None:
                continue
            if tmp.is_dir():
                shutil.rmtree(tmp, ignore_errors=True)
            else:
                tmp.unlink(missing_ok=True)
        for folder in created:
            try:
                folder.rmdir()
            except OSError:
                pass
    return [Path(i.path) for i in items]
