"""Robot models: serial chains in standard or modified DH, with Hayati's beta, base and tool.

Conventions (DESIGN.md), per joint i (1-based in names):

- standard DH: ``A_i = Rz(theta_i + theta_off_i) Tz(d_i) Tx(a_i) Rx(alpha_i) Ry(beta_i)``
- modified DH: ``A_i = Rx(alpha_i) Ry(beta_i) Tx(a_i) Rz(theta_i + theta_off_i) Tz(d_i)``, where
  ``alpha_i`` and ``a_i`` are Craig's ``alpha_{i-1}`` and ``a_{i-1}``.

A prismatic joint adds its variable to ``d_i`` instead of ``theta_i``. ``F(q) = base A_1 ... A_n
tool``. A joint marked ``hayati`` gets ``beta`` as a geometric parameter in place of the ``d`` that
parallel axes make ill-posed: its own ``d`` in standard DH, the previous joint's in modified DH.

Non-geometric terms act through the effective joint value (``q`` is the joint reading, rad or m):

    q_eff = q (1 + scale) + compliance tau(q) + harmonic_c cos q + harmonic_s sin q   (per joint)

``tau_i`` is the gravity torque about joint i (N m; the force along it for a prismatic joint)
from the link masses and centres of mass and a lumped payload (:class:`Loads`), computed with
the geometry the loads were attached to (nominal kinematics, so it does not move with the
identified errors). ``nongeometric`` names, per joint, which of the terms are calibration
parameters (see :func:`relcal.robot.kinematics.make_layout`); all are off by default.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import pydantic

from relcal import geometry as tf
from relcal.checks import check_instance, check_path, describe
from relcal.errors import ArgumentError, RelcalError
from relcal.robot.priors import Priors

KINDS = ("theta_off", "a", "d", "alpha", "beta")
ANGLE_KINDS = ("theta_off", "alpha", "beta")
NONGEOMETRIC = ("scale", "compliance", "harmonic")  # options per joint
NONGEOMETRIC_KINDS = ("scale", "compliance", "harmonic_c", "harmonic_s")  # their parameters
GRAVITY = (0.0, 0.0, -9.81)  # m/s^2 in the base frame


@dataclass(frozen=True)
class Loads:
    """What gravity pulls on: per link the mass (kg) and centre of mass (m, in the frame after
    its joint, ``base A_1 ... A_i``), a lumped payload (kg; centre in the tool frame), gravity
    (m/s^2, base frame), and the geometry the torques are computed with (``reference``)."""

    mass: np.ndarray  # (n,)
    com: np.ndarray  # (n, 3)
    payload_mass: float
    payload_com: np.ndarray  # (3,)
    gravity: np.ndarray  # (3,)
    reference: RobotModel  # geometry only (no loads, no non-geometric values)

    @property
    def total_mass(self) -> float:
        return float(self.mass.sum() + self.payload_mass)


@dataclass(frozen=True)
class ChainJoint:
    """One URDF joint on the chain from root to tip (fixed ones included)."""

    name: str
    type: str
    parent: str
    child: str
    origin: np.ndarray  # (4, 4) parent link -> joint frame
    axis: np.ndarray  # (3,) unit vector in the joint frame (zeros for fixed joints)
    line: int  # line of the <joint> element in the file


@dataclass(frozen=True)
class UrdfChain:
    """What a model loaded from a URDF keeps of its file, for exports back into it.

    ``frames[i]`` ``(4, 4)`` is the URDF frame of movable joint i expressed in relcal's frame of
    joint i at ``q = 0`` (``base A_1(0) ... A_i(0)``): a rotation taking the URDF axis to z and
    a shift along z. It stays attached to relcal's frame when the model is calibrated.
    """

    path: str
    data: bytes  # the file as read, for byte-exact exports
    robot_name: str
    root: str
    tip: str
    joints: tuple[ChainJoint, ...]
    movable: tuple[int, ...]  # indices into ``joints`` of the n movable joints
    frames: np.ndarray  # (n, 4, 4)
    parametrisation: str = "minimal"  # the error parameters make_layout gives: minimal | origins


@dataclass(frozen=True)
class Inertials:
    """Rigid-body data of the n moving bodies, each in relcal's frame of its joint.

    Body i is every chain link that moves with joint i and no later joint (links hung off the
    chain are not included). Mass in kg, centre of mass in m, inertia in kg m^2 about the centre
    of mass, axes of the joint frame (``forward_frames(model, q)[:, i + 1]``).
    """

    mass: np.ndarray  # (n,)
    com: np.ndarray  # (n, 3)
    inertia: np.ndarray  # (n, 3, 3)


@dataclass(frozen=True)
class RobotModel:
    """A serial chain. Arrays have one entry per joint; lengths in m, angles in rad.

    Build one with :func:`relcal.get_robot`, :func:`relcal.load_model` or
    :func:`relcal.load_urdf`; it is frozen (:meth:`with_values` makes a changed copy).

    Parameters
    ----------
    name : str
        The robot's name (``a465``, or the URDF robot's name).
    convention : {"dh", "mdh"}
        Standard DH, ``A_i = Rz(theta_i + theta_off_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``, or
        modified DH (Craig), ``A_i = Rx(alpha_{i-1}) Tx(a_{i-1}) Rz(theta_i + theta_off_i)
        Tz(d_i)``.
    theta_off, d, a, alpha, beta : (n_joints,) ndarray of float
        The geometric parameters per joint: zero offset (rad), d and a (m), twist alpha (rad)
        and Hayati's beta (rad, used where ``hayati`` is set).
    prismatic : (n_joints,) ndarray of bool
        Joints that slide along their axis (``q`` in m) instead of turning (``q`` in rad).
    hayati : (n_joints,) ndarray of bool
        Joints modelled with Hayati's extra rotation ``Ry(beta)`` (consecutive parallel axes).
    lower, upper : (n_joints,) ndarray of float
        Joint limits, rad (m for prismatic joints).
    joint_names : tuple of str
        One name per joint, as in the samples table's header.
    base, tool : (4, 4) ndarray of float
        Fixed base and tool transforms (m); identity by default.
    source : str
        Where the model came from (a file path or a built-in name), for messages.
    inertials : Inertials or None
        Link masses in the joint frames (URDF models), or None.
    urdf : UrdfChain or None
        The URDF chain the model was loaded from (for exports back into it), or None.
    scale, compliance, harmonic_c, harmonic_s : (n_joints,) ndarray of float or None
        Non-geometric values per joint (zero: no effect): joint scale (1), compliance
        (rad/(N m), m/N for a prismatic joint), first harmonic cosine and sine (rad). None
        means zeros.
    nongeometric : tuple of tuple of str
        Per joint, the non-geometric terms (``scale``, ``compliance``, ``harmonic``) that are
        calibration parameters; empty tuples by default.
    loads : Loads or None
        Link masses and payload that gravity pulls on (for compliance), or None.
    priors : Priors
        Manufacturing tolerances per parameter kind that hold weakly determined directions
        (``priors:`` of the model file; :class:`relcal.robot.priors.Priors`).

    Raises
    ------
    ValueError
        A non-geometric array or ``nongeometric`` whose length is not the number of joints.
    """

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
    # Non-geometric values per joint (zero: no effect): scale (1), compliance (rad/(N m), m/N
    # for a prismatic joint), first harmonic (rad); None means zeros.
    scale: np.ndarray | None = None
    compliance: np.ndarray | None = None
    harmonic_c: np.ndarray | None = None
    harmonic_s: np.ndarray | None = None
    nongeometric: tuple[tuple[str, ...], ...] = ()  # per joint, the terms calibrated (or ())
    loads: Loads | None = None
    # Manufacturing tolerances that hold weakly determined directions (``priors:``).
    priors: Priors = field(default_factory=Priors)

    def __post_init__(self) -> None:
        # Zeros where not given; also when a copy changes the number of joints (``replace``
        # with new geometry arrays) and there is nothing to carry over.
        n = len(self.theta_off)
        for kind in NONGEOMETRIC_KINDS:
            value = getattr(self, kind)
            value = np.zeros(n) if value is None else np.asarray(value, dtype=float)
            if value.shape != (n,):
                if value.any():
                    raise ValueError(f"{kind} has shape {value.shape}, expected ({n},)")
                value = np.zeros(n)
            object.__setattr__(self, kind, value)
        if len(self.nongeometric) != n:
            if any(self.nongeometric):
                raise ValueError(f"nongeometric has {len(self.nongeometric)} joints, expected {n}")
            object.__setattr__(self, "nongeometric", ((),) * n)
        if self.loads is not None and len(self.loads.mass) != n:
            raise ValueError(f"loads have {len(self.loads.mass)} links, expected {n}")

    @property
    def n_joints(self) -> int:
        """Number of joints ``n_joints`` of the chain."""
        return len(self.theta_off)

    def __repr__(self) -> str:
        from relcal._repr import plural, short

        slides = int(np.count_nonzero(self.prismatic))
        joints = plural(self.n_joints, "joint") + (f" ({slides} prismatic)" if slides else "")
        hayati = [str(i + 1) for i in np.flatnonzero(self.hayati)]
        terms = sorted({t for flags in self.nongeometric for t in flags})
        return short(
            "RobotModel",
            repr(self.name),
            joints,
            {"dh": "standard DH", "mdh": "modified DH"}.get(self.convention, self.convention),
            f"Hayati beta at joint {', '.join(hayati)}" if hayati else "",
            f"non-geometric {', '.join(terms)}" if terms else "",
            f"from {Path(self.urdf.path).name}" if self.urdf is not None else "",
        )

    def has_nongeometric_values(self) -> bool:
        """Whether any non-geometric term changes the kinematics.

        Returns
        -------
        bool
            True when a scale, compliance or harmonic value of some joint is not zero.
        """
        return any(getattr(self, k).any() for k in NONGEOMETRIC_KINDS)

    def geometric(self, kind: str) -> np.ndarray:
        """The per-joint array of one parameter kind.

        Parameters
        ----------
        kind : str
            ``theta_off``, ``a``, ``d``, ``alpha``, ``beta``, ``scale``, ``compliance``,
            ``harmonic_c`` or ``harmonic_s``.

        Returns
        -------
        (n_joints,) ndarray of float
            The values, m or rad (scale 1, compliance rad/(N m) or m/N).
        """
        return getattr(self, kind)

    def with_values(self, **arrays: np.ndarray) -> RobotModel:
        """A copy with some arrays replaced.

        Parameters
        ----------
        **arrays : array_like
            New per-joint arrays by field name (``theta_off=...``, ``scale=...``), each
            ``(n_joints,)``, converted to float.

        Returns
        -------
        RobotModel
            The copy; this model is unchanged.
        """
        return replace(self, **{k: np.asarray(v, dtype=float) for k, v in arrays.items()})

    def fixed_d(self) -> np.ndarray:
        """Mask of joints whose ``d`` is not a geometric parameter (replaced by a Hayati beta).

        Returns
        -------
        (n_joints,) ndarray of bool
            True where ``d`` is held (the joint before a Hayati beta in modified DH, the same
            joint in standard DH).
        """
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
Mass = Annotated[float, pydantic.Strict(), pydantic.AllowInfNan(False), pydantic.Field(ge=0)]
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
    mass: Mass = 0.0
    com: tuple[Number, Number, Number] = (0.0, 0.0, 0.0)
    scale: Number = 0.0
    compliance: Number = 0.0
    harmonic: tuple[Number, Number] = (0.0, 0.0)
    nongeometric: list[Literal["scale", "compliance", "harmonic"]] = []

    @pydantic.field_validator("d", "a")
    @classmethod
    def _metres(cls, value: float) -> float:
        return plausible_length(value, MAX_LINK, "link length or offset")

    @pydantic.field_validator("com")
    @classmethod
    def _com_metres(cls, com: tuple[float, float, float]) -> tuple[float, float, float]:
        for v in com:
            plausible_length(v, MAX_LINK, "centre of mass coordinate")
        return com

    @pydantic.model_validator(mode="after")
    def _ordered_limits(self) -> _Joint:
        if self.limits is not None and self.limits[0] >= self.limits[1]:
            raise ValueError(f"limits must be [lower, upper] with lower < upper, got {self.limits}")
        if self.type == "prismatic" and ("harmonic" in self.nongeometric or any(self.harmonic)):
            raise ValueError(
                "a prismatic joint has no first harmonic (cos/sin of a length): "
                "remove harmonic from this joint"
            )
        return self


class _Payload(_Strict):
    mass: Mass
    com: tuple[Number, Number, Number] = (0.0, 0.0, 0.0)


class _ReferenceJoint(_Strict):
    theta_off: Number = 0.0
    d: Number = 0.0
    a: Number = 0.0
    alpha: Number = 0.0
    beta: Number = 0.0


class _GravityReference(_Strict):
    """The geometry the gravity torques of compliance are computed with, when it is not the
    model's own (a calibrated model keeps the nominal geometry its compliance was fitted with)."""

    joints: list[_ReferenceJoint] = pydantic.Field(min_length=1)
    base: _Transform = _Transform()
    tool: _Transform = _Transform()


class _Robot(_Strict):
    name: str
    source: str = ""
    convention: Literal["dh", "mdh"]
    angle_unit: Literal["deg", "rad"] = "deg"
    joints: list[_Joint] = pydantic.Field(min_length=1)
    base: _Transform = _Transform()
    tool: _Transform = _Transform()
    payload: _Payload | None = None
    gravity: tuple[Number, Number, Number] = GRAVITY
    priors: str | dict[str, Number] | None = None  # relcal.robot.priors.Priors.parse
    gravity_reference: _GravityReference | None = None

    @pydantic.model_validator(mode="after")
    def _reference_joints(self) -> _Robot:
        ref = self.gravity_reference
        if ref is not None and len(ref.joints) != len(self.joints):
            raise ValueError(
                f"gravity_reference has {len(ref.joints)} joints, the model {len(self.joints)}"
            )
        return self

    @pydantic.model_validator(mode="after")
    def _masses_for_compliance(self) -> _Robot:
        mass = sum(j.mass for j in self.joints) + (self.payload.mass if self.payload else 0.0)
        wanted = any("compliance" in j.nongeometric or j.compliance for j in self.joints)
        if wanted and mass == 0:
            raise ValueError(
                "compliance needs gravity torques: give link masses (mass, com per joint) or a "
                "payload {mass, com}"
            )
        return self

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


def with_loads(
    model: RobotModel,
    mass: np.ndarray | None = None,
    com: np.ndarray | None = None,
    payload_mass: float = 0.0,
    payload_com: np.ndarray | None = None,
    gravity: np.ndarray = GRAVITY,  # type: ignore[assignment]
) -> RobotModel:
    """``model`` with link masses (kg) ``(n,)``, centres of mass (m) ``(n, 3)`` in the link frames,
    a payload (kg, centre in the tool frame) and gravity (m/s^2, base frame). The gravity torques
    are computed with the present geometry of ``model`` from then on."""
    n = model.n_joints
    reference = replace(
        model,
        loads=None,
        **{k: None for k in NONGEOMETRIC_KINDS},
        nongeometric=(),
    )
    loads = Loads(
        mass=np.zeros(n) if mass is None else np.asarray(mass, dtype=float).reshape(n),
        com=np.zeros((n, 3)) if com is None else np.asarray(com, dtype=float).reshape(n, 3),
        payload_mass=float(payload_mass),
        payload_com=np.zeros(3) if payload_com is None else np.asarray(payload_com, float),
        gravity=np.asarray(gravity, dtype=float).reshape(3),
        reference=reference,
    )
    return replace(model, loads=loads)


def _has_inertials(model: RobotModel) -> bool:
    """Whether the model carries link masses from its URDF (in the same link frames as loads)."""
    return model.inertials is not None and float(np.sum(model.inertials.mass)) > 0


def nongeometric_options(model: RobotModel) -> tuple[str, ...]:
    """The non-geometric terms ``model`` can have: ``scale`` always, ``compliance`` when it has
    masses (loads, or a URDF's inertials), ``harmonic`` when it has a revolute joint (candidates
    for model selection)."""
    out = ["scale"]
    if (model.loads is not None and model.loads.total_mass > 0) or _has_inertials(model):
        out.append("compliance")
    if not model.prismatic.all():
        out.append("harmonic")
    return tuple(out)


def with_nongeometric(
    model: RobotModel, terms: tuple[str, ...] | list[str], joints: list[int] | None = None
) -> RobotModel:
    """``model`` with non-geometric ``terms`` (``scale``, ``compliance``, ``harmonic``) calibrated
    on ``joints`` (1-based; default all that can have them: harmonic skips prismatic joints).
    Compliance of a URDF robot without loads takes the URDF's link masses."""
    unknown = sorted(set(terms) - set(NONGEOMETRIC))
    if unknown:
        raise RelcalError(
            f"unknown non-geometric term(s) {', '.join(unknown)}: expected "
            f"{', '.join(NONGEOMETRIC)}"
        )
    chosen = range(1, model.n_joints + 1) if joints is None else joints
    if "compliance" in terms and model.loads is None and _has_inertials(model):
        model = with_loads(model, model.inertials.mass, model.inertials.com)  # from the URDF
    flags = [set(f) for f in model.nongeometric]
    for j in chosen:
        if not 1 <= j <= model.n_joints:
            raise RelcalError(f"joint {j} is not a joint of {model.name} (1..{model.n_joints})")
        for term in terms:
            if term == "harmonic" and model.prismatic[j - 1]:
                if joints is not None:
                    raise RelcalError(
                        f"joint {j} of {model.name} is prismatic: it has no first harmonic"
                    )
                continue
            flags[j - 1].add(term)
    if any("compliance" in f for f in flags) and (
        model.loads is None or model.loads.total_mass == 0
    ):
        raise RelcalError(
            f"compliance on {model.name} needs gravity torques: give link masses (mass, com per "
            "joint) or a payload {mass, com} in the robot model file"
        )
    ordered = tuple(tuple(t for t in NONGEOMETRIC if t in f) for f in flags)
    return replace(model, nongeometric=ordered)


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

    model = RobotModel(
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
        priors=Priors.parse(spec.priors, f"{path}: priors"),
    )
    masses = [j.mass for j in joints]
    if any(masses) or spec.payload is not None:
        payload = spec.payload or _Payload(mass=0.0)
        model = with_loads(
            model,
            mass=np.array(masses),
            com=np.array([j.com for j in joints]),
            payload_mass=payload.mass,
            payload_com=np.array(payload.com),
            gravity=np.array(spec.gravity),
        )
        if spec.gravity_reference is not None:
            ref = spec.gravity_reference
            geometry = replace(
                model.loads.reference,
                theta_off=np.array([ang(j.theta_off) for j in ref.joints]),
                d=np.array([j.d for j in ref.joints], dtype=float),
                a=np.array([j.a for j in ref.joints], dtype=float),
                alpha=np.array([ang(j.alpha) for j in ref.joints]),
                beta=np.array([ang(j.beta) for j in ref.joints]),
                base=frame(ref.base),
                tool=frame(ref.tool),
            )
            model = replace(model, loads=replace(model.loads, reference=geometry))
    if any(j.nongeometric for j in joints) or any(
        j.scale or j.compliance or any(j.harmonic) for j in joints
    ):
        model = replace(
            model,
            scale=np.array([j.scale for j in joints]),
            compliance=np.array(
                [
                    ang(j.compliance) if not p else j.compliance
                    for j, p in zip(joints, prismatic, strict=True)
                ]
            ),
            harmonic_c=np.array([ang(j.harmonic[0]) for j in joints]),
            harmonic_s=np.array([ang(j.harmonic[1]) for j in joints]),
            nongeometric=tuple(
                tuple(t for t in NONGEOMETRIC if t in j.nongeometric) for j in joints
            ),
        )
    return model


def load_model(path: str | Path) -> RobotModel:
    """Load a robot model YAML file.

    A YAML file that is not a robot model (no ``joints:`` list) is refused without its content
    in the message: a file named in the wrong place must not be shown.

    Parameters
    ----------
    path : str or Path
        The model file (``name``, ``convention`` and a ``joints:`` list; lengths in m, angles in
        degrees, see ``relcal/robot/library/a465.yaml``).

    Returns
    -------
    RobotModel
        The model, lengths in m and angles in rad.

    Raises
    ------
    ArgumentError
        ``path`` is not a str or Path.
    RelcalError
        The file is missing, too large, not YAML, not a robot model, or has a field of the wrong
        type or an unknown field (named with its line).
    """
    from relcal.io import load_yaml

    path = check_path(path, "path", "a robot model YAML file")
    data, node = load_yaml(path)
    if not isinstance(data, dict) or not isinstance(data.get("joints"), list):
        raise RelcalError(
            f"{path}: not a robot model file (a model YAML is a mapping with name, convention "
            "and a joints: list; see relcal/robot/library/a465.yaml)"
        )
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
        loads = model.loads
        if loads is not None and (loads.mass[i] or loads.com[i].any()):
            j.update(mass=float(loads.mass[i]), com=[float(v) for v in loads.com[i]])
        if model.scale[i]:
            j["scale"] = float(model.scale[i])
        if model.compliance[i]:
            j["compliance"] = float(model.compliance[i]) if p else deg(model.compliance[i])
        if model.harmonic_c[i] or model.harmonic_s[i]:
            j["harmonic"] = [deg(model.harmonic_c[i]), deg(model.harmonic_s[i])]
        if model.nongeometric[i]:
            j["nongeometric"] = list(model.nongeometric[i])
        joints.append(j)
    out = {"name": model.name}
    if model.source:
        out["source"] = model.source
    out.update(convention=model.convention, angle_unit="deg", joints=joints)
    out.update(base=frame(model.base), tool=frame(model.tool))
    if model.loads is not None:
        if model.loads.payload_mass:
            out["payload"] = {
                "mass": model.loads.payload_mass,
                "com": [float(v) for v in model.loads.payload_com],
            }
        if tuple(model.loads.gravity) != GRAVITY:
            out["gravity"] = [float(v) for v in model.loads.gravity]
        reference = _gravity_reference(model)
        if reference is not None:
            out["gravity_reference"] = reference
    if model.priors != Priors():
        out["priors"] = model.priors.to_dict()
    return out


_GEOMETRY = ("theta_off", "d", "a", "alpha", "beta", "base", "tool")


def _gravity_reference(model: RobotModel) -> dict | None:
    """The YAML form of the geometry the gravity torques are computed with (degrees), when it
    is not the model's own (a calibrated model with compliance: its compliance was fitted with
    the torques of the nominal geometry, and a reloaded file must give the same kinematics)."""
    if model.loads is None:
        return None
    ref = model.loads.reference
    if all(np.array_equal(getattr(ref, k), getattr(model, k)) for k in _GEOMETRY):
        return None

    def deg(x: float) -> float:
        return float(np.degrees(x))

    def frame(t: np.ndarray) -> dict:
        xyz, rpy = tf.to_xyz_rpy(t)
        return {"xyz": [float(v) for v in xyz], "rpy": [deg(v) for v in rpy]}

    joints = [
        {
            "theta_off": deg(ref.theta_off[i]),
            "d": float(ref.d[i]),
            "a": float(ref.a[i]),
            "alpha": deg(ref.alpha[i]),
            "beta": deg(ref.beta[i]),
        }
        for i in range(ref.n_joints)
    ]
    return {"joints": joints, "base": frame(ref.base), "tool": frame(ref.tool)}


def dump_model(model: RobotModel) -> str:
    """The model as YAML text."""
    from relcal.io import yaml_text

    return yaml_text(model_to_dict(model))


# --- built-in library ----------------------------------------------------------------------------


def library_names() -> list[str]:
    """Names of the built-in robots (file stems under ``relcal/robot/library``)."""
    files = resources.files("relcal.robot") / "library"
    return sorted(p.name[:-5] for p in files.iterdir() if p.name.endswith(".yaml"))


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


def restrict_limits(
    model: RobotModel, limits: dict[str, tuple[float, float]], source: str = "joint limits"
) -> RobotModel:
    """A copy of ``model`` with narrower joint limits: ``limits`` maps a joint name (or ``q1`` ..
    ``qn``) to ``(lower, upper)`` in rad (m for prismatic joints). A user's limits may narrow the
    robot's own, never widen them: a limit outside the robot's is refused (it would plan poses the
    controller stops at), naming ``source``."""
    lower, upper = model.lower.copy(), model.upper.copy()
    index = {name: i for i, name in enumerate(model.joint_names)}
    index.update({f"q{i + 1}": i for i in range(model.n_joints)})
    for name, (lo, hi) in limits.items():
        if name not in index:
            raise RelcalError(
                f"{source}: unknown joint '{name}'; the robot '{model.name}' has joints "
                f"{', '.join(model.joint_names)} (or q1..q{model.n_joints})"
            )
        i = index[name]
        unit, f = ("m", 1.0) if model.prismatic[i] else ("deg", np.degrees(1.0))
        if not lo < hi:
            raise RelcalError(
                f"{source}: {name}: lower {lo * f:g} {unit} must be below upper {hi * f:g} "
                f"{unit} (a joint that cannot move between its limits can be neither planned "
                "for nor calibrated): give LO:HI with LO < HI"
            )
        if lo < model.lower[i] - 1e-9 or hi > model.upper[i] + 1e-9:
            raise RelcalError(
                f"{source}: {name}: [{lo * f:g}, {hi * f:g}] {unit} goes beyond the robot's own "
                f"limits [{model.lower[i] * f:g}, {model.upper[i] * f:g}] {unit}; a user limit "
                "may only narrow them (wrong unit?)"
            )
        lower[i], upper[i] = lo, hi
    return replace(model, lower=lower, upper=upper)


def check_model(model: Any, name: str = "model") -> Any:
    """A :class:`relcal.robot.model.RobotModel`."""
    if isinstance(model, str | Path):
        raise ArgumentError(
            f"{name}: expected a RobotModel, got {describe(model)}: load it first, "
            f"relcal.get_robot({str(model)!r})"
        )
    return check_instance(model, RobotModel, name, "a RobotModel (relcal.get_robot('a465'))")
