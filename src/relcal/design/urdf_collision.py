"""Self- and cell-collision checks from a URDF's own ``<collision>`` geometry, with python-fcl
(``pip install 'relcal[collision]'``).

For a robot loaded from a URDF whose chain links carry collision geometry, every link of the file
is placed from the chain's joint values (links off the chain, such as a mobile manipulator's
body, head or other arm, at their joints' zero), in the chain root's frame (relcal's base frame).
Boxes, cylinders and spheres are used as given; meshes when their file can be found (a path
relative to the URDF or absolute; ``package://`` paths are not resolved and those geometries are
left out, counted in :attr:`UrdfCollision.skipped`). Pairs checked: two bodies of which at least
one moves with the chain, not of the same link or of links joined by one joint, and not in
contact in nearly every pose (95 % of 100 random poses within the limits, the rule of MoveIt's
setup assistant for "always in collision" pairs, e.g. overlapping housings at a joint). A
bounding-sphere test screens the pairs before fcl's exact test. The camera is a sphere of
``camera_radius`` about its optical centre; ``obstacles`` are boxes in the base frame.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from relcal import geometry as tf
from relcal.errors import require
from relcal.robot.model import RobotModel

ALWAYS = 0.95  # pairs in contact in this share of random poses are never checked
SAMPLES = 100  # random poses for that test


@dataclass(frozen=True)
class _Body:
    link: str
    geometry: object  # an fcl geometry
    offset: np.ndarray  # (4, 4) link -> geometry
    radius: float  # bounding sphere about the geometry's origin, m


def _rotation(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """``(N, 4, 4)`` rotations about the unit ``axis`` by ``angle`` ``(N,)`` (rad)."""
    return tf.homogeneous(tf.exp_rotation(axis[None] * angle[:, None]), np.zeros((len(angle), 3)))


class UrdfCollision:
    """The collision geometry of ``model``'s URDF, checked per configuration.

    Raises
    ------
    ValueError
        ``model`` was not loaded from a URDF.
    """

    def __init__(self, model: RobotModel, seed: int = 0) -> None:
        if model.urdf is None:
            raise ValueError("UrdfCollision needs a model loaded from a URDF")
        self.fcl = require("fcl", "collision", "collision checks from URDF geometry")
        import yourdfpy

        chain = model.urdf
        robot = yourdfpy.URDF.load(
            io.BytesIO(chain.data),
            build_scene_graph=False,
            load_meshes=False,
            load_collision_meshes=False,
        ).robot
        self.model = model
        movable = {chain.joints[i].name: k for k, i in enumerate(chain.movable)}
        self._parent = {j.child: j for j in robot.joints}
        self._movable = movable
        self.skipped = 0
        self.bodies: list[_Body] = []
        folder = Path(chain.path).parent
        for link in robot.links:
            for c in link.collisions:
                body = self._body(link.name, c, folder)
                if body is None:
                    self.skipped += 1
                else:
                    self.bodies.append(body)
        moving = {b.link: self._moves(b.link) for b in self.bodies}
        root = chain.root
        self._root_inverse = np.linalg.inv(self._link_pose(root, np.zeros((1, model.n_joints)))[0])
        links = sorted({b.link for b in self.bodies})
        self.links = links
        joined = {frozenset((j.parent, j.child)) for j in robot.joints}
        pairs = []
        for a in range(len(self.bodies)):
            for b in range(a + 1, len(self.bodies)):
                la, lb = self.bodies[a].link, self.bodies[b].link
                if la == lb or frozenset((la, lb)) in joined:
                    continue
                if moving[la] or moving[lb]:
                    pairs.append((a, b))
        self.pairs = np.array(pairs, dtype=int).reshape(-1, 2)
        self.has_chain_geometry = any(moving.values())
        if len(self.pairs):
            rng = np.random.default_rng(seed)
            lo = np.where(np.isfinite(model.lower), model.lower, -np.pi)
            hi = np.where(np.isfinite(model.upper), model.upper, np.pi)
            hits = self._contacts(rng.uniform(lo, hi, (SAMPLES, model.n_joints)))
            self.pairs = self.pairs[hits.mean(axis=0) < ALWAYS]

    # -- geometry ------------------------------------------------------------------------------
    def _body(self, link: str, collision, folder: Path) -> _Body | None:
        fcl = self.fcl
        g = collision.geometry
        offset = collision.origin if collision.origin is not None else np.eye(4)
        if g.box is not None:
            size = np.asarray(g.box.size, float)
            return _Body(link, fcl.Box(*size), offset, float(np.linalg.norm(size) / 2))
        if g.cylinder is not None:
            r, length = float(g.cylinder.radius), float(g.cylinder.length)
            return _Body(link, fcl.Cylinder(r, length), offset, float(np.hypot(r, length / 2)))
        if g.sphere is not None:
            return _Body(link, fcl.Sphere(float(g.sphere.radius)), offset, float(g.sphere.radius))
        if g.mesh is not None:
            name = str(g.mesh.filename)
            if "://" in name:
                return None
            path = Path(name) if Path(name).is_absolute() else folder / name
            if not path.is_file():
                return None
            import trimesh

            mesh = trimesh.load(path, force="mesh")
            scale = np.asarray(g.mesh.scale if g.mesh.scale is not None else 1.0, float)
            vertices = np.asarray(mesh.vertices) * scale
            model = fcl.BVHModel()
            model.beginModel(len(vertices), len(mesh.faces))
            model.addSubModel(vertices, np.asarray(mesh.faces))
            model.endModel()
            return _Body(link, model, offset, float(np.linalg.norm(vertices, axis=1).max()))
        return None

    def _moves(self, link: str) -> bool:
        while link in self._parent:
            joint = self._parent[link]
            if joint.name in self._movable:
                return True
            link = joint.parent
        return False

    def _link_pose(self, link: str, q: np.ndarray) -> np.ndarray:
        """``(N, 4, 4)`` pose of ``link`` in the URDF tree's root frame."""
        pose = np.broadcast_to(np.eye(4), (len(q), 4, 4))
        while link in self._parent:
            joint = self._parent[link]
            step = np.asarray(joint.origin if joint.origin is not None else np.eye(4), float)
            k = self._movable.get(joint.name)
            if k is not None:
                axis = np.asarray(joint.axis if joint.axis is not None else [1.0, 0, 0], float)
                axis = axis / np.linalg.norm(axis)
                if joint.type == "prismatic":
                    motion = np.broadcast_to(np.eye(4), (len(q), 4, 4)).copy()
                    motion[:, :3, 3] = axis * q[:, k, None]
                else:
                    motion = _rotation(axis, q[:, k])
                step = step @ motion
            pose = step @ pose
            link = joint.parent
        return pose

    def poses(self, q: np.ndarray) -> np.ndarray:
        """``(N, B, 4, 4)`` pose of every body in relcal's base frame (the chain's root)."""
        q = np.atleast_2d(q)
        by_link = {link: self._root_inverse @ self._link_pose(link, q) for link in self.links}
        return np.stack([by_link[b.link] @ b.offset for b in self.bodies], axis=1)

    # -- checks --------------------------------------------------------------------------------
    def _contacts(self, q: np.ndarray) -> np.ndarray:
        """``(N, P)`` contact of each checked pair in each configuration."""
        fcl = self.fcl
        poses = self.poses(q)
        radius = np.array([b.radius for b in self.bodies])
        a, b = self.pairs[:, 0], self.pairs[:, 1]
        centres = poses[..., :3, 3]  # (N, B, 3)
        centre_gap = np.linalg.norm(centres[:, a] - centres[:, b], axis=-1)
        near = centre_gap <= radius[a] + radius[b]  # bounding spheres overlap
        objects = [fcl.CollisionObject(body.geometry, fcl.Transform()) for body in self.bodies]
        request = fcl.CollisionRequest()
        hits = np.zeros(near.shape, dtype=bool)
        for n, p in zip(*np.nonzero(near), strict=True):
            i, j = self.pairs[p]
            for k in (i, j):
                objects[k].setTransform(fcl.Transform(poses[n, k, :3, :3], poses[n, k, :3, 3]))
            hits[n, p] = fcl.collide(objects[i], objects[j], request, fcl.CollisionResult()) > 0
        return hits

    def self_collision_free(self, q: np.ndarray) -> np.ndarray:
        """Mask ``(N,)`` of configurations whose checked pairs are all apart."""
        q = np.atleast_2d(q)
        if not len(self.pairs) or not len(q):
            return np.ones(len(q), dtype=bool)
        return ~self._contacts(q).any(axis=1)

    def cell_free(
        self,
        q: np.ndarray,
        camera: np.ndarray,
        obstacles: np.ndarray,
        camera_radius: float,
    ) -> np.ndarray:
        """Mask ``(N,)``: no moving body and no camera sphere (centres ``camera`` ``(N, 3)``) in
        any box of ``obstacles`` ``(B, 6)`` (``xmin, ymin, zmin, xmax, ymax, zmax``, m)."""
        fcl = self.fcl
        q = np.atleast_2d(q)
        obstacles = np.asarray(obstacles, float).reshape(-1, 6)
        ok = np.ones(len(q), dtype=bool)
        if not len(obstacles) or not len(q):
            return ok
        poses = self.poses(q)
        moving = [k for k, b in enumerate(self.bodies) if self._moves(b.link)]
        boxes = [
            fcl.CollisionObject(
                fcl.Box(*(box[3:] - box[:3])), fcl.Transform(np.eye(3), (box[3:] + box[:3]) / 2)
            )
            for box in obstacles
        ]
        sphere = fcl.CollisionObject(fcl.Sphere(max(camera_radius, 1e-6)), fcl.Transform())
        objects = {k: fcl.CollisionObject(self.bodies[k].geometry, fcl.Transform()) for k in moving}
        request = fcl.CollisionRequest()
        for n in range(len(q)):
            for k in moving:
                objects[k].setTransform(fcl.Transform(poses[n, k, :3, :3], poses[n, k, :3, 3]))
            sphere.setTranslation(camera[n])
            things = [*objects.values(), *([sphere] if camera_radius > 0 else [])]
            ok[n] = not any(
                fcl.collide(t, box, request, fcl.CollisionResult()) for t in things for box in boxes
            )
        return ok


_GEOMETRY: dict[tuple, object] = {}


def urdf_geometry(model: RobotModel):
    """The :class:`~relcal.design.urdf_collision.UrdfCollision` of a URDF model whose chain has
    collision geometry (built once per model), else ``None``. Without python-fcl installed it is
    ``None`` too, with a warning: the capsules are used instead."""
    if model.urdf is None:
        return None
    chain = model.urdf
    key = (hash(chain.data), chain.root, chain.tip, model.lower.tobytes(), model.upper.tobytes())
    if key not in _GEOMETRY:
        from relcal.errors import RelcalError

        try:
            geometry = UrdfCollision(model)
        except RelcalError as exc:
            import warnings

            warnings.warn(f"{exc}; checking capsules about the links instead", stacklevel=2)
            geometry = None
        _GEOMETRY[key] = geometry if geometry is not None and geometry.has_chain_geometry else None
    return _GEOMETRY[key]
