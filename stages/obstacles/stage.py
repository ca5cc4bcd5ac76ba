"""Obstacle stage: `build_obstacle_set` (once per scene) and `ObstacleCollider` (the per-step state
the cloth simulation drives). The numba kernel contract is documented in `kernels.py`."""
from __future__ import annotations

import numpy as np

from stages.checks import ContractError, check_array
from stages.geometry.kdop import DEFAULT_K, build_particle_tree, build_triangle_tree, merge_forest
from stages.obstacles.kernels import collide_obstacles
from stages.obstacles.types import Obstacle, ObstacleSet


def build_obstacle_set(obstacles, k: int = DEFAULT_K, t0: float = 0.0) -> ObstacleSet:
    """Concatenate the obstacles and build one k-DOP tree each (bounds world at time t0,
    inflated by each obstacle's thickness). Static trees are never rebuilt."""
    obstacles = tuple(obstacles)
    if not obstacles:
        raise ContractError("build_obstacle_set: needs at least one obstacle")
    if not all(isinstance(o, Obstacle) for o in obstacles):
        raise ContractError("build_obstacle_set: expected Obstacle instances")
    v_off = np.zeros(len(obstacles) + 1, dtype=np.int32)
    t_off = np.zeros(len(obstacles) + 1, dtype=np.int32)
    trees = []
    for i, ob in enumerate(obstacles):
        v_off[i + 1] = v_off[i] + ob.vertices.shape[0]
        t_off[i + 1] = t_off[i] + ob.triangles.shape[0]
        pose = ob.pose_at(t0)
        world = ob.vertices @ pose[:3, :3].T + pose[:3, 3]
        tree = build_triangle_tree(world, ob.triangles, k=k, margin=float(ob.thickness))
        trees.append(tree)
    forest = merge_forest(trees)
    # leaves hold global triangle ids
    leaf = forest.leaf_prim.copy()
    for i in range(len(obstacles)):
        sl = slice(forest.tree_offsets[i], forest.tree_offsets[i + 1])
        leaf[sl] = np.where(leaf[sl] >= 0, leaf[sl] + t_off[i], -1)
    from dataclasses import replace
    forest = replace(forest, leaf_prim=leaf.astype(np.int32))
    vertices = np.concatenate([o.vertices for o in obstacles])
    triangles = np.concatenate([o.triangles + v_off[i] for i, o in enumerate(obstacles)]).astype(np.int32)
    tri_obstacle = np.repeat(np.arange(len(obstacles), dtype=np.int32), np.diff(t_off))
    return ObstacleSet(obstacles=obstacles, vertices=vertices, triangles=triangles,
                       tri_obstacle=tri_obstacle, vertex_offsets=v_off, triangle_offsets=t_off,
                       tree=forest, built_at=float(t0))


class ObstacleCollider:
    """Mutable per-run state: the cloth particle tree and the current obstacle bounds.

    oset: the scene's ObstacleSet. x_rest: (N, 3) float64 cloth positions the particle tree's
    topology is built from (the initial drape); its bounds are refit every step.
    passes: detection + response rounds per step (1 = each particle's contact resolved exactly
    once; 2 also resolves a second triangle the first push ended behind, e.g. at a table's edge).
    """

    def __init__(self, oset: ObstacleSet, x_rest: np.ndarray, passes: int = 2):
        check_array("ObstacleCollider", "x_rest", x_rest, (None, 3), np.float64)
        self.oset = oset
        ctree = build_particle_tree(x_rest, k=oset.tree.k)
        self.cloth_tree = ctree
        self.c_min = ctree.node_min.copy()
        self.c_max = ctree.node_max.copy()
        t = oset.tree
        self.o_min = t.node_min.copy()
        self.o_max = t.node_max.copy()
        r = len(oset.obstacles)
        self.moving = np.array([not o.is_static for o in oset.obstacles], dtype=np.bool_)
        self.thickness = oset.per_obstacle("thickness")
        self.friction = oset.per_obstacle("friction")
        self.restitution = oset.per_obstacle("restitution")
        self._identity = np.tile(np.eye(4), (r, 1, 1))
        n = x_rest.shape[0]
        self.out_particle = np.zeros(n, dtype=np.int32)
        self.out_triangle = np.zeros(n, dtype=np.int32)
        self.out_toi = np.zeros(n)
        self.out_point = np.zeros((n, 3))
        self.out_normal = np.zeros((n, 3))
        self.stats = np.zeros(4, dtype=np.int64)
        self.n_contacts = 0
        if not (isinstance(passes, int) and passes >= 1):
            raise ContractError(f"ObstacleCollider.passes: expected an integer >= 1, got {passes!r}")
        self.passes = passes

    def poses(self, t: float) -> np.ndarray:
        """(r, 4, 4) body -> world of every obstacle at time t."""
        if not self.moving.any():
            return self._identity
        return np.stack([o.pose_at(t) for o in self.oset.obstacles])

    def kernel_args(self, t0: float, t1: float) -> tuple:
        """Everything `collide_obstacles` takes after (x_prev, x, inv_mass), for the step t0 -> t1."""
        o = self.oset
        t = o.tree
        return (self.c_min, self.c_max, self.cloth_tree.children, self.cloth_tree.leaf_prim,
                self.o_min, self.o_max, t.children, t.leaf_prim, t.tree_offsets,
                t.directions, o.vertices, o.triangles, o.tri_obstacle, o.vertex_offsets, o.triangle_offsets,
                self.poses(t0), self.poses(t1), self.moving, self.thickness, self.friction, self.restitution,
                self.out_particle, self.out_triangle, self.out_toi, self.out_point, self.out_normal, self.stats, self.passes)

    def collide(self, x_prev: np.ndarray, x: np.ndarray, inv_mass: np.ndarray, t0: float = 0.0,
                t1: float = 0.0) -> int:
        """Resolve this step's contacts in place (see kernels.collide_obstacles). Returns the count."""
        if x.shape != self.out_point.shape:
            raise ContractError(f"ObstacleCollider.collide: expected x of shape {self.out_point.shape}, got {x.shape}")
        self.n_contacts = int(collide_obstacles(x_prev, x, inv_mass, *self.kernel_args(t0, t1)))
        return self.n_contacts

    def contacts(self) -> dict:
        """The last step's contacts: particle (c,) int32, triangle (c,) int32 (global id),
        obstacle (c,) int32, toi (c,), point (c, 3) world (responded position), normal (c, 3) world."""
        c = self.n_contacts
        tri = self.out_triangle[:c].copy()
        return {"particle": self.out_particle[:c].copy(), "triangle": tri,
                "obstacle": self.oset.tri_obstacle[tri], "toi": self.out_toi[:c].copy(),
                "point": self.out_point[:c].copy(), "normal": self.out_normal[:c].copy()}
