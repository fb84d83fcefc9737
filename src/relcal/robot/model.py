"""Robot models: serial chains in standard or modified DH, with Hayati's beta, base and tool.

Conventions (DESIGN.md), per joint i (1-based in names):

- standard DH: ``A_i = Rz(theta_i + theta_off_i) Tz(d_i) Tx(a_i) Rx(alpha_i) Ry(beta_i)``
- modified DH: ``A_i = Rx(alpha_i) Ry(beta_i) Tx(a_i) Rz(theta_i + theta_off_i) Tz(d_i)``, where
  ``alpha_i`` and ``a_i`` are Craig's ``alpha_{i-1}`` and ``a_{i-1}``.

A prismatic joint adds its variable to ``d_i`` instead of ``theta_i``. ``F(q) = base A_1 ... A_n
tool``. A joint marked ``hayati`` gets ``beta`` as a geometric parameter in place of the ``d`` that
parallel axes make ill-posed: its own ``d`` in standard DH, the previous joint's in modified DH.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

import numpy as np
import pydantic
import yaml

from relcal import geometry as tf
from relcal.errors import RelcalError

if TYPE_CHECKING:
    from relcal.robot.urdf import Inertials, UrdfChain

KINDS = ("theta_off", "a", "d", "alpha", "beta")
ANGLE_KINDS = ("theta_off", "alpha", "beta")


@dataclass(frozen=True)
class RobotModel:
    """A serial chain. Arrays have one entry per joint; lengths in m, angles in rad."""

    name: str
    convention: Literal["dh", "mdh"]
    theta_off: np.ndarray
    d: np.ndarray
    a: np.ndarray
    alpha: np.ndarray
    beta: np.ndarray
    prismatic: np.ndarray
    hayati: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    joint_names: tuple[str, ...]
    base: np.ndarray = field(default_factory=lambda: np.eye(4))
    tool: np.ndarray = field(default_factory=lambda: np.eye(4))
    source: str = ""
    inertials: Inertials | None = None  # link masses in the joint frames (URDF models)
    urdf: UrdfChain | None = None  # the URDF it was loaded from, for exports back into it

    @property
    def n_joints(self) -> int:
        return len(self.theta_off)

    def geometric(self, kind: str) -> np.ndarray:
        """The per-joint array of one parameter kind (``theta_off``, ``a``, ``d``, ...)."""
        return getattr(self, kind)

    def with_values(self, **arrays: np.ndarray) -> RobotModel:
        """A copy with some arrays replaced."""
        return replace(self, **{k: np.asarray(v, dtype=float) for k, v in arrays.items()})

    def fixed_d(self) -> np.ndarray:
        """Mask of joints whose ``d`` is not a geometric parameter (replaced by a Hayati beta)."""
        fixed = np.zeros(self.n_joints, dtype=bool)
        for i in np.flatnonzero(self.hayati):
            j = i if self.convention == "dh" else i - 1
            if j >= 0:
                fixed[j] = True
        return fixed


# --- YAML schema ---------------------------------------------------------------------------------


class _Strict(pydantic.BaseModel):
    model_config = pydantic.ConfigDict(extra="forbid")


# a number written as a number: "90" (quoted) is refused, not read as 90
Number = Annotated[float, pydantic.Strict(), pydantic.AllowInfNan(False)]
MAX_LINK = 5.0  # m: a longer link length or offset looks like millimetres
MAX_FRAME = 20.0  # m: a base or tool offset beyond this looks like millimetres
MAX_LENGTH = 1e3  # m: beyond any machine


def plausible_length(value: float, limit: float, what: str) -> float:
    """``value`` (m) if plausible; a ValueError naming the likely unit mistake otherwise."""
    if abs(value) > MAX_LENGTH:
        raise ValueError(f"{value:g} m is not a physical {what} (lengths are in metres)")
    if abs(value) > limit:
        raise ValueError(
            f"{value:g} m looks like millimetres (a {what} above {limit:g} m is implausible); "
            "give lengths in metres"
        )
    return value


class _Transform(_Strict):
    xyz: tuple[Number, Number, Number] = (0.0, 0.0, 0.0)
    rpy: tuple[Number, Number, Number] = (0.0, 0.0, 0.0)

    @pydantic.field_validator("xyz")
    @classmethod
    def _metres(cls, xyz: tuple[float, float, float]) -> tuple[float, float, float]:
        for v in xyz:
            plausible_length(v, MAX_FRAME, "base or tool offset")
        return xyz


class _Joint(_Strict):
    name: str | None = None
    type: Literal["revolute", "prismatic"] = "revolute"
    theta_off: Number = 0.0
    d: Number = 0.0
    a: Number = 0.0
    alpha: Number = 0.0
    beta: Number = 0.0
    hayati: bool = False
    limits: tuple[Number, Number] | None = None

    @pydantic.field_validator("d", "a")
    @classmethod
    def _metres(cls, value: float) -> float:
        return plausible_length(value, MAX_LINK, "link length or offset")

    @pydantic.model_validator(mode="after")
    def _ordered_limits(self) -> _Joint:
        if self.limits is not None and self.limits[0] >= self.limits[1]:
            raise ValueError(f"limits must be [lower, upper] with lower < upper, got {self.limits}")
        return self


class _Robot(_Strict):
    name: str
    source: str = ""
    convention: Literal["dh", "mdh"]
    angle_unit: Literal["deg", "rad"] = "deg"
    joints: list[_Joint] = pydantic.Field(min_length=1)
    base: _Transform = _Transform()
    tool: _Transform = _Transform()

    @pydantic.model_validator(mode="after")
    def _names_and_angles(self) -> _Robot:
        names = [j.name for j in self.joints if j.name]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ValueError(f"joint names must be unique: {', '.join(twice)} named twice")
        full = 360.0 if self.angle_unit == "deg" else 2 * np.pi
        for i, j in enumerate(self.joints):
            for kind in ("theta_off", "alpha", "beta"):
                value = getattr(j, kind)
                if abs(value) <= full + 1e-9:
                    continue
                hint = (
                    "looks like degrees, but angle_unit: rad (set angle_unit: deg)"
                    if self.angle_unit == "rad" and abs(value) <= 360
                    else f"is beyond a full turn ({full:g} {self.angle_unit})"
                )
                raise ValueError(f"joints[{i}].{kind}: {value:g} {hint}")
            if self.angle_unit == "rad" and j.type == "revolute" and j.limits is not None:
                if max(abs(v) for v in j.limits) > 4 * np.pi + 1e-9:
                    raise ValueError(
                        f"joints[{i}].limits: {list(j.limits)} looks like degrees, but "
                        "angle_unit: rad (set angle_unit: deg)"
                    )
        return self


def model_from_dict(data: object, path: str | Path = "<robot>", node: object = None) -> RobotModel:
    """Build a model from parsed YAML; errors name ``path``, the line and the field."""
    from relcal.io import validate

    spec = validate(_Robot, data, path, node)  # type: ignore[arg-type]
    deg = spec.angle_unit == "deg"

    def ang(x: float) -> float:
        return float(np.radians(x)) if deg else float(x)

    joints = spec.joints
    prismatic = np.array([j.type == "prismatic" for j in joints])
    lower, upper = [], []
    for j, is_p in zip(joints, prismatic, strict=True):
        lim = j.limits if j.limits is not None else (-np.inf, np.inf)
        conv = (lambda x: float(x)) if is_p else ang
        lower.append(conv(lim[0]) if np.isfinite(lim[0]) else -np.inf)
        upper.append(conv(lim[1]) if np.isfinite(lim[1]) else np.inf)

    def frame(t: _Transform) -> np.ndarray:
        return tf.from_xyz_rpy(np.array(t.xyz), np.array([ang(v) for v in t.rpy]))

    return RobotModel(
        name=spec.name,
        convention=spec.convention,
        theta_off=np.array([ang(j.theta_off) for j in joints]),
        d=np.array([j.d for j in joints], dtype=float),
        a=np.array([j.a for j in joints], dtype=float),
        alpha=np.array([ang(j.alpha) for j in joints]),
        beta=np.array([ang(j.beta) for j in joints]),
        prismatic=prismatic,
        hayati=np.array([j.hayati for j in joints]),
        lower=np.array(lower),
        upper=np.array(upper),
        joint_names=tuple(j.name or f"joint{i + 1}" for i, j in enumerate(joints)),
        base=frame(spec.base),
        tool=frame(spec.tool),
        source=spec.source,
    )


def load_model(path: str | Path) -> RobotModel:
    """Load a robot model YAML file."""
    from relcal.io import load_yaml

    data, node = load_yaml(path)
    return model_from_dict(data, path, node)


def model_to_dict(model: RobotModel) -> dict:
    """The YAML form of a model (angles in degrees), the inverse of :func:`model_from_dict`."""

    def deg(x: float) -> float:
        return float(np.degrees(x))

    def frame(t: np.ndarray) -> dict:
        xyz, rpy = tf.to_xyz_rpy(t)
        return {"xyz": [float(v) for v in xyz], "rpy": [deg(v) for v in rpy]}

    joints = []
    for i in range(model.n_joints):
        p = bool(model.prismatic[i])
        j: dict = {"name": model.joint_names[i], "type": "prismatic" if p else "revolute"}
        j.update(
            theta_off=deg(model.theta_off[i]),
            d=float(model.d[i]),
            a=float(model.a[i]),
            alpha=deg(model.alpha[i]),
        )
        if model.beta[i] != 0 or model.hayati[i]:
            j["beta"] = deg(model.beta[i])
        if model.hayati[i]:
            j["hayati"] = True
        if np.isfinite(model.lower[i]) or np.isfinite(model.upper[i]):
            conv = float if p else deg
            j["limits"] = [conv(model.lower[i]), conv(model.upper[i])]
        joints.append(j)
    out = {"name": model.name}
    if model.source:
        out["source"] = model.source
    out.update(convention=model.convention, angle_unit="deg", joints=joints)
    out.update(base=frame(model.base), tool=frame(model.tool))
    return out


def dump_model(model: RobotModel) -> str:
    """The model as YAML text."""
    return yaml.safe_dump(model_to_dict(model), sort_keys=False)


# --- built-in library ----------------------------------------------------------------------------


def library_names() -> list[str]:
    """Names of the built-in robots (file stems under ``relcal/robot/library``)."""
    files = resources.files("relcal.robot") / "library"
    return sorted(p.name[:-5] for p in files.iterdir() if p.name.endswith(".yaml"))


def get_robot(
    name_or_path: str | Path,
    root: str | None = None,
    tip: str | None = None,
    parametrisation: str = "minimal",
) -> RobotModel:
    """A built-in robot by name (``a465``, ``puma560``, ...), a model YAML file by path, or the
    serial chain ``root`` -> ``tip`` of a URDF file (``.urdf``; root and tip may be omitted when
    the tree has one obvious serial chain; ``parametrisation``: ``minimal`` or ``origins``, see
    :func:`relcal.robot.urdf.load_urdf`)."""
    name = str(name_or_path)
    if Path(name).suffix.lower() in (".urdf", ".xacro"):
        from relcal.robot.urdf import load_urdf

        return load_urdf(name, root, tip, parametrisation)
    if root is not None or tip is not None:
        raise RelcalError(f"robot '{name}': root and tip links apply to URDF files (.urdf) only")
    if name.lower() in library_names():
        ref = resources.files("relcal.robot") / "library" / f"{name.lower()}.yaml"
        with resources.as_file(ref) as path:
            return load_model(path)
    if Path(name).suffix in (".yaml", ".yml") or Path(name).exists():
        return load_model(name)
    raise RelcalError(
        f"unknown robot '{name}': expected one of {', '.join(library_names())}, a model YAML file "
        "path or a URDF file (.urdf)"
    )


def parallel_axes(model: RobotModel, tol_deg: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Which joints' axes are parallel (within ``tol_deg``) to the previous joint's axis, and the
    angle between them (rad), both ``(n,)`` and indexed by the joint whose parameters carry
    Hayati's beta for the pair: in standard DH joint i's twist ``alpha_i`` lies between axes i and
    i+1 (so the first joint of the pair), in modified DH ``alpha_i`` lies between axes i-1 and i.
    Judged at the nominal geometry."""
    n = model.n_joints
    angle = np.arcsin(np.minimum(np.abs(np.sin(model.alpha)), 1.0))
    parallel = angle < np.radians(tol_deg)
    if model.convention == "dh":
        parallel[n - 1] = False  # the last twist lies between the last axis and the tool
    else:
        parallel[0] = False  # the first twist lies between the base frame and axis 1
    return parallel, angle


def auto_hayati(model: RobotModel, tol_deg: float = 1.0) -> RobotModel:
    """Mark joints whose axis is parallel (within ``tol_deg``) to the neighbouring one as Hayati
    joints (:func:`parallel_axes`)."""
    return replace(model, hayati=model.hayati | parallel_axes(model, tol_deg)[0])
