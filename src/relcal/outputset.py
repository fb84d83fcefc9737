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
- :func:`written` lists what this run has installed (sets, files, registry records, the samples
  of a capture: :func:`note_written`), so that a message after an interrupt says truthfully
  what is in place.
- **Never the user's.** A file or folder inside an output folder that the previous set did not
  list as its own (a ``joints.csv`` a user wrote into ``cal/``) stays where it is: it is moved
  into the new set (and with the set into ``.prev``), never deleted; a file of the new set with
  the same name is refused before any work. A folder that is the working folder or holds it
  (``--out .``, an empty path) is refused: it would be swapped away under the shell. A
  calibration registry (a SQLite database, :func:`note_registry`) is never written over.
- **Declared first.** A command declares every destination of its run before any work
  (:func:`declare`; the command line does it from the options that name outputs), and every
  write of the run checks all of them against what the run has read so far, so a ``--json``
  that names an input is refused before ``--out`` is written, not after.
- **One writer.** :func:`exclusive` serialises or refuses concurrent writers of one place (a
  capture's dataset folder, a registry's migration) with a lock file that is removed when the
  run ends.
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
_REGISTRIES: set[Path] = set()  # SQLite registries this run opened: never an output
_DECLARED: list[File | Folder] = []  # the destinations of this run (:func:`declare`)
_WRITTEN: dict[object, str] = {}  # what this run installed, in words (see :func:`written`)
SQLITE_MAGIC = b"SQLite format 3\x00"


def _real(path: str | Path) -> Path:
    return Path(os.path.realpath(os.path.abspath(path)))


def note_input(path: str | Path) -> None:
    """Record that this run read ``path`` (it is then never written over)."""
    _INPUTS.add(_real(path))


def inputs() -> frozenset[Path]:
    """The resolved paths read so far in this run."""
    return frozenset(_INPUTS)


def note_registry(path: str | Path) -> None:
    """Record that this run uses the SQLite registry ``path``: no output of the run may be
    written over it or replace a folder that holds it."""
    _REGISTRIES.add(_real(path))


@contextmanager
def tracking() -> Iterator[None]:
    """A fresh record of inputs, registries and declared destinations for one run (the command
    line wraps each command in it)."""
    saved = set(_INPUTS), set(_REGISTRIES), list(_DECLARED)
    _INPUTS.clear()
    _REGISTRIES.clear()
    _DECLARED.clear()
    try:
        yield
    finally:
        _INPUTS.clear()
        _INPUTS.update(saved[0])
        _REGISTRIES.clear()
        _REGISTRIES.update(saved[1])
        _DECLARED[:] = saved[2]


def written() -> list[str]:
    """What this run has installed so far, in words (``--out cal/ (run 3f2a...)``, ``registry
    run 7``): each entry is complete; empty when nothing was written."""
    return list(_WRITTEN.values())


def note_written(text: str, key: object = None) -> None:
    """Add ``text`` to :func:`written` (something this run has made durable, whole); an entry
    with the same ``key`` is replaced (a capture's growing count of samples)."""
    _WRITTEN[object() if key is None else key] = text


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
    """A single file written as one unit; ``content`` may be a function returning the text or
    bytes, called once the set's journal is prepared (see :func:`write_set`)."""

    path: str | Path
    content: str | bytes | Callable[[], str | bytes]
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
    hits = [p for p in _INPUTS if p == real or real in p.parents]
    return max(hits, key=lambda p: (len(p.parts), str(p))) if hits else None  # the file read


def is_registry(path: str | Path) -> bool:
    """A regular file that starts as a SQLite database does (a calibration registry)."""
    try:
        if not os.path.isfile(path):
            return False
        with open(path, "rb") as handle:
            return handle.read(len(SQLITE_MAGIC)) == SQLITE_MAGIC
    except OSError:
        return False


def _registry_hit(real: Path, folder: bool) -> Path | None:
    """A registry of this run that ``real`` is (or, for a ``folder``, holds): with SQLite's
    companions (``-wal``, ``-shm``, ``-journal``)."""
    for reg in sorted(_REGISTRIES):
        names = {reg, *(reg.with_name(reg.name + s) for s in ("-wal", "-shm", "-journal"))}
        if real in names or (folder and real in reg.parents):
            return reg
    return None


def _empty_path(path: str | Path) -> bool:
    return not str(path).strip()


