"""The calibration registry: one record per calibration, in any SQL database SQLAlchemy reaches.

A registry is a SQLite file by default (``--registry PATH`` or the ``RELCAL_REGISTRY`` variable)
or any SQLAlchemy URL (``postgresql+psycopg://user@host/relcal``), so a plant can point all its
cells at one server. The schema is versioned by the Alembic migrations shipped in
``relcal/fleet/migrations`` and brought to the newest revision whenever a registry is opened.

Concurrent writers are safe: every record is one short ``INSERT`` transaction; SQLite runs in WAL
mode with a busy timeout (readers never block the writer, writers queue), and a write that still
finds the database locked is retried with a randomised back-off. Migrations of a SQLite file are
serialised by a lock file beside it (``NAME.lock``, present only while a migration runs: it is
removed when the lock is released; besides it, SQLite's own ``-wal`` and ``-shm``).

**Opening is checking.** :func:`open_for_writing` runs before any computation and refuses, with a
message naming the registry, a path that is a folder, a device, a file this run reads (an input
is never turned into a database), a file that is not a SQLite database, a corrupt database, a
database of another program, a schema newer than this relcal knows, a database or folder that
cannot be written, or a server that cannot be reached. A SQLite file that does not exist yet is
only checked (its folder exists and is writable) and created when the first record is written,
so a run refused later leaves no file behind. A record is written by :meth:`Registry.pending`, a
:class:`relcal.outputset.Journal`: the row is inserted in a transaction that commits only once
the outputs are in place (:func:`relcal.outputset.write_set`).

Parameters, standard deviations and covariances are stored in SI units (m, rad) with their names.
"""

from __future__ import annotations

import contextlib
import os
import random
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import sqlalchemy as sa

from relcal.errors import RelcalError

ENV = "RELCAL_REGISTRY"
MIGRATIONS = Path(__file__).resolve().parent / "migrations"
BUSY_TIMEOUT_S = 30.0
RETRIES = 12

T = TypeVar("T")

metadata = sa.MetaData()
calibrations = sa.Table(
    "calibrations",
    metadata,
    sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
    sa.Column("uid", sa.String(32), nullable=False, unique=True),
    sa.Column("robot_id", sa.String(200), nullable=False),
    sa.Column("session", sa.String(200)),
    sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
    sa.Column("relcal_version", sa.String(40), nullable=False),
    sa.Column("model_name", sa.String(200), nullable=False),
    sa.Column("dataset_path", sa.Text, nullable=False),
    sa.Column("outputs_path", sa.Text),
    sa.Column("settings", sa.JSON, nullable=False),
    sa.Column("input_hashes", sa.JSON, nullable=False),
    sa.Column("converged", sa.Boolean, nullable=False),
    sa.Column("rank", sa.Integer, nullable=False),
    sa.Column("parameters", sa.JSON, nullable=False),
    sa.Column("covariance", sa.JSON, nullable=False),
    sa.Column("baseline_position_rms_mm", sa.Float),
    sa.Column("baseline_orientation_rms_deg", sa.Float),
    sa.Column("calibrated_position_rms_mm", sa.Float),
    sa.Column("calibrated_orientation_rms_deg", sa.Float),
    sa.Column("validation", sa.JSON),
)
verifications = sa.Table(
    "verifications",
    metadata,
    sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
    sa.Column("uid", sa.String(32), nullable=False, unique=True),
    sa.Column("calibration_id", sa.Integer),  # the calibration's run in this registry, if known
    sa.Column("calibration", sa.Text, nullable=False),  # what was verified, in words
    sa.Column("robot_id", sa.String(200), nullable=False),
    sa.Column("session", sa.String(200)),
    sa.Column("dataset_path", sa.Text, nullable=False),
    sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
    sa.Column("relcal_version", sa.String(40), nullable=False),
    sa.Column("kind", sa.String(20), nullable=False),
    sa.Column("n_samples", sa.Integer, nullable=False),
    sa.Column("folds", sa.Integer, nullable=False),
    sa.Column("baseline_position_rms_mm", sa.Float),
    sa.Column("calibrated_position_rms_mm", sa.Float),
    sa.Column("baseline_orientation_rms_deg", sa.Float),
    sa.Column("calibrated_orientation_rms_deg", sa.Float),
    sa.Column("ratio_position", sa.Float),
    sa.Column("at_calibration_position_rms_mm", sa.Float),
    sa.Column("verdict", sa.String(20), nullable=False),
    sa.Column("intervals", sa.JSON, nullable=False),
    sa.Column("details", sa.JSON, nullable=False),
)
ERROR_COLUMNS = (
    "baseline_position_rms_mm",
    "baseline_orientation_rms_deg",
    "calibrated_position_rms_mm",
    "calibrated_orientation_rms_deg",
)


