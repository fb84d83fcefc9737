"""Forward kinematics, the geometric parameter vector, and its analytic identification Jacobian.

Everything is vectorised over N joint configurations ``q`` of shape ``(N, n)``.

The parameter vector is ordered by kind, as in the published formulation: all ``theta_off``, all
``a``, all ``d``, all ``alpha``, then ``beta`` of Hayati joints, then optionally the base and tool
transforms as 6-vectors of small motions in their own frames (``base.tx`` ... ``base.rz``).
"""

from __future__ import annotations

import importlib.util
import sys
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from relcal import transforms as tf
from relcal.errors import RelcalError
from relcal.model import ANGLE_KINDS, KINDS, RobotModel

FRAME_COMPONENTS = ("tx", "ty", "tz", "rx", "ry", "rz")


@dataclass(frozen=True)
class Layout:
    """Names and meaning of the entries of a parameter vector.

    ``kinds[k]`` is ``theta_off``, ``a``, ``d``, ``alpha``, ``beta``, ``base`` or ``tool``;
    ``index[k]`` is the 0-based joint, or the component 0..5 of a base/tool 6-vector.
    """

    names: tuple[str, ...]
    kinds: tuple[str, ...]
    index: tuple[int, ...]

    @property
    def size(self) -> int:
        return len(self.names)

    def is_angle(self) -> np.ndarray:
        """Mask of entries in radians (the others are in metres); frame 6-vectors end in radians."""
        return np.array(
            [k in ANGLE_KINDS or (k not in KINDS and i >= 3) for k, i in self],
            dtype=bool,
        )

    def __iter__(self):
        return iter(zip(self.kinds, self.index, strict=True))

    def extended(self, prefix: str) -> Layout:
        """This layout followed by a 6-vector frame named ``prefix`` (e.g. ``handeye``)."""
        names = tuple(f"{prefix}.{c}" for c in FRAME_COMPONENTS)
        return Layout(self.names + names, self.kinds + (prefix,) * 6, self.index + tuple(range(6)))


def make_layout(model: RobotModel, base: bool = False, tool: bool = False) -> Layout:
    """The geometric parameters of ``model`` (plus base and tool 6-vectors if asked)."""
    n = model.n_joints
    fixed_d = model.fixed_d()
    entries: list[tuple[str, int]] = []
    for kind in ("theta_off", "a", "d", "alpha"):
        entries += [(kind, i) for i in range(n) if not (kind == "d" and fixed_d[i])]
    entries += [("beta", i) for i in range(n) if model.hayati[i]]
    for frame, wanted in (("base", base), ("tool", tool)):
        if wanted:
            entries += [(frame, c) for c in range(6)]
    names = tuple(
        f"{k}.{FRAME_COMPONENTS[i]}" if k in ("base", "tool") else f"{k}[{i + 1}]"
        for k, i in entries
    )
    return Layout(names, tuple(k for k, _ in entries), tuple(i for _, i in entries))


def apply_errors(model: RobotModel, layout: Layout, errors: np.ndarray) -> RobotModel:
    """The model with additive geometric errors; base/tool errors move those frames locally."""
    errors = np.asarray(errors, dtype=float)
    arrays = {k: model.geometric(k).copy() for k in ("theta_off", "a", "d", "alpha", "beta")}
    frames = {"base": np.zeros(6), "tool": np.zeros(6)}
    for (kind, i), e in zip(layout, errors, strict=False):
        if kind in arrays:
            arrays[kind][i] += e
        elif kind in frames:
            frames[kind][i] += e
    return replace(
        model,
        **arrays,
        base=model.base @ tf.from_vector(frames["base"]),
        tool=model.tool @ tf.from_vector(frames["tool"]),
    )


