"""Joint configurations of an ISO 9283 accuracy test: cubes in the workspace, one tool orientation
per cube, each cube's points visited in cycles.

ISO 9283 (manipulating industrial robots, performance criteria and test methods) measures pose
accuracy and repeatability at five points of a cube placed in the workspace: ``P1`` at the centre
and ``P2`` .. ``P5`` on the cube's diagonal plane, a tenth of the diagonal in from its corners;
the robot visits ``P1`` .. ``P5`` in cycles with the tool at one orientation. A recording of
several such cubes is what laser-tracker users have on file (the Fraunhofer IPA UR10 series
among them): its relative motions within a cube are pure translations, its repeated visits are
repeatability data, and the orientations differ only from cube to cube. :func:`iso9283_joints`
gives those configurations for a simulation (:func:`relcal.sim.scenario.make_scenario` with
``q``), so that the calibration and its plausibility checks can be tried on this structure.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from relcal import geometry as tf
from relcal.errors import RelcalError
from relcal.robot.ik import solve
from relcal.robot.model import RobotModel

# The diagonal plane's four corners of a unit cube (half-edge 1) in the order P2 .. P5: the
# plane through two opposite edges parallel to z.
DIAGONAL_PLANE = np.array([[1, 1, 1], [-1, -1, 1], [-1, -1, -1], [1, 1, -1]], dtype=float)
INSET = 0.8  # P2 .. P5 a tenth of the diagonal in from the corners: 0.8 of the way out


def cube_points(centre: np.ndarray, edge: float) -> np.ndarray:
    """``P1`` .. ``P5`` ``(5, 3)`` of an ISO 9283 cube (m): its centre, then the four points on
    the diagonal plane a tenth of the diagonal in from its corners."""
    centre = np.asarray(centre, dtype=float)
    return np.vstack([centre, centre + INSET * 0.5 * edge * DIAGONAL_PLANE])


def iso9283_joints(
    model: RobotModel,
    cubes: Sequence[tuple[np.ndarray, np.ndarray]],
    tool: np.ndarray,
    edge: float = 0.3,
    visits: int = 3,
    q_near: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Joint configurations of an ISO 9283 recording: for each cube ``(centre (3,) m, tool
    rotation (3, 3) in the base frame)``, the tool frame (``tool`` ``(4, 4)``: flange-from-tool)
    at ``P1`` .. ``P5`` (:func:`cube_points`) with that one rotation, the cycle repeated
    ``visits`` times; cube after cube.

    Returns the joints ``(N, n)`` (rad; ``N = 5 * visits * len(cubes)``, the inverse kinematics
    nearest ``q_near``, the same branch for every point) and the cube of each row ``(N,)``.
    Raises :class:`RelcalError` naming the cube whose points the arm cannot reach."""
    if visits < 1 or not len(cubes):
        raise RelcalError("an ISO 9283 recording needs at least one cube and one visit")
    rows, which = [], []
    for c, (centre, rotation) in enumerate(cubes):
        targets = tf.homogeneous(np.asarray(rotation, float), cube_points(centre, edge))
        flange = targets @ tf.invert(np.asarray(tool, float))
        result = solve(model, flange, q_near)
        if not np.all(result.converged):
            missed = np.flatnonzero(~result.converged) + 1
            raise RelcalError(
                f"cube {c + 1} (centre {np.array2string(np.asarray(centre), precision=3)} m): "
                f"P{', P'.join(map(str, missed))} out of the arm's reach at that orientation"
            )
        rows += [result.q] * visits
        which += [c] * (5 * visits)
    return np.concatenate(rows), np.array(which)