def check_destination(item: Folder | File) -> None:
    """The checks every destination gets, declared or about to be written: not empty, not an
    input of the run (nor, for a folder, holding one), not a calibration registry (nor a folder
    holding the run's), not the working folder (nor a folder holding it)."""
    folder = isinstance(item, Folder)
    if _empty_path(item.path):
        raise RelcalError(
            f"{item.what}: an empty path; give a {'folder' if folder else 'file'} name "
            "(the working folder itself is never an output: it would be replaced under you)"
        )
    path = Path(item.path)
    what = f"{item.what} {path}"
    real = _real(path)
    if is_stream(path):
        if path.exists() and real in _INPUTS:
            raise RelcalError(f"{what}: this run reads it; write the output elsewhere")
        return
    reg = _registry_hit(real, folder)
    if reg is not None:
        if folder and reg != real:
            raise RelcalError(
                f"{what}: the registry {reg} of this run is inside the output folder, which is "
                "replaced as a whole; put the registry or the outputs elsewhere"
            )
        raise RelcalError(
            f"{what}: also given as the registry of this run ({reg}); relcal never writes over "
            "a registry: give another path"
        )
    if not folder and is_registry(path):
        raise RelcalError(
            f"{what}: is a calibration registry (a SQLite database); relcal never writes over "
            "one: give another file name"
        )
    if folder:
        hit = _is_input_inside(path)
        if hit is not None:
            raise RelcalError(
                f"{what}: would overwrite {hit}, which this run reads; write the outputs elsewhere"
            )
        cwd = _real(os.getcwd())
        if real == cwd or real in cwd.parents:
            here = "is the working folder" if real == cwd else f"holds the working folder {cwd}"
            raise RelcalError(
                f"{what}: {here}; an output folder is replaced as a whole, which would leave "
                "this process (and your shell) in a deleted folder: give a new folder name, "
                "e.g. 'results'"
            )
    elif real in _INPUTS:
        raise RelcalError(
            f"{what}: would overwrite {real}, which this run reads; give another file"
        )


def check_folder(item: Folder) -> None:
    """Refuse a folder destination that is a file, holds an input, or is not relcal's own."""
    check_destination(item)
    path = Path(item.path)
    what = f"{item.what} {path}"
    if is_stream(path):
        raise RelcalError(f"{what}: a device or pipe, not a folder; give a folder path")
    if path.exists() and not path.is_dir():
        raise RelcalError(f"{what}: exists and is a file, not a folder; give a folder path")
    check_parent(path, item.what)
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
        clash = sorted(set(_foreign(path)) & _names_of(item.files))
        if clash:
            raise RelcalError(
                f"{what}: {path / clash[0]} was not written by relcal (not in {MARKER}) and "
                "this run writes a file of that name; move it out of the folder (files of "
                "yours in an output folder are kept, never replaced)"
            )
        if prev.is_dir() and _is_set(prev):
            clash = sorted(set(_foreign(prev)) & _staying(path, _foreign(path)))
            if clash:
                raise RelcalError(
                    f"{what}: {prev / clash[0]} was not written by relcal and the outputs "
                    f"about to be kept in {prev} include a file of that name; move it away"
                )


def check_file(item: File) -> None:
    """Refuse a file destination that is a folder, an input, a registry, or in an unwritable
    place."""
    check_destination(item)
    path = Path(item.path)
    what = f"{item.what} {path}"
    if is_stream(path):
        return
    if path.is_dir():
        raise RelcalError(f"{what}: is a folder; give a file name")
    if str(_real(path)).startswith(("/dev/", "/proc/")):
        raise RelcalError(f"{what}: no such device; relcal does not create files there")
    owner = _set_holding(path)
    if owner is not None:
        raise RelcalError(
            f"{what}: is a file of the output set {owner} (listed in its {MARKER}), which "
            "relcal replaces only as a whole: writing over it would leave that set with a "
            "file of another run; give another file name"
        )
    check_parent(path, item.what)


def _set_holding(path: Path) -> Path | None:
    """The output set (a folder with a manifest, at any depth above ``path``) that lists the
    existing file ``path`` as one of its own, else None."""
    if not path.is_file():
        return None
    real = _real(path)
    for folder in real.parents:
        if _is_set(folder):
            try:
                owned = _manifest_files(folder)
            except RelcalError:
                return None  # an unreadable manifest is named when the set itself is written
            return folder if str(real.relative_to(folder)) in owned else None
    return None


