"""The session's name (its folder, or a label given by the user) beside the robot id.

Revision ID: 0002
Revises: 0001
"""

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("calibrations") as batch:
        batch.add_column(sa.Column("session", sa.String(200)))
    op.create_index("ix_calibrations_robot_time", "calibrations", ["robot_id", "created_at"])


def downgrade() -> None:
    op.drop_index("ix_calibrations_robot_time", "calibrations")
    with op.batch_alter_table("calibrations") as batch:
        batch.drop_column("session")
