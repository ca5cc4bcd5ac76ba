"""Data contracts of the hull stage: convex hulls per rigid region, spheres per flexible region.

All geometry is in the bone-local frame of the collider's joint (see stages/rig/types.py):
rigid regions do not deform, so everything built here is valid for the whole animation.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from stages.checks import ContractError, check_array, check_index


@dataclass(frozen=True)
class ConvexMesh:
    """A closed convex triangle mesh.

    vertices: (n, 3) float64, metres, bone-local.
    faces: (m, 3) int32, counter-clockwise seen from outside (outward normals).
    """

    vertices: np.ndarray
    faces: np.ndarray

    def __post_init__(self):
        v = check_array("ConvexMesh", "vertices", self.vertices, (None, 3), np.float64)
        f = check_array("ConvexMesh", "faces", self.faces, (None, 3), np.int32)
        check_index("ConvexMesh", "faces", f, v.shape[0])
        if f.shape[0] < 4:
            raise ContractError(f"ConvexMesh.faces: a closed convex mesh needs >= 4 faces, got {f.shape[0]}")

    @property
    def planes(self) -> np.ndarray:
        """(m, 4) float64: unit outward normal n and offset d per face; inside iff n.x <= d."""
        a, b, c = (self.vertices[self.faces[:, i]] for i in range(3))
        n = np.cross(b - a, c - a)
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        return np.column_stack([n, np.einsum("ij,ij->i", n, a)])


@dataclass(frozen=True)
class HullFitReport:
    """Fit figures of one hull (paper A §2.2). Volumes in m^3, distances in m."""

    faces_raw: int
    faces_inflated: int
    faces_simplified: int
    volume_raw: float
    volume_simplified: float
    hausdorff: float          # one-sided, simplified hull surface -> raw hull
    contains_region: bool     # every region vertex on or inside the simplified hull
    worst_violation: float    # max signed distance of a region vertex outside it (<= 0 is fine)

    @property
    def excess_volume(self) -> float:
        return self.volume_simplified - self.volume_raw


@dataclass(frozen=True)
class HullCollider:
    """The collider of one rigid region, or of part of a flexible region swept over the motion.

    bone: joint index whose bone-local frame the meshes are in; name: the collider's name (the
        joint's name for a rigid hull, '<joint>_flex' or '<joint>_flex_<bone>' for a swept one).
    region_points: (p, 3) float64, bone-local: a rigid hull's region vertices in the bind pose; a
        swept hull's vertices at every pose of the motion sample (and the bind pose).
    raw / inflated / simplified: the hull at each step; `simplified` is what collides.
    kind: 'rigid' (a rigid region, paper A §2) or 'swept' (flexible vertices over the motion).
    region_vertices: (n,) int64, the character's vertices the collider was built around.
    joint: the joint whose flexible region a swept hull belongs to (= bone for a rigid hull).
    """

    bone: int
    name: str
    region_points: np.ndarray
    raw: ConvexMesh
    inflated: ConvexMesh
    simplified: ConvexMesh
    report: HullFitReport
    kind: str = "rigid"
    region_vertices: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    joint: int = -1

    def __post_init__(self):
        o = f"HullCollider[{self.name!r}]"
        check_array(o, "region_points", self.region_points, (None, 3), np.float64)
        check_array(o, "region_vertices", self.region_vertices, (None,), np.int64)
        if self.kind not in ("rigid", "swept"):
            raise ContractError(f"{o}.kind: expected 'rigid' or 'swept', got {self.kind!r}")
        if self.joint < 0:
            object.__setattr__(self, "joint", int(self.bone))


@dataclass(frozen=True)
class SphereCollider:
    """The collider of one flexible region: a sphere at the joint (paper A), or one skinned ball.

    joint: joint index; center: (3,) float64, in the collider frame (the joint origin in `joint`'s
    bone-local frame; 0 for a ball); radius: metres, farthest region vertex + delta (a ball: its depth
    + slack + delta). region_points: (p, 3) in the collider frame.
    frame: the collider frame it is posed by, an index into ColliderSet.frame_poses (-1: `joint`; a
    ball k of B: J + k, a frame that moves with the skinned ball centre).
    """

    joint: int
    name: str
    center: np.ndarray
    radius: float
    region_points: np.ndarray
    region_vertices: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    frame: int = -1

    @property
    def pose_index(self) -> int:
        """Index of the transform posing it in ColliderSet.frame_poses (J joints, then the balls)."""
        return self.frame if self.frame >= 0 else self.joint

    def __post_init__(self):
        o = f"SphereCollider[{self.name!r}]"
        check_array(o, "center", self.center, (3,), np.float64)
        check_array(o, "region_points", self.region_points, (None, 3), np.float64)
        check_array(o, "region_vertices", self.region_vertices, (None,), np.int64)
        if not (np.isfinite(self.radius) and self.radius > 0):
            raise ContractError(f"{o}.radius: expected a positive radius, got {self.radius}")


@dataclass(frozen=True)
class ColliderSet:
    """Every collider of a character, plus the parameters they were fitted with.

    hulls: rigid hulls (at most one per bone) and swept hulls of flexible regions, names unique.
    spheres: joint spheres (at most one per joint), then the skinned balls (flexible 'balls').
    flexible: how flexible regions were fitted, 'sphere' (paper A), 'swept' or 'balls'.
    balls: the skinned balls (stages/hulls/balls.py) the ball spheres are posed by, else None.
    notes: fallbacks taken (e.g. a region too flat for a hull).
    """

    hulls: tuple[HullCollider, ...]
    spheres: tuple[SphereCollider, ...]
    delta: float              # inflation thickness, metres
    min_triangles: int        # simplification floor
    flexible: str = "sphere"
    notes: tuple[str, ...] = ()
    balls: object = None     # stages.hulls.balls.BallSet | None

    def frame_poses(self, inverse_bind: np.ndarray, joint_world: np.ndarray) -> np.ndarray:
        """(..., J + B, 4, 4): the joint transforms (..., J, 4, 4), then one per skinned ball (no
        rotation, its centre skinned like a vertex). Colliders are posed by `pose_index` into it."""
        if self.balls is None or self.balls.radius.size == 0:
            return joint_world
        c = self.balls.centers(inverse_bind, joint_world)
        m = np.zeros((*c.shape[:-1], 4, 4))
        m[..., 0, 0] = m[..., 1, 1] = m[..., 2, 2] = m[..., 3, 3] = 1.0
        m[..., :3, 3] = c
        return np.concatenate([joint_world, m], axis=-3)

    def __post_init__(self):
        bones = [h.bone for h in self.hulls if h.kind == "rigid"]
        if len(set(bones)) != len(bones):
            raise ContractError("ColliderSet.hulls: at most one rigid hull per bone")
        names = [h.name for h in self.hulls]
        if len(set(names)) != len(names):
            raise ContractError("ColliderSet.hulls: hull names must be unique")
        if self.flexible not in ("sphere", "swept", "balls"):
            raise ContractError(f"ColliderSet.flexible: expected 'sphere', 'swept' or 'balls', got {self.flexible!r}")
        n_balls = 0 if self.balls is None else self.balls.radius.size
        if sum(s.frame >= 0 for s in self.spheres) != n_balls:
            raise ContractError(f"ColliderSet.spheres: {n_balls} balls but {sum(s.frame >= 0 for s in self.spheres)} ball spheres")
        joints = [s.joint for s in self.spheres if s.frame < 0]
        if len(set(joints)) != len(joints):
            raise ContractError("ColliderSet.spheres: at most one sphere per joint")
        if not (np.isfinite(self.delta) and self.delta >= 0):
            raise ContractError(f"ColliderSet.delta: expected a non-negative thickness, got {self.delta}")
