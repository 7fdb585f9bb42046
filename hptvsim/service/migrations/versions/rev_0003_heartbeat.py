"""The ``heartbeat`` table: one row that ``/healthz`` rewrites to check the database takes writes.

* ``heartbeat.id`` (integer, primary key): always 1.
* ``heartbeat.beat_at`` (timezone-aware, not null): when a service last wrote it.

The row is made here, so services sharing one database only ever update it.

Revision ID: 0003
Revises: 0002
Create Date: 2026-03-01
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0003"
down_revision: str | Sequence[str] | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    """Create the heartbeat table and its one row."""
    op.create_table(
        "heartbeat",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("beat_at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("id"),
    )
    op.execute("INSERT INTO heartbeat (id, beat_at) VALUES (1, CURRENT_TIMESTAMP)")


def downgrade() -> None:
    """Back to 0002: no heartbeat table."""
    op.drop_table("heartbeat")
