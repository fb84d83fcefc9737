"""The published simulation: known geometric errors, camera poses in front of a board, IK, synthetic
measurements and identification (the tables are in :mod:`relcal.reporting.text`).

Flow (Lu & Hayes' flowchart): errors (random or from a file) -> end-effector poses over a working
region in front of the board -> inverse kinematics of the *nominal* model (what a controller would
command) -> true camera poses from the *true* model -> measurements with optional noise ->
identification -> comparison. The truth is a :class:`relcal.sim.scenario.Scenario`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from relcal.calibration.identify import Method, Result, SolverOptions, identify
from relcal.calibration.measurement import (
    Formulation,
    Measure,
    PairStrategy,
    Problem,
    pair_errors,
)
from relcal.calibration.noise import Noise
from relcal.design.cell import Cell
from relcal.robot.kinematics import Layout
from relcal.robot.model import RobotModel
from relcal.sim.scenario import make_scenario, measure_once, problem_for, truth_vector


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

    def pair_errors(self) -> tuple[np.ndarray, np.ndarray]:
        """Residuals ``(P, 6)`` per pair of the nominal model (no correction) and of the
        identified one (training residuals: the simulation holds nothing out)."""
        zero = np.zeros_like(self.result.params)
        return pair_errors(self.problem, zero), pair_errors(self.problem, self.result.params)

    def identification_rms(self) -> tuple[float, float]:
        """RMS of identified minus specified error over the identifiable parameters: lengths
        (m) and angles (rad); NaN where there are none."""
        ok, units = self.result.identifiable, np.array(self.layout.units())
        diff = self.result.params - self.specified
        out = []
        for mask in (units == "m", units == "rad"):
            d = diff[ok & mask]
            out.append(float(np.sqrt(np.mean(d**2))) if d.size else float("nan"))
        return out[0], out[1]


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
    cell: Cell | None = None,
    options: SolverOptions | None = None,
) -> Simulation:
    """Run the published simulation once. ``errors`` follows ``make_layout(model)`` (random if
    None); the frame-invariant formulation starts from a hand-eye guess about 1 mm / 0.5 deg off
    the truth. One seeded stream draws the scenario (errors, guess, joints) and then the noise."""
    from relcal.checks import check_choice, check_model, check_number

    check_model(model)
    check_choice(formulation, "formulation", ("published", "invariant", "absolute"))
    check_choice(measure, "measure", ("pose", "position"))
    check_number(n_poses, "n_poses", 3, integer=True)
    check_choice(method, "method", ("published", "lm"))
    check_choice(pairing, "pairing", ("consecutive", "star", "all"))
    rng = np.random.default_rng(seed)
    scenario = make_scenario(
        model,
        noise=noise,
        seed=rng,
        formulation=formulation,
        measure=measure,
        pairing=pairing,
        errors=errors,
        cell=cell,
        n_poses=n_poses,
    )
    q_read, measured = measure_once(scenario, rng)
    problem = problem_for(scenario, q_read, measured)
    result = identify(problem, options or SolverOptions(method=method))
    return Simulation(
        problem=problem,
        layout=problem.full_layout,
        specified=truth_vector(scenario),
        result=result,
        formulation=formulation,
        measure=measure,
        noise=noise,
    )
