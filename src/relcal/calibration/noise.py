"""The noise model of measured poses and joint readings."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from relcal.errors import RelcalError
from relcal.geometry import DEG, MM


@dataclass(frozen=True)
class Noise:
    """Standard deviations of measurement noise: position (m), orientation (rad), joints (rad)."""

    position: float = 0.0
    orientation: float = 0.0
    joints: float = 0.0

    @classmethod
    def parse(cls, text: str) -> Noise:
        """From ``"POS_MM,ORI_DEG[,JOINT_DEG]"``, e.g. ``"0.05,0.01,0.001"``."""
        try:
            values = [float(v) for v in text.split(",")]
        except ValueError:
            values = []
        if not 2 <= len(values) <= 3 or any(not np.isfinite(v) or v < 0 for v in values):
            raise RelcalError(
                f"--noise '{text}': expected POS_MM,ORI_DEG[,JOINT_DEG] as non-negative numbers"
            )
        values += [0.0] * (3 - len(values))
        return cls(values[0] * MM, values[1] * DEG, values[2] * DEG)


def robust_sigma(errors: np.ndarray) -> np.ndarray:
    """Per-row noise levels ``(6,)``: 1.4826 MAD of the translation and of the rotation rows."""
    sigma = np.empty(6)
    for rows in (slice(0, 3), slice(3, 6)):
        values = errors[:, rows].ravel()
        mad = 1.4826 * np.median(np.abs(values - np.median(values)))
        sigma[rows] = max(mad, 1e-12)
    return sigma
