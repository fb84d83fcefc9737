"""Serial chains from URDF files, converted exactly to relcal's modified-DH :class:`RobotModel`.

A URDF chain is ``T(q) = O_1 M_1(q_1) O_2 M_2(q_2) ... O_m`` with ``O_k`` the joints' fixed
``<origin>`` transforms and ``M_k`` the motion about (revolute, continuous) or along (prismatic)
each joint's ``<axis>``; fixed joints have no motion. Two chains with the same joint axes (as
lines in space, with direction) at ``q = 0`` and the same tip pose at ``q = 0`` have the same
forward kinematics at every ``q`` (product of exponentials), so the conversion only has to place
relcal's joint frames on the URDF axes:

- joint i's relcal frame has its z axis along the URDF axis direction (so relcal's ``q_i`` is the
  URDF joint position, prismatic in m) and its origin on the axis;
- between non-parallel axes, x is the common normal (Craig's modified DH, ``beta = 0``);
- between parallel axes (within ``parallel_tol_deg``), Hayati's ``beta`` replaces the previous
  joint's ``d`` (held at 0) and x is chosen so that ``Rx(alpha) Ry(beta) Tx(a)`` lands on the
  next axis;
- the base transform takes the root link to joint 1's frame, the tool transform takes the last
  joint's frame to the tip link.

Parsing uses yourdfpy; lxml (its XML parser) gives line numbers and tells a missing ``<axis>``
from an explicit one.
"""

from __future__ import annotations

import difflib
import io
import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from relcal import geometry as tf
from relcal.checks import check_number, check_path, describe
from relcal.errors import ArgumentError, RelcalError
from relcal.robot.model import ChainJoint, Inertials, RobotModel, UrdfChain

MOVABLE = ("revolute", "continuous", "prismatic")
PARAMETRISATIONS = ("minimal", "origins")
PARALLEL_TOL_DEG = 1.0  # the tolerance of relcal.robot.model.auto_hayati


# --- parsing -------------------------------------------------------------------------------------


def _fail(path: str, line: int | None, message: str) -> RelcalError:
    where = f"{path} line {line}" if line else path
    return RelcalError(f"{where}: {message}")


def _parse(path: str, data: bytes):
    """The yourdfpy robot and, per top-level joint name, ``(line, has_axis)`` from lxml."""
    import yourdfpy
    from lxml import etree

    try:
        root = etree.fromstring(data, parser=etree.XMLParser(remove_comments=True))
    except etree.XMLSyntaxError as exc:
        raise _fail(path, exc.lineno, f"malformed XML: {exc.msg}") from None
    if root.tag != "robot":
        raise _fail(path, root.sourceline, f"expected a <robot> element, found <{root.tag}>")
    info: dict[str, tuple[int, bool]] = {}
    for el in root.findall("joint"):
        name = el.get("name")
        if name is None:
            raise _fail(path, el.sourceline, "<joint> without a name attribute")
        for role in ("parent", "child"):
            sub = el.find(role)
            if sub is None or not sub.get("link"):
                raise _fail(path, el.sourceline, f"joint '{name}' needs <{role} link=\"LINK\"/>")
        if not el.get("type"):
            raise _fail(path, el.sourceline, f"joint '{name}' has no type attribute")
        if name in info:
            raise _fail(path, el.sourceline, f"joint name '{name}' is used twice")
        info[name] = (el.sourceline, el.find("axis") is not None)
    link_lines = {}
    for el in root.findall("link"):
        if not el.get("name"):
            raise _fail(path, el.sourceline, "<link> without a name attribute")
        link_lines[el.get("name")] = el.sourceline
    try:
        urdf = yourdfpy.URDF.load(
            io.BytesIO(data),
            build_scene_graph=False,
            load_meshes=False,
            load_collision_meshes=False,
        )
    except Exception as exc:  # yourdfpy raises plain exceptions on malformed values
        raise _fail(path, None, f"yourdfpy could not read the URDF: {exc}") from None
    return urdf.robot, info, link_lines