@dataclass(frozen=True)
class Run:
    """One stored calibration. ``parameters``: one mapping per parameter with ``name``, ``unit``
    (SI: ``m``, ``rad``, ``1`` for a joint scale, ``rad/(N m)`` or ``m/N`` for a compliance;
    older records wrote ``m`` for all but angles), ``value`` (identified error relative
    to nominal, or None when not estimated), ``std`` (or None), ``identifiable``, ``estimated``
    (in the solved subset) and ``status`` (results.json's: ``estimated``, ``combination``, ...;
    newer records).
    ``covariance``: ``{"names": [...], "matrix": [[...]]}`` over the estimated subset, SI."""

    id: int
    uid: str
    robot_id: str
    session: str | None
    created_at: datetime
    relcal_version: str
    model_name: str
    dataset_path: str
    outputs_path: str | None
    settings: dict
    input_hashes: dict
    converged: bool
    rank: int
    parameters: list[dict]
    covariance: dict
    errors: dict  # the four ERROR_COLUMNS (mm, deg), None where no held-out set
    validation: dict | None

    @property
    def names(self) -> list[str]:
        return [p["name"] for p in self.parameters]

    @property
    def labels(self) -> dict[str, str]:
        """``{name: label}`` where a parameter is shown by another name than its key (robots
        loaded from a URDF: joint parameters named after their joints), as the calibration
        showed them (:func:`relcal.robot.kinematics.parameter_label`); empty for older records
        and robots with numbered joints."""
        return dict(self.settings.get("parameter_labels") or {})

    def label(self, name: str) -> str:
        """The name parameter ``name`` is shown by (:attr:`labels`)."""
        return self.labels.get(name, name)

    def parameter(self, name: str) -> dict:
        for p in self.parameters:
            if p["name"] == name:
                return p
        raise KeyError(name)

    def covariance_of(self, names: list[str]) -> np.ndarray:
        """The ``(k, k)`` covariance (SI) of ``names``, all in the estimated subset."""
        where = {n: i for i, n in enumerate(self.covariance["names"])}
        idx = [where[n] for n in names]
        matrix = np.asarray(self.covariance["matrix"], dtype=float)
        return matrix[np.ix_(idx, idx)] if idx else np.zeros((0, 0))


@dataclass(frozen=True)
class VerificationRun:
    """One stored verification: a calibration's prediction errors on a new session, nuisance
    refitted (``relcal verify``). Errors in mm and degrees; ``intervals`` holds the 95 %
    intervals (``baseline_position_mm``, ``calibrated_position_mm``, ``ratio_position``, ... as
    ``[low, high]``), ``details`` the verdict's reason, warnings and the joints outside the
    calibration's ranges."""

    id: int
    uid: str
    calibration_id: int | None
    calibration: str
    robot_id: str
    session: str | None
    dataset_path: str
    created_at: datetime
    relcal_version: str
    kind: str
    n_samples: int
    folds: int
    baseline_position_rms_mm: float | None
    calibrated_position_rms_mm: float | None
    baseline_orientation_rms_deg: float | None
    calibrated_orientation_rms_deg: float | None
    ratio_position: float | None
    at_calibration_position_rms_mm: float | None
    verdict: str
    intervals: dict
    details: dict


