"""Schema migrations on SQLite and PostgreSQL: revision 0001 is the 0.1.0 schema, and opening a
Store upgrades a database at 0001, or one made by 0.1.0 (no alembic_version table), to the newest
revision with its rows intact; a second opening changes nothing; services opening one fresh
database at the same moment all start."""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import pytest
import sqlalchemy as sa
from alembic import command
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from pg_fixtures import DATABASES, fresh_database
from service_helpers import ROOT

from hptvsim.service.db import BASELINE_REVISION, EpisodeRow, Store, migration_config

HEAD = "0003"
T0 = datetime(2026, 1, 2, 3, 4, 5, 678901, tzinfo=UTC)

# the episodes table exactly as 0.1.0's SQLModel.metadata.create_all made it
LEGACY_DDL = """
CREATE TABLE episodes (
    id VARCHAR(32) NOT NULL, mode VARCHAR(16) NOT NULL, status VARCHAR(16) NOT NULL,
    label VARCHAR(200) NOT NULL, scenario VARCHAR(200) NOT NULL, seed INTEGER NOT NULL,
    max_steps INTEGER NOT NULL, backend VARCHAR(16) NOT NULL, sensor_fidelity VARCHAR(16),
    agents JSON, policies JSON, policy_list VARCHAR(4000) NOT NULL, config JSON, versions JSON,
    summary JSON, steps INTEGER NOT NULL, error VARCHAR, recording_path VARCHAR,
    trajectory_path VARCHAR, created_at {ts} NOT NULL, started_at {ts}, finished_at {ts},
    PRIMARY KEY (id)
)"""
LEGACY_INDEXES = [
    "CREATE INDEX ix_episodes_mode ON episodes (mode)",
    "CREATE INDEX ix_episodes_scenario ON episodes (scenario)",
    "CREATE INDEX ix_episodes_status ON episodes (status)",
    "CREATE INDEX ix_episodes_created_at ON episodes (created_at)",
]
TIMESTAMP = {"sqlite": "DATETIME", "postgresql": "TIMESTAMP WITH TIME ZONE"}


def _rows() -> list[dict[str, Any]]:
    base: dict[str, Any] = {
        "mode": "run",
        "label": "",
        "seed": 0,
        "max_steps": 100,
        "backend": "batched",
        "sensor_fidelity": None,
        "agents": ["pursuer_0", "evader_0"],
        "config": {"scenario": "source", "dt": 0.1},
        "versions": {"hptvsim": "0.1.0"},
        "recording_path": None,
        "trajectory_path": None,
    }

    def policies(p: str) -> dict[str, Any]:
        return {"policies": {"pursuer_0": p}, "policy_list": f",{p},"}

    return [
        {
            **base,
            **policies("scripted:pure_pursuit"),
            "id": "00000000000000a1",
            "status": "finished",
            "scenario": "source",
            "summary": {"status": "finished", "steps": 42, "captured": True},
            "steps": 42,
            "error": None,
            "created_at": T0,
            "started_at": T0 + timedelta(seconds=1),
            "finished_at": T0 + timedelta(seconds=9, microseconds=5),
        },
        {
            **base,
            **policies("scripted:random"),
            "id": "00000000000000a2",
            "status": "running",
            "scenario": "target",
            "summary": None,
            "steps": 7,
            "error": None,
            "created_at": T0 + timedelta(minutes=1),
            "started_at": T0 + timedelta(minutes=1, seconds=2),
            "finished_at": None,
        },
        {
            **base,
            **policies("scripted:stationary"),
            "id": "00000000000000a3",
            "mode": "interactive",
            "status": "queued",
            "scenario": "goto_tiny (inline)",
            "summary": None,
            "steps": 0,
            "error": 'it\'s "quoted" – and ünicode',
            "created_at": T0 + timedelta(minutes=2),
            "started_at": None,
            "finished_at": None,
        },
    ]


def _utc(value: Any) -> Any:
    if isinstance(value, datetime):
        return value.replace(tzinfo=UTC) if value.tzinfo is None else value.astimezone(UTC)
    return value


@pytest.fixture(params=DATABASES)
def databases(request: pytest.FixtureRequest, tmp_path: Path) -> Callable[[], str]:
    """A factory of fresh empty databases of one kind (SQLite files, or PostgreSQL databases)."""
    count = [0]

    def make() -> str:
        count[0] += 1
        return fresh_database(str(request.param), tmp_path / f"db{count[0]}", request)

    return make


@pytest.fixture
def engines() -> Iterator[Callable[[str], sa.Engine]]:
    """Engines of the test's databases (disposed at the end, so PostgreSQL sees no lingering sessions)."""
    made: list[sa.Engine] = []

    def make(url: str) -> sa.Engine:
        engine = sa.create_engine(url, poolclass=sa.NullPool)
        made.append(engine)
        return engine

    yield make
    for e in made:
        e.dispose()


