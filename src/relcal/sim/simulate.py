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

    def report(self) -> dict:
        """The JSON document of the README (SI units)."""
        r = self.result
        return {
            "robot": self.problem.model.name,
            "formulation": self.formulation,
            "measure": self.measure,
            "method": r.method,
            "n_poses": len(self.problem.q),
            "n_measurement_rows": r.n_residuals,
            "noise": {
                "position_m": self.noise.position,
                "orientation_rad": self.noise.orientation,
                "joints_rad": self.noise.joints,
            },
            "rank": r.identifiability.rank,
            "solver_rank": r.rank,
            "n_params": len(r.params),
            "unidentifiable": r.unidentifiable,
            "iterations": r.iterations,
            "converged": r.converged,
            "initial_residual_norm": r.initial_residual_norm,
            "residual_norm": r.residual_norm,
            "seconds": r.seconds,
            "parameters": [
                {
                    "name": name,
                    "unit": "rad" if is_angle else "m",
                    "specified": float(s),
                    "identified": float(v),
                    "identifiable": bool(ok),
                }
                for name, is_angle, s, v, ok in zip(
                    self.layout.names,
                    self.layout.is_angle(),
                    self.specified,
                    r.params,
                    r.identifiable,
                    strict=True,
                )
            ],
        }


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


# --- the published table -------------------------------------------------------------------------

_KIND_UNITS = {"theta_off": ("dtheta", "deg"), "alpha": ("dalpha", "deg"), "a": ("da", "mm")}
_KIND_UNITS["d"] = ("dd", "mm")


def _display(value: float, is_angle: bool) -> float:
    return float(np.degrees(value)) if is_angle else value / MM


def format_table(sim: Simulation) -> str:
    """Per joint the specified and identified errors of theta, alpha, a and d with percent error,
    RMS per kind, then beta/hand-eye rows, rank, residual, iterations, time and the unidentifiable
    combinations. Unidentifiable parameters show ``n/i`` instead of a number."""
    layout, r = sim.layout, sim.result
    where = {(k, i): p for p, (k, i) in enumerate(layout)}
    angle = layout.is_angle()
    kinds = ("theta_off", "alpha", "a", "d")
    head = " | ".join(f"{_KIND_UNITS[k][0] + ' (' + _KIND_UNITS[k][1] + ')':^27s}" for k in kinds)
    sub = " | ".join(f"{'specified':>9s} {'identified':>10s} {'err%':>6s}" for _ in kinds)
    lines = [f"joint | {head}", f"      | {sub}"]
    sq_err: dict[str, list[float]] = {k: [] for k in kinds}
    n_joints = sim.problem.model.n_joints
    for j in range(n_joints):
        cells = [_cell(sim, where.get((k, j)), sq_err[k]) for k in kinds]
        lines.append(f"{j + 1:^5d} | " + " | ".join(cells))
    rms = []
    for k in kinds:
        e = sq_err[k]
        rms.append(f"{np.sqrt(np.mean(np.square(e))):>27.3g}" if e else f"{'-':>27s}")
    lines.append("  RMS | " + " | ".join(rms) + "   (identified - specified, identifiable only)")
    extra = [p for p, (k, _) in enumerate(layout) if k not in kinds]
    if extra:
        lines.append("")
        lines.append(f"{'parameter':<14s} {'unit':>4s} {'specified':>10s} {'identified':>10s}")
        for p in extra:
            unit = "deg" if angle[p] else "mm"
            lines.append(f"{layout.names[p]:<14s} {unit:>4s} " + _cell(sim, p, None))
    lines += [
        "",
        f"rank {r.identifiability.rank} of {len(r.params)} parameters (scaled Jacobian at the "
        f"nominal model, tolerance {r.identifiability.rcond:g} x the largest singular value); "
        f"the solver's last step kept {r.rank}",
        f"{r.n_residuals} measurement rows; "
        f"{'converged' if r.converged else 'NOT converged'} in {r.iterations} iterations, "
        f"{r.seconds * 1e3:.1f} ms",
        f"residual norm {r.initial_residual_norm:.3e} -> {r.residual_norm:.3e} (m and rad)",
    ]
    if r.unidentifiable:
        lines.append("unidentifiable (n/i), with the reason:")
        lines += [f"  - {c}" for c in r.unidentifiable]
    named = {n for c in r.identifiability.combinations for n in c.names}
    curved = [
        n for n, ok in zip(layout.names, r.identifiable, strict=True) if not ok and n not in named
    ]
    if curved:
        lines.append(
            f"  - {', '.join(curved)}: drawn into one of these combinations at the estimate "
            "(the symmetry is curved), so not determined individually"
        )
    return "\n".join(lines)


def _cell(sim: Simulation, p: int | None, errors: list[float] | None) -> str:
    """``specified identified err%`` for parameter ``p`` (blank if not in the model)."""
    if p is None:
        return f"{'(fixed)':>27s}"
    is_angle = bool(sim.layout.is_angle()[p])
    spec = _display(sim.specified[p], is_angle)
    if not sim.result.identifiable[p]:
        return f"{spec:>9.4f} {'n/i':>10s} {'':>6s}"
    ident = _display(sim.result.params[p], is_angle)
    if errors is not None:
        errors.append(ident - spec)
    pct = f"{100 * abs(ident - spec) / abs(spec):6.2f}" if spec != 0 else f"{'-':>6s}"
    return f"{spec:>9.4f} {ident:>10.4f} {pct}"