def _manifest_files(folder: Path) -> set[str]:
    """The files a set's manifest lists as its own (relative paths)."""
    try:
        manifest = json.loads((folder / MARKER).read_text())
        files = manifest.get("files") if isinstance(manifest, dict) else None
        if not isinstance(files, list):
            raise ValueError("no list of files")
    except (OSError, ValueError) as exc:
        raise RelcalError(
            f"{folder / MARKER}: unreadable ({exc}); relcal cannot tell its files from yours "
            "there: move the folder away (or give another --out)"
        ) from None
    return {str(f) for f in files}


def _foreign(folder: Path) -> list[str]:
    """The entries of a set ``folder`` that its manifest does not list as its own (relative
    paths, outermost: a folder holding none of the set's files is one entry)."""
    own = _manifest_files(folder) | {MARKER}
    prefixes = {str(Path(f).parent) for f in own}
    prefixes |= {str(p) for f in own for p in Path(f).parents}
    out: list[str] = []

    def walk(rel: Path) -> None:
        try:
            entries = sorted(os.scandir(folder / rel), key=lambda e: e.name)
        except OSError:
            return
        for e in entries:
            name = str(rel / e.name) if str(rel) != "." else e.name
            if e.is_dir(follow_symlinks=False):
                if name in prefixes:
                    walk(Path(name))
                else:
                    out.append(name)
            elif name not in own:
                out.append(name)

    walk(Path("."))
    return out


def _names_of(files: dict) -> set[str]:
    """The relative names of a set's files and the folders they are in."""
    names = set()
    for name in files:
        p = Path(name)
        names.add(str(p))
        names.update(str(q) for q in p.parents if str(q) != ".")
    return names


def check(items: Iterable[Folder | File]) -> None:
    """Check every destination (and that no two are the same) without writing anything; the
    run's declared destinations (:func:`declare`) are checked against its inputs too."""
    items = list(items)
    for item in _DECLARED:
        if not any(item is i or _same(item, i) for i in items):
            check_destination(item)
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


def _same(a: Folder | File, b: Folder | File) -> bool:
    return not _empty_path(a.path) and not _empty_path(b.path) and _real(a.path) == _real(b.path)


def declare(*items: Folder | File) -> None:
    """Declare destinations this run will write (before any work): each is checked now
    (:func:`check_destination`, and no two the same), and again against the run's inputs at
    every write of the run, so that no write happens while another destination of the run is
    an input (the command line declares every option that names an output)."""
    seen: dict[Path, str] = {}
    for item in items:
        check_destination(item)
        real = _real(item.path)
        if real in seen and not is_stream(item.path):
            raise RelcalError(f"{item.what} {item.path}: also given as {seen[real]}")
        seen[real] = f"{item.what} {item.path}"
    for item in items:
        for other in _DECLARED:
            if _same(item, other) and not is_stream(item.path):
                raise RelcalError(
                    f"{item.what} {item.path}: also given as {other.what} {other.path}"
                )
    _DECLARED.extend(items)


def declared() -> list[Folder | File]:
    """The destinations declared in this run (:func:`declare`)."""
    return list(_DECLARED)


