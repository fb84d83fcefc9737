"""The published simulation: known geometric errors, camera poses in front of a board, IK, synthetic
measurements, identification, and the specified-versus-identified tables.

Flow (Lu & Hayes' flowchart): errors (random or from a file) -> end-effector poses over a working
region in front of the board -> inverse kinematics of the *nominal* model (what a controller would
command) -> true camera poses from the *true* model -> measurements with optional noise ->
identification -> comparison.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pydantic

from relcal import geometry as tf
from relcal.calibration.identify import Method, Result, SolverOptions, identify
from relcal.calibration.measurement import Formulation, Measure, PairStrategy, Problem, make_pairs
from relcal.calibration.noise import Noise
from relcal.design.cell import Setup, joint_path, place_board
from relcal.errors import RelcalError
from relcal.geometry import DEG, MM
from relcal.io import load_validated
from relcal.robot.kinematics import Layout, apply_errors, fk, make_layout
from relcal.robot.model import RobotModel


def random_errors(layout: Layout, rng: np.random.Generator) -> np.ndarray:
    """Random errors with magnitudes 0.1..0.9 mm and 0.01..0.9 deg, random signs."""
    angle = layout.is_angle()
    size = np.where(angle, rng.uniform(0.01, 0.9, layout.size) * DEG, 0.0)
    size = np.where(angle, size, rng.uniform(0.1, 0.9, layout.size) * MM)
    return size * rng.choice([-1.0, 1.0], layout.size)


class _ErrorsFile(pydantic.BaseModel):
    model_config = pydantic.ConfigDict(extra="forbid")
    length_unit: str = pydantic.Field("mm", pattern="^(m|mm)$")
    angle_unit: str = pydantic.Field("deg", pattern="^(rad|deg)$")
    errors: dict[str, pydantic.FiniteFloat]


def load_errors(path: str | Path, layout: Layout) -> np.ndarray:
    """Errors from a YAML file: ``errors: {theta_off[2]: 0.1, d[3]: -0.4, ...}`` in the declared
    units (default mm and deg); parameters not listed are zero."""
    spec = load_validated(_ErrorsFile, path)
    unknown = sorted(set(spec.errors) - set(layout.names))
    if unknown:
        raise RelcalError(
            f"{path}: errors: unknown parameter(s) {', '.join(unknown)}; "
            f"expected names like {', '.join(layout.names[:3])}, ..."
        )
    length = MM if spec.length_unit == "mm" else 1.0
    angle = DEG if spec.angle_unit == "deg" else 1.0
    scale = np.where(layout.is_angle(), angle, length)
    values = np.array([spec.errors.get(n, 0.0) for n in layout.names])
    return values * scale


@dataclass(frozen=True)
class Simulation:
    """A simulated calibration: the truth, the problem solved, and its result."""

    problem: Problem
    layout: Layout  # problem.full_layout
    specified: np.ndarray  # true errors, same layout
    result: Result
    formulation: Formulation
    measure: Measure
    noise: Noise


def simulate(
    model: RobotModel,
    formulation: Formulation = "published",
    measure: Measure = "pose",
    n_poses: int = 60,
    noise: Noise = Noise(),  # noqa: B008 (frozen, immutable)
    seed: int = 0,
    errors: np.ndarray | None = None,
    method: Method = "published",
    pairing: PairStrategy = "consecutive",
    setup: Setup | None = None,
    options: SolverOptions | None = None,
) -> Simulation:
    """Run the published simulation once. ``errors`` follows ``make_layout(model)`` (random if
    None); the invariant formulation also gets a random hand-eye error of about 1 mm / 0.5 deg."""
    rng = np.random.default_rng(seed)
    setup = setup or place_board(model)
    layout = make_layout(model)
    specified = random_errors(layout, rng) if errors is None else np.asarray(errors, float)
    handeye_error = np.zeros(0)
    truth_x = setup.handeye
    if formulation == "invariant":
        handeye_error = np.concatenate([rng.normal(0, 1 * MM, 3), rng.normal(0, 0.5 * DEG, 3)])
        truth_x = setup.handeye @ tf.from_vector(handeye_error)
    true_model = apply_errors(model, layout, specified)

    q = joint_path(model, setup, n_poses, rng)
    if len(q) < 3:
        raise RelcalError(f"only {len(q)} of {n_poses} simulated poses are reachable")
    camera = fk(true_model, q) @ truth_x
    if formulation == "invariant":
        board = tf.from_vector(np.array([0.55, 0.0, 0.0, np.pi, 0.0, 0.3]))  # unknown W
        measured = tf.invert(board) @ camera
    else:  # base-aligned, unknown board position
        measured = camera.copy()
        measured[:, :3, 3] -= setup.board_center
    measured = _add_noise(measured, noise, rng)
    q_read = q + rng.normal(0.0, noise.joints, q.shape) if noise.joints > 0 else q

    ident_model = model if formulation == "invariant" else _with_tool(model, setup.handeye)
    problem = Problem(
        model=ident_model,
        layout=layout,
        q=q_read,
        poses=measured,
        formulation=formulation,
        measure=measure,
        pairs=make_pairs(len(q), pairing),
        handeye=setup.handeye,
    )
    result = identify(problem, options or SolverOptions(method=method))
    return Simulation(
        problem=problem,
        layout=problem.full_layout,
        specified=np.concatenate([specified, handeye_error]),
        result=result,
        formulation=formulation,
        measure=measure,
        noise=noise,
    )


def _with_tool(model: RobotModel, handeye: np.ndarray) -> RobotModel:
    from dataclasses import replace

    return replace(model, tool=model.tool @ handeye)


def _add_noise(poses: np.ndarray, noise: Noise, rng: np.random.Generator) -> np.ndarray:
    """Perturb poses in their own frame by Gaussian translation (m) and rotation (rad) noise."""
    if noise.position == 0 and noise.orientation == 0:
        return poses
    n = len(poses)
    delta = np.concatenate(
        [rng.normal(0, noise.position, (n, 3)), rng.normal(0, noise.orientation, (n, 3))], axis=1
    )
    return poses @ tf.from_vector(delta)
