"""Forward kinematics, the geometric parameter vector, and its analytic identification Jacobian.

Everything is vectorised over N joint configurations ``q`` of shape ``(N, n)``.

The parameter vector is ordered by kind, as in the published formulation: all ``theta_off``, all
``a``, all ``d``, all ``alpha``, then ``beta`` of Hayati joints, then the non-geometric terms the
model asks for (``scale[i]``, ``compliance[i]``, ``harmonic_c[i]``, ``harmonic_s[i]``, kind by
kind), then optionally the base and tool transforms as 6-vectors of small motions in their own
frames (``base.tx`` ... ``base.rz``).

Robots loaded from a URDF with the ``origins`` parametrisation get instead, per joint, its zero
offset (``theta_off``, or ``d`` for a prismatic joint) and a motion of its URDF origin in the
joint's own frame (kind ``origin``, index ``6 * joint + component``), as robot_calibration and
FIGAROH parametrise: redundant, and the identifiability analysis names the redundancy. Both are
counted from the file's origins (the zero offset along the joint axis), so they add up and the
Jacobian is exact at any error (:func:`apply_errors`, :func:`_origin_screws`).

Non-geometric terms change the effective joint value (:func:`effective_joints`), so each one
moves the tool along its joint's screw, scaled by ``d q_eff / d parameter``: ``q``, the gravity
torque ``tau``, ``cos q`` or ``sin q``.
"""

from __future__ import annotations

import copy
import functools
import importlib.util
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from relcal import geometry as tf
from relcal.checks import check_array, check_flag, check_instance
from relcal.errors import ArgumentError, RelcalError
from relcal.robot.model import KINDS, NONGEOMETRIC_KINDS, RobotModel, check_model

FRAME_COMPONENTS = ("tx", "ty", "tz", "rx", "ry", "rz")
# SI unit of each kind of parameter; frame 6-vectors are m then rad.
_UNITS = {"theta_off": "rad", "alpha": "rad", "beta": "rad", "a": "m", "d": "m"}
_UNITS |= {"scale": "1", "compliance": "rad/(N m)", "harmonic_c": "rad", "harmonic_s": "rad"}
# How a person reads each unit: factor from SI and the shown unit.
DISPLAY_UNITS = {
    "m": (1e3, "mm"),
    "rad": (float(np.degrees(1.0)), "deg"),
    "1": (1e6, "ppm"),
    "rad/(N m)": (1e6, "urad/Nm"),
    "m/N": (1e6, "um/N"),
}


@dataclass(frozen=True)
class Layout:
    """Names and meaning of the entries of a parameter vector.

    Made by :func:`relcal.make_layout`; iterating gives ``(kind, index)`` per entry.

    Parameters
    ----------
    names : tuple of str
        ``P`` names a person reads, such as ``theta_off[2]`` or ``d[1]`` (1-based joints).
    kinds : tuple of str
        Per entry ``theta_off``, ``a``, ``d``, ``alpha``, ``beta``, ``origin``, a non-geometric
        kind (``scale``, ``compliance``, ``harmonic_c``, ``harmonic_s``), ``base`` or ``tool``
        (or the prefix of a frame added by :meth:`extended`).
    index : tuple of int
        Per entry the 0-based joint, or the component 0..5 of a 6-vector frame (x, y, z in m,
        then a rotation vector in rad).
    prismatic : tuple of int
        0-based joints that slide (their compliance is in m/N).
    """

    names: tuple[str, ...]
    kinds: tuple[str, ...]
    index: tuple[int, ...]
    prismatic: tuple[int, ...] = ()  # 0-based joints that slide (their compliance is in m/N)

    @property
    def size(self) -> int:
        """Number of entries ``P`` of the parameter vector."""
        return len(self.names)

    def units(self) -> tuple[str, ...]:
        """SI unit of each entry.

        Returns
        -------
        tuple of str
            ``P`` units: ``m``, ``rad``, ``1`` (scale), ``rad/(N m)`` or ``m/N`` (compliance);
            frame 6-vectors and URDF origins are three lengths then three angles.
        """
        out = []
        for k, i in self:
            if k == "compliance" and i in self.prismatic:
                out.append("m/N")
            elif k in _UNITS:
                out.append(_UNITS[k])
            else:
                out.append("rad" if i % 6 >= 3 else "m")  # frames and URDF origins
        return tuple(out)

    def display(self) -> tuple[np.ndarray, tuple[str, ...]]:
        """Factors from SI to the units a person reads, and those units.

        Returns
        -------
        factors : (P,) ndarray of float
            Multiply an SI parameter vector by these to show it (1000 for m to mm, ...).
        units : tuple of str
            ``P`` display units: mm, deg, ppm, urad/Nm or um/N.
        """
        shown = [DISPLAY_UNITS[u] for u in self.units()]
        return np.array([f for f, _ in shown]), tuple(u for _, u in shown)

    def is_angle(self) -> np.ndarray:
        """Mask of entries in radians.

        Returns
        -------
        (P,) ndarray of bool
            True for angles; lengths, scales and compliances are False.
        """
        return np.array([u == "rad" for u in self.units()], dtype=bool)

    def is_geometric(self) -> np.ndarray:
        """Mask of entries that are not non-geometric terms.

        Returns
        -------
        (P,) ndarray of bool
            False for ``scale``, ``compliance``, ``harmonic_c`` and ``harmonic_s`` entries.
        """
        return np.array([k not in NONGEOMETRIC_KINDS for k in self.kinds], dtype=bool)

    def __iter__(self):
        return iter(zip(self.kinds, self.index, strict=True))

    def extended(self, prefix: str, components: tuple[str, ...] = FRAME_COMPONENTS) -> Layout:
        """This layout followed by a frame or a point of nuisance parameters.

        Parameters
        ----------
        prefix : str
            The kind and name prefix of the new entries (e.g. ``handeye``).
        components : tuple of str
            Their components: a 6-vector frame by default (x, y, z in m, then a rotation vector
            in rad), or ``("x", "y", "z")`` for a point in m.

        Returns
        -------
        Layout
            ``P + len(components)`` entries, the new ones named ``prefix.component``.
        """
        names = tuple(f"{prefix}.{c}" for c in components)
        k = len(components)
        return Layout(
            self.names + names,
            self.kinds + (prefix,) * k,
            self.index + tuple(range(k)),
            self.prismatic,
        )