def registry_url(where: str | os.PathLike | None = None) -> str | None:
    """The SQLAlchemy URL of ``where`` (a URL, or a path of a SQLite file), else of
    ``$RELCAL_REGISTRY``, else None (no registry)."""
    where = where if where not in (None, "") else os.environ.get(ENV) or None
    if where is None:
        return None
    text = str(where)
    if "://" in text:
        return text
    path = Path(text).expanduser().resolve()
    return f"sqlite:///{path}"


def _is_sqlite(url: sa.URL) -> bool:
    return url.get_backend_name() == "sqlite"


def _locked(exc: BaseException) -> bool:
    """A transient lock or serialisation conflict worth retrying."""
    text = str(getattr(exc, "orig", exc)).lower()
    return any(
        word in text for word in ("locked", "busy", "could not serialize", "deadlock", "exists")
    )


def _reason(exc: BaseException) -> str:
    """The database's own words for an error (one line), with the usual causes named."""
    text = str(getattr(exc, "orig", exc)).strip().splitlines()[0] if str(exc) else repr(exc)
    low = text.lower()
    if "not a database" in low or "malformed" in low:
        return f"{text} (the file is corrupt or not a SQLite database)"
    if (
        "readonly" in low
        or "read-only" in low
        or "permission denied" in low
        or "unable to open" in low
    ):
        return f"{text} (the database or its folder cannot be written)"
    return text


def _retry(action: Callable[[], T], what: str) -> T:
    """``action()``, retried with a randomised exponential back-off while the database is busy."""
    delay = 0.05
    for attempt in range(RETRIES + 1):
        try:
            return action()
        except sa.exc.DBAPIError as exc:
            if attempt == RETRIES or not _locked(exc):
                raise RelcalError(f"registry: {what} failed: {_reason(exc)}") from None
            time.sleep(delay * (1 + random.random()))
            delay = min(delay * 2, 2.0)
    raise AssertionError("unreachable")


@contextlib.contextmanager
def _file_lock(path: Path | None) -> Iterator[None]:
    """An exclusive lock on ``path`` (:func:`relcal.outputset.exclusive`: the file is removed
    when the lock is released); a no-op without a path."""
    if path is None:
        yield
        return
    from relcal.outputset import exclusive

    with exclusive(path, f"registry {path.with_suffix('')} (migration lock)"):
        yield


def _alembic_config(connection: sa.Connection):
    from alembic.config import Config

    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS))
    config.attributes["connection"] = connection
    return config


def head_revision() -> str:
    """The newest schema revision shipped with this relcal."""
    from alembic.script import ScriptDirectory

    config = _alembic_config(None)  # type: ignore[arg-type]
    return ScriptDirectory.from_config(config).get_current_head()


def current_revision(engine: sa.Engine) -> str | None:
    """The schema revision of the database (None for an empty one)."""
    from alembic.runtime.migration import MigrationContext

    with engine.connect() as conn:
        return MigrationContext.configure(conn).get_current_revision()


def known_revisions() -> set[str]:
    """Every schema revision shipped with this relcal."""
    from alembic.script import ScriptDirectory

    script = ScriptDirectory.from_config(_alembic_config(None))  # type: ignore[arg-type]
    return {rev.revision for rev in script.walk_revisions()}


def _lock_path(url: sa.URL) -> Path | None:
    """The lock file that serialises migrations of a SQLite registry (beside it)."""
    if _is_sqlite(url) and url.database and url.database != ":memory:":
        return Path(url.database + ".lock")
    return None


def migrate(engine: sa.Engine, revision: str = "head", locked: bool = False) -> None:
    """Bring the schema to ``revision`` (default the newest) with the shipped migrations
    (``locked``: the caller holds the migration lock already)."""
    from alembic import command

    def upgrade() -> None:
        with engine.begin() as conn:
            command.upgrade(_alembic_config(conn), revision)

    with _file_lock(None if locked else _lock_path(engine.url)):
        _retry(upgrade, "schema migration")


