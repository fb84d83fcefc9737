"""Simulated coincidence data: a ball on the flange seated in the sockets of a plate, by hand.

The truth: the nominal model with planted geometric errors, a tool point a little off its guess,
and several placements of a plate with sockets ``spacing`` apart. For each socket, the robot is
moved (as a person guides it) to configurations that put the true ball centre on the socket
centre, up to a seating scatter: from a configuration reaching the plate, each joint is turned at
random, then the arm is brought back onto the socket by the minimum joint change (Gauss-Newton on
the true model's tool point), so the orientations differ from sample to sample. The recorded
joints are those solutions: what the controller reads, with the true geometry.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from relcal import geometry as tf
from relcal.errors import RelcalError
from relcal.geometry import MM
from relcal.robot.ik import joint_layout, within_limits
from relcal.robot.kinematics import apply_errors, fk, make_layout, spatial_jacobian
from relcal.robot.model import RobotModel
from relcal.sim.scenario import random_errors

SOCKETS = ("hole_0", "hole_1")


@dataclass(frozen=True)
class CoincidenceTruth:
    """What a simulated coincidence dataset was made from (SI units).

    ``errors`` on ``make_layout(model)``; ``tool_point`` the true tool point in the tip frame
    (``tool_guess`` the one written as the guess); ``points`` ``{group: (3,)}`` the true socket
    centres in the base frame; ``q`` ``(N, n)`` the recorded joints and ``groups`` their groups.
    """

    model: RobotModel
    errors: np.ndarray
    tool_point: np.ndarray
    tool_guess: np.ndarray
    points: dict[str, np.ndarray]
    q: np.ndarray
    groups: tuple[str, ...]
    spacing: float
    seating: float

    @property
    def true_model(self) -> RobotModel:
        return apply_errors(self.model, make_layout(self.model), self.errors)


def _onto(
    model: RobotModel,
    q: np.ndarray,
    tool: np.ndarray,
    target: np.ndarray,
    iterations: int = 60,
    tol: float = 1e-11,
) -> tuple[np.ndarray, np.ndarray]:
    """Joints ``(N, n)`` moved by minimum-norm Gauss-Newton steps (clipped to the limits) until
    the tool point reaches ``target`` ``(N, 3)``, and whether each did."""
    joints = joint_layout(model)
    q = np.array(q, dtype=float)
    for _ in range(iterations):
        tip, spatial = spatial_jacobian(model, q, joints)
        y = tip[:, :3, :3] @ tool + tip[:, :3, 3]
        err = target - y
        if np.abs(err).max() < tol:
            break
        jp = spatial[:, :3] - tf.skew(y) @ spatial[:, 3:]
        step = (np.linalg.pinv(jp) @ err[:, :, None])[:, :, 0]
        step *= np.minimum(1.0, 0.3 / np.maximum(np.abs(step).max(axis=1), 1e-12))[:, None]
        q = np.clip(q + step, model.lower, model.upper)
    y = fk(model, q)
    miss = np.linalg.norm(y[:, :3, :3] @ tool + y[:, :3, 3] - target, axis=1)
    return q, (miss < 1e-9) & within_limits(model, q)


def simulate_coincidence(
    model: RobotModel,
    placements: int = 4,
    per_socket: int = 30,
    spacing: float = 0.050,
    seating: float = 0.08 * MM,
    errors: np.ndarray | None = None,
    tool_error: float = 0.5 * MM,
    turn: float = 0.5,
    seed: int = 0,
) -> CoincidenceTruth:
    """Joint readings of a ball seated ``per_socket`` times in each of two sockets ``spacing``
    apart, on ``placements`` placements of the plate.

    From the seed, in this order: random errors (:func:`relcal.sim.scenario.random_errors`)
    unless given; the true tool point ``tool_error`` (per axis) off the guess (the tip link's
    origin); per placement, a plate centre where a random configuration (the middle 60 % of the
    joint ranges) puts the tool point and a random heading in the horizontal plane; per socket,
    configurations turned by ``turn`` rad (per joint, normal) from that one and brought back onto
    the socket centre plus an isotropic normal scatter of ``seating`` (m) per axis.
    """
    rng = np.random.default_rng(seed)
    layout = make_layout(model)
    errors = random_errors(layout, rng) if errors is None else np.asarray(errors, dtype=float)
    true_model = apply_errors(model, layout, errors)
    guess = np.zeros(3)
    tool = guess + rng.normal(0.0, tool_error, 3)
    lo = np.where(np.isfinite(model.lower), model.lower, -np.pi)
    hi = np.where(np.isfinite(model.upper), model.upper, np.pi)
    mid, half = (lo + hi) / 2, (hi - lo) / 2 * 0.6
    points: dict[str, np.ndarray] = {}
    q_all, groups = [], []
    for j in range(placements):
        name = f"p{j}"
        for _attempt in range(200):
            centre_q = rng.uniform(mid - half, mid + half)
            tip = fk(true_model, centre_q[None])[0]
            centre = tip[:3, :3] @ tool + tip[:3, 3]
            if centre[2] > -0.1:  # above the base's mounting plane, roughly
                break
        heading = rng.uniform(0, 2 * np.pi)
        along = np.array([np.cos(heading), np.sin(heading), 0.0]) * spacing / 2
        for s, socket in enumerate(SOCKETS):
            point = centre + (along if s else -along)
            group = f"{name}/{socket}"
            points[group] = point
            got: list[np.ndarray] = []
            for _round in range(20):
                need = per_socket - len(got)
                if need <= 0:
                    break
                count = 2 * need + 4
                seeds = np.clip(centre_q + rng.normal(0.0, turn, (count, model.n_joints)), lo, hi)
                target = point + rng.normal(0.0, seating, (count, 3))
                q, ok = _onto(true_model, seeds, tool, target)
                got += list(q[ok][:need])
            if len(got) < per_socket:
                raise RelcalError(
                    f"simulated placement {name}: only {len(got)} of {per_socket} configurations "
                    f"reach {socket}"
                )
            q_all += got
            groups += [group] * per_socket
    return CoincidenceTruth(
        model=model,
        errors=errors,
        tool_point=tool,
        tool_guess=guess,
        points=points,
        q=np.array(q_all),
        groups=tuple(groups),
        spacing=spacing,
        seating=seating,
    )


def robot_entry(robot: str, root: str | None, tip: str | None) -> str | dict:
    """The ``robot:`` entry of dataset.yaml for ``--robot`` (a URDF referenced by its absolute
    path, not copied)."""
    path = Path(robot)
    if path.suffix.lower() == ".urdf":
        entry: dict = {"urdf": str(path.resolve())}
        if root:
            entry["root"] = root
        if tip:
            entry["tip"] = tip
        return entry
    if path.suffix.lower() in (".yaml", ".yml"):
        return str(path.resolve())
    return robot


def dataset_files(
    truth: CoincidenceTruth, robot: str | dict, distance_std: float | None = None
) -> dict[str, str]:
    """The files of a dataset folder: ``dataset.yaml`` (with the sockets' distance on every
    placement unless ``distance_std`` is None), ``samples.csv`` (joints in rad) and
    ``truth.yaml`` (the planted errors in mm and deg, the true tool point and socket centres)."""
    from relcal.data.dataset import write_coincidence_samples
    from relcal.io import yaml_text

    ids = [f"{k:04d}" for k in range(len(truth.q))]
    spec: dict = {
        "robot": robot,
        "hayati": "off",
        "measurement": "coincidence",
        "joint_unit": "rad",
        "samples": "samples.csv",
        "tool": {"xyz": [float(v) for v in truth.tool_guess]},
    }
    if distance_std is not None:
        placements = dict.fromkeys(g.rpartition("/")[0] for g in truth.groups)
        spec["distances"] = [
            {
                "groups": [f"{p}/{SOCKETS[0]}", f"{p}/{SOCKETS[1]}"],
                "distance": float(truth.spacing),
                "std": float(distance_std),
            }
            for p in placements
        ]
    layout = make_layout(truth.model)
    shown, _ = layout.display()
    truth_doc = {
        "units": "errors in mm and deg; points in m",
        "errors": {
            n: float(v * f) for n, v, f in zip(layout.names, truth.errors, shown, strict=True)
        },
        "tool_point": [float(v) for v in truth.tool_point],
        "points": {g: [float(v) for v in p] for g, p in truth.points.items()},
        "seating_mm": float(truth.seating * 1e3),
    }
    return {
        "dataset.yaml": yaml_text(spec),
        "samples.csv": write_coincidence_samples(ids, truth.groups, truth.q),
        "truth.yaml": yaml_text(truth_doc),
    }
