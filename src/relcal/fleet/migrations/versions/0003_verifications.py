"""The verifications table: a finished calibration's prediction errors on a new session.

Revision ID: 0003
Revises: 0002
"""

import sqlalchemy as sa
from alembic import op

revision = "0003"
down_revision = "0002"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "verifications",
        sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
        sa.Column("uid", sa.String(32), nullable=False, unique=True),
        sa.Column("calibration_id", sa.Integer, index=True),
        sa.Column("calibration", sa.Text, nullable=False),
        sa.Column("robot_id", sa.String(200), nullable=False),
        sa.Column("session", sa.String(200)),
        sa.Column("dataset_path", sa.Text, nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("relcal_version", sa.String(40), nullable=False),
        sa.Column("kind", sa.String(20), nullable=False),
        sa.Column("n_samples", sa.Integer, nullable=False),
        sa.Column("folds", sa.Integer, nullable=False),
        sa.Column("baseline_position_rms_mm", sa.Float),
        sa.Column("calibrated_position_rms_mm", sa.Float),
        sa.Column("baseline_orientation_rms_deg", sa.Float),
        sa.Column("calibrated_orientation_rms_deg", sa.Float),
        sa.Column("ratio_position", sa.Float),
        sa.Column("at_calibration_position_rms_mm", sa.Float),
        sa.Column("verdict", sa.String(20), nullable=False),
        sa.Column("intervals", sa.JSON, nullable=False),
        sa.Column("details", sa.JSON, nullable=False),
    )
    op.create_index("ix_verifications_robot_time", "verifications", ["robot_id", "created_at"])


def downgrade() -> None:
    op.drop_index("ix_verifications_robot_time", "verifications")
    op.drop_table("verifications")