def _parse_url(url: str) -> sa.URL:
    try:
        return sa.make_url(url)
    except sa.exc.ArgumentError as exc:
        raise RelcalError(f"registry {url!r}: not a SQLAlchemy URL or file path ({exc})") from None


def _engine(url: str) -> sa.Engine:
    parsed = _parse_url(url)
    if _is_sqlite(parsed):
        if parsed.database and parsed.database != ":memory:":
            folder = Path(parsed.database).parent
            if not folder.is_dir():
                raise RelcalError(f"registry {parsed.database}: folder {folder} does not exist")
        engine = sa.create_engine(parsed, connect_args={"timeout": BUSY_TIMEOUT_S})

        @sa.event.listens_for(engine, "connect")
        def _pragmas(dbapi_connection, _record) -> None:
            cursor = dbapi_connection.cursor()
            cursor.execute(f"PRAGMA busy_timeout = {int(BUSY_TIMEOUT_S * 1000)}")
            cursor.execute("PRAGMA synchronous = NORMAL")
            cursor.close()

        return engine
    connect_args = {"connect_timeout": 10} if parsed.get_backend_name() == "postgresql" else {}
    try:
        return sa.create_engine(parsed, pool_pre_ping=True, connect_args=connect_args)
    except (ImportError, sa.exc.NoSuchModuleError) as exc:
        raise RelcalError(
            f"registry {parsed.render_as_string(hide_password=True)}: no database driver "
            f"({exc}); install it, e.g. pip install 'relcal[postgresql]'"
        ) from None


def _sqlite_path(url: sa.URL) -> Path | None:
    """The file of a SQLite URL (None for other databases and in-memory SQLite)."""
    if not _is_sqlite(url) or not url.database or url.database == ":memory:":
        return None
    if url.database.startswith("file:"):  # a URI filename: file:PATH?mode=ro
        return Path(url.database[5:].split("?", 1)[0]).resolve()
    return Path(url.database).resolve()


SQLITE_MAGIC = b"SQLite format 3\x00"


def check_sqlite_path(path: Path, write: bool) -> bool:
    """Refuse a SQLite registry path that cannot be one (see the module docstring), without
    creating anything; True when the file exists."""
    from relcal.outputset import inputs, is_stream

    where = f"registry {path}"
    if path in inputs():
        raise RelcalError(
            f"{where}: is a file this run reads (an input); a registry is a database of its own, "
            "and relcal never turns an input into one: give another path, e.g. history.sqlite"
        )
    if path.is_dir():
        raise RelcalError(f"{where}: is a folder; give a database file path, e.g. {path}/h.sqlite")
    if path.exists() and (is_stream(path) or not path.is_file()):
        raise RelcalError(f"{where}: not a regular file (a device or pipe); give a file path")
    if not path.exists():
        folder = path.parent
        if not folder.is_dir():
            raise RelcalError(f"{where}: folder {folder} does not exist")
        if write and not os.access(folder, os.W_OK | os.X_OK):
            raise RelcalError(f"{where}: cannot create it: folder {folder} is not writable")
        return False
    try:
        with open(path, "rb") as handle:
            head = handle.read(len(SQLITE_MAGIC))
    except OSError as exc:
        raise RelcalError(f"{where}: cannot read: {exc.strerror or exc}") from None
    if head and head != SQLITE_MAGIC:
        raise RelcalError(
            f"{where}: not a SQLite database (a file of another kind, {path.stat().st_size} "
            "bytes); relcal never turns another file into a registry: give a new file name or an "
            "existing registry"
        )
    if write and not os.access(path, os.W_OK):
        raise RelcalError(f"{where}: read-only (no write permission); records cannot be added")
    if write and not os.access(path.parent, os.W_OK | os.X_OK):
        raise RelcalError(
            f"{where}: its folder {path.parent} is not writable (SQLite needs it for its journal)"
        )
    return True