def check_outside(path: str | Path, what: str, source: str | Path, source_what: str) -> None:
    """Refuse the output ``path`` (the option ``what``) inside the input folder ``source``
    (``source_what`` names it): outputs go where they are asked, never into the input tree."""
    source = Path(source)
    if source.is_dir() and _real(path).is_relative_to(_real(source)):
        raise RelcalError(
            f"{what} {path}: inside {source_what} {source}: the outputs would land in the input "
            "tree; give a folder outside it"
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


def _lock_fd(lock: Path, what: str, wait: bool) -> int | None:
    """Open ``lock`` (created if missing) and lock it; None where locks are not available or
    the file cannot be created (a read-only folder: nobody can write there either)."""
    try:
        import fcntl
    except ImportError:  # not POSIX
        return None
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError:
            return None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except OSError:
            holder = ""
            try:
                holder = os.pread(fd, 32, 0).decode(errors="replace").strip()
            except OSError:
                pass
            os.close(fd)
            raise RelcalError(
                f"{what}: another relcal run"
                + (f" (process {holder})" if holder.isdigit() else "")
                + " is writing it now; wait until it has finished, then run this again"
            ) from None
        try:  # the file may have been removed by the run that held it: lock the one in place
            same = os.path.samestat(os.fstat(fd), os.stat(lock))
        except OSError:
            same = False
        if same:
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
            return fd
        os.close(fd)


_LOCKS: dict[tuple, list] = {}  # lock files held, by (thread, path): [descriptor, depth]


@contextmanager
def exclusive(lock: str | Path, what: str, wait: bool = True) -> Iterator[None]:
    """Hold the lock file ``lock`` for the block: concurrent relcal runs that take the same lock
    wait for it (``wait``) or are refused with a message naming ``what`` (``wait=False``). The
    file holds the holder's process id and is removed when the block ends (a run killed with
    SIGKILL leaves it, unlocked: the next run takes it and removes it). Re-entrant within the
    thread: a block that holds the lock already takes it again without waiting (another thread
    of the process waits for it, as another process does)."""
    import threading

    lock = Path(os.path.abspath(lock))
    key = (threading.get_ident(), lock)  # another thread waits, as another process does
    if key in _LOCKS:  # held by this thread already (re-entrant)
        entry = _LOCKS[key]  # (an inner block closed late, by the garbage collector, may end
        entry[1] += 1  # after the outer one released the lock: it must not fail then)
        try:
            yield
        finally:
            entry[1] -= 1
        return
    fd = _lock_fd(lock, what, wait)
    _LOCKS[key] = [fd, 1]
    try:
        yield
    finally:
        del _LOCKS[key]
        if fd is not None:
            try:  # removed while still held: a waiting run then finds it gone and retries
                if os.path.samestat(os.fstat(fd), os.stat(lock)):
                    lock.unlink()
            except OSError:
                pass
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


def _stage_folder(item: Folder, holds: list[int], made: list[Path]) -> Path:
    path = Path(os.path.abspath(item.path))
    # created and locked before any cleanup can see it, and known to the caller before an
    # interrupt can land (else a temporary would outlive the run)
    with _signals_held(), _folder_locks([path.parent]):
        tmp = Path(tempfile.mkdtemp(dir=path.parent, prefix=f".{path.name}.tmp-{os.getpid()}-"))
        made.append(tmp)
        fd = _hold(tmp)
        if fd is not None:
            holds.append(fd)
    _fill_folder(tmp, item)  # (removed by the caller if this fails)
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


def _content(item: File) -> bytes:
    content = item.content() if callable(item.content) else item.content
    return content.encode() if isinstance(content, str) else content


def _stage_file(item: File, holds: list[int], made: list[Path]) -> Path | None:
    if is_stream(item.path):
        return None  # written at commit time
    path = _real(item.path)  # a symbolic link keeps pointing at the file, which is replaced
    path.parent.mkdir(parents=True, exist_ok=True)
    with _signals_held(), _folder_locks([path.parent]):
        tmp = _temp_file(path)
        made.append(tmp)
        fd = _hold(tmp)
        if fd is not None:
            holds.append(fd)
    _write_bytes(tmp, _content(item))  # (removed by the caller if this fails)
    os.chmod(tmp, 0o666 & ~_umask())
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


def _entries(folder: Path) -> set[str]:
    """Every file and folder under ``folder`` (relative paths)."""
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


def _staying(folder: Path, moved: list[str]) -> set[str]:
    """The entries of ``folder`` that stay in it once ``moved`` (and what they hold) are out."""
    out = set()
    for name in _entries(folder):
        parts = Path(name).parts
        if not any(parts[: len(Path(m).parts)] == Path(m).parts for m in moved):
            out.add(name)
    return out


def _carry(src: Path, dst: Path, names: list[str], undo: Undo) -> None:
    """Move the entries ``names`` (a user's files, not the set's) from the set ``src`` into the
    set ``dst``, each by one rename; ``undo`` gets what moves them back."""
    for name in names:
        a, b = src / name, dst / name
        missing = []
        parent = b.parent
        while not parent.exists() and parent != dst:
            missing.append(parent)
            parent = parent.parent
        for folder in reversed(missing):
            folder.mkdir()
            undo.append(folder.rmdir)
        if os.path.lexists(b):
            raise OSError(f"{b} exists; cannot keep {a} there")
        os.rename(a, b)
        undo.append(lambda a=a, b=b: os.rename(b, a))


def _commit_folder(tmp: Path, item: Folder, undo: Undo, trash: list[Path]) -> None:
    """Put the staged set ``tmp`` in place; the current set becomes ``.prev`` and the older
    ``.prev`` goes to ``trash`` (deleted once the run is complete). Entries the sets do not list
    as their own (a user's files) move along: those of the current set into the new one, those
    of the older ``.prev`` into the new ``.prev``, so that nothing of the user's is deleted.
    ``undo`` gets, step by step, what puts everything back."""
    path = Path(os.path.abspath(item.path))
    prev = _prev(path)
    if path.is_dir() and any(path.iterdir()):
        mine = _foreign(path)
        older = _foreign(prev) if prev.is_dir() and _is_set(prev) else []
        clash = sorted(set(mine) & _entries(tmp))
        if clash:
            raise RelcalError(
                f"{item.what} {item.path}: {path / clash[0]} was not written by relcal and this "
                "run writes a file of that name; move it out of the folder; nothing written"
            )
        clash = sorted(set(older) & _staying(path, mine))
        if clash:
            raise RelcalError(
                f"{item.what} {item.path}: {prev / clash[0]} was not written by relcal and the "
                f"outputs about to be kept in {prev} include a file of that name; move it away; "
                "nothing written"
            )
        if _exchange(tmp, path):  # new set in place; tmp holds the old one
            undo.append(lambda: _exchange(tmp, path))
            _carry(tmp, path, mine, undo)
            if prev.exists():
                if not _exchange(tmp, prev):  # the old set is .prev; tmp holds the older one
                    raise OSError(f"cannot exchange {tmp} and {prev}")
                undo.append(lambda: _exchange(tmp, prev))
                _carry(tmp, prev, older, undo)
                trash.append(tmp)
            else:
                os.rename(tmp, prev)
                undo.append(lambda: os.rename(prev, tmp))
        else:  # no atomic exchange here: three renames (the folder is missing for a moment)
            aside = None
            if prev.exists():
                aside = Path(f"{tmp}-older")
                os.rename(prev, aside)
                undo.append(lambda: os.rename(aside, prev))
                trash.append(aside)
            os.rename(path, prev)
            undo.append(lambda: os.rename(prev, path))
            os.rename(tmp, path)
            undo.append(lambda: os.rename(path, tmp))
            _carry(prev, path, mine, undo)
            if aside is not None:
                _carry(aside, prev, older, undo)
    else:
        if path.is_dir():
            path.rmdir()
            undo.append(path.mkdir)
        os.rename(tmp, path)
        undo.append(lambda: os.rename(path, tmp))
    _fsync_path(path.parent)


def _write_stream(item: File) -> None:
    data = _content(item)
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
    failure the staged files are removed and the disk is as it was. A :class:`File` whose
    content is a function is staged once the journal is prepared (a document that quotes the
    id of its record).
    """
    check(items)
    files = [i for i in items if not is_stream(i.path)]
    created = _missing_parents(files)  # removed again if the write fails
    staged: list[tuple[Folder | File, Path | None]] = []
    made: list[Path] = []  # every temporary this write created, removed unless committed
    holds: list[int] = []
    undo: Undo = []
    trash: list[Path] = []
    prepared = committed = False

    def stage(group: list[Folder | File]) -> None:
        for item in group:
            with _naming(item):
                if isinstance(item, Folder):
                    staged.append((item, _stage_folder(item, holds, made)))
                else:
                    staged.append((item, _stage_file(item, holds, made)))
        # streams once the rest is staged: a full disk or a closed pipe stops the run before
        for item in group:  # any rename
            if isinstance(item, File) and is_stream(item.path):
                with _naming(item):
                    _write_stream(item)

    try:
        for item in files:
            with _naming(item):
                Path(os.path.abspath(item.path)).parent.mkdir(parents=True, exist_ok=True)
        parents = [Path(os.path.abspath(i.path)).parent for i in files]
        with _folder_locks(parents):
            remove_stale(*files)
        late = [i for i in items if isinstance(i, File) and callable(i.content)]
        stage([i for i in items if not any(i is j for j in late)])
        if journal is not None:
            journal.prepare()
            prepared = True
        stage(late)
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
            for i in items:
                note_written(_describe(i))
            if journal is not None:
                note_written(journal.describe())
            made, created = [], []
    finally:  # held too: an interrupt in the middle of the clean-up would leave half-removed
        with _signals_held():  # temporaries (delivered once it is done)
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
            for tmp in made:
                if tmp.is_dir() and not tmp.is_symlink():
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
