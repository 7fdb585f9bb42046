"""Fixtures of the database tests (registered in ``tests/conftest.py``): SQLite and a real PostgreSQL.

``pg_databases`` starts one throwaway PostgreSQL server per test process (see ``pg_cluster``),
on first use only, and yields a factory of fresh databases. Without the PostgreSQL server
programs its tests are skipped, or fail when ``HPTVSIM_REQUIRE_POSTGRES=1`` (``make unit`` sets
it, so CI cannot skip them silently). ``database_url`` runs a test once on each database.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from pg_cluster import REQUIRE_VARIABLE, PgCluster, PgUnavailable

DATABASES = ("sqlite", "postgresql")


@pytest.fixture(scope="session")
def pg_databases() -> Iterator[Callable[[], str]]:
    """A factory of fresh, empty PostgreSQL databases; each call returns a SQLAlchemy URL."""
    try:
        cluster = PgCluster.start()
    except PgUnavailable as exc:
        missing = str(exc)
    else:
        missing = ""
    if missing and os.environ.get(REQUIRE_VARIABLE) == "1":
        pytest.fail(f"{REQUIRE_VARIABLE}=1, and {missing}", pytrace=False)
    if missing:
        pytest.skip(missing)
    try:
        yield cluster.create_database
    finally:
        cluster.stop()


def fresh_database(kind: str, folder: Path, request: pytest.FixtureRequest) -> str:
    """The URL of a new empty database: a SQLite file in ``folder``, or a PostgreSQL database."""
    if kind == "sqlite":
        folder.mkdir(parents=True, exist_ok=True)
        return f"sqlite:///{folder / 'episodes.db'}"
    factory: Callable[[], str] = request.getfixturevalue("pg_databases")
    return factory()


@pytest.fixture(params=DATABASES)
def database_url(request: pytest.FixtureRequest, tmp_path: Path) -> str:
    """A fresh empty database, once SQLite and once PostgreSQL (the test's id says which)."""
    return fresh_database(str(request.param), tmp_path / "db", request)
