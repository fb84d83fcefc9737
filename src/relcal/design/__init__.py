"""Pose planning: the cell, feasibility and pose selection."""