def _nongeometric_entries(model: RobotModel) -> list[tuple[str, int]]:
    """``(kind, joint)`` of the non-geometric terms that ``model.nongeometric`` asks for."""
    entries = []
    for kind in NONGEOMETRIC_KINDS:
        term = "harmonic" if kind.startswith("harmonic") else kind
        entries += [(kind, i) for i in range(model.n_joints) if term in model.nongeometric[i]]
    return entries


def make_layout(model: RobotModel, base: bool = False, tool: bool = False) -> Layout:
    """The parameters of ``model`` that a calibration can identify.

    The geometric parameters (the DH parameters, ordered by kind, or the URDF origins for URDF
    robots loaded with ``parametrisation: origins``), the non-geometric terms its joints ask for
    (``model.nongeometric``), plus base and tool 6-vectors if asked.

    Parameters
    ----------
    model : RobotModel
        The nominal robot.
    base, tool : bool
        Add the base, and the tool, transform as a 6-vector each (x, y, z in m, rotation vector
        in rad).

    Returns
    -------
    Layout
        Names, kinds and joints of the ``P`` entries of a parameter (error) vector.

    Raises
    ------
    ArgumentError
        ``model`` is not a :class:`RobotModel`.

    Examples
    --------
    >>> import relcal
    >>> layout = relcal.make_layout(relcal.get_robot("a465"))
    >>> layout.size, layout.names[:3]
    (24, ('theta_off[1]', 'theta_off[2]', 'theta_off[3]'))
    """
    check_model(model)
    check_flag(base, "base")
    check_flag(tool, "tool")
    if model.urdf is not None and model.urdf.parametrisation == "origins":
        return origins_layout(model, base, tool)
    n = model.n_joints
    fixed_d = model.fixed_d()
    entries: list[tuple[str, int]] = []
    for kind in ("theta_off", "a", "d", "alpha"):
        entries += [(kind, i) for i in range(n) if not (kind == "d" and fixed_d[i])]
    entries += [("beta", i) for i in range(n) if model.hayati[i]]
    entries += _nongeometric_entries(model)
    for frame, wanted in (("base", base), ("tool", tool)):
        if wanted:
            entries += [(frame, c) for c in range(6)]
    names = tuple(
        f"{k}.{FRAME_COMPONENTS[i]}" if k in ("base", "tool") else f"{k}[{i + 1}]"
        for k, i in entries
    )
    prismatic = tuple(int(i) for i in np.flatnonzero(model.prismatic))
    return Layout(names, tuple(k for k, _ in entries), tuple(i for _, i in entries), prismatic)


_PER_JOINT = re.compile(r"\b([a-z_]+)\[(\d+)\]")


def parameter_label(name: str, joint_names: Sequence[str] | None = None) -> str:
    """The name a parameter is shown by, in every command, file and report.

    A per-joint parameter ``kind[i]`` (1-based joint ``i``) of a robot loaded from a URDF is
    named after its joint, as a person reads the URDF (``theta_off[3]`` ->
    ``theta_off[arm_right_2_joint]``); every other name is shown as it is (the numbered joints
    of relcal's own robot files, frames such as ``handeye.tx``, URDF origins such as
    ``joint2.origin.x``, which already name their joint).

    Parameters
    ----------
    name : str
        The parameter's key, :attr:`Layout.names` (what files such as ``--errors``, the priors
        and the registry use).
    joint_names : sequence of str, optional
        The chain's joint names, first joint first, for a robot loaded from a URDF
        (:func:`label_joints`); None: the joints are numbered.

    Returns
    -------
    str
        The label.

    Examples
    --------
    >>> parameter_label("theta_off[2]", ["shoulder", "elbow"])
    'theta_off[elbow]'
    >>> parameter_label("theta_off[2]"), parameter_label("handeye.tx", ["shoulder"])
    ('theta_off[2]', 'handeye.tx')
    """
    match = _PER_JOINT.fullmatch(name)
    if match is None or not joint_names:
        return name
    index = int(match.group(2)) - 1
    if not 0 <= index < len(joint_names):
        return name
    return f"{match.group(1)}[{joint_names[index]}]"


def label_joints(model: RobotModel) -> tuple[str, ...] | None:
    """The joint names that :func:`parameter_label` names parameters by: the chain's, for a
    robot loaded from a URDF; None for relcal's own robot files (their joints are numbered)."""
    return None if model.urdf is None else tuple(model.joint_names)