def _pick_chain(
    path: str, robot, info: dict, link_lines: dict, root: str | None, tip: str | None
) -> tuple[str, str, list]:
    """The joints from ``root`` to ``tip`` (yourdfpy Joint objects), after checking the tree."""
    links = set(link_lines)
    parent_joint: dict[str, object] = {}
    children: dict[str, list] = {}
    for j in robot.joints:
        line = info[j.name][0]
        for role, link in (("parent", j.parent), ("child", j.child)):
            if link not in links:
                hint = difflib.get_close_matches(link, links, n=1)
                raise _fail(
                    path,
                    line,
                    f"joint '{j.name}': {role} link '{link}' is not defined in the file"
                    + (f" (did you mean '{hint[0]}'?)" if hint else "")
                    + "; add the <link> or fix the name",
                )
        if j.child in parent_joint:
            other = parent_joint[j.child]
            raise _fail(
                path,
                line,
                f"link '{j.child}' is the child of two joints, '{other.name}' and '{j.name}': "
                "a URDF must be a tree (closed loops are not allowed); remove one of them",
            )
        parent_joint[j.child] = j
        children.setdefault(j.parent, []).append(j)
    for link in links:  # a loop: following parents comes back to where it started
        seen, cur = [link], link
        while cur in parent_joint:
            cur = parent_joint[cur].parent
            if cur in seen:
                j = parent_joint[link]
                raise _fail(
                    path,
                    info[j.name][0],
                    f"the joints form a loop through links {' -> '.join(seen[seen.index(cur) :])}"
                    ": a URDF must be a tree; remove the joint that closes the loop",
                )
            seen.append(cur)

    def check_link(name: str, what: str) -> None:
        if name not in links:
            hint = difflib.get_close_matches(name, links, n=3)
            raise _fail(
                path,
                None,
                f"{what} link '{name}' is not in the file"
                + (f"; close names: {', '.join(hint)}" if hint else "")
                + f" (it has {len(links)} links)",
            )

    roots = sorted(link for link in links if link not in parent_joint)
    if root is None:
        if len(roots) != 1:
            raise _fail(path, None, f"several root links ({', '.join(roots)}): give root: LINK")
        root = roots[0]
    check_link(root, "root")
    if tip is None:
        tip = _obvious_tip(path, root, children)
    check_link(tip, "tip")
    chain, cur = [], tip
    while cur != root:
        if cur not in parent_joint:
            raise _fail(
                path,
                None,
                f"tip link '{tip}' is not below root link '{root}' (its branch starts at "
                f"'{cur}'); choose a tip on the root's subtree or another root",
            )
        chain.append(parent_joint[cur])
        cur = parent_joint[cur].parent
    return root, tip, chain[::-1]


def _moves(j) -> bool:
    return j.type in MOVABLE and j.mimic is None


def _obvious_tip(path: str, root: str, children: dict) -> str:
    """Descend from ``root`` while exactly one branch holds movable (non-mimic) joints, then
    along fixed joints while there is exactly one child."""

    def has_motion(link: str) -> bool:
        return any(_moves(j) or has_motion(j.child) for j in children.get(link, []))

    cur = root
    while True:
        branches = [j for j in children.get(cur, []) if _moves(j) or has_motion(j.child)]
        if len(branches) > 1:
            names = ", ".join(f"'{j.name}' -> {j.child}" for j in branches)
            raise _fail(
                path,
                None,
                f"the tree is not a serial chain below link '{cur}' (branches {names}): "
                "give root: LINK and tip: LINK (--root/--tip) to pick the chain",
            )
        if not branches:
            break
        cur = branches[0].child
    while len(children.get(cur, [])) == 1 and children[cur][0].type == "fixed":
        cur = children[cur][0].child
    return cur