def _make_legacy(engine: sa.Engine) -> None:
    with engine.begin() as conn:
        conn.execute(sa.text(LEGACY_DDL.format(ts=TIMESTAMP[engine.dialect.name])))
        for ddl in LEGACY_INDEXES:
            conn.execute(sa.text(ddl))


def _migrate_to(engine: sa.Engine, revision: str) -> None:
    with engine.begin() as conn:
        command.upgrade(migration_config(conn), revision)


def _insert(engine: sa.Engine, rows: list[dict[str, Any]]) -> None:
    with engine.begin() as conn:
        table = sa.Table("episodes", sa.MetaData(), autoload_with=conn)
        conn.execute(table.insert(), rows)


def _read(engine: sa.Engine) -> dict[str, dict[str, Any]]:
    with engine.connect() as conn:
        table = sa.Table("episodes", sa.MetaData(), autoload_with=conn)
        return {
            r["id"]: {k: _utc(v) for k, v in r.items()}
            for r in conn.execute(sa.select(table)).mappings().all()
        }


def _schema(engine: sa.Engine) -> dict[str, Any]:
    """Tables, columns (name, type, nullable), primary keys and indexes, as the database reports them."""
    out: dict[str, Any] = {}
    with engine.connect() as conn:
        insp = sa.inspect(conn)
        for table in sorted(insp.get_table_names()):
            out[table] = {
                "columns": [
                    (c["name"], str(c["type"].compile(dialect=engine.dialect)), c["nullable"])
                    for c in insp.get_columns(table)
                ],
                "pk": insp.get_pk_constraint(table)["constrained_columns"],
                "indexes": sorted(
                    (str(i["name"]), tuple(str(c) for c in i["column_names"]), bool(i["unique"]))
                    for i in insp.get_indexes(table)
                ),
            }
    return out


def _version(engine: sa.Engine) -> list[str]:
    with engine.connect() as conn:
        return [str(v) for v in conn.execute(sa.text("SELECT version_num FROM alembic_version")).scalars()]


def _assert_upgraded(engine: sa.Engine, rows: list[dict[str, Any]]) -> None:
    """Rows intact, updated_at filled, the new index in place of the old one, the version at head."""
    assert _version(engine) == [HEAD]
    schema = _schema(engine)["episodes"]
    columns = {name: nullable for name, _, nullable in schema["columns"]}
    assert columns["updated_at"] is False  # NOT NULL
    indexes = {name: cols for name, cols, _ in schema["indexes"]}
    assert indexes["ix_episodes_status_created_at"] == ("status", "created_at")
    assert "ix_episodes_status" not in indexes
    assert {"ix_episodes_mode", "ix_episodes_scenario", "ix_episodes_created_at"} <= set(indexes)
    stored = _read(engine)
    assert set(stored) == {r["id"] for r in rows}
    for row in rows:
        now = stored[row["id"]]
        assert {k: now[k] for k in row} == {k: _utc(v) for k, v in row.items()}
        assert now["updated_at"] == _utc(row["finished_at"] or row["started_at"] or row["created_at"])


def _assert_matches_the_model(engine: sa.Engine) -> None:
    with engine.connect() as conn:
        diff = compare_metadata(MigrationContext.configure(conn), EpisodeRow.metadata)
    assert diff == [], diff


def test_revision_0001_is_the_schema_0_1_0_made(
    databases: Callable[[], str], engines: Callable[[str], sa.Engine]
) -> None:
    legacy, migrated = engines(databases()), engines(databases())
    _make_legacy(legacy)
    _migrate_to(migrated, BASELINE_REVISION)
    made = _schema(migrated)
    assert made.pop("alembic_version")["columns"] == [("version_num", "VARCHAR(32)", False)]
    assert made == _schema(legacy)
    assert _version(migrated) == [BASELINE_REVISION]


def test_a_database_at_0001_with_rows_is_upgraded_by_opening_a_store(
    databases: Callable[[], str], engines: Callable[[str], sa.Engine]
) -> None:
    url = databases()
    engine = engines(url)
    _migrate_to(engine, BASELINE_REVISION)
    rows = _rows()
    _insert(engine, rows)
    store = Store(url)
    try:
        assert store.revisions == (BASELINE_REVISION, HEAD)
        _assert_upgraded(engine, rows)
        _assert_matches_the_model(engine)
        # the store reads and writes the upgraded rows
        old = store.get("00000000000000a1")
        assert old is not None and old.summary == rows[0]["summary"] and old.policies == rows[0]["policies"]
        assert old.updated_at == rows[0]["finished_at"] and old.created_at == T0
        page, total = store.list(status=["running", "queued"])
        assert total == 2 and [r.id for r in page] == ["00000000000000a3", "00000000000000a2"]
        assert store.list(policy="scripted:random")[1] == 1
        assert store.finish("00000000000000a2", status="cancelled")
        cancelled = store.get("00000000000000a2")
        assert cancelled is not None and cancelled.updated_at > T0 + timedelta(days=1)
    finally:
        store.close()