def parameter_labels(model: RobotModel, names: Sequence[str]) -> dict[str, str]:
    """``{name: label}`` (:func:`parameter_label`) of the ``names`` whose label differs from
    the name, for ``model``'s robot: empty unless it was loaded from a URDF."""
    joints = label_joints(model)
    labels = {n: parameter_label(n, joints) for n in names}
    return {n: label for n, label in labels.items() if label != n}


def relabel(text: str, labels: dict[str, str]) -> str:
    """``text`` with every per-joint parameter name of ``labels`` (``kind[i]``) replaced by its
    label (:func:`parameter_labels`); labels already in ``text`` are left as they are."""
    if not labels:
        return text
    return _PER_JOINT.sub(lambda m: labels.get(m.group(0), m.group(0)), text)


ORIGIN_COMPONENTS = ("x", "y", "z", "rx", "ry", "rz")


def origins_layout(model: RobotModel, base: bool = False, tool: bool = False) -> Layout:
    """Per joint its zero offset (``{joint}.zero``: ``theta_off``, or ``d`` when prismatic) and
    a small motion of its URDF origin in its own frame (``{joint}.origin.x`` .. ``.rz``)."""
    names, kinds, index = [], [], []
    for i, joint in enumerate(model.joint_names):
        names.append(f"{joint}.zero")
        kinds.append("d" if model.prismatic[i] else "theta_off")
        index.append(i)
        for c, comp in enumerate(ORIGIN_COMPONENTS):
            names.append(f"{joint}.origin.{comp}")
            kinds.append("origin")
            index.append(6 * i + c)
    for kind, i in _nongeometric_entries(model):
        names.append(f"{kind}[{i + 1}]")
        kinds.append(kind)
        index.append(i)
    for frame, wanted in (("base", base), ("tool", tool)):
        if wanted:
            names += [f"{frame}.{c}" for c in FRAME_COMPONENTS]
            kinds += [frame] * 6
            index += list(range(6))
    prismatic = tuple(int(i) for i in np.flatnonzero(model.prismatic))
    return Layout(tuple(names), tuple(kinds), tuple(index), prismatic)


_FRAMES = ("base", "tool")


def apply_errors(model: RobotModel, layout: Layout, errors: np.ndarray) -> RobotModel:
    """The model with additive errors applied.

    Geometric and non-geometric values are added; base/tool errors move those frames locally;
    URDF origin errors move the joint origins (and the model is converted again, exactly).
    In a layout with origin entries the zero offsets (``theta_off``, ``d``) go into the origins
    too, along the joint axis (:func:`relcal.robot.urdf.zero_directions`): every origin error is
    then additive, ``apply_errors(apply_errors(m, l, x), l, y) == apply_errors(m, l, x + y)``,
    which :func:`pose_jacobian` differentiates exactly.

    Parameters
    ----------
    model : RobotModel
        The nominal robot.
    layout : Layout
        What each entry of ``errors`` is (:func:`relcal.make_layout` of ``model``).
    errors : (P,) array_like of float
        One error per entry of ``layout``, in its SI unit (m, rad, ...; :meth:`Layout.units`).

    Returns
    -------
    RobotModel
        A new model; ``model`` is unchanged.

    Raises
    ------
    ArgumentError
        ``errors`` of the wrong length or not finite, or ``model`` not a :class:`RobotModel`.
    RelcalError
        Origin errors for a model that was not loaded from a URDF.

    Examples
    --------
    >>> import numpy as np, relcal
    >>> model = relcal.get_robot("a465")
    >>> layout = relcal.make_layout(model)
    >>> errors = np.zeros(layout.size)
    >>> errors[layout.names.index("d[1]")] = 0.001  # 1 mm
    >>> float(relcal.apply_errors(model, layout, errors).d[0])
    0.331
    """
    check_model(model)
    check_layout(layout, model)
    return errors_applied(model, layout, check_errors(errors, layout))


