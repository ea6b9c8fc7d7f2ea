"""bodies: stored bodies (synthesised, from a fit, edited), tenant-scoped

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-23 12:55:21.533876

"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

# revision identifiers, used by Alembic.
revision: str = "0004"
down_revision: str | Sequence[str] | None = "0003"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    """Upgrade schema."""
    op.create_table(
        "bodies",
        sa.Column("id", sa.String(length=32), nullable=False),
        sa.Column("tenant_id", sa.String(length=32), nullable=False),
        sa.Column("model", sa.String(length=64), nullable=False),
        sa.Column("sex", sa.String(length=16), nullable=False),
        sa.Column("source", sa.String(length=16), nullable=False),
        sa.Column("fit_id", sa.String(length=32), nullable=True),
        sa.Column("derived_from", sa.String(length=32), nullable=True),
        sa.Column("params", sa.JSON(), nullable=False),
        sa.Column("features", sa.JSON(), nullable=False),
        sa.Column("blob_key", sa.String(length=255), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(["derived_from"], ["bodies.id"], ondelete="SET NULL"),
        sa.ForeignKeyConstraint(["fit_id"], ["fits.id"], ondelete="CASCADE"),
        sa.ForeignKeyConstraint(["tenant_id"], ["tenants.id"], ondelete="CASCADE"),
        sa.PrimaryKeyConstraint("id"),
    )
    with op.batch_alter_table("bodies", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_bodies_derived_from"), ["derived_from"], unique=False)
        batch_op.create_index(batch_op.f("ix_bodies_fit_id"), ["fit_id"], unique=False)
        batch_op.create_index(
            "ix_bodies_tenant_created", ["tenant_id", "created_at", "id"], unique=False
        )


def downgrade() -> None:
    """Downgrade schema: the bodies' blob rows go with the table (their files stay in the
    blob store, under ``<tenant>/bodies/`` and ``<tenant>/fits/<fit>/bodies/``)."""
    op.execute("DELETE FROM blobs WHERE kind = 'body.npy'")
    with op.batch_alter_table("bodies", schema=None) as batch_op:
        batch_op.drop_index("ix_bodies_tenant_created")
        batch_op.drop_index(batch_op.f("ix_bodies_fit_id"))
        batch_op.drop_index(batch_op.f("ix_bodies_derived_from"))
    op.drop_table("bodies")
