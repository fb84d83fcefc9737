"""The simulated truth that every simulation uses: one robot in one cell with known errors.

A :class:`Scenario` fixes the nominal model, the cell (board pose, camera, mount drawing of the
hand-eye transform), the commanded joints, the true geometric errors, the true hand-eye transform
and the guess the identification starts from, the noise model and how the poses are measured and
paired. ``relcal simulate``, ``relcal study``, the synthetic image datasets, the observability
report's simulated poses and the benchmarks all build it with :func:`make_scenario`.

Conventions: the cell's hand-eye ``X`` is the mount drawing, the guess the identification starts
from; in the frame-invariant formulation the true ``X`` is about 1 mm / 0.5 deg off it and the
correction is estimated, the published and absolute ones take the true ``X`` (the drawing) as the
tool. A measured camera pose is the camera
in the board frame ``B^-1 F_true(q) X`` (frame-invariant), or in a base-aligned frame centred on
the board ``F_true(q) X - c`` (published; the board's position cancels in the differences), or in
the base frame (absolute).

The frame-invariant data are identified in pairs (consecutive, star or all), or with the pairing
``board`` by the board formulation: each camera pose against ``W F(q) X``, the board-from-base
``W`` estimated too, started (like a calibration) from
:func:`~relcal.calibration.measurement.board_guess` of the noise-free poses at the nominal model
and the hand-eye guess; its true value is the inverse of the cell's board pose.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pydantic

from relcal import geometry as tf
from relcal.calibration.measurement import (
    Formulation,
    Measure,
    PairStrategy,
    Problem,
    board_guess,
    camera_pairing,
    camera_problem,
)
from relcal.calibration.noise import Noise
from relcal.design.cell import Cell, joint_path, place_board
from relcal.errors import RelcalError
from relcal.geometry import DEG, MM
from relcal.io import load_validated
from relcal.robot.kinematics import Layout, apply_errors, fk, make_layout
from relcal.robot.model import NONGEOMETRIC_KINDS, RobotModel

HANDEYE_ERROR = (1 * MM, 0.5 * DEG)  # std per axis of the true hand-eye off the drawing (m, rad)


# Random non-geometric errors, from the same draws as lengths (0.1..0.9 mm) and angles: scale
# 100..900 ppm, compliance 10..90 urad/(N m) (1..9 um/N sliding), harmonics 0.001..0.09 deg.
_RANDOM_FACTOR = {"scale": 1.0, "compliance": 0.1, "harmonic_c": 0.1, "harmonic_s": 0.1}


def random_errors(layout: Layout, rng: np.random.Generator) -> np.ndarray:
    """Random errors with magnitudes 0.1..0.9 mm and 0.01..0.9 deg, random signs (non-geometric
    terms: see ``_RANDOM_FACTOR``)."""
    angle = layout.is_angle()
    size = np.where(angle, rng.uniform(0.01, 0.9, layout.size) * DEG, 0.0)
    size = np.where(angle, size, rng.uniform(0.1, 0.9, layout.size) * MM)
    factor = [_RANDOM_FACTOR.get(k, 1.0) for k in layout.kinds]
    sliding = [u == "m/N" for u in layout.units()]
    size = size * np.where(sliding, 0.01, factor)
    return size * rng.choice([-1.0, 1.0], layout.size)


class _ErrorsFile(pydantic.BaseModel):
    model_config = pydantic.ConfigDict(extra="forbid")
    length_unit: str = pydantic.Field("mm", pattern="^(m|mm)$")
    angle_unit: str = pydantic.Field("deg", pattern="^(rad|deg)$")
    errors: dict[str, pydantic.FiniteFloat]


def load_errors(path: str | Path, layout: Layout) -> np.ndarray:
    """Errors from a YAML file: ``errors: {theta_off[2]: 0.1, d[3]: -0.4, ...}`` in the declared
    units (default mm and deg); parameters not listed are zero. Non-geometric terms: ``scale[i]``
    as a plain number, ``compliance[i]`` in angle units per N m (length units per N for a
    prismatic joint), ``harmonic_c[i]`` and ``harmonic_s[i]`` in angle units."""
    spec = load_validated(_ErrorsFile, path)
    unknown = sorted(set(spec.errors) - set(layout.names))
    if unknown:
        hint = ""
        if any(n.split("[")[0] in NONGEOMETRIC_KINDS for n in unknown):
            hint = " (non-geometric terms need the joint's option: --nongeometric or the model)"
        raise RelcalError(
            f"{path}: errors: unknown parameter(s) {', '.join(unknown)}; "
            f"expected names like {', '.join(layout.names[:3])}, ...{hint}"
        )
    length = MM if spec.length_unit == "mm" else 1.0
    angle = DEG if spec.angle_unit == "deg" else 1.0
    per_unit = {"m": length, "rad": angle, "1": 1.0, "rad/(N m)": angle, "m/N": length}
    scale = np.array([per_unit[u] for u in layout.units()])
    values = np.array([spec.errors.get(n, 0.0) for n in layout.names])
    return values * scale


def nongeometric_in_errors(path: str | Path) -> dict[str, list[int]]:
    """The non-geometric terms an errors file names, with their joints (1-based):
    ``{"scale": [2], "harmonic": [1, 3]}``, so that a simulation can switch them on."""
    import re

    spec = load_validated(_ErrorsFile, path)
    out: dict[str, list[int]] = {}
    for name in spec.errors:
        match = re.fullmatch(r"(scale|compliance|harmonic_[cs])\[(\d+)\]", name)
        if match:
            term = "harmonic" if match[1].startswith("harmonic") else match[1]
            joints = out.setdefault(term, [])
            if int(match[2]) not in joints:
                joints.append(int(match[2]))
    return out


@dataclass(frozen=True)
class Scenario:
    """A simulated calibration: the truth and how it is measured.

    ``q`` ``(N, n)`` commanded joints (rad); ``errors`` true geometric errors on
    ``make_layout(model)`` (m, rad); ``handeye`` the true flange-from-camera ``X`` and
    ``handeye_guess`` the one the identification starts from (the cell's, the mount drawing).
    ``pairing``: how the poses are compared (``consecutive``, ``star``, ``all``, or ``board``:
    the board formulation, frame-invariant data only; :func:`make_scenario` resolves ``auto``).
    """

    model: RobotModel
    cell: Cell
    q: np.ndarray
    errors: np.ndarray
    handeye: np.ndarray
    handeye_guess: np.ndarray
    noise: Noise
    formulation: Formulation = "invariant"
    measure: Measure = "pose"
    pairing: PairStrategy = "consecutive"

    @property
    def true_model(self) -> RobotModel:
        """The nominal model with the true errors applied."""
        return apply_errors(self.model, make_layout(self.model), self.errors)

    @property
    def problem_formulation(self) -> Formulation:
        """The formulation of the identification problem: ``board`` for the board pairing, else
        :attr:`formulation`."""
        return "board" if self.pairing == "board" else self.formulation

    @functools.cached_property
    def board_guess(self) -> np.ndarray | None:
        """The board-from-base ``W`` ``(4, 4)`` the board formulation starts from (None for the
        other pairings): :func:`~relcal.calibration.measurement.board_guess` of the noise-free
        camera poses at the nominal model and :attr:`handeye_guess`, as a calibration guesses it
        from its measured poses; one guess per scenario, so that every noisy measurement of it
        is identified from the same start and the same ``board.*`` truth."""
        if self.pairing != "board":
            return None
        return board_guess(fk(self.model, self.q), clean_poses(self), self.handeye_guess)

    @property
    def noise_dimension(self) -> int:
        """Independent standard normals per measurement: 6 per pose, plus one per joint reading."""
        n_pose, n_joint = self.q.shape
        return n_pose * (6 + (n_joint if self.has_joint_noise else 0))

    @property
    def has_joint_noise(self) -> bool:
        return bool(np.any(np.asarray(self.noise.joints) > 0))


def simulated_joints(
    model: RobotModel, n_poses: int, seed: int | np.random.Generator, cell: Cell | None = None
) -> np.ndarray:
    """Joint values ``(K, n)``, ``K <= n_poses``, reaching the spiral of camera poses over the
    board of ``cell`` (default: :func:`relcal.design.cell.place_board`)."""
    cell = cell or place_board(model)
    q = joint_path(model, cell, n_poses, np.random.default_rng(seed))
    if len(q) < 3:
        raise RelcalError(f"only {len(q)} of {n_poses} simulated poses are reachable")
    return q


def make_scenario(
    model: RobotModel,
    q: np.ndarray | None = None,
    noise: Noise = Noise(),  # noqa: B008 (frozen, immutable)
    seed: int | np.random.Generator = 0,
    formulation: Formulation = "invariant",
    measure: Measure = "pose",
    pairing: PairStrategy = "consecutive",
    errors: np.ndarray | None = None,
    cell: Cell | None = None,
    n_poses: int = 30,
) -> Scenario:
    """A scenario in ``cell`` (default: :func:`relcal.design.cell.place_board`). From the seed, in
    this order: random errors (0.1..0.9 mm, 0.01..0.9 deg) unless given; for the frame-invariant
    formulation, the true hand-eye (:data:`HANDEYE_ERROR` per axis off the cell's); unless
    ``q`` is given, the joints of ``n_poses`` spiral poses (:func:`simulated_joints`).
    ``pairing`` is one of :data:`~relcal.calibration.measurement.PAIRINGS`, ``auto`` resolved by
    the number of poses and ``board`` checked against the formulation
    (:func:`~relcal.calibration.measurement.camera_pairing`: frame-invariant data only)."""
    rng = np.random.default_rng(seed)
    cell = cell or place_board(model)
    layout = make_layout(model)
    errors = random_errors(layout, rng) if errors is None else np.asarray(errors, dtype=float)
    truth = cell.handeye
    if formulation == "invariant":
        pos, ori = HANDEYE_ERROR
        offset = np.concatenate([rng.normal(0, pos, 3), rng.normal(0, ori, 3)])
        truth = cell.handeye @ tf.from_vector(offset)
    q = simulated_joints(model, n_poses, rng, cell) if q is None else q
    pairing = camera_pairing(formulation, pairing, len(q))
    return Scenario(
        model=model,
        cell=cell,
        q=np.asarray(q, dtype=float),
        errors=errors,
        handeye=truth,
        handeye_guess=cell.handeye,
        noise=noise,
        formulation=formulation,
        measure=measure,
        pairing=pairing,
    )


def clean_poses(scenario: Scenario) -> np.ndarray:
    """Noise-free measured poses ``(N, 4, 4)`` (see the module docstring)."""
    camera = fk(scenario.true_model, scenario.q) @ scenario.handeye
    if scenario.formulation == "invariant":
        return tf.invert(scenario.cell.board_pose) @ camera
    if scenario.formulation == "published":
        camera[:, :3, 3] -= scenario.cell.center
    return camera


def problem_for(scenario: Scenario, q: np.ndarray, poses: np.ndarray) -> Problem:
    """The identification problem for measured joints ``q`` and poses."""
    handeye = scenario.handeye_guess if scenario.formulation == "invariant" else scenario.handeye
    return camera_problem(
        scenario.model,
        q,
        handeye,
        scenario.formulation,
        scenario.measure,
        scenario.pairing,
        poses=poses,
        board=scenario.board_guess,
    )


def truth_vector(scenario: Scenario) -> np.ndarray:
    """The true parameters on the problem's full layout (hand-eye error as ``X_guess^-1 X``; for
    the board formulation then the board's as ``W_guess^-1 W``, ``W`` the inverse of the cell's
    board pose)."""
    if scenario.formulation != "invariant":
        return scenario.errors.copy()
    offset = tf.to_vector(tf.invert(scenario.handeye_guess) @ scenario.handeye)
    if scenario.pairing != "board":
        return np.concatenate([scenario.errors, offset])
    world = tf.invert(scenario.cell.board_pose)  # the board-from-base W
    board = tf.to_vector(tf.invert(scenario.board_guess) @ world)
    return np.concatenate([scenario.errors, offset, board])


def noisy_measurement(
    scenario: Scenario, clean: np.ndarray, z: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Joint readings ``(N, n)`` and measured poses ``(N, 4, 4)`` for standard normals ``z``
    ``(D,)``: pose errors ``C exp(eps)`` in the camera frame, joint errors added to the readings."""
    n_pose, n_joint = scenario.q.shape
    noise = scenario.noise
    sd = np.r_[np.full(3, noise.position), np.full(3, noise.orientation)]
    eps = z[: 6 * n_pose].reshape(n_pose, 6) * sd
    poses = clean @ tf.from_vector(eps)
    q = scenario.q
    if z.size > 6 * n_pose:
        q = q + z[6 * n_pose :].reshape(n_pose, n_joint) * np.asarray(noise.joints, dtype=float)
    return q, poses


def draw_normals(scenario: Scenario, rng: np.random.Generator) -> np.ndarray:
    """Standard normals ``(noise_dimension,)`` for one measurement of ``scenario``, drawn from
    ``rng`` in this order: position ``(N, 3)``, orientation ``(N, 3)`` (only if either is noisy),
    then joints ``(N, n)`` (only with joint noise)."""
    n_pose, n_joint = scenario.q.shape
    z = np.zeros((n_pose, 6))
    if scenario.noise.position != 0 or scenario.noise.orientation != 0:
        z[:, :3] = rng.standard_normal((n_pose, 3))
        z[:, 3:] = rng.standard_normal((n_pose, 3))
    if not scenario.has_joint_noise:
        return z.reshape(-1)
    return np.concatenate([z.reshape(-1), rng.standard_normal(n_pose * n_joint)])


def measure_once(
    scenario: Scenario, rng: np.random.Generator, clean: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """One noisy measurement of ``scenario`` from ``rng``: joint readings and poses."""
    clean = clean_poses(scenario) if clean is None else clean
    return noisy_measurement(scenario, clean, draw_normals(scenario, rng))