def _check_database(conn: sa.Connection, name: str) -> None:
    """Refuse a corrupt database, one of another program, or a schema newer than this relcal."""
    from alembic.runtime.migration import MigrationContext

    if conn.dialect.name == "sqlite":
        result = conn.execute(sa.text("PRAGMA quick_check")).scalars().all()
        if result != ["ok"]:
            first = str(result[0]).strip().splitlines()[0] if result else "no answer"
            raise RelcalError(
                f"corrupt SQLite database ({first}); restore it from a backup or give a new file"
            )
    tables = set(sa.inspect(conn).get_table_names())
    revision = MigrationContext.configure(conn).get_current_revision()
    # a SQLite file is one program's; a server database may hold other programs' tables beside
    # relcal's, but not a calibrations table relcal did not make
    foreign = (
        tables - {"alembic_version"} if conn.dialect.name == "sqlite" else tables & {"calibrations"}
    )
    if revision is None and foreign:
        shown = ", ".join(sorted(foreign)[:5])
        raise RelcalError(
            f"a database of another program (tables {shown}), not a relcal registry; give a new "
            "file or an existing registry"
        )
    if revision is not None and revision not in known_revisions():
        raise RelcalError(
            f"schema revision {revision!r} is newer than this relcal knows (up to "
            f"{head_revision()!r}): written by a newer relcal; upgrade relcal to use it"
        )


def _probe_write(engine: sa.Engine) -> None:
    """A write that changes nothing (an insert of no rows, rolled back): the database, its
    folder and the user's privileges allow records."""

    def probe() -> None:
        with engine.connect() as conn:
            with conn.begin() as txn:
                conn.execute(
                    calibrations.insert().from_select(
                        ["uid"], sa.select(sa.literal("probe")).where(sa.false())
                    )
                )
                txn.rollback()

    _retry(probe, "checking that records can be written")


class PendingRecord:
    """One record written as a :class:`relcal.outputset.Journal`: ``prepare`` inserts it in an
    open transaction, ``commit`` commits, ``rollback`` forgets it. For a SQLite registry that
    does not exist yet, ``prepare`` creates and migrates it under the migration lock (held until
    the end), and ``rollback`` removes it again."""

    def __init__(
        self, registry: Registry, record: dict[str, Any], table: sa.Table | None = None
    ) -> None:
        self.registry = registry
        self.table = calibrations if table is None else table
        self.row = _row(record) if table is None else _verification_row(record)
        self.what = "calibration" if table is None else "verification"
        self.run_id: int | None = None
        self._conn: sa.Connection | None = None
        self._txn = None
        self._lock = None
        self._created = False

    def prepare(self) -> None:
        reg = self.registry
        if reg._create:
            self._lock = _file_lock(_lock_path(reg.engine.url))
            self._lock.__enter__()
            self._created = not reg.path.exists()  # type: ignore[union-attr]
            reg._open(write=True, locked=True)

        def insert() -> int:
            conn = reg.engine.connect()
            txn = conn.begin()
            try:
                key = conn.execute(self.table.insert().values(**self.row)).inserted_primary_key
            except BaseException:
                txn.rollback()
                conn.close()
                raise
            self._conn, self._txn = conn, txn
            return int(key[0])

        self.run_id = _retry(insert, f"recording the {self.what} of {self.row.get('robot_id')}")

    def commit(self) -> None:
        try:
            self._txn.commit()  # type: ignore[union-attr]
        except sa.exc.DBAPIError as exc:
            self._close(remove=self._created)
            raise RelcalError(
                f"registry {self.registry.name}: recording the {self.what} failed: {_reason(exc)}"
            ) from None
        self._close()
        self.registry._create = False

    def rollback(self) -> None:
        try:
            if self._txn is not None:
                self._txn.rollback()
        finally:
            self._close(remove=self._created)

    def _close(self, remove: bool = False) -> None:
        """Close the connection; ``remove``: delete the SQLite file this record created (while
        the migration lock is still held); then release the lock."""
        if self._conn is not None:
            self._conn.close()
            self._conn = self._txn = None
        if remove and self._lock is not None and self.registry.path is not None:
            self.registry.engine.dispose()
            for suffix in ("", "-wal", "-shm", "-journal"):
                Path(f"{self.registry.path}{suffix}").unlink(missing_ok=True)
        self._created = False
        if self._lock is not None:
            self._lock.__exit__(None, None, None)
            self._lock = None

    def describe(self) -> str:
        if self.what == "verification":
            return f"registry {self.registry.name} verification {self.run_id}"
        return f"registry {self.registry.name} run {self.run_id}"


