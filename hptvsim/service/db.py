"""Persistence: the episodes table (SQLModel on SQLAlchemy 2.x), SQLite by default.

Only the API process writes the database; worker processes report to it through the job
runner. SQLite runs in WAL mode so readers never wait for the writer; ``DATABASE_URL`` selects
another database (PostgreSQL: ``postgresql+psycopg://user:password@host/db``).

On startup :meth:`Store.recover` turns every ``queued`` or ``running`` row left by a previous
process into ``interrupted`` (or ``finished``, when the episode's worker had completed and written
its result file before the API went down), so a restart loses no finished episode.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from sqlalchemy import JSON, Column, event, func
from sqlalchemy.engine import Engine
from sqlmodel import Field, Session, SQLModel, col, create_engine, select

__all__ = ["ACTIVE", "FINAL", "STATUSES", "EpisodeRow", "Store", "utcnow"]

STATUSES: tuple[str, ...] = ("queued", "running", "finished", "failed", "cancelled", "interrupted")
"""Every episode status; the first two are active, the rest final."""
ACTIVE: tuple[str, ...] = ("queued", "running")
FINAL: tuple[str, ...] = ("finished", "failed", "cancelled", "interrupted")


def utcnow() -> datetime:
    """The current time in UTC (timezone-aware)."""
    return datetime.now(UTC)


class EpisodeRow(SQLModel, table=True):
    """One episode: its configuration, status, results and files."""

    __tablename__ = "episodes"

    id: str = Field(primary_key=True, max_length=32)
    mode: str = Field(default="run", index=True, max_length=16)  # "run" or "interactive"
    status: str = Field(default="queued", index=True, max_length=16)
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


class Store:
    """The episodes table: create, read, list with filters, update.

    Args:
        url: SQLAlchemy database URL.
    """

    def __init__(self, url: str) -> None:
        self.url = url
        sqlite = url.startswith("sqlite")
        if sqlite and url.startswith("sqlite:///") and url != "sqlite:///:memory:":
            Path(url.removeprefix("sqlite:///")).parent.mkdir(parents=True, exist_ok=True)
        self.engine: Engine = create_engine(
            url,
            connect_args={"check_same_thread": False, "timeout": 30} if sqlite else {},
            pool_pre_ping=not sqlite,
            json_serializer=lambda obj: json.dumps(obj, allow_nan=False, default=str),
        )
        if sqlite:
            event.listen(self.engine, "connect", _sqlite_pragmas)
        SQLModel.metadata.create_all(self.engine)
        self._add_missing_columns()
        self._lock = threading.Lock()  # one writer at a time (SQLite's own rule, kept for all)

    def _add_missing_columns(self) -> None:
        """Add columns a newer version of the table has (a database made by an older version)."""
        from sqlalchemy import inspect, text

        table = EpisodeRow.__table__  # type: ignore[attr-defined]  # SQLModel's table object
        present = {c["name"] for c in inspect(self.engine).get_columns(table.name)}
        with self.engine.begin() as conn:
            for column in table.columns:
                if column.name in present:
                    continue
                kind = column.type.compile(dialect=self.engine.dialect)
                value = getattr(column.default, "arg", None)
                default = "NULL"
                if isinstance(value, bool):
                    default = "1" if value else "0"
                elif isinstance(value, int | float):
                    default = repr(value)
                elif isinstance(value, str):
                    default = "'" + value.replace("'", "''") + "'"
                conn.execute(
                    text(f'ALTER TABLE {table.name} ADD COLUMN "{column.name}" {kind} DEFAULT {default}')
                )

    @staticmethod
    def policy_list(policies: dict[str, str]) -> str:
        """The ``policy_list`` column of a row with these policies."""
        return "," + ",".join(sorted(set(policies.values()))) + ","

    @contextmanager
    def session(self) -> Iterator[Session]:
        """A session that expires nothing on commit (rows stay readable after it)."""
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
        return row

    # -- writes ------------------------------------------------------------------------------------

    def add(self, row: EpisodeRow) -> EpisodeRow:
        """Insert a new episode."""
        with self._lock, self.session() as s:
            s.add(row)
            s.commit()
        return self._fix(row)

    def update(self, episode_id: str, **values: Any) -> EpisodeRow | None:
        """Set columns of one episode; returns the updated row (None if it does not exist)."""
        with self._lock, self.session() as s:
            row = s.get(EpisodeRow, episode_id)
            if row is None:
                return None
            for key, value in values.items():
                setattr(row, key, value)
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
            row.finished_at = utcnow()
            for key, value in values.items():
                setattr(row, key, value)
            s.add(row)
            s.commit()
            return True

    def recover(self, result_reader: Any = None) -> tuple[list[str], list[str]]:
        """Close the rows a previous process left active.

        Args:
            result_reader: ``f(row) -> dict | None``: the result a worker wrote for the episode
                (its files), or None. Rows with a result become ``finished`` with it.

        Returns:
            The ids marked ``finished`` and the ids marked ``interrupted``.
        """
        finished: list[str] = []
        interrupted: list[str] = []
        with self._lock, self.session() as s:
            rows = s.exec(select(EpisodeRow).where(col(EpisodeRow.status).in_(ACTIVE))).all()
            for row in rows:
                result = result_reader(row) if result_reader is not None else None
                row.finished_at = utcnow()
                if result is not None:
                    row.status = "finished"
                    for key, value in result.items():
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

    # -- reads -------------------------------------------------------------------------------------

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
