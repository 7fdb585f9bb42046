"""The 0.1.0 schema: the ``episodes`` table as ``SQLModel.metadata.create_all`` made it.

A database made by 0.1.0 has exactly this table and no ``alembic_version`` table;
:class:`hptvsim.service.db.Store` stamps it with this revision before upgrading it.

Revision ID: 0001
Revises:
Create Date: 2026-02-01
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0001"
down_revision: str | Sequence[str] | None = None
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    """Create the episodes table and its four indexes."""
    op.create_table(
        "episodes",
        sa.Column("id", sa.String(length=32), nullable=False),
        sa.Column("mode", sa.String(length=16), nullable=False),
        sa.Column("status", sa.String(length=16), nullable=False),
        sa.Column("label", sa.String(length=200), nullable=False),
        sa.Column("scenario", sa.String(length=200), nullable=False),
        sa.Column("seed", sa.Integer(), nullable=False),
        sa.Column("max_steps", sa.Integer(), nullable=False),
        sa.Column("backend", sa.String(length=16), nullable=False),
        sa.Column("sensor_fidelity", sa.String(length=16), nullable=True),
        sa.Column("agents", sa.JSON(), nullable=True),
        sa.Column("policies", sa.JSON(), nullable=True),
        sa.Column("policy_list", sa.String(length=4000), nullable=False),
        sa.Column("config", sa.JSON(), nullable=True),
        sa.Column("versions", sa.JSON(), nullable=True),
        sa.Column("summary", sa.JSON(), nullable=True),
        sa.Column("steps", sa.Integer(), nullable=False),
        sa.Column("error", sa.String(), nullable=True),
        sa.Column("recording_path", sa.String(), nullable=True),
        sa.Column("trajectory_path", sa.String(), nullable=True),
        # timezone-aware: TIMESTAMP WITH TIME ZONE on PostgreSQL; SQLite keeps UTC without an offset
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("started_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("finished_at", sa.DateTime(timezone=True), nullable=True),
        sa.PrimaryKeyConstraint("id"),
    )
    op.create_index("ix_episodes_mode", "episodes", ["mode"])
    op.create_index("ix_episodes_scenario", "episodes", ["scenario"])
    op.create_index("ix_episodes_status", "episodes", ["status"])
    op.create_index("ix_episodes_created_at", "episodes", ["created_at"])


def downgrade() -> None:
    """Drop the episodes table."""
    op.drop_table("episodes")
