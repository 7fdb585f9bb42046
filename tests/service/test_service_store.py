"""The episode store: filters, recovery after a crash, and opening a database of an older version."""

from __future__ import annotations

import sqlite3
from pathlib import Path

from hptvsim.service.db import EpisodeRow, Store, utcnow


def _row(i: int, status: str, policies: dict[str, str], scenario: str = "source") -> EpisodeRow:
    return EpisodeRow(
        id=f"{i:016x}",
        status=status,
        scenario=scenario,
        policies=policies,
        policy_list=Store.policy_list(policies),
        started_at=utcnow() if status == "running" else None,
    )


def test_filters_and_recovery(tmp_path: Path) -> None:
    store = Store(f"sqlite:///{tmp_path / 'x.db'}")
    store.add(
        _row(1, "finished", {"pursuer_0": "scripted:pure_pursuit", "evader_0": "scripted:potential_field"})
    )
    store.add(_row(2, "running", {"pursuer_0": "scripted:random", "evader_0": "scripted:potential_field"}))
    store.add(_row(3, "queued", {"pursuer_0": "scripted:pure_pursuit"}, scenario="target"))
    store.add(_row(4, "running", {"evader_0": "scripted:stationary"}, scenario="target"))
    rows, total = store.list(policy="scripted:pure_pursuit")
    assert total == 2 and {r.id for r in rows} == {f"{1:016x}", f"{3:016x}"}
    assert store.list(policy="scripted:pure")[1] == 0  # whole names only
    assert store.list(policy="scripted:pure_pursui_")[1] == 0  # LIKE wildcards are escaped
    assert store.list(policy="scripted:potential_field", status=["running"])[1] == 1
    assert (
        store.list(scenario="target", limit=1)[1] == 2 and len(store.list(scenario="target", limit=1)[0]) == 1
    )
    store.close()
    # a new process: the running row whose worker left a result becomes finished, the others interrupted
    store = Store(f"sqlite:///{tmp_path / 'x.db'}")

    def reader(row: EpisodeRow) -> dict[str, object] | None:
        return {"steps": 7, "summary": {"status": "finished"}} if row.id == f"{4:016x}" else None

    finished, interrupted = store.recover(reader)
    assert finished == [f"{4:016x}"] and set(interrupted) == {f"{2:016x}", f"{3:016x}"}
    four = store.get(f"{4:016x}")
    assert four is not None and four.status == "finished" and four.steps == 7
    two = store.get(f"{2:016x}")
    assert two is not None and two.status == "interrupted" and two.finished_at is not None
    assert two.finished_at.tzinfo is not None
    assert store.count_status() == {"finished": 2, "interrupted": 2}
    assert store.recover(reader) == ([], [])


def test_a_database_of_an_older_version_gains_the_new_columns(tmp_path: Path) -> None:
    path = tmp_path / "old.db"
    with sqlite3.connect(path) as conn:
        conn.execute(
            "CREATE TABLE episodes (id VARCHAR(32) PRIMARY KEY, mode VARCHAR(16), status VARCHAR(16), "
            "label VARCHAR(200), scenario VARCHAR(200), seed INTEGER, max_steps INTEGER, "
            "backend VARCHAR(16), created_at DATETIME)"
        )
        conn.execute(
            "INSERT INTO episodes VALUES "
            "('00000000000000aa', 'run', 'finished', '', 'source', 1, 10, 'batched', '2026-01-01 00:00:00')"
        )
    store = Store(f"sqlite:///{path}")
    row = store.get("00000000000000aa")
    assert row is not None and row.status == "finished" and row.policy_list == "" and row.summary is None
    assert row.steps == 0 and row.error is None
    assert store.list(policy="scripted:random")[1] == 0