def _joint_values(model: RobotModel, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Total joint angles and offsets ``(N, n)``: the joint variable goes to theta or d."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    theta = model.theta_off + np.where(model.prismatic, 0.0, q)
    d = model.d + np.where(model.prismatic, q, 0.0)
    return theta, d


def _link_transforms(model: RobotModel, q: np.ndarray) -> np.ndarray:
    """Joint transforms ``A_i``, shape ``(N, n, 4, 4)``."""
    theta, d = _joint_values(model, q)
    rc = tf.rot_x(model.alpha) @ tf.rot_y(model.beta)  # (n, 3, 3)
    rz = tf.rot_z(theta)  # (N, n, 3, 3)
    if model.convention == "dh":
        rot = rz @ rc
        trans = np.stack([model.a * np.cos(theta), model.a * np.sin(theta), d], axis=-1)
    else:
        rot = rc @ rz
        trans = model.a[:, None] * rc[:, :, 0] + d[..., None] * rc[:, :, 2]
    return tf.homogeneous(rot, trans)


def forward_frames(model: RobotModel, q: np.ndarray) -> np.ndarray:
    """Frames ``base A_1 ... A_i`` for i = 0..n, shape ``(N, n + 1, 4, 4)`` (tool not applied)."""
    links = _link_transforms(model, q)
    n_conf, n = links.shape[:2]
    frames = np.empty((n_conf, n + 1, 4, 4))
    frames[:, 0] = model.base
    for i in range(n):
        frames[:, i + 1] = frames[:, i] @ links[:, i]
    return frames


Backend = Literal["auto", "numpy", "numba"]
_LOAD_MIN = 20_000  # configurations that pay for loading the kernel (import 0.3 s, compile 2 s)


def _fast_available() -> bool:
    return importlib.util.find_spec("numba") is not None


def _use_fast(backend: Backend, n_conf: int) -> bool:
    if backend == "numpy":
        return False
    if backend == "numba":
        if not _fast_available():
            raise RelcalError("backend='numba' needs the numba package: pip install numba")
        return True
    if backend != "auto":
        raise ValueError(f"unknown FK backend '{backend}': use auto, numpy or numba")
    if "relcal.fastkin" in sys.modules:  # loaded: faster from a single configuration on
        return True
    return n_conf >= _LOAD_MIN and _fast_available()


def fk(model: RobotModel, q: np.ndarray, backend: Backend = "auto") -> np.ndarray:
    """Flange/tool poses in the base frame ``F(q)``, shape ``(N, 4, 4)`` for ``q`` of ``(N, n)``.

    ``backend="numpy"`` is the reference implementation; ``"numba"`` the compiled kernel of
    :mod:`relcal.fastkin` (same result to round-off, 20-50 times faster on large batches);
    ``"auto"`` takes the kernel when it is already loaded, or when Numba is installed and the batch
    is large enough to pay for loading it (small batches alone never import Numba, so short
    commands start quickly).
    """
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if _use_fast(backend, q.shape[0]):
        from relcal import fastkin

        return fastkin.fk(model, q)
    links = _link_transforms(model, q)
    out = np.broadcast_to(model.base, (links.shape[0], 4, 4))
    for i in range(links.shape[1]):
        out = out @ links[:, i]
    return out @ model.tool


def _columns(kind: str, axis: np.ndarray, point: np.ndarray, tip: np.ndarray) -> np.ndarray:
    """Base-frame columns ``(N, 6)``: (velocity of the tip, angular velocity) per unit parameter."""
    if kind == "translation":
        return np.concatenate([axis, np.zeros_like(axis)], axis=-1)
    return np.concatenate([np.cross(axis, tip - point), axis], axis=-1)


def pose_jacobian(
    model: RobotModel, q: np.ndarray, layout: Layout
) -> tuple[np.ndarray, np.ndarray]:
    """Poses ``F(q)`` ``(N, 4, 4)`` and the Jacobian ``(N, 6, P)`` of the pose error.

    Rows are the tool position change (m) and the small rotation (rad), both in the base frame,
    per unit change of each parameter of ``layout``: ``F(p + dp) ~ (I + [J dp]) F(p)`` with the
    rotation part acting about the tool point.
    """
    frames = forward_frames(model, q)
    theta, _ = _joint_values(model, q)
    tip_pose = frames[:, -1] @ model.tool
    tip = tip_pose[:, :3, 3]
    jac = np.empty((frames.shape[0], 6, layout.size))
    rot_ab = tf.rot_x(model.alpha) @ tf.rot_y(model.beta)  # (n, 3, 3)
    for k, (kind, i) in enumerate(layout):
        if kind in ("base", "tool"):
            pose = np.broadcast_to(model.base, tip_pose.shape) if kind == "base" else tip_pose
            axis = pose[:, :3, i % 3]
            motion = "translation" if i < 3 else "rotation"
            jac[:, :, k] = _columns(motion, axis, pose[:, :3, 3], tip)
            continue
        if kind not in ("theta_off", "a", "d", "alpha", "beta"):
            raise ValueError(f"parameter kind '{kind}' is not a kinematic parameter")
        prev = frames[:, i]
        rot, origin = prev[:, :3, :3], prev[:, :3, 3]
        if model.convention == "dh":
            c, s = np.cos(theta[:, i]), np.sin(theta[:, i])
            x_axis = rot[:, :, 0] * c[:, None] + rot[:, :, 1] * s[:, None]  # x after Rz(theta)
            link_origin = frames[:, i + 1, :3, 3]
            table = {
                "theta_off": ("rotation", rot[:, :, 2], origin),
                "d": ("translation", rot[:, :, 2], origin),
                "a": ("translation", x_axis, origin),
                "alpha": ("rotation", x_axis, link_origin),
                "beta": ("rotation", frames[:, i + 1, :3, 1], link_origin),
            }
        else:
            rx = rot @ tf.rot_x(model.alpha[i])
            rab = rot @ rot_ab[i]
            joint_origin = origin + model.a[i] * rab[:, :, 0]
            table = {
                "alpha": ("rotation", rot[:, :, 0], origin),
                "beta": ("rotation", rx[:, :, 1], origin),
                "a": ("translation", rab[:, :, 0], origin),
                "theta_off": ("rotation", rab[:, :, 2], joint_origin),
                "d": ("translation", rab[:, :, 2], joint_origin),
            }
        motion, axis, point = table[kind]
        jac[:, :, k] = _columns(motion, axis, point, tip)
    return tip_pose, jac
