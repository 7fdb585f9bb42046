"""``updated_at`` on every episode, and one index for the episode list's filter and order.

* ``episodes.updated_at`` (timezone-aware, not null): when the row last changed. Rows already
  there get their latest known time, ``coalesce(finished_at, started_at, created_at)``.
* ``ix_episodes_status_created_at`` on ``(status, created_at)``: the list filters by status and
  orders by creation time. It also serves every lookup by status alone (its first column), so the
  single-column ``ix_episodes_status`` goes.

Revision ID: 0002
Revises: 0001
Create Date: 2026-02-01
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0002"
down_revision: str | Sequence[str] | None = "0001"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    """Add and fill ``updated_at``; replace the status index by the (status, created_at) one."""
    op.add_column("episodes", sa.Column("updated_at", sa.DateTime(timezone=True), nullable=True))
    op.execute("UPDATE episodes SET updated_at = COALESCE(finished_at, started_at, created_at)")
    # NOT NULL once filled (SQLite: batch mode copies the table, in the caller's transaction)
    with op.batch_alter_table("episodes") as batch:
        batch.alter_column("updated_at", existing_type=sa.DateTime(timezone=True), nullable=False)
    op.create_index("ix_episodes_status_created_at", "episodes", ["status", "created_at"])
    op.drop_index("ix_episodes_status", table_name="episodes")


def downgrade() -> None:
    """Back to 0001: the status index again, no ``updated_at``."""
    op.create_index("ix_episodes_status", "episodes", ["status"])
    op.drop_index("ix_episodes_status_created_at", table_name="episodes")
    with op.batch_alter_table("episodes") as batch:
        batch.drop_column("updated_at")
