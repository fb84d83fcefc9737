"""The calibrations table: one row per calibration of one robot.

Revision ID: 0001
Revises:
"""

import sqlalchemy as sa
from alembic import op

revision = "0001"
down_revision = None
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "calibrations",
        sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
        sa.Column("uid", sa.String(32), nullable=False, unique=True),
        sa.Column("robot_id", sa.String(200), nullable=False, index=True),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False, index=True),
        sa.Column("relcal_version", sa.String(40), nullable=False),
        sa.Column("model_name", sa.String(200), nullable=False),
        sa.Column("dataset_path", sa.Text, nullable=False),
        sa.Column("outputs_path", sa.Text),
        sa.Column("settings", sa.JSON, nullable=False),
        sa.Column("input_hashes", sa.JSON, nullable=False),
        sa.Column("converged", sa.Boolean, nullable=False),
        sa.Column("rank", sa.Integer, nullable=False),
        sa.Column("parameters", sa.JSON, nullable=False),
        sa.Column("covariance", sa.JSON, nullable=False),
        sa.Column("baseline_position_rms_mm", sa.Float),
        sa.Column("baseline_orientation_rms_deg", sa.Float),
        sa.Column("calibrated_position_rms_mm", sa.Float),
        sa.Column("calibrated_orientation_rms_deg", sa.Float),
        sa.Column("validation", sa.JSON),
    )


def downgrade() -> None:
    op.drop_table("calibrations")