def _filled(row: dict[str, Any], table, what: str) -> dict[str, Any]:
    """``row`` with ``uid`` and ``created_at`` filled in when missing, checked against the
    columns of ``table`` (an unknown key is a ``ValueError`` naming the ``what`` fields)."""
    row.setdefault("uid", uuid.uuid4().hex)
    row.setdefault("created_at", datetime.now(UTC))
    unknown = set(row) - set(table.c.keys())
    if unknown:
        raise ValueError(f"unknown {what} fields: {sorted(unknown)}")
    return row


def _verification_row(record: dict[str, Any]) -> dict[str, Any]:
    """The table row of a verification record (``uid`` and ``created_at`` filled in)."""
    return _filled(dict(record), verifications, "verification")


def _row(record: dict[str, Any]) -> dict[str, Any]:
    """The table row of a record (the keys of :class:`Run` but ``id``; ``uid`` and
    ``created_at`` filled in when missing)."""
    row = {k: v for k, v in record.items() if k != "errors"}
    row.update(record.get("errors") or {})
    return _filled(row, calibrations, "registry")


class Registry:
    """A calibration registry at a SQLAlchemy URL (see :func:`registry_url`), checked and
    migrated on open (see the module docstring).

    ``write``: also check that records can be written (before any computation), and for a SQLite
    file that does not exist yet, create it only when the first record is written
    (:meth:`pending`)."""

    def __init__(self, url: str, write: bool = False) -> None:
        self.url = url
        self.engine = _engine(url)
        self.name = self.engine.url.render_as_string(hide_password=True)
        self.path = _sqlite_path(self.engine.url)
        self._create = False  # a SQLite file to create with the first record
        if self.path is not None:
            from relcal.outputset import note_registry

            self.name = str(self.path)
            exists = check_sqlite_path(self.path, write)
            note_registry(self.path)  # never an output of this run
            if not exists and write:
                self._create = True
                return
        try:
            self._open(write)
        except BaseException:
            self.engine.dispose()
            raise

    def _open(self, write: bool, locked: bool = False) -> None:
        """Check the schema and the database, migrate, and (``write``) probe a write.

        SQLite's driver commits each DDL statement of a migration on its own, so a check beside
        another process's migration can see its tables before its revision and take the file
        for another program's: a refusal is confirmed under the migration lock (whose file is
        removed again when it is released)."""

        def check() -> None:
            with self.engine.connect() as conn:
                _check_database(conn, self.name)
                if conn.dialect.name == "sqlite":  # WAL (kept in the file) once it is ours
                    with contextlib.suppress(sa.exc.DBAPIError):  # another process may be too
                        conn.exec_driver_sql("PRAGMA journal_mode = WAL")

        try:
            try:
                check()
            except RelcalError:
                lock = _lock_path(self.engine.url)
                if locked or lock is None:
                    raise
                with _file_lock(lock):  # a migration may be under way: look once it is done
                    check()
            migrate(self.engine, locked=locked)
            if write:
                _probe_write(self.engine)
        except RelcalError as exc:
            text = str(exc).removeprefix("registry: ")
            raise RelcalError(f"registry {self.name}: {text}") from None
        except sa.exc.DBAPIError as exc:
            raise RelcalError(f"registry {self.name}: cannot open: {_reason(exc)}") from None
        except sa.exc.SQLAlchemyError as exc:
            raise RelcalError(f"registry {self.name}: cannot open: {exc}") from None

    def pending(self, record: dict[str, Any]) -> PendingRecord:
        """The record as a :class:`relcal.outputset.Journal`: inserted in a transaction that
        :func:`relcal.outputset.write_set` commits once the outputs are in place."""
        return PendingRecord(self, record)

    def __repr__(self) -> str:
        return f"Registry({self.engine.url.render_as_string(hide_password=True)!r})"

    def close(self) -> None:
        self.engine.dispose()

    def __enter__(self) -> Registry:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def add(self, record: dict[str, Any]) -> int:
        """Store one record (the keys of :class:`Run` but ``id``; ``uid`` and ``created_at``
        are filled in when missing); its id."""
        if self._create:  # a new SQLite file: created (and migrated) with its first record
            pending = self.pending(record)
            pending.prepare()
            pending.commit()
            return int(pending.run_id)  # type: ignore[arg-type]
        row = _row(record)

        def insert() -> int:
            with self.engine.begin() as conn:
                return int(
                    conn.execute(calibrations.insert().values(**row)).inserted_primary_key[0]
                )

        return _retry(insert, f"recording the calibration of {row.get('robot_id')}")

    def _select(self, query) -> list[Run]:
        if self._create:  # not created yet: no runs
            return []

        def read() -> list[Run]:
            with self.engine.connect() as conn:
                return [_run(r) for r in conn.execute(query).mappings()]

        return _retry(read, "reading")

    def runs(self, robot_id: str | None = None) -> list[Run]:
        """Every run (of one robot), oldest first."""
        query = sa.select(calibrations).order_by(calibrations.c.created_at, calibrations.c.id)
        if robot_id is not None:
            query = query.where(calibrations.c.robot_id == robot_id)
        return self._select(query)

    def pending_verification(self, record: dict[str, Any]) -> PendingRecord:
        """A verification record as a :class:`relcal.outputset.Journal` (see :meth:`pending`):
        written in one transaction with the files that report it."""
        return PendingRecord(self, record, verifications)

    def add_verification(self, record: dict[str, Any]) -> int:
        """Store one verification (the keys of :class:`VerificationRun` but ``id``; ``uid`` and
        ``created_at`` are filled in when missing); its id."""
        if self._create:  # a new SQLite file: created (and migrated) with its first record
            pending = self.pending_verification(record)
            pending.prepare()
            pending.commit()
            return int(pending.run_id)  # type: ignore[arg-type]
        row = _verification_row(record)

        def insert() -> int:
            with self.engine.begin() as conn:
                return int(
                    conn.execute(verifications.insert().values(**row)).inserted_primary_key[0]
                )

        return _retry(insert, f"recording the verification of {row.get('robot_id')}")

    def verifications(
        self, robot_id: str | None = None, calibration_id: int | None = None
    ) -> list[VerificationRun]:
        """Every verification (of one robot, or of one calibration run), oldest first."""
        query = sa.select(verifications).order_by(verifications.c.created_at, verifications.c.id)
        if robot_id is not None:
            query = query.where(verifications.c.robot_id == robot_id)
        if calibration_id is not None:
            query = query.where(verifications.c.calibration_id == calibration_id)

        if self._create:  # not created yet: no verifications
            return []

        def read() -> list[VerificationRun]:
            with self.engine.connect() as conn:
                return [_verification(r) for r in conn.execute(query).mappings()]

        return _retry(read, "reading the verifications")

    def robots(self) -> list[str]:
        query = sa.select(calibrations.c.robot_id).distinct().order_by(calibrations.c.robot_id)

        if self._create:
            return []

        def read() -> list[str]:
            with self.engine.connect() as conn:
                return [r[0] for r in conn.execute(query)]

        return _retry(read, "reading")

    def get(self, ref: str | int) -> Run:
        """A run by id (``12``) or by a unique prefix of its uid (at least 6 characters)."""
        text = str(ref).strip()
        found = []
        if text.isdigit():
            found = self._select(sa.select(calibrations).where(calibrations.c.id == int(text)))
        if not found and len(text) >= 6:  # a uid prefix (which may be all digits)
            found = self._select(
                sa.select(calibrations).where(calibrations.c.uid.startswith(text.lower()))
            )
        if len(found) != 1:
            what = "no run" if not found else f"{len(found)} runs"
            raise RelcalError(
                f"registry {self.engine.url.render_as_string(hide_password=True)}: {what} with "
                f"id or uid {text!r} (give the number of `relcal history`, or 6+ uid characters)"
            )
        return found[0]


