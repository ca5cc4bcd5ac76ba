"""Small self-contained scenes for the simulation's tests and benchmark: a one-joint character,
motions of it (static or with a root translation) and single-collider ColliderSets."""
from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull

from stages.hulls.types import ColliderSet, ConvexMesh, HullCollider, HullFitReport, SphereCollider
from stages.rig.types import Character, Motion


def fibonacci_points(n: int, radii=(1.0, 1.0, 1.0), center=(0.0, 0.0, 0.0)) -> np.ndarray:
    """n points spread evenly on an ellipsoid (deterministic)."""
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    theta = np.pi * (1 + 5 ** 0.5) * i
    p = np.stack([np.cos(theta) * np.sin(phi), np.cos(phi), np.sin(theta) * np.sin(phi)], axis=1)
    return p * np.asarray(radii, float) + np.asarray(center, float)


def convex_mesh(points: np.ndarray) -> ConvexMesh:
    """Outward-oriented convex hull of points (a hull of n points on an ellipsoid has 2n - 4 faces)."""
    hull = ConvexHull(points)
    used = np.unique(hull.simplices)
    remap = np.full(points.shape[0], -1)
    remap[used] = np.arange(used.size)
    v = points[used]
    f = remap[hull.simplices]
    c = v.mean(axis=0)
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    flip = np.einsum("ij,ij->i", n, v[f[:, 0]] - c) < 0
    f[flip] = f[flip][:, ::-1]
    return ConvexMesh(np.ascontiguousarray(v), np.ascontiguousarray(f, dtype=np.int32))


def toy_character(vertices: np.ndarray, triangles: np.ndarray, name: str = "toy") -> Character:
    """A one-joint character (joint 'root' at the origin, identity bind) skinned rigidly to it."""
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    eye = np.eye(4)[None]
    return Character(name=name, vertices=v, triangles=np.ascontiguousarray(triangles, dtype=np.int32),
                     primitive_ids=np.zeros(v.shape[0], np.int32), joint_names=("root",),
                     parents=np.array([-1], np.int32), rest_local=eye.copy(), inverse_bind=eye.copy(),
                     skin_joints=np.zeros((v.shape[0], 1), np.int32), skin_weights=np.ones((v.shape[0], 1)),
                     source="procedural")


def toy_motion(n_frames: int, dt: float = 1 / 30, root_translation=None, rotations=None) -> Motion:
    """A motion of the one-joint character.

    root_translation: (F, 3) world translation of the root (0 at frame 0), or None (static).
    rotations: (F, 3, 3) rotation of the joint about the origin in the relative frame, or None.
    """
    jw = np.tile(np.eye(4), (n_frames, 1, 1, 1))
    if rotations is not None:
        jw[:, 0, :3, :3] = rotations
    t = np.zeros((n_frames, 3)) if root_translation is None else np.asarray(root_translation, float)
    return Motion("toy", np.arange(n_frames) * dt, jw, t - t[0])


def sphere_set(center=(0.0, 0.0, 0.0), radius: float = 0.3, joint: int = 0) -> ColliderSet:
    s = SphereCollider(joint, "ball", np.asarray(center, float), float(radius), np.zeros((0, 3)))
    return ColliderSet(hulls=(), spheres=(s,), delta=0.0, min_triangles=4)


def hull_set(mesh: ConvexMesh, bone: int = 0, name: str = "hull") -> ColliderSet:
    f = mesh.faces.shape[0]
    report = HullFitReport(f, f, f, 0.0, 0.0, 0.0, True, 0.0)
    h = HullCollider(bone, name, mesh.vertices.copy(), mesh, mesh, mesh, report)
    return ColliderSet(hulls=(h,), spheres=(), delta=0.0, min_triangles=4)
