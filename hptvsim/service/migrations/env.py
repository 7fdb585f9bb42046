"""The Alembic environment: runs the revisions on the connection :class:`~hptvsim.service.db.Store` passes.

:func:`hptvsim.service.db.migration_config` hands the connection over in
``config.attributes["connection"]``; that connection may already be inside a transaction (the
caller's, which the caller commits). Run from the ``alembic`` command line instead, the environment
connects to the ``sqlalchemy.url`` of the configuration, else to ``DATABASE_URL``.
"""

from __future__ import annotations

import os

from alembic import context
from sqlalchemy import create_engine, pool
from sqlalchemy.engine import Connection

from hptvsim.service.db import EpisodeRow

target_metadata = EpisodeRow.metadata


def _run(connection: Connection) -> None:
    # batch mode: SQLite alters a column by copying the table, and Alembic does that for us
    context.configure(connection=connection, target_metadata=target_metadata, render_as_batch=True)
    with context.begin_transaction():
        context.run_migrations()


def run_migrations_online() -> None:
    """Run the revisions on the given connection, or on a new one to the configured database."""
    connection = context.config.attributes.get("connection")
    if connection is not None:
        _run(connection)
        return
    url = context.config.get_main_option("sqlalchemy.url") or os.environ.get("DATABASE_URL")
    if not url:
        raise RuntimeError("no database: set sqlalchemy.url in the Alembic configuration or DATABASE_URL")
    engine = create_engine(url, poolclass=pool.NullPool)
    try:
        with engine.connect() as conn:
            _run(conn)
    finally:
        engine.dispose()


if context.is_offline_mode():
    raise RuntimeError("offline (--sql) migrations are not supported; run them on a database")
run_migrations_online()