def _chain_joints(path: str, chain: list, info: dict) -> tuple[ChainJoint, ...]:
    out = []
    for j in chain:
        line, has_axis = info[j.name]
        if j.type not in (*MOVABLE, "fixed"):
            raise _fail(
                path,
                line,
                f"joint '{j.name}' is of type '{j.type}' and lies on the chain: relcal calibrates "
                "serial chains of revolute, continuous, prismatic and fixed joints; choose a root "
                f"below it (e.g. root: {j.child})",
            )
        if j.mimic is not None and j.type != "fixed":
            raise _fail(
                path,
                line,
                f"joint '{j.name}' mimics '{j.mimic.joint}' and lies on the chain: choose a tip "
                f"before it (e.g. tip: {j.parent})",
            )
        axis = np.zeros(3)
        if j.type in MOVABLE:
            if not has_axis:
                raise _fail(
                    path,
                    line,
                    f"joint '{j.name}' ({j.type}) has no <axis>: URDF would silently use 1 0 0; "
                    'write the intended axis, e.g. <axis xyz="0 0 1"/>',
                )
            axis = np.asarray(j.axis, dtype=float)
            norm = np.linalg.norm(axis)
            if axis.shape != (3,) or not np.isfinite(norm) or norm < 1e-9:
                raise _fail(path, line, f"joint '{j.name}': <axis xyz> must be a non-zero 3-vector")
            axis = axis / norm
        origin = np.eye(4) if j.origin is None else np.asarray(j.origin, dtype=float)
        if not np.all(np.isfinite(origin)) or np.abs(origin[:3, 3]).max() > 1e6:
            raise _fail(
                path, line, f"joint '{j.name}': <origin xyz rpy> must be finite numbers (m, rad)"
            )
        out.append(ChainJoint(j.name, j.type, j.parent, j.child, origin, axis, line))
    if not any(c.type in MOVABLE for c in out):
        raise _fail(path, None, "the chain from root to tip has no movable joint")
    return tuple(out)


