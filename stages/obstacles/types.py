"""Data contracts of the obstacle stage (paper B): environment meshes and their k-DOP trees.

Frames
- *body frame* of an obstacle: the frame its `vertices` are given in. A static obstacle's body
  frame IS world (Y up, metres). A moving obstacle maps body -> world at time t by
  `motion.pose_at(t)` (a rigid 4x4); with `motion.transforms[0] = I` the vertices are world at t0.
- k-DOP bounds of obstacle trees are in world at the current step (static: built once; moving:
  refit every step over the obstacle's start- and end-of-step poses).

Rigid motion is ONE representation: keyed rigid transforms over time (`ObstacleMotion`), sampled
with lerp (translation) + slerp (rotation). Constant linear / angular velocity is a constructor
(`ObstacleMotion.from_velocity`) that writes such keys, so the run time has one code path.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from stages.checks import ContractError, check_array, check_index, check_positive, check_rigid
from stages.geometry.kdop import KdopTree
from stages.rig.transforms import slerp


@dataclass(frozen=True)
class ObstacleMotion:
    """Rigid motion of an obstacle as keyed body -> world transforms.

    times: (F,) float64, seconds, strictly increasing, F >= 1.
    transforms: (F, 4, 4) float64, rigid (rotation + translation), body -> world at times[f].
    loop: past the last key, wrap around (True) or hold the last pose (False). Before the first
    key the first pose is held.
    """

    times: np.ndarray
    transforms: np.ndarray
    loop: bool = False

    def __post_init__(self):
        t = check_array("ObstacleMotion", "times", self.times, (None,), np.float64)
        if t.size == 0:
            raise ContractError("ObstacleMotion.times: needs at least one key")
        if t.size > 1 and not np.all(np.diff(t) > 0):
            raise ContractError("ObstacleMotion.times: key times must be strictly increasing")
        m = check_array("ObstacleMotion", "transforms", self.transforms, (t.size, 4, 4), np.float64)
        check_rigid("ObstacleMotion", "transforms", m)

    @staticmethod
    def from_velocity(linear=(0.0, 0.0, 0.0), angular=(0.0, 0.0, 0.0), pivot=(0.0, 0.0, 0.0),
                      duration: float = 10.0, key_dt: float = 1.0 / 30.0) -> "ObstacleMotion":
        """Constant velocity: translation `linear` (m/s) and rotation `angular` (rad/s, axis * rate,
        world axes) about the world point `pivot` (which itself moves with `linear`)."""
        check_positive("ObstacleMotion", "duration", float(duration))
        check_positive("ObstacleMotion", "key_dt", float(key_dt))
        n = int(np.ceil(duration / key_dt)) + 1
        times = np.arange(n, dtype=np.float64) * key_dt
        lin = np.asarray(linear, np.float64)
        ang = np.asarray(angular, np.float64)
        piv = np.asarray(pivot, np.float64)
        rot = Rotation.from_rotvec(times[:, None] * ang[None, :]).as_matrix()
        m = np.zeros((n, 4, 4))
        m[:, :3, :3] = rot
        # x_world = R (x - pivot) + pivot + v t
        m[:, :3, 3] = piv[None, :] - np.einsum("fij,j->fi", rot, piv) + times[:, None] * lin[None, :]
        m[:, 3, 3] = 1.0
        return ObstacleMotion(times, m, loop=False)

    def pose_at(self, t: float) -> np.ndarray:
        """(4, 4) body -> world at time t (seconds)."""
        times = self.times
        if times.size == 1:
            return self.transforms[0].copy()
        if self.loop:
            span = times[-1] - times[0]
            t = times[0] + (t - times[0]) % span
        if t <= times[0]:
            return self.transforms[0].copy()
        if t >= times[-1]:
            return self.transforms[-1].copy()
        i = int(np.searchsorted(times, t, side="right")) - 1
        u = (t - times[i]) / (times[i + 1] - times[i])
        a, b = self.transforms[i], self.transforms[i + 1]
        qa, qb = Rotation.from_matrix(np.stack([a[:3, :3], b[:3, :3]])).as_quat()
        out = np.eye(4)
        out[:3, :3] = Rotation.from_quat(slerp(qa, qb, np.float64(u))).as_matrix()
        out[:3, 3] = (1.0 - u) * a[:3, 3] + u * b[:3, 3]
        return out


@dataclass(frozen=True)
class Obstacle:
    """One environment obstacle: a triangle mesh the cloth must stay outside of.

    name: unique, used in entity paths (`obstacles/<name>/mesh`).
    vertices: (n, 3) float64, metres, body frame (= world for static obstacles).
    triangles: (m, 3) int32, counter-clockwise seen from outside (outward normals), m >= 1,
      no zero-area triangle (the builders drop them).
    thickness: metres > 0, the proximity band: particles are kept at this distance in front of
      each triangle (and for thin / open meshes, on whichever side they come from).
    friction: Coulomb-like coefficient >= 0 (tangential travel reduced by friction * normal push).
    restitution: in [0, 1], the fraction of the normal approach speed reflected (0 = inelastic).
    motion: None for static, else the rigid `ObstacleMotion` body -> world.
    """

    name: str
    vertices: np.ndarray
    triangles: np.ndarray
    thickness: float = 0.005
    friction: float = 0.3
    restitution: float = 0.0
    motion: ObstacleMotion | None = None

    def __post_init__(self):
        o = f"Obstacle[{self.name!r}]"
        v = check_array(o, "vertices", self.vertices, (None, 3), np.float64)
        f = check_array(o, "triangles", self.triangles, (None, 3), np.int32)
        if f.shape[0] == 0:
            raise ContractError(f"{o}.triangles: needs at least one triangle")
        check_index(o, "triangles", f, v.shape[0])
        area2 = np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
        if not np.all(area2 > 0.0):
            raise ContractError(f"{o}.triangles: zero-area triangle at index {int(np.argmin(area2 > 0))}")
        check_positive(o, "thickness", float(self.thickness))
        check_positive(o, "friction", float(self.friction), strict=False)
        if not (0.0 <= float(self.restitution) <= 1.0):
            raise ContractError(f"{o}.restitution: expected a number in [0, 1], got {self.restitution}")
        if self.motion is not None and not isinstance(self.motion, ObstacleMotion):
            raise ContractError(f"{o}.motion: expected an ObstacleMotion or None")

    @property
    def is_static(self) -> bool:
        return self.motion is None

    def pose_at(self, t: float) -> np.ndarray:
        """(4, 4) body -> world at time t (identity for static obstacles)."""
        return np.eye(4) if self.motion is None else self.motion.pose_at(t)


@dataclass(frozen=True)
class ObstacleSet:
    """Every obstacle of a scene, concatenated for the collision kernel, with one k-DOP tree each.

    obstacles: the `Obstacle`s, in scene order (obstacle id = position).
    vertices: (V, 3) float64, metres, each obstacle's body-frame vertices, concatenated.
    triangles: (T, 3) int32, global vertex ids into `vertices`, outward; triangle id = row.
    tri_obstacle: (T,) int32, the obstacle id of each triangle.
    vertex_offsets, triangle_offsets: (r + 1,) int32, obstacle i owns rows [off[i], off[i+1]).
    tree: a forest, tree i is obstacle i's, leaves hold global triangle ids, bounds world at the
      obstacle's pose at time `built_at` (seconds) inflated by its thickness.
    """

    obstacles: tuple
    vertices: np.ndarray
    triangles: np.ndarray
    tri_obstacle: np.ndarray
    vertex_offsets: np.ndarray
    triangle_offsets: np.ndarray
    tree: KdopTree
    built_at: float = 0.0

    def __post_init__(self):
        o = "ObstacleSet"
        r = len(self.obstacles)
        if r == 0:
            raise ContractError(f"{o}.obstacles: needs at least one obstacle")
        names = [ob.name for ob in self.obstacles]
        if len(set(names)) != r:
            raise ContractError(f"{o}.obstacles: names must be unique, got {names}")
        v = check_array(o, "vertices", self.vertices, (None, 3), np.float64)
        f = check_array(o, "triangles", self.triangles, (None, 3), np.int32)
        check_index(o, "triangles", f, v.shape[0])
        check_array(o, "tri_obstacle", self.tri_obstacle, (f.shape[0],), np.int32)
        check_index(o, "tri_obstacle", self.tri_obstacle, r)
        check_array(o, "vertex_offsets", self.vertex_offsets, (r + 1,), np.int32)
        check_array(o, "triangle_offsets", self.triangle_offsets, (r + 1,), np.int32)
        if self.tree.n_trees != r:
            raise ContractError(f"{o}.tree: expected {r} trees, got {self.tree.n_trees}")

    @property
    def names(self) -> list[str]:
        return [ob.name for ob in self.obstacles]

    def per_obstacle(self, attr: str) -> np.ndarray:
        """(r,) float64 of an Obstacle scalar attribute (thickness, friction, restitution)."""
        return np.array([float(getattr(ob, attr)) for ob in self.obstacles], dtype=np.float64)
