"""Peers shared by the benchmark modules."""

from __future__ import annotations

import numpy as np
import scipy.optimize

from relcal.calibration.measurement import Problem, residuals


def fd_least_squares(problem: Problem, subset: np.ndarray) -> tuple[np.ndarray, bool]:
    """What a user without relcal would run: ``scipy.optimize.least_squares`` (LM, 2-point
    finite-difference Jacobian, tight tolerances) on relcal's residual, estimating ``subset``
    (given for free) from the nominal model. Returns the full parameter vector and convergence."""
    full = np.zeros(problem.full_layout.size)

    def expand(x: np.ndarray) -> np.ndarray:
        out = full.copy()
        out[subset] = x
        return out

    sol = scipy.optimize.least_squares(
        lambda x: -residuals(problem, expand(x), jacobian=False),
        np.zeros(len(subset)),
        jac="2-point",
        method="lm",
        x_scale="jac",
        xtol=1e-12,
        ftol=1e-12,
        gtol=1e-12,
    )
    return expand(sol.x), bool(sol.status > 0)
