"""Persistence: the episodes table (SQLModel on SQLAlchemy 2.x), SQLite by default.

Only the API process writes the database; worker processes report to it through the job
runner. SQLite runs in WAL mode so readers never wait for the writer; ``DATABASE_URL`` selects
another database (PostgreSQL: ``postgresql+psycopg://user:password@host/db``).

The schema is made and upgraded by the Alembic revisions in ``hptvsim/service/migrations``:
opening a :class:`Store` upgrades its database to the newest revision (a fresh database gets
every revision; a database made by 0.1.0, which has the ``episodes`` table but no
``alembic_version`` table, is stamped ``0001`` first), so an existing database survives an
upgrade of hptvsim. Services starting together on one database upgrade it one at a time:
PostgreSQL under a transaction-level advisory lock, SQLite under ``BEGIN IMMEDIATE``.

On startup :meth:`Store.recover` turns every ``queued`` or ``running`` row left by a previous
process into ``interrupted`` (or ``finished``, when the episode's worker had completed and written
its result file before the API went down), so a restart loses no finished episode.

A database that fails is told apart from one that works: :meth:`Store.heartbeat` writes the one
row of the ``heartbeat`` table (revision 0003), which ``/healthz`` uses to check that the database
takes a write now; and a SQLite file deleted or replaced while the service runs (whose open
connections would go on writing into the deleted file, and whose new connections would make an
empty one) is noticed by comparing the path's device and inode with those of the file opened at
start, before every use: the store then raises :class:`DatabaseUnavailableError` instead.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sqlalchemy import JSON, Column, Index, delete, event, func, inspect, make_url, text, update
from sqlalchemy.engine import Connection, Engine
from sqlalchemy.pool import NullPool
from sqlmodel import Field, Session, SQLModel, col, create_engine, select

if TYPE_CHECKING:
    from alembic.config import Config

__all__ = [
    "ACTIVE",
    "BASELINE_REVISION",
    "FINAL",
    "STATUSES",
    "DatabaseUnavailableError",
    "EpisodeRow",
    "HeartbeatRow",
    "Store",
    "migration_config",
    "upgrade_schema",
    "utcnow",
]

STATUSES: tuple[str, ...] = ("queued", "running", "finished", "failed", "cancelled", "interrupted")
"""Every episode status; the first two are active, the rest final."""
ACTIVE: tuple[str, ...] = ("queued", "running")
FINAL: tuple[str, ...] = ("finished", "failed", "cancelled", "interrupted")

MIGRATIONS = Path(__file__).with_name("migrations")
"""The Alembic script folder (shipped inside the package)."""
BASELINE_REVISION = "0001"
"""The revision of the schema 0.1.0 made with ``create_all`` (before migrations existed)."""
_BASELINE_COLUMNS = (
    "id", "mode", "status", "label", "scenario", "seed", "max_steps", "backend", "sensor_fidelity",
    "agents", "policies", "policy_list", "config", "versions", "summary", "steps", "error",
    "recording_path", "trajectory_path", "created_at", "started_at", "finished_at",
)  # fmt: skip
PG_CONNECT_TIMEOUT_S = 10
"""Longest wait for a new PostgreSQL connection [s] (a server that does not answer fails, not hangs)."""
_PG_LOCK_KEY = 0x68707476_73696D00  # "hptvsim\0": the advisory lock of schema upgrades
_MIGRATING = threading.Lock()  # Alembic's ``context``/``op`` are module globals: one run per process


class DatabaseUnavailableError(RuntimeError):
    """The database cannot be used any more (its SQLite file was deleted or replaced).

    The message is short and safe to show a client (no paths).
    """


def utcnow() -> datetime:
    """The current time in UTC (timezone-aware)."""
    return datetime.now(UTC)


class EpisodeRow(SQLModel, table=True):
    """One episode: its configuration, status, results and files."""

    __tablename__ = "episodes"
    # the list filters by status and orders by creation time (revision 0002)
    __table_args__ = (Index("ix_episodes_status_created_at", "status", "created_at"),)

    id: str = Field(primary_key=True, max_length=32)
    mode: str = Field(default="run", index=True, max_length=16)  # "run" or "interactive"
    status: str = Field(default="queued", max_length=16)
    label: str = Field(default="", max_length=200)
    scenario: str = Field(index=True, max_length=200)  # shipped name, or "<name> (inline)"
    seed: int = 0
    max_steps: int = 0
    backend: str = Field(default="batched", max_length=16)
    sensor_fidelity: str | None = Field(default=None, max_length=16)
    agents: list[str] = Field(default_factory=list, sa_column=Column(JSON))
    policies: dict[str, str] = Field(default_factory=dict, sa_column=Column(JSON))
    policy_list: str = Field(default="", max_length=4000)  # ",name,name," of every policy, for filtering
    config: dict[str, Any] = Field(default_factory=dict, sa_column=Column(JSON))
    versions: dict[str, str] = Field(default_factory=dict, sa_column=Column(JSON))
    summary: dict[str, Any] | None = Field(
        default=None, sa_column=Column(JSON)
    )  # frame schema EpisodeSummary
    steps: int = 0
    error: str | None = None
    recording_path: str | None = None
    trajectory_path: str | None = None
    created_at: datetime = Field(default_factory=utcnow, index=True)
    started_at: datetime | None = None
    finished_at: datetime | None = None
    # when the row last changed: set on insert, by every Store write, and by any other ORM update
    updated_at: datetime = Field(default_factory=utcnow, sa_column_kwargs={"onupdate": utcnow})


class HeartbeatRow(SQLModel, table=True):
    """The one row ``/healthz`` rewrites to check that the database takes a write (revision 0003)."""

    __tablename__ = "heartbeat"

    id: int = Field(primary_key=True)  # always 1
    beat_at: datetime = Field(default_factory=utcnow)


def _sqlite_pragmas(dbapi_connection: Any, connection_record: Any) -> None:
    cursor = dbapi_connection.cursor()
    cursor.execute("PRAGMA journal_mode=WAL")
    cursor.execute("PRAGMA synchronous=NORMAL")
    cursor.execute("PRAGMA busy_timeout=10000")
    cursor.close()


def _aware(value: datetime | None) -> datetime | None:
    # SQLite hands datetimes back naive; they were written in UTC
    if value is not None and value.tzinfo is None:
        return value.replace(tzinfo=UTC)
    return value


def _in_memory(url: str) -> bool:
    parsed = make_url(url)
    return parsed.get_backend_name() == "sqlite" and (
        parsed.database in (None, "", ":memory:") or parsed.query.get("mode") == "memory"
    )


def migration_config(connection: Connection | None = None) -> Config:
    """An Alembic configuration of the shipped migrations (no ``alembic.ini`` needed).

    Args:
        connection: The connection the revisions run on (``config.attributes["connection"]``);
            when it is inside a transaction, Alembic leaves committing to the caller.

    Returns:
        The configuration, for the functions of ``alembic.command``.
    """
    from alembic.config import Config

    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS).replace("%", "%%"))
    if connection is not None:
        cfg.attributes["connection"] = connection
    return cfg


def _migration_engine(url: str) -> Engine:
    """A one-connection engine on which an upgrade runs in one transaction.

    On SQLite the driver's own transaction handling is switched off and the transaction begins
    with ``BEGIN IMMEDIATE``: the write lock is taken before the schema is read, so two processes
    upgrading one file run one after the other, and the table copies of batch mode are atomic.
    """
    sqlite = make_url(url).get_backend_name() == "sqlite"
    engine = create_engine(url, poolclass=NullPool, connect_args={"timeout": 30} if sqlite else {})
    if sqlite:

        def connect(dbapi_connection: Any, connection_record: Any) -> None:
            _sqlite_pragmas(dbapi_connection, connection_record)
            dbapi_connection.isolation_level = None

        def begin(conn: Connection) -> None:
            conn.exec_driver_sql("BEGIN IMMEDIATE")

        event.listen(engine, "connect", connect)
        event.listen(engine, "begin", begin)
    return engine


def upgrade_schema(engine: Engine) -> tuple[str | None, str]:
    """Upgrade a database to the newest revision, in one transaction where the database allows.

    A fresh database gets every revision; a database made by 0.1.0 (an ``episodes`` table and no
    ``alembic_version`` table) is stamped :data:`BASELINE_REVISION` first. On PostgreSQL the
    transaction first takes an advisory lock, so services starting together on one database
    upgrade it one after the other (the later ones then find nothing to do).

    Args:
        engine: An engine of the database (see :func:`_migration_engine` for SQLite files).

    Returns:
        The revision found (None for a fresh database) and the revision now.

    Raises:
        RuntimeError: The database is at a revision this version does not know (a newer
            hptvsim made it), or holds an ``episodes`` table that is not the 0.1.0 one.
    """
    from alembic import command
    from alembic.runtime.migration import MigrationContext
    from alembic.script import ScriptDirectory

    with _MIGRATING, engine.connect() as conn:
        if conn.dialect.name == "postgresql":  # the first statement: held until the commit
            conn.execute(text("SELECT pg_advisory_xact_lock(:key)"), {"key": _PG_LOCK_KEY})
        cfg = migration_config(conn)
        script = ScriptDirectory.from_config(cfg)
        head = script.get_current_head()
        if head is None:  # pragma: no cover - the package ships its revisions
            raise RuntimeError(f"no migrations in {MIGRATIONS}")
        tables = set(inspect(conn).get_table_names())
        if "episodes" in tables and "alembic_version" not in tables:
            _check_baseline(conn)
            command.stamp(cfg, BASELINE_REVISION)
            found: str | None = BASELINE_REVISION
        else:
            found = MigrationContext.configure(conn).get_current_revision()
        known = {s.revision for s in script.walk_revisions()}
        if found is not None and found not in known:
            raise RuntimeError(
                f"the database {engine.url.render_as_string(hide_password=True)} is at schema "
                f"revision {found!r}, which this hptvsim does not know (its newest is {head!r}): "
                "a newer hptvsim made it; run that version, or point DATABASE_URL elsewhere"
            )
        if found != head:
            command.upgrade(cfg, "head")
        conn.commit()
    return found, head


def _check_baseline(conn: Connection) -> None:
    """Refuse to stamp an ``episodes`` table that lacks columns of the 0.1.0 schema."""
    present = {c["name"] for c in inspect(conn).get_columns("episodes")}
    missing = [c for c in _BASELINE_COLUMNS if c not in present]
    if missing:
        raise RuntimeError(
            "the database has an episodes table without an alembic_version table, as 0.1.0 made, "
            f"but it lacks the columns {', '.join(missing)} of that schema; it was not made by "
            "hptvsim 0.1.0 and is left alone"
        )


class Store:
    """The episodes table: create, read, list with filters, update.

    Opening a store upgrades the database schema to the newest revision (see the module
    docstring).

    Args:
        url: SQLAlchemy database URL.

    Attributes:
        revisions: The schema revision the database was at when opened (None: a fresh database)
            and the revision it is at now.
    """

    def __init__(self, url: str) -> None:
        self.url = url
        parsed = make_url(url)
        sqlite = parsed.get_backend_name() == "sqlite"
        if sqlite and parsed.database and not _in_memory(url):
            Path(parsed.database).parent.mkdir(parents=True, exist_ok=True)
        connect_args: dict[str, Any] = {}
        if sqlite:
            connect_args = {"check_same_thread": False, "timeout": 30}
        elif parsed.get_backend_name() == "postgresql":
            connect_args = {"connect_timeout": PG_CONNECT_TIMEOUT_S}  # a dead server fails, not hangs
        self.engine: Engine = create_engine(
            url,
            connect_args=connect_args,
            pool_pre_ping=not sqlite,
            json_serializer=lambda obj: json.dumps(obj, allow_nan=False, default=str),
        )
        if sqlite:
            event.listen(self.engine, "connect", _sqlite_pragmas)
        self.revisions: tuple[str | None, str]
        if _in_memory(url):  # only this engine's connection sees the database
            self.revisions = upgrade_schema(self.engine)
        else:
            migrator = _migration_engine(url)
            try:
                self.revisions = upgrade_schema(migrator)
            finally:
                migrator.dispose()
        self._lock = threading.Lock()  # one writer at a time (SQLite's own rule, kept for all)
        # the SQLite file this store opened: (path, (device, inode)); None for other databases
        self._file: tuple[Path, tuple[int, int]] | None = None
        self._lost: str | None = None  # why the database cannot be used any more
        if sqlite and parsed.database and not _in_memory(url):
            path = Path(parsed.database)
            st = path.stat()
            self._file = (path, (st.st_dev, st.st_ino))

    @staticmethod
    def policy_list(policies: dict[str, str]) -> str:
        """The ``policy_list`` column of a row with these policies."""
        return "," + ",".join(sorted(set(policies.values()))) + ","

    def check(self) -> None:
        """Raise :class:`DatabaseUnavailableError` when the SQLite file opened at start is gone.

        A stat of the path (microseconds): a deleted file, or another file at its path, means
        the open connections write where nobody will read again and a new connection would
        start an empty database. Once lost, the store stays unusable (restart the service).
        """
        if self._lost is None and self._file is not None:
            path, identity = self._file
            try:
                st = path.stat()
            except FileNotFoundError:
                self._lost = "its file was deleted while the service ran"
            except OSError as exc:
                self._lost = f"its file cannot be read ({exc.strerror or type(exc).__name__})"
            else:
                if (st.st_dev, st.st_ino) != identity:
                    self._lost = "its file was replaced while the service ran"
        if self._lost is not None:
            raise DatabaseUnavailableError(f"the database is unavailable: {self._lost}; restart the service")

    @contextmanager
    def session(self) -> Iterator[Session]:
        """A session that expires nothing on commit (rows stay readable after it).

        Raises:
            DatabaseUnavailableError: The SQLite file was deleted or replaced (:meth:`check`).
        """
        self.check()
        with Session(self.engine, expire_on_commit=False) as s:
            yield s

    def close(self) -> None:
        """Release the connection pool."""
        self.engine.dispose()

    @staticmethod
    def _fix(row: EpisodeRow) -> EpisodeRow:
        row.created_at = _aware(row.created_at) or row.created_at
        row.started_at = _aware(row.started_at)
        row.finished_at = _aware(row.finished_at)
        row.updated_at = _aware(row.updated_at) or row.updated_at
        return row

    # -- writes ------------------------------------------------------------------------------------

    def add(self, row: EpisodeRow) -> EpisodeRow:
        """Insert a new episode (its ``updated_at`` is now)."""
        row.updated_at = utcnow()
        with self._lock, self.session() as s:
            s.add(row)
            s.commit()
        return self._fix(row)

    def update(self, episode_id: str, **values: Any) -> EpisodeRow | None:
        """Set columns of one episode and its ``updated_at``; returns the row (None if it does not exist)."""
        with self._lock, self.session() as s:
            row = s.get(EpisodeRow, episode_id)
            if row is None:
                return None
            for key, value in values.items():
                setattr(row, key, value)
            row.updated_at = utcnow()
            s.add(row)
            s.commit()
            return self._fix(row)

    def finish(self, episode_id: str, *, status: str, only_if_active: bool = True, **values: Any) -> bool:
        """Move an episode to a final status (once: a final row is left alone when ``only_if_active``)."""
        with self._lock, self.session() as s:
            row = s.get(EpisodeRow, episode_id)
            if row is None or (only_if_active and row.status not in ACTIVE):
                return False
            row.status = status
            row.finished_at = row.updated_at = utcnow()
            for key, value in values.items():
                setattr(row, key, value)
            s.add(row)
            s.commit()
            return True

    def recover(self, result_reader: Any = None) -> tuple[list[str], list[str]]:
        """Close the rows a previous process left active.

        Args:
            result_reader: ``f(row) -> dict | None``: the result a worker wrote for the episode
                (its files), or None. Rows with a result become ``finished`` with it, or the
                final status the result names in its ``status`` key (an outcome the service
                could not store while it ran).

        Returns:
            The ids given a result (``finished`` or the status it names) and the ids marked
            ``interrupted``.
        """
        finished: list[str] = []
        interrupted: list[str] = []
        with self._lock, self.session() as s:
            rows = s.exec(select(EpisodeRow).where(col(EpisodeRow.status).in_(ACTIVE))).all()
            for row in rows:
                result = result_reader(row) if result_reader is not None else None
                row.finished_at = row.updated_at = utcnow()
                if result is not None:
                    values = dict(result)
                    row.status = str(values.pop("status", "finished"))
                    for key, value in values.items():
                        setattr(row, key, value)
                    finished.append(row.id)
                else:
                    row.status = "interrupted"
                    row.error = "the service stopped while this episode was " + (
                        "running" if row.started_at else "queued"
                    )
                    interrupted.append(row.id)
                s.add(row)
            s.commit()
        return finished, interrupted

    def heartbeat(self) -> None:
        """Rewrite the heartbeat row: raises unless the database takes a write now."""
        with self._lock, self.session() as s:
            now = utcnow()
            done = s.exec(update(HeartbeatRow).where(col(HeartbeatRow.id) == 1).values(beat_at=now))
            if not done.rowcount:  # the row revision 0003 made is gone: make it again
                s.add(HeartbeatRow(id=1, beat_at=now))
            s.commit()

    def delete_ended(self, ids: Sequence[str]) -> list[str]:
        """Delete the rows of these episodes that are in a final status; returns the ids deleted.

        An active row is never deleted (it may have started again since it was picked).
        """
        if not ids:
            return []
        with self._lock, self.session() as s:
            picked = col(EpisodeRow.id).in_(list(ids))
            final = col(EpisodeRow.status).in_(FINAL)
            found = [str(i) for i in s.exec(select(EpisodeRow.id).where(picked, final)).all()]
            if found:
                s.exec(delete(EpisodeRow).where(col(EpisodeRow.id).in_(found), final))
                s.commit()
        return found

    # -- reads -------------------------------------------------------------------------------------

    def ended_before(self, cutoff: datetime, limit: int = 500) -> list[str]:
        """Ids of episodes in a final status that ended before ``cutoff``, oldest first.

        An episode's end is its ``finished_at``, else (rows of old versions) its ``updated_at``.
        """
        ended = func.coalesce(col(EpisodeRow.finished_at), col(EpisodeRow.updated_at))
        query = (
            select(EpisodeRow.id)
            .where(col(EpisodeRow.status).in_(FINAL), ended < cutoff)
            .order_by(ended, col(EpisodeRow.id))
            .limit(limit)
        )
        with self.session() as s:
            return [str(i) for i in s.exec(query).all()]

    def existing(self, ids: Sequence[str]) -> set[str]:
        """Which of these episode ids have a row."""
        if not ids:
            return set()
        with self.session() as s:
            query = select(EpisodeRow.id).where(col(EpisodeRow.id).in_(list(ids)))
            return {str(i) for i in s.exec(query).all()}

    def get(self, episode_id: str) -> EpisodeRow | None:
        """One episode, or None."""
        with self.session() as s:
            row = s.get(EpisodeRow, episode_id)
            return None if row is None else self._fix(row)

    def list(
        self,
        *,
        status: Sequence[str] = (),
        scenario: str | None = None,
        mode: str | None = None,
        policy: str | None = None,
        limit: int = 100,
        offset: int = 0,
    ) -> tuple[list[EpisodeRow], int]:
        """Episodes, newest first, with filters; returns the page and the total matching.

        ``policy`` matches episodes in which any agent follows that policy.
        """
        query = select(EpisodeRow)
        count = select(func.count()).select_from(EpisodeRow)
        conditions: list[Any] = []
        if status:
            conditions.append(col(EpisodeRow.status).in_(list(status)))
        if scenario:
            conditions.append(col(EpisodeRow.scenario) == scenario)
        if mode:
            conditions.append(col(EpisodeRow.mode) == mode)
        if policy:
            conditions.append(col(EpisodeRow.policy_list).contains(f",{policy},", autoescape=True))
        for cond in conditions:
            query = query.where(cond)
            count = count.where(cond)
        query = (
            query.order_by(col(EpisodeRow.created_at).desc(), col(EpisodeRow.id)).offset(offset).limit(limit)
        )
        with self.session() as s:
            rows = [self._fix(r) for r in s.exec(query).all()]
            total = int(s.exec(count).one())
        return rows, total

    def count_status(self) -> dict[str, int]:
        """Number of episodes per status."""
        with self.session() as s:
            rows = s.exec(select(EpisodeRow.status, func.count()).group_by(EpisodeRow.status)).all()
        return {str(status): int(n) for status, n in rows}