def errors_applied(model: RobotModel, layout: Layout, errors: np.ndarray) -> RobotModel:
    """:func:`apply_errors` without its argument checks, for callers whose model, layout and
    ``errors`` ``(P,)`` are already checked (a solver's inner loop evaluates it every step)."""
    if not errors.any():  # the nominal model (a fit's first evaluation)
        return model
    plan = _error_plan(layout)
    if plan.origin_moves.size and np.any(errors[plan.origin_moves]):
        from relcal.robot.urdf import move_origins, zero_directions

        if model.urdf is None:
            raise RelcalError(f"'{model.name}': origin errors need a robot loaded from a URDF")
        motions = np.zeros((model.n_joints, 6))
        zero = zero_directions(model.urdf)
        for column in plan.origin_moves:
            kind, i = layout.kinds[column], layout.index[column]
            if kind == "origin":
                motions[i // 6, i % 6] += errors[column]
            else:  # a zero offset, along the joint axis
                motions[i] += errors[column] * zero[i]
        model = move_origins(model, motions)
    out = copy.copy(model)  # not replace(): the arrays keep their shapes, nothing to re-check
    for kind, columns, joints in plan.arrays:
        value = model.geometric(kind).copy()
        np.add.at(value, joints, errors[columns])
        object.__setattr__(out, kind, value)
    for frame, columns, components in plan.frames:
        vec = np.zeros(6)
        np.add.at(vec, components, errors[columns])
        if vec.any():
            object.__setattr__(out, frame, getattr(model, frame) @ tf.from_vector(vec))
    return out


@dataclass(frozen=True)
class _ErrorPlan:
    """Where :func:`errors_applied` puts each entry of a layout: the columns that move URDF
    origins, and per array kind or frame the columns and the joints (components) they change."""

    origin_moves: np.ndarray
    arrays: tuple[tuple[str, np.ndarray, np.ndarray], ...]
    frames: tuple[tuple[str, np.ndarray, np.ndarray], ...]


@functools.lru_cache(maxsize=64)
def _error_plan(layout: Layout) -> _ErrorPlan:
    kinds, index = np.array(layout.kinds), np.array(layout.index, dtype=int)
    folded = (
        np.isin(kinds, _ORIGIN_KINDS) if "origin" in layout.kinds else np.zeros(len(kinds), bool)
    )

    def groups(names) -> tuple[tuple[str, np.ndarray, np.ndarray], ...]:
        out = []
        for kind in names:
            columns = np.flatnonzero((kinds == kind) & ~folded)
            if columns.size:
                out.append((kind, columns, index[columns]))
        return tuple(out)

    return _ErrorPlan(np.flatnonzero(folded), groups(KINDS + NONGEOMETRIC_KINDS), groups(_FRAMES))


_ORIGIN_KINDS = ("origin", "theta_off", "d")  # what moves URDF origins in an origins layout


@functools.lru_cache(maxsize=64)
def _origin_entries(layout: Layout) -> np.ndarray:
    """Mask ``(P,)`` of the entries that move URDF origins: the origin 6-vectors and, in a layout
    that has them, the zero offsets (``theta_off``, ``d``)."""
    kinds = np.array(layout.kinds)
    if "origin" not in layout.kinds:
        return np.zeros(len(kinds), dtype=bool)
    return np.isin(kinds, _ORIGIN_KINDS)


def gravity_torques(model: RobotModel, q: np.ndarray) -> np.ndarray:
    """Gravity torque about each joint ``(N, n)`` (N m; force along the axis, N, for a prismatic
    joint) at joint readings ``q`` ``(N, n)``: the links after joint i and the payload pull with
    ``m g`` at their centres of mass. Computed with ``model.loads.reference`` (the geometry the
    loads were given with, no non-geometric terms); zeros without loads."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    loads = model.loads
    if loads is None:
        return np.zeros(q.shape)
    ref = loads.reference
    frames, c, s = _chain(ref, q)
    n = ref.n_joints
    centres = frames[:, 1:, :3, :3] @ loads.com[..., None]  # (N, n, 3, 1)
    centres = centres[..., 0] + frames[:, 1:, :3, 3]
    tip = frames[:, -1] @ ref.tool
    payload = tip[:, :3, :3] @ loads.payload_com + tip[:, :3, 3]
    weights = np.append(loads.mass, loads.payload_mass)[:, None] * loads.gravity  # (n + 1, 3)
    points = np.concatenate([centres, payload[:, None]], axis=1)  # (N, n + 1, 3)
    # Sums over the bodies beyond each joint: force, and moment about the base origin.
    force = np.cumsum(weights[::-1], axis=0)[::-1][:n]  # (n, 3)
    moment = np.cumsum(_cross(points, weights)[:, ::-1], axis=1)[:, ::-1][:, :n]  # (N, n, 3)
    axes, origins = _joint_screws(ref, frames, c, s)
    axis, origin = axes[:, :n], origins[:, :n]  # the theta_off screws: the joint axes
    torque = np.einsum("nij,nij->ni", axis, moment - _cross(origin, force))
    return np.where(ref.prismatic, np.einsum("nij,ij->ni", axis, force), torque)


def effective_joints(model: RobotModel, q: np.ndarray) -> np.ndarray:
    """Effective joint values ``(N, n)`` (rad or m) from readings ``q`` ``(N, n)``:
    ``q (1 + scale) + compliance tau(q) + harmonic_c cos q + harmonic_s sin q`` (harmonic terms on
    revolute joints only). ``q`` itself when the model has no non-geometric values."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if not model.has_nongeometric_values():
        return q
    out = q * (1.0 + model.scale)
    if model.compliance.any():
        out = out + model.compliance * gravity_torques(model, q)
    revolute = ~model.prismatic
    return out + revolute * (model.harmonic_c * np.cos(q) + model.harmonic_s * np.sin(q))


def _nongeometric_factors(model: RobotModel, q: np.ndarray, layout: Layout) -> np.ndarray:
    """``d q_eff / d parameter`` ``(N, P)`` for the non-geometric entries of ``layout`` (the
    others get 1)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    out = np.ones((len(q), layout.size))
    tau = None
    for p, (kind, i) in enumerate(layout):
        if kind == "scale":
            out[:, p] = q[:, i]
        elif kind == "compliance":
            tau = gravity_torques(model, q) if tau is None else tau
            out[:, p] = tau[:, i]
        elif kind == "harmonic_c":
            out[:, p] = np.cos(q[:, i])
        elif kind == "harmonic_s":
            out[:, p] = np.sin(q[:, i])
    return out


def _joint_values(model: RobotModel, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Total joint angles and offsets ``(N, n)``: the effective joint variable goes to theta or
    d."""
    q = effective_joints(model, q)
    theta = model.theta_off + np.where(model.prismatic, 0.0, q)
    d = model.d + np.where(model.prismatic, q, 0.0)
    return theta, d


def _twist_rotations(model: RobotModel) -> np.ndarray:
    """``Rx(alpha_i) Ry(beta_i)`` per joint, ``(n, 3, 3)``, written out."""
    ca, sa = np.cos(model.alpha), np.sin(model.alpha)
    cb, sb = np.cos(model.beta), np.sin(model.beta)
    zero = np.zeros_like(ca)
    rows = [cb, zero, sb, sa * sb, ca, -sa * cb, -ca * sb, sa, ca * cb]
    return np.stack(rows, axis=-1).reshape(-1, 3, 3)


def _link_transforms(model: RobotModel, q: np.ndarray) -> np.ndarray:
    """Joint transforms ``A_i``, shape ``(N, n, 4, 4)``."""
    theta, d = _joint_values(model, q)
    return _links(model, np.cos(theta), np.sin(theta), d)


def _link_parts(
    model: RobotModel, c: np.ndarray, s: np.ndarray, d: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The two factors of the joint transforms, from ``cos``/``sin`` of the total joint angles
    and the total offsets ``d`` ``(N, n)``: ``Rz(theta) Tz(d)`` ``(N, n, 4, 4)``, and the
    constant ``Tx(a) Rx(alpha) Ry(beta)`` (DH: ``A_i = Rz Tz C_i``) or ``Rx(alpha) Ry(beta)
    Tx(a)`` (MDH: ``A_i = C_i Rz Tz``) ``(n, 4, 4)``."""
    turn = np.zeros((*d.shape, 4, 4))
    turn[..., 0, 0], turn[..., 0, 1], turn[..., 2, 3] = c, -s, d
    turn[..., 1, 0], turn[..., 1, 1] = s, c
    turn[..., 2, 2] = turn[..., 3, 3] = 1.0
    rc = _twist_rotations(model)  # (n, 3, 3)
    constant = np.zeros((len(rc), 4, 4))
    constant[:, :3, :3] = rc
    constant[:, 3, 3] = 1.0
    if model.convention == "dh":
        constant[:, 0, 3] = model.a
    else:
        constant[:, :3, 3] = model.a[:, None] * rc[..., 0]
    return turn, constant


def _links(model: RobotModel, c: np.ndarray, s: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Joint transforms ``A_i`` ``(N, n, 4, 4)`` (see :func:`_link_parts`)."""
    turn, constant = _link_parts(model, c, s, d)
    return turn @ constant if model.convention == "dh" else constant @ turn


def _chain(model: RobotModel, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frames ``base A_1 ... A_i`` for i = 0..n ``(N, n + 1, 4, 4)``, with ``cos`` and ``sin`` of
    the total joint angles ``(N, n)`` (the Jacobian needs them again)."""
    theta, d = _joint_values(model, q)
    c, s = np.cos(theta), np.sin(theta)
    turn, constant = _link_parts(model, c, s, d)
    n_conf, n = d.shape
    frames = np.empty((n_conf, n + 1, 4, 4))
    frames[:, 0] = model.base
    # A joint's constant factor is the same for every configuration: one matrix product over
    # the frames' stacked rows (F C) applies it to all of them.
    for i in range(n):
        if model.convention == "dh":
            rows = (frames[:, i] @ turn[:, i]).reshape(-1, 4) @ constant[i]
            frames[:, i + 1] = rows.reshape(n_conf, 4, 4)
        else:
            rows = frames[:, i].reshape(-1, 4) @ constant[i]
            frames[:, i + 1] = rows.reshape(n_conf, 4, 4) @ turn[:, i]
    return frames, c, s


def forward_frames(model: RobotModel, q: np.ndarray) -> np.ndarray:
    """Frames ``base A_1 ... A_i`` for i = 0..n, shape ``(N, n + 1, 4, 4)`` (tool not applied)."""
    return _chain(model, q)[0]


Backend = Literal["auto", "numpy", "numba"]
_LOAD_MIN = 50_000  # configurations that pay for loading the kernel (~0.5 s; compiling ~3 s)


def _fast_available() -> bool:
    return importlib.util.find_spec("numba") is not None


def _use_fast(backend: Backend, n_conf: int) -> bool:
    if backend == "numpy":
        return False
    if backend == "numba":
        if not _fast_available():
            raise RelcalError(
                "backend='numba' needs the numba package, which is optional: "
                "pip install 'relcal[fast]' (or use backend='numpy', the default path)"
            )
        return True
    if backend != "auto":
        raise ArgumentError(f"unknown FK backend '{backend}': use auto, numpy or numba")
    # By batch size alone, not by whether the kernel happens to be loaded: the same call gives
    # the same round-off in every process (worker pools must agree with a serial run).
    return n_conf >= _LOAD_MIN and _fast_available()


def fk(model: RobotModel, q: np.ndarray, backend: Backend = "numpy") -> np.ndarray:
    """Flange/tool poses in the base frame, ``F(q)``: base, joint and tool transforms chained.

    ``backend="numpy"`` (the default) is the reference implementation; ``"numba"`` the compiled
    kernel of :mod:`relcal.robot.fastkin` (same result to round-off, about 40 times faster on large
    batches); ``"auto"`` takes the kernel when Numba is installed and the batch is large enough to
    pay for loading it (``_LOAD_MIN`` configurations), so small batches never import Numba. Numba
    is optional (the ``fast`` extra): ``"numba"`` without it raises :class:`RelcalError`; the
    default never depends on whether it is installed. Non-geometric terms enter both paths
    through :func:`effective_joints`.

    Parameters
    ----------
    model : RobotModel
        The robot.
    q : (n_joints,) or (N, n_joints) array_like of float
        One configuration or a batch: joint values in rad (m for prismatic joints).
    backend : {"numpy", "numba", "auto"}
        Which implementation computes the poses.

    Returns
    -------
    (4, 4) or (N, 4, 4) ndarray of float
        The homogeneous transform(s) base-from-tool, translation in m.

    Raises
    ------
    ArgumentError
        ``q`` with the wrong number of joints, or not finite; ``model`` not a
        :class:`RobotModel`.
    RelcalError
        ``backend="numba"`` and the compiled kernel cannot be loaded.

    Examples
    --------
    >>> import numpy as np, relcal
    >>> model = relcal.get_robot("a465")
    >>> pose = relcal.fk(model, np.zeros(6))
    >>> pose.shape, np.round(pose[:3, 3], 3) + 0.0  # the flange position, m
    ((4, 4), array([ 0.303,  0.   , -0.076]))
    >>> relcal.fk(model, np.zeros((5, 6))).shape
    (5, 4, 4)
    """
    from relcal.checks import check_choice, check_joints

    check_model(model)
    check_choice(backend, "backend", ("numpy", "numba", "auto"))
    if np.ndim(q) == 1:  # one configuration: one pose (4, 4)
        return fk(model, np.asarray(q, dtype=float)[None], backend)[0]
    q = check_joints(q, model.n_joints, "q", model.name)
    if _use_fast(backend, q.shape[0]):
        try:
            from relcal.robot import fastkin
        except Exception as exc:  # e.g. Numba finds no writable cache directory
            if backend == "numba":
                raise RelcalError(f"the compiled FK kernel could not be loaded: {exc}") from exc
        else:
            return fastkin.fk(model, effective_joints(model, q))
    links = _link_transforms(model, q)
    out = np.broadcast_to(model.base, (links.shape[0], 4, 4))
    for i in range(links.shape[1]):
        out = out @ links[:, i]
    return out @ model.tool


_JOINT_KINDS = ("theta_off", "a", "d", "alpha", "beta")
_ROTATIONS = ("theta_off", "alpha", "beta")  # the other joint kinds translate


def _joint_screws(
    model: RobotModel, frames: np.ndarray, c: np.ndarray, s: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Axes and points on them ``(N, 5 n, 3)`` (base frame) that a unit change of each joint
    parameter rotates about or translates along, ordered kind by kind as ``_JOINT_KINDS``;
    ``c``, ``s``: cosine and sine of the total joint angles."""
    rot, origin = frames[:, :-1, :3, :3], frames[:, :-1, :3, 3]  # frame before each joint
    after = frames[:, 1:, :3]  # frame after each joint
    if model.convention == "dh":  # Rz(theta) Tz(d) Tx(a) Rx(alpha) Ry(beta)
        c, s = c[..., None], s[..., None]
        z_axis = rot[..., 2]
        x_axis = rot[..., 0] * c + rot[..., 1] * s  # x after Rz(theta)
        link_origin = after[..., 3]
        # theta_off, a, d, alpha, beta
        axes = (z_axis, x_axis, z_axis, x_axis, after[..., 1])
        points = (origin, origin, origin, link_origin, link_origin)
    else:  # modified DH: Rx(alpha) Ry(beta) Tx(a) Rz(theta) Tz(d)
        ca, sa = np.cos(model.alpha)[:, None], np.sin(model.alpha)[:, None]
        y_alpha = rot[..., 1] * ca + rot[..., 2] * sa  # y after Rx(alpha)
        x_ab = np.einsum("nikl,il->nik", rot, _twist_rotations(model)[..., 0])
        joint_origin = origin + model.a[:, None] * x_ab
        z_axis = after[..., 2]  # Rz(theta) keeps z: the joint axis
        axes = (z_axis, x_ab, z_axis, rot[..., 0], y_alpha)
        points = (joint_origin, origin, joint_origin, origin, origin)
    return np.concatenate(axes, axis=1), np.concatenate(points, axis=1)


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``u x v`` over the last axis (``np.cross`` costs more on small batches)."""
    return np.stack(
        [
            u[..., 1] * v[..., 2] - u[..., 2] * v[..., 1],
            u[..., 2] * v[..., 0] - u[..., 0] * v[..., 2],
            u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0],
        ],
        axis=-1,
    )


@functools.lru_cache(maxsize=64)
def _slots(layout: Layout, n_joints: int) -> tuple[np.ndarray, ...]:
    """Where each parameter's screw is found: joint parameters index the ``(kind, joint)`` table
    of :func:`_joint_screws` flattened (kind-major); frame parameters name their component."""
    kinds, index = np.array(layout.kinds), np.array(layout.index, dtype=int)
    # A non-geometric term moves the tool along its joint's own screw (theta_off or d).
    sliding = np.isin(index, layout.prismatic)
    on_joint = np.isin(kinds, NONGEOMETRIC_KINDS)
    kinds = np.where(on_joint, np.where(sliding, "d", "theta_off"), kinds)
    joint = np.isin(kinds, _JOINT_KINDS)
    frames = ("base", "tool", "origin")
    if np.any(~joint & ~np.isin(kinds, frames)):
        bad = kinds[~joint & ~np.isin(kinds, frames)][0]
        raise ValueError(f"parameter kind '{bad}' is not a kinematic parameter")
    table = np.array(
        [_JOINT_KINDS.index(k) if j else 0 for k, j in zip(kinds, joint, strict=True)], dtype=int
    )
    rotation = np.where(joint, np.isin(kinds, _ROTATIONS), index % 6 >= 3)
    return (
        np.flatnonzero(joint),
        table[joint] * n_joints + index[joint],
        np.flatnonzero(kinds == "base"),
        index[kinds == "base"] % 3,
        np.flatnonzero(kinds == "tool"),
        index[kinds == "tool"] % 3,
        np.flatnonzero(kinds == "origin"),
        index[kinds == "origin"],
        rotation,
    )


def _screws(
    model: RobotModel, q: np.ndarray, layout: Layout
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Tool poses ``(N, 4, 4)``, and per parameter of ``layout`` the unit screw it moves the tool
    by: axes and points on them ``(N, P, 3)`` in the base frame, and which ones rotate ``(P,)``
    (the others translate along their axis)."""
    frames, c, s = _chain(model, q)
    tip_pose = frames[:, -1] @ model.tool
    (
        joint_cols,
        joint_slots,
        base_cols,
        base_axes,
        tool_cols,
        tool_axes,
        origin_cols,
        origin_idx,
        rotation,
    ) = _slots(layout, model.n_joints)
    screw_axes, screw_points = _joint_screws(model, frames, c, s)  # (N, 5 n, 3) each
    if len(joint_cols) == layout.size:  # joint parameters only (the usual layout)
        axes, points = screw_axes[:, joint_slots], screw_points[:, joint_slots]
    else:
        axes = np.empty((len(tip_pose), layout.size, 3))
        points = np.empty((len(tip_pose), layout.size, 3))
        axes[:, joint_cols] = screw_axes[:, joint_slots]
        points[:, joint_cols] = screw_points[:, joint_slots]
    if not set(layout.kinds).isdisjoint(NONGEOMETRIC_KINDS):  # screw times d q_eff / d param
        axes *= _nongeometric_factors(model, q, layout)[..., None]
    # Base and tool 6-vectors are small motions in their own frames.
    if base_cols.size:
        axes[:, base_cols] = model.base[:3, base_axes].T
        points[:, base_cols] = model.base[:3, 3]
    if tool_cols.size:
        axes[:, tool_cols] = np.swapaxes(tip_pose[:, :3, tool_axes], -1, -2)
        points[:, tool_cols] = tip_pose[:, None, :3, 3]
    if origin_cols.size:
        _origin_screws(model, frames, q, layout, axes, points)
    return tip_pose, axes, points, rotation


def _origin_screws(
    model: RobotModel,
    frames: np.ndarray,
    q: np.ndarray,
    layout: Layout,
    axes: np.ndarray,
    points: np.ndarray,
) -> None:
    """Fill in the screws of the entries that move URDF origins (:func:`_origin_entries`), in
    place: a change ``ds`` of joint i's origin 6-vector ``s = (t, w)`` moves its origin frame by
    ``R(w)^T dt`` and rotates it by ``J_r(w) dw`` about its own origin, in its own axes
    (:func:`relcal.robot.urdf.origin_tangents`), exactly at any ``s``; a zero offset is the
    change along its joint's direction (:func:`relcal.robot.urdf.zero_directions`)."""
    from relcal.robot.urdf import origin_tangents

    if model.urdf is None:
        raise ValueError("origin parameters need a robot loaded from a URDF")
    cols, joint, directions = _origin_directions(layout, model.urdf)  # (n, 6, P_o)
    tangents = origin_tangents(model)  # (n, 6, 6), block diagonal
    # an entry's 6-vector direction lies in one block (a component, or a joint's zero direction),
    # so its translation or its rotation, in the joint's origin frame, is the sum of both
    local = np.einsum("jab,jbp->jap", tangents[:, :3, :3], directions[:, :3])
    local += np.einsum("jab,jbp->jap", tangents[:, 3:, 3:], directions[:, 3:])  # (n, 3, P_o)
    picked = _urdf_joint_frames(model, frames, q)  # (N, n, 4, 4)
    n_conf, n = picked.shape[:2]
    rot = np.swapaxes(picked[..., :3, :3], 1, 2).reshape(n_conf, 3, 3 * n)  # [N, a, 3 j + b]
    axes[:, cols] = np.swapaxes(rot @ local.reshape(3 * n, -1), -1, -2)
    points[:, cols] = picked[:, :, :3, 3][:, joint]


@functools.lru_cache(maxsize=64)
def _origin_slots(layout: Layout) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Columns of the origin-moving entries of ``layout`` ``(P_o,)``, their joints, and the
    origin component each one is (0..5; -1 for a zero offset)."""
    cols = np.flatnonzero(_origin_entries(layout))
    kinds = np.array(layout.kinds)[cols]
    index = np.array(layout.index, dtype=int)[cols]
    is_origin = kinds == "origin"
    return cols, np.where(is_origin, index // 6, index), np.where(is_origin, index % 6, -1)


def _origin_directions(layout: Layout, chain) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Columns and joints of the origin-moving entries of ``layout`` ``(P_o,)``, and their
    6-vector directions per joint ``(n, 6, P_o)`` (zero for another joint's entries): a unit
    component of the joint's origin, or its zero direction
    (:func:`relcal.robot.urdf.zero_directions`)."""
    from relcal.robot.urdf import zero_directions

    zero = zero_directions(chain)
    return _directions(layout, zero.tobytes(), len(zero))


@functools.lru_cache(maxsize=64)
def _directions(layout: Layout, zero: bytes, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    cols, joint, comp = _origin_slots(layout)
    zero_dirs = np.frombuffer(zero).reshape(n, 6)
    out = np.zeros((n, 6, len(cols)))
    entry = np.arange(len(cols))
    unit, shift = comp >= 0, comp < 0
    out[joint[unit], comp[unit], entry[unit]] = 1.0
    out[joint[shift], :, entry[shift]] = zero_dirs[joint[shift]]
    out.setflags(write=False)
    return cols, joint, out


def _urdf_joint_frames(model: RobotModel, frames: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The URDF joint frames before each joint's motion ``(N, n, 4, 4)``, base frame: relcal's
    frame after joint i with the motion taken out, times the URDF frame in it."""
    if model.urdf is None:
        raise ValueError("origin parameters need a robot loaded from a URDF")
    q = effective_joints(model, q)  # the motion that the chain frames hold
    undo = np.broadcast_to(np.eye(4), (*q.shape, 4, 4)).copy()
    rot = ~model.prismatic
    undo[..., :3, :3] = np.where(rot[:, None, None], tf.rot_z(-q), np.eye(3))
    undo[..., 2, 3] = np.where(model.prismatic, -q, 0.0)
    return frames[:, 1:] @ undo @ model.urdf.frames


def _columns(axes: np.ndarray, moments: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """Twist columns ``(N, 6, P)``: ``(moment, axis)`` for rotations, ``(axis, 0)`` for
    translations, from axes and moments ``(N, P, 3)`` (a translation's moment is not used)."""
    out = np.empty((axes.shape[0], 6, axes.shape[1]))
    if rotation.all():
        out[:, :3] = np.swapaxes(moments, -1, -2)
        out[:, 3:] = np.swapaxes(axes, -1, -2)
    else:
        turns = rotation[:, None]
        out[:, :3] = np.swapaxes(np.where(turns, moments, axes), -1, -2)
        out[:, 3:] = np.swapaxes(axes * turns, -1, -2)
    return out


def pose_jacobian(
    model: RobotModel, q: np.ndarray, layout: Layout
) -> tuple[np.ndarray, np.ndarray]:
    """Poses ``F(q)`` ``(N, 4, 4)`` and the Jacobian ``(N, 6, P)`` of the pose error.

    Rows are the tool position change (m) and the small rotation (rad), both in the base frame,
    per unit change of each parameter of ``layout``: ``F(p + dp) ~ (I + [J dp]) F(p)`` with the
    rotation part acting about the tool point.

    Each parameter moves the tool by a unit screw: a translation along an axis (column
    ``(axis, 0)``) or a rotation about an axis through a point (``(axis x (tip - point), axis)``).
    """
    tip_pose, axes, points, rotation = _screws(model, q, layout)
    tip = tip_pose[:, None, :3, 3]
    return tip_pose, _columns(axes, _cross(axes, tip - points), rotation)


def spatial_jacobian(
    model: RobotModel, q: np.ndarray, layout: Layout
) -> tuple[np.ndarray, np.ndarray]:
    """Poses ``F(q)`` ``(N, 4, 4)`` and the spatial twists ``(N, 6, P)`` of the parameters.

    The same motion as :func:`pose_jacobian` with the velocity taken at the base origin instead
    of the tool point: ``F(p + dp) ~ exp([S dp]) F(p)``; a rotation about an axis through a point
    is ``(point x axis, axis)``. It does not depend on the tool point, which relative
    measurements (that difference two poses) exploit.
    """
    tip_pose, axes, points, rotation = _screws(model, q, layout)
    return tip_pose, _columns(axes, _cross(points, axes), rotation)


def check_errors(errors: Any, layout, name: str = "errors") -> np.ndarray:
    """A parameter vector of ``layout`` (``apply_errors``): one finite value per entry."""
    check_instance(layout, Layout, "layout", "a Layout (relcal.make_layout(model))")
    size = layout.size
    names = ", ".join(layout.names[:4]) + (", ..." if size > 4 else "")
    return check_array(
        errors,
        name,
        (size,),
        hint=f"one value per parameter of the layout ({size}: {names}; m and rad); a vector "
        "made for another layout or model?",
    )


def check_layout(layout: Any, model: RobotModel, name: str = "layout") -> Layout:
    """``layout`` is a :class:`Layout` whose joint entries fit ``model`` (a layout made for a
    robot with more joints is refused naming its first entry beyond ``model``'s joints)."""
    check_instance(layout, Layout, name, "a Layout (relcal.make_layout(model))")
    n = model.n_joints
    for entry, (kind, i) in zip(layout.names, layout, strict=True):
        joint = i // 6 if kind == "origin" else i
        if (kind in KINDS or kind in NONGEOMETRIC_KINDS or kind == "origin") and joint >= n:
            raise ArgumentError(
                f"{name}: entry {entry!r} is of joint {joint + 1}, the robot {model.name!r} has "
                f"{n} joints; a layout made by make_layout of another model?"
            )
    return layout