def _run(row) -> Run:
    created = row["created_at"]
    if created.tzinfo is None:  # SQLite stores naive datetimes; relcal writes UTC
        created = created.replace(tzinfo=UTC)
    return Run(
        id=row["id"],
        uid=row["uid"],
        robot_id=row["robot_id"],
        session=row["session"],
        created_at=created,
        relcal_version=row["relcal_version"],
        model_name=row["model_name"],
        dataset_path=row["dataset_path"],
        outputs_path=row["outputs_path"],
        settings=row["settings"],
        input_hashes=row["input_hashes"],
        converged=bool(row["converged"]),
        rank=row["rank"],
        parameters=row["parameters"],
        covariance=row["covariance"],
        errors={k: row[k] for k in ERROR_COLUMNS},
        validation=row["validation"],
    )


def _verification(row) -> VerificationRun:
    created = row["created_at"]
    if created.tzinfo is None:  # SQLite stores naive datetimes; relcal writes UTC
        created = created.replace(tzinfo=UTC)
    return VerificationRun(**{**row, "created_at": created})


def open_registry(where: str | os.PathLike | None = None, create: bool = True) -> Registry | None:
    """The registry at ``where`` (URL or SQLite path), else at ``$RELCAL_REGISTRY``, else None.
    ``create=False``: a SQLite file that does not exist is an error (reading commands)."""
    url = registry_url(where)
    if url is None:
        return None
    parsed = _parse_url(url)
    path = _sqlite_path(parsed)
    if not create and path is not None and not path.exists():
        raise RelcalError(f"registry {path}: no such file (nothing recorded yet?)")
    return Registry(url)