# --- exact conversion to modified DH -------------------------------------------------------------


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _frame(x: np.ndarray, z: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """A right-handed frame from its x and z axes (orthogonal unit vectors) and origin."""
    return tf.homogeneous(np.column_stack([x, _cross(z, x), z]), origin)


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``u x v`` of two 3-vectors (``np.cross`` costs more at this size)."""
    return np.array(
        [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]
    )


def _twist(alpha: float, beta: float, a: float) -> np.ndarray:
    """``Rx(alpha) Ry(beta) Tx(a)``, the fixed head of a modified-DH link."""
    ca, sa, cb, sb = math.cos(alpha), math.sin(alpha), math.cos(beta), math.sin(beta)
    return np.array(
        [
            [cb, 0.0, sb, a * cb],
            [sa * sb, ca, -sa * cb, a * sa * sb],
            [-ca * sb, sa, ca * cb, -a * ca * sb],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def _screw(theta: float, d: float) -> np.ndarray:
    """``Rz(theta) Tz(d)``."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s, 0.0, 0.0], [s, c, 0.0, 0.0], [0.0, 0.0, 1.0, d], [0.0, 0.0, 0.0, 1.0]])


def joint_frames(joints: tuple[ChainJoint, ...]) -> tuple[list[np.ndarray], np.ndarray]:
    """World frames (root link) at ``q = 0`` of the movable joints, and the tip frame."""
    t, frames = np.eye(4), []
    for j in joints:
        t = t @ j.origin
        if j.type in MOVABLE:
            frames.append(t)
    return frames, t


def chain_fk(chain: UrdfChain, q: np.ndarray, origins: dict | None = None) -> np.ndarray:
    """Tip poses ``(N, 4, 4)`` in the root frame straight from the URDF joints (a reference).

    ``origins`` maps joint names to replacement ``(4, 4)`` origins.
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    out = np.broadcast_to(np.eye(4), (len(q), 4, 4))
    i = 0
    for j in chain.joints:
        origin = (origins or {}).get(j.name, j.origin)
        out = out @ origin
        if j.type in MOVABLE:
            motion = np.broadcast_to(np.eye(4), (len(q), 4, 4)).copy()
            if j.type == "prismatic":
                motion[:, :3, 3] = q[:, i, None] * j.axis
            else:
                motion[:, :3, :3] = tf.exp_rotation(q[:, i, None] * j.axis)
            out = out @ motion
            i += 1
    return out


def _to_mdh(
    axes_world: list[np.ndarray], tip: np.ndarray, tol_deg: float, hayati: np.ndarray | None = None
) -> dict:
    """Modified-DH parameters, base and tool, and relcal's joint frames at ``q = 0``, from the
    joint frames and axes ``[(frame (4, 4), axis (3,)), ...]`` and the tip pose; ``hayati``
    forces which joints get Hayati's beta (else: those parallel to the previous axis)."""
    n = len(axes_world)
    z = [f[:3, :3] @ a for f, a in axes_world]
    c = [f[:3, 3] for f, _ in axes_world]
    theta_off, d, a, alpha, beta = (np.zeros(n) for _ in range(5))
    forced = hayati
    hayati = np.zeros(n, dtype=bool)
    sin_tol = np.sin(np.radians(tol_deg))

    # Joint 1's frame: on axis 1 nearest the root origin, x from the root's x (or y) axis.
    z0 = _unit(z[0])
    ref = np.eye(3)[0] if np.linalg.norm(_cross(np.eye(3)[0], z0)) > 0.1 else np.eye(3)[1]
    base = _frame(_unit(ref - (ref @ z0) * z0), z0, c[0] - (c[0] @ z0) * z0)
    pre, frames = base, []
    for i in range(n):
        zi, oi, xpre = pre[:3, 2], pre[:3, 3], pre[:3, 0]
        if i == n - 1:
            frames.append(pre)
            break
        zn, cn = _unit(z[i + 1]), c[i + 1]
        cross = _cross(zi, zn)
        parallel = np.linalg.norm(cross) < sin_tol if forced is None else forced[i + 1]
        if parallel:  # parallel: Hayati's beta, d[i] held at 0
            hayati[i + 1] = True
            foot = oi
            w = _cross(cn - oi, zn)
            if np.linalg.norm(w) < 1e-12:  # collinear axes: keep x
                x = xpre
            else:
                x = _unit(_cross(zi, w))
                x = -x if x @ (cn - oi) < 0 else x
        else:  # common normal between the two axes
            x = _unit(cross)
            # feet oi + t zi and cn + u zn with (foot_n - foot_i) along x
            m = np.array([[zi @ zi, -(zi @ zn)], [zi @ zn, -(zn @ zn)]])
            t, _ = np.linalg.solve(m, [(cn - oi) @ zi, (cn - oi) @ zn])
            foot = oi + t * zi
            x = -x if x @ (cn - foot) < -1e-12 else x
        theta_off[i] = np.arctan2(_cross(xpre, x) @ zi, xpre @ x)
        d[i] = (foot - oi) @ zi
        post = pre @ _screw(theta_off[i], d[i])
        frames.append(post)
        local = post[:3, :3].T @ zn
        # x is the common normal unless the pair is parallel: beta is round-off there, keep 0
        beta[i + 1] = np.arcsin(np.clip(local[0], -1.0, 1.0)) if parallel else 0.0
        alpha[i + 1] = np.arctan2(-local[1], local[2])
        head = _twist(alpha[i + 1], beta[i + 1], 0.0)
        a[i + 1] = (cn - post[:3, 3]) @ (post[:3, :3] @ head[:3, 0])
        pre = post @ _twist(alpha[i + 1], beta[i + 1], a[i + 1])
    tool = tf.invert(frames[-1]) @ tip
    return dict(
        theta_off=theta_off,
        d=d,
        a=a,
        alpha=alpha,
        beta=beta,
        hayati=hayati,
        base=base,
        tool=tool,
        frames=np.array(frames),
    )


def _inertials(robot, joints: tuple[ChainJoint, ...], frames: np.ndarray) -> Inertials:
    """Mass, centre of mass and inertia of each moving body in its joint frame.

    A body is the chain links between two movable joints plus every link hung off them by
    fixed joints (as Pinocchio merges them); links behind other movable joints are left out.
    """
    n = len(frames)
    links = {link.name: link for link in robot.links}
    fixed_children: dict[str, list] = {}
    chain_names = {j.name for j in joints}
    for j in robot.joints:
        if j.type == "fixed" and j.name not in chain_names:
            fixed_children.setdefault(j.parent, []).append(j)
    mass, first, second = np.zeros(n), np.zeros((n, 3)), np.zeros((n, 3, 3))

    def add(body: int, link_name: str, pose: np.ndarray) -> None:
        """Add the link at ``pose`` (in the body's joint frame) and its fixed subtree."""
        inertial = links[link_name].inertial
        if inertial is not None and inertial.mass:
            at = pose if inertial.origin is None else pose @ inertial.origin
            m, r, rot = float(inertial.mass), at[:3, 3], at[:3, :3]
            own = np.zeros((3, 3)) if inertial.inertia is None else np.asarray(inertial.inertia)
            mass[body] += m
            first[body] += m * r
            # about the joint frame's origin: rotated inertia plus m (|r|^2 I - r r^T)
            second[body] += rot @ own @ rot.T + m * ((r @ r) * np.eye(3) - np.outer(r, r))
        for j in fixed_children.get(link_name, []):
            add(body, j.child, pose @ (np.eye(4) if j.origin is None else j.origin))

    world, body = np.eye(4), -1
    for j in joints:
        world = world @ j.origin
        if j.type in MOVABLE:
            body += 1
        if body >= 0:
            add(body, j.child, tf.invert(frames[body]) @ world)
    safe = np.where(mass > 0, mass, 1.0)
    com = first / safe[:, None]
    outer = np.einsum("ni,nj->nij", com, com)
    about_com = second - mass[:, None, None] * (
        np.einsum("ni,ni->n", com, com)[:, None, None] * np.eye(3) - outer
    )
    return Inertials(mass, com, about_com)


def load_urdf(
    path: str | Path,
    root: str | None = None,
    tip: str | None = None,
    parametrisation: str = "minimal",
    parallel_tol_deg: float = PARALLEL_TOL_DEG,
) -> RobotModel:
    """The serial chain ``root`` -> ``tip`` of a URDF as a modified-DH :class:`RobotModel`.

    ``root``/``tip`` default to the tree's root link and the end of its one serial chain.
    Joint names, limits (rad, m) and link inertials come from the URDF; relcal's ``q`` of each
    joint is the URDF joint position. The model is always the exact modified-DH conversion
    (Hayati's beta where consecutive axes are parallel within ``parallel_tol_deg``, base and
    tool); ``parametrisation`` chooses the error parameters that
    :func:`relcal.robot.kinematics.make_layout` gives it: ``minimal`` (the DH parameters) or
    ``origins`` (per joint a small motion of its URDF origin and a zero offset).

    Parameters
    ----------
    path : str or Path
        The URDF file (``.urdf``; a ``.xacro`` is refused with how to expand it).
    root, tip : str, optional
        The chain's first and last links.
    parametrisation : {"minimal", "origins"}
        The error parameters of the model's layout.
    parallel_tol_deg : float
        Angle (deg) below which consecutive joint axes count as parallel.

    Returns
    -------
    RobotModel
        The chain in modified DH, lengths in m and angles in rad, with ``model.urdf`` set.

    Raises
    ------
    ArgumentError
        ``path`` is not a str or Path.
    RelcalError
        An unknown parametrisation, a xacro file, a file that is too large or not a URDF, links
        that are not in the tree or not one serial chain, or an unsupported joint type.
    """
    path = str(check_path(path, "path", "a URDF file"))
    for name, link in (("root", root), ("tip", tip)):
        if link is not None and (not isinstance(link, str) or not link.strip()):
            raise ArgumentError(
                f"{name}: expected a link name of the URDF (a str) or None, got {describe(link)}"
            )
    check_number(parallel_tol_deg, "parallel_tol_deg", 0, 90, low_open=True)
    if not isinstance(parametrisation, str) or parametrisation not in PARAMETRISATIONS:
        raise RelcalError(
            f"{path}: unknown parametrisation '{parametrisation}': use minimal or origins"
        )
    if Path(path).suffix.lower() == ".xacro":
        raise RelcalError(
            f"{path}: a xacro file: expand it to a URDF first (xacro {Path(path).name} > "
            f"{Path(path).stem.removesuffix('.urdf')}.urdf) and give that file"
        )
    from relcal.limits import read_input

    try:
        data = read_input(path, "urdf")
    except FileNotFoundError:
        raise RelcalError(f"{path}: file not found (expected a URDF file)") from None
    except OSError as exc:
        raise RelcalError(f"{path}: cannot read the URDF: {exc.strerror}") from None
    robot, info, link_lines = _parse(path, data)
    root, tip, picked = _pick_chain(path, robot, info, link_lines, root, tip)
    joints = _chain_joints(path, picked, info)
    movable = tuple(k for k, j in enumerate(joints) if j.type in MOVABLE)
    world, tip_pose = joint_frames(joints)
    mdh = _to_mdh(
        [(w, joints[k].axis) for w, k in zip(world, movable, strict=True)],
        tip_pose,
        parallel_tol_deg,
    )
    frames = np.array([tf.invert(f) @ w for f, w in zip(mdh["frames"], world, strict=True)])
    lower, upper, names, prismatic = [], [], [], []
    robot_by_name = {j.name: j for j in robot.joints}
    for k in movable:
        j = joints[k]
        lim = robot_by_name[j.name].limit
        bounded = j.type != "continuous" and lim is not None
        lo = lim.lower if bounded and lim.lower is not None else -np.inf
        hi = lim.upper if bounded and lim.upper is not None else np.inf
        if np.isnan(lo) or np.isnan(hi):
            raise _fail(path, j.line, f"joint '{j.name}': <limit lower upper> must be numbers")
        if lo > hi:
            raise _fail(
                path, j.line, f"joint '{j.name}': <limit> lower {lo} is above upper {hi}; swap them"
            )
        if lo == hi:  # some files write 0 0 for unlimited joints
            lo, hi = -np.inf, np.inf
        lower.append(float(lo))
        upper.append(float(hi))
        names.append(j.name)
        prismatic.append(j.type == "prismatic")
    chain = UrdfChain(path, data, robot.name, root, tip, joints, movable, frames, parametrisation)
    inertials = _inertials(robot, joints, mdh["frames"])
    for i, k in enumerate(movable):
        values = (inertials.mass[i], inertials.com[i], inertials.inertia[i])
        if not all(np.all(np.isfinite(v)) for v in values):
            raise _fail(
                path,
                None,
                f"the links moved by joint '{joints[k].name}' have a non-finite <inertial> "
                "(mass, origin or inertia): fix the numbers",
            )
    return RobotModel(
        name=f"{robot.name} ({root} -> {tip})",
        convention="mdh",
        theta_off=mdh["theta_off"],
        d=mdh["d"],
        a=mdh["a"],
        alpha=mdh["alpha"],
        beta=mdh["beta"],
        prismatic=np.array(prismatic),
        hayati=mdh["hayati"],
        lower=np.array(lower),
        upper=np.array(upper),
        joint_names=tuple(names),
        base=mdh["base"],
        tool=mdh["tool"],
        source=f"URDF {path}, chain {root} -> {tip}, exact modified DH",
        inertials=inertials,
        urdf=chain,
    )


# --- the origins parametrisation ------------------------------------------------------------------


def mdh_frames(model: RobotModel) -> np.ndarray:
    """relcal's joint frames ``base A_1(0) ... A_i(0)`` for i = 1..n, ``(n, 4, 4)`` (as
    ``kinematics.forward_frames`` at ``q = 0``, which this module cannot import)."""
    out, t = [], model.base
    for i in range(model.n_joints):
        t = (
            t
            @ _twist(model.alpha[i], model.beta[i], model.a[i])
            @ _screw(model.theta_off[i], model.d[i])
        )
        out.append(t)
    return np.array(out)


_CONSTANTS: dict[int, tuple] = {}  # id(chain.joints) -> (joints, steps, zero directions)


def _chain_constants(chain: UrdfChain) -> tuple[np.ndarray, np.ndarray]:
    """:func:`nominal_steps` and :func:`zero_directions` of a chain, computed once per joint tuple
    (every model moved from one URDF shares it)."""
    hit = _CONSTANTS.get(id(chain.joints))
    if hit is not None and hit[0] is chain.joints:
        return hit[1], hit[2]
    world, _ = joint_frames(chain.joints)
    world = np.array(world)
    steps = np.concatenate([world[:1], tf.invert(world[:-1]) @ world[1:]])
    zero = np.zeros((len(chain.movable), 6))
    for i, k in enumerate(chain.movable):
        joint = chain.joints[k]
        start = 0 if joint.type == "prismatic" else 3
        zero[i, start : start + 3] = joint.axis
    for array in (steps, zero):
        array.setflags(write=False)
    if len(_CONSTANTS) > 256:
        _CONSTANTS.clear()
    _CONSTANTS[id(chain.joints)] = (chain.joints, steps, zero)
    return steps, zero


def nominal_steps(chain: UrdfChain) -> np.ndarray:
    """Per movable joint ``(n, 4, 4)``: the transform from the previous movable joint's URDF frame
    (the root link for the first) to its own at ``q = 0``, fixed joints included, as the file
    gives it (read-only)."""
    return _chain_constants(chain)[0]


def zero_directions(chain: UrdfChain) -> np.ndarray:
    """Per movable joint ``(n, 6)``: the 6-vector direction its zero offset adds to its origin's
    motion, the joint axis as a rotation (revolute) or a translation (prismatic) (read-only)."""
    return _chain_constants(chain)[1]


def origin_motions(model: RobotModel) -> np.ndarray:
    """The 6-vectors ``s`` ``(n, 6)`` (m, rotation vector rad) of the model's URDF origins against
    the file's, ``origin = nominal from_vector(s)`` (fixed joints before a movable one are part
    of its origin): zeros for a model as loaded. A zero offset in ``theta_off`` or ``d`` beyond the
    converted value is read as part of the origin."""
    return _origin_state(model)[2]


def _origin_state(model: RobotModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """relcal's joint frames and the URDF joint frames at ``q = 0`` ``(n, 4, 4)``, and
    :func:`origin_motions`."""
    chain = model.urdf
    if chain is None:
        raise RelcalError(f"'{model.name}': origin errors need a robot loaded from a URDF")
    frames = mdh_frames(model)
    world = frames @ chain.frames
    current = np.concatenate([world[:1], tf.invert(world[:-1]) @ world[1:]])
    return frames, world, tf.to_vector(tf.invert(nominal_steps(chain)) @ current)


def origin_tangents(model: RobotModel) -> np.ndarray:
    """Per movable joint ``(n, 6, 6)``: the small motion of its moved origin frame, in that frame
    (translation m, rotation rad), per unit change of its 6-vector ``s`` (:func:`origin_motions`):
    ``nominal from_vector(s + ds) = nominal from_vector(s) exp([T ds])`` to first order, with
    ``T = diag(R(w)^T, J_r(w))`` exactly at any ``s = (t, w)``."""
    return tf.vector_tangent(origin_motions(model))


def move_origins(model: RobotModel, motions: np.ndarray) -> RobotModel:
    """The model with each movable joint's URDF origin moved: ``motions`` ``(n, 6)`` (m, then
    rotation vector rad) add to the origins' 6-vectors against the file's (:func:`origin_motions`),
    ``origin' = nominal from_vector(s + motions[i])``, so that moving twice is moving once by the
    sum; the distal chain and tool follow, and the chain is converted to modified DH again,
    exactly, keeping the Hayati joints."""
    frames, world, current = _origin_state(model)
    chain, steps = model.urdf, nominal_steps(model.urdf)
    tip = frames[-1] @ model.tool
    total = current + np.asarray(motions, dtype=float)
    moved, prev = [], np.eye(4)
    for i in range(model.n_joints):
        prev = prev @ steps[i] @ tf.from_vector(total[i])
        moved.append(prev)
    tip = moved[-1] @ tf.invert(world[-1]) @ tip
    axes = [(w, chain.joints[k].axis) for w, k in zip(moved, chain.movable, strict=True)]
    mdh = _to_mdh(axes, tip, PARALLEL_TOL_DEG, hayati=model.hayati)
    new_frames = np.array([tf.invert(f) @ w for f, w in zip(mdh["frames"], moved, strict=True)])
    return replace(
        model,
        **{k: mdh[k] for k in ("theta_off", "d", "a", "alpha", "beta", "base", "tool")},
        urdf=replace(chain, frames=new_frames),
    )