def test_a_database_made_by_0_1_0_is_stamped_and_upgraded(
    databases: Callable[[], str], engines: Callable[[str], sa.Engine]
) -> None:
    url = databases()
    engine = engines(url)
    _make_legacy(engine)
    rows = _rows()
    _insert(engine, rows)
    assert "alembic_version" not in _schema(engine)
    store = Store(url)
    try:
        assert store.revisions == (BASELINE_REVISION, HEAD)
        _assert_upgraded(engine, rows)
        _assert_matches_the_model(engine)
        assert store.count_status() == {"finished": 1, "running": 1, "queued": 1}
    finally:
        store.close()


def test_opening_a_store_twice_changes_nothing_the_second_time(
    databases: Callable[[], str], engines: Callable[[str], sa.Engine]
) -> None:
    url = databases()
    engine = engines(url)
    first = Store(url)
    assert first.revisions == (None, HEAD)
    first.add(EpisodeRow(id="00000000000000b1", scenario="source", created_at=T0))
    before_schema, before_rows = _schema(engine), _read(engine)
    first.close()
    second = Store(url)
    try:
        assert second.revisions == (HEAD, HEAD)
        assert _schema(engine) == before_schema and _read(engine) == before_rows
        assert _version(engine) == [HEAD]
        _assert_matches_the_model(engine)
    finally:
        second.close()


def test_the_newest_revision_downgrades_to_0001_and_upgrades_again(
    databases: Callable[[], str], engines: Callable[[str], sa.Engine]
) -> None:
    url = databases()
    engine = engines(url)
    _migrate_to(engine, BASELINE_REVISION)
    at_0001 = _schema(engine)
    rows = _rows()
    _insert(engine, rows)
    Store(url).close()
    with engine.begin() as conn:
        command.downgrade(migration_config(conn), BASELINE_REVISION)
    assert _schema(engine) == at_0001 and _version(engine) == [BASELINE_REVISION]
    assert _read(engine) == {r["id"]: {k: _utc(v) for k, v in r.items()} for r in rows}
    Store(url).close()
    _assert_upgraded(engine, rows)


def test_services_opening_one_fresh_database_at_once_all_start(
    databases: Callable[[], str], engines: Callable[[str], sa.Engine], tmp_path: Path
) -> None:
    url = databases()
    go = tmp_path / "go"
    # separate processes, as separate services are; each waits for the go file, then opens the store
    script = (
        "import os, sys, time\n"
        "from hptvsim.service.db import Store\n"
        "while not os.path.exists(sys.argv[2]): time.sleep(0.001)\n"
        "print(Store(sys.argv[1]).revisions)\n"
    )
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", script, url, str(go)],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for _ in range(3)
    ]
    time.sleep(3.0)  # let them import and wait
    go.touch()
    outs = [p.communicate(timeout=120) for p in procs]
    assert [p.returncode for p in procs] == [0, 0, 0], [err for _, err in outs]
    # exactly one of them made the schema; the others found it made
    assert sorted(out.strip() for out, _ in outs) == [
        f"('{HEAD}', '{HEAD}')",
        f"('{HEAD}', '{HEAD}')",
        f"(None, '{HEAD}')",
    ]
    engine = engines(url)
    assert _version(engine) == [HEAD]
    _assert_matches_the_model(engine)


def test_a_table_that_is_not_the_0_1_0_one_is_left_alone(
    databases: Callable[[], str], engines: Callable[[str], sa.Engine]
) -> None:
    url = databases()
    engine = engines(url)
    with engine.begin() as conn:
        conn.execute(sa.text("CREATE TABLE episodes (id VARCHAR(32) PRIMARY KEY, status VARCHAR(16))"))
    before = _schema(engine)
    with pytest.raises(RuntimeError, match=r"lacks the columns .*created_at"):
        Store(url)
    assert _schema(engine) == before


def test_a_database_of_a_newer_version_is_refused(
    databases: Callable[[], str], engines: Callable[[str], sa.Engine]
) -> None:
    url = databases()
    engine = engines(url)
    Store(url).close()
    with engine.begin() as conn:
        conn.execute(sa.text("UPDATE alembic_version SET version_num = '9999'"))
    with pytest.raises(RuntimeError, match="revision '9999', which this hptvsim does not know"):
        Store(url)
