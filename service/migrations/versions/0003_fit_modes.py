"""fit modes: fits.mode, fits.scan_id nullable (markers-only fits have no scan)

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-23 07:00:00.000000

"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

# revision identifiers, used by Alembic.
revision: str = "0003"
down_revision: str | Sequence[str] | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    """Upgrade schema (batch mode: SQLite rebuilds the table, PostgreSQL alters in place)."""
    with op.batch_alter_table("fits", schema=None) as batch_op:
        batch_op.add_column(
            sa.Column("mode", sa.String(length=16), server_default="full", nullable=False)
        )
        batch_op.alter_column("scan_id", existing_type=sa.String(length=32), nullable=True)


def downgrade() -> None:
    """Downgrade schema: fits without a scan (markers-only) cannot be kept and are deleted."""
    op.execute("DELETE FROM blobs WHERE fit_id IN (SELECT id FROM fits WHERE scan_id IS NULL)")
    op.execute("DELETE FROM fits WHERE scan_id IS NULL")
    with op.batch_alter_table("fits", schema=None) as batch_op:
        batch_op.alter_column("scan_id", existing_type=sa.String(length=32), nullable=False)
        batch_op.drop_column("mode")
