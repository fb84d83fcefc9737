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
    PAIRINGS,
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
    """A simulated calibration: the truth, the problem solved, and its result.

    Parameters
    ----------
    problem : Problem
        The identification problem of the simulated measurements.
    layout : Layout
        ``problem.full_layout``: what each entry of ``specified`` and ``result.params`` is.
    specified : (P,) ndarray of float
        The true errors (m, rad), in ``layout``.
    result : Result
        The identification.
    formulation : str
        The formulation of the identification (``published``, ``invariant``, ``board`` or
        ``absolute``): ``problem.formulation``.
    measure : {"pose", "position"}
        What was measured.
    noise : Noise
        The measurement noise simulated.
    pairing : str
        How the poses were compared: ``consecutive``, ``star``, ``all`` or ``board`` (``auto``
        resolved).
    """

    problem: Problem
    layout: Layout  # problem.full_layout
    specified: np.ndarray  # true errors, same layout
    result: Result
    formulation: Formulation
    measure: Measure
    noise: Noise
    pairing: PairStrategy = "consecutive"

    def pair_errors(self) -> tuple[np.ndarray, np.ndarray]:
        """Residuals per pair of the nominal model and of the identified one.

        Training residuals: the simulation holds nothing out.

        Returns
        -------
        nominal : (M, 6) ndarray of float
            Per pair the translation (m) and rotation vector (rad) of ``model^-1 measured``
            under the nominal model (no correction).
        identified : (M, 6) ndarray of float
            The same under the identified model.
        """
        zero = np.zeros_like(self.result.params)
        return pair_errors(self.problem, zero), pair_errors(self.problem, self.result.params)

    def identification_rms(self) -> tuple[float, float]:
        """RMS of identified minus specified error over the identifiable parameters.

        Returns
        -------
        lengths : float
            RMS over the length parameters, m; NaN where there are none.
        angles : float
            RMS over the angle parameters, rad; NaN where there are none.
        """
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
    """Run the published simulation once.

    The frame-invariant formulation starts from a hand-eye guess about 1 mm / 0.5 deg off the
    truth. One seeded stream draws the scenario (errors, guess, joints) and then the noise.

    Parameters
    ----------
    model : RobotModel
        The nominal robot.
    formulation : {"published", "invariant", "absolute"}
        The identification formulation (what the simulated poses are: base-aligned tool poses,
        or camera poses in the board frame for ``invariant``).
    measure : {"pose", "position"}
        Position and orientation, or position only.
    n_poses : int
        Number of joint configurations drawn (3 to 10,000: each is reached by inverse
        kinematics, about 20 ms).
    noise : Noise
        Measurement noise added (m, rad); none by default.
    seed : int
        Seed of the scenario and the noise.
    errors : (P,) ndarray of float, optional
        True errors (m, rad) following ``make_layout(model)``; random if None.
    method : {"published", "lm"}
        The solver, when ``options`` is not given.
    pairing : {"consecutive", "star", "all", "board", "auto"}
        Which pairs of poses form relative measurements, or ``board``: each camera pose against
        a fitted board frame (the board formulation, the board's 6-vector ``board.*`` estimated
        with the geometry and the hand-eye; ``formulation="invariant"`` only); ``auto`` is all
        pairs up to 300 poses and ``board`` above, as in :func:`relcal.calibrate`.
    cell : Cell, optional
        The board and camera of the frame-invariant formulation (default :class:`Cell`).
    options : SolverOptions, optional
        The solver's options (overrides ``method``).

    Returns
    -------
    Simulation
        The truth, the problem and the identification.

    Raises
    ------
    ArgumentError
        ``model`` not a :class:`RobotModel`, an unknown choice, ``board`` pairing of another
        formulation than ``invariant``, fewer than 3 poses, ``noise`` not a :class:`Noise`,
        ``cell`` not a :class:`~relcal.Cell`, ``options`` not :class:`~relcal.SolverOptions`.

    Examples
    --------
    >>> import relcal
    >>> sim = relcal.simulate(relcal.get_robot("franka_fr3"), n_poses=20, seed=0)  # no noise
    >>> lengths, angles = sim.identification_rms()  # m, rad: exact, held directions symmetries
    >>> bool(lengths < 1e-9 and angles < 1e-9)
    True
    """
    from relcal.checks import check_choice, check_instance, check_number, check_seed
    from relcal.limits import MAX_SIMULATED_POSES
    from relcal.robot.model import check_model

    check_model(model)
    check_choice(formulation, "formulation", ("published", "invariant", "absolute"))
    check_choice(measure, "measure", ("pose", "position"))
    check_number(n_poses, "n_poses", 3, MAX_SIMULATED_POSES, integer=True)  # (IK: 20 ms each)
    check_choice(method, "method", ("published", "lm"))
    check_choice(pairing, "pairing", PAIRINGS)
    if not isinstance(seed, np.random.Generator | np.random.SeedSequence):
        check_seed(seed)
    check_instance(noise, Noise, "noise", "a Noise (relcal.Noise(position=, orientation=), m, rad)")
    if cell is not None:
        check_instance(cell, Cell, "cell", "a Cell (relcal.Cell()) or None")
    if options is not None:
        check_instance(options, SolverOptions, "options", "SolverOptions(method=..., loss=...)")
    if errors is not None:
        from relcal.checks import check_vector
        from relcal.robot.kinematics import make_layout

        layout = make_layout(model)
        errors = check_vector(errors, "errors", layout.size, "make_layout(model).names (m, rad)")
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
        formulation=problem.formulation,
        measure=measure,
        noise=noise,
        pairing=scenario.pairing,
    )