def open_for_writing(where: str | os.PathLike | None = None, outputs=()) -> Registry | None:
    """The registry at ``where`` (else ``$RELCAL_REGISTRY``, else None) for a command that will
    record: opened, migrated and checked now, before any computation (see the module
    docstring). Call it after the inputs are read (an input is refused as a registry), with the
    run's ``outputs`` (:class:`relcal.outputset.Folder` and ``File`` items: a registry that is
    one of them or inside an output folder is refused)."""
    url = registry_url(where)
    if url is None:
        return None
    path = _sqlite_path(_parse_url(url))
    if path is not None:
        from relcal.outputset import check_apart

        check_apart(path, f"registry {path}", outputs)
    return Registry(url, write=True)


def require_registry(where: str | os.PathLike | None) -> Registry:
    """:func:`open_registry` for commands that read one: an error naming both ways to give it."""
    registry = open_registry(where, create=False)
    if registry is None:
        raise RelcalError(f"no registry: give --registry PATH|URL or set {ENV}")
    return registry


def run_from_record(record: dict[str, Any], id: int = 0) -> Run:
    """A :class:`Run` of a record not (yet) stored: for comparisons without a registry."""
    fields = {k: v for k, v in record.items() if k != "errors"}
    fields.setdefault("uid", "")
    fields.setdefault("session", None)
    fields.setdefault("created_at", datetime.now(UTC))
    errors = {k: (record.get("errors") or {}).get(k) for k in ERROR_COLUMNS}
    return Run(id=id, errors=errors, **fields)
