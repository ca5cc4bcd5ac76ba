"""Obstacle meshes: primitives (box, table, sphere, plane, cylinder) and files through trimesh.

Every builder returns (vertices (n, 3) float64, triangles (m, 3) int32) in world metres, Y up,
outward (counter-clockwise seen from outside) winding; `make_obstacle` wraps them in an Obstacle.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from stages.checks import ContractError
from stages.errors import InputError
from stages.obstacles.types import Obstacle, ObstacleMotion

MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf")


def _out(mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    return np.ascontiguousarray(mesh.vertices, dtype=np.float64), np.ascontiguousarray(mesh.faces, dtype=np.int32)


def _positive(what: str, *values) -> None:
    for v in values:
        if not np.isfinite(v) or v <= 0:
            raise ContractError(f"{what}: expected positive sizes, got {values}")


def box_mesh(center=(0.0, 0.0, 0.0), size=(1.0, 1.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box, 8 vertices, 12 triangles. size = full extents (x, y, z), metres."""
    _positive("box_mesh.size", *size)
    m = trimesh.creation.box(extents=np.asarray(size, np.float64))
    m.apply_translation(np.asarray(center, np.float64))
    return _out(m)


def table_mesh(top_center=(0.0, 0.75, 0.0), top_size=(1.0, 1.0), top_thickness=0.03,
               leg_size=0.05, leg_inset=0.05) -> tuple[np.ndarray, np.ndarray]:
    """A table: a top slab (its upper face at top_center.y) on 4 square legs down to y = 0.

    top_size: (x, z) extents; leg_size: leg side; leg_inset: leg distance from the slab's edges.
    The 5 closed boxes overlap under the slab; each is outward, which is all the contact test needs.
    Legs are skipped when the top is at or below the slab thickness (a low box).
    """
    cx, cy, cz = (float(c) for c in top_center)
    sx, sz = (float(s) for s in top_size)
    _positive("table_mesh", sx, sz, top_thickness, leg_size)
    parts = [box_mesh((cx, cy - top_thickness / 2, cz), (sx, top_thickness, sz))]
    leg_h = cy - top_thickness
    if leg_h > 0:
        ox = sx / 2 - leg_inset - leg_size / 2
        oz = sz / 2 - leg_inset - leg_size / 2
        if ox <= 0 or oz <= 0:
            raise ContractError("table_mesh: legs do not fit under the top (leg_size / leg_inset too large)")
        for dx in (-ox, ox):
            for dz in (-oz, oz):
                parts.append(box_mesh((cx + dx, leg_h / 2, cz + dz), (leg_size, leg_h, leg_size)))
    return concatenate_meshes(parts)


def sphere_mesh(center=(0.0, 0.0, 0.0), radius=0.5, subdivisions=3) -> tuple[np.ndarray, np.ndarray]:
    """Icosphere (20 * 4**subdivisions triangles) with vertices ON the sphere, so the faceted
    surface lies up to radius * (1 - cos(edge angle / 2)) inside it."""
    _positive("sphere_mesh.radius", radius)
    m = trimesh.creation.icosphere(subdivisions=int(subdivisions), radius=float(radius))
    m.apply_translation(np.asarray(center, np.float64))
    return _out(m)


def plane_mesh(center=(0.0, 0.0, 0.0), normal=(0.0, 1.0, 0.0), size=(10.0, 10.0)) -> tuple[np.ndarray, np.ndarray]:
    """A finite two-sided plane: a square quad pair facing +normal and -normal (4 vertices,
    4 triangles), so the obstacle's thickness applies on both sides. size: extents along the two
    in-plane axes (for normal = +Y: x and z)."""
    n = np.asarray(normal, np.float64)
    ln = np.linalg.norm(n)
    if not np.isfinite(ln) or ln == 0:
        raise ContractError(f"plane_mesh.normal: expected a non-zero vector, got {normal}")
    _positive("plane_mesh.size", *size)
    n = n / ln
    ref = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    # in-plane axes u, w with u x w = n so (0,1,2),(0,2,3) faces +n
    w = np.cross(n, ref)
    w /= np.linalg.norm(w)
    u = np.cross(w, n)
    hu, hw = size[0] / 2, size[1] / 2
    c = np.asarray(center, np.float64)
    v = np.array([c - hu * u - hw * w, c + hu * u - hw * w, c + hu * u + hw * w, c - hu * u + hw * w])
    f = np.array([[0, 1, 2], [0, 2, 3], [0, 2, 1], [0, 3, 2]], dtype=np.int32)
    return v, f


def cylinder_mesh(center=(0.0, 0.5, 0.0), radius=0.3, height=1.0, sections=32,
                  axis=(0.0, 1.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Closed capped cylinder centred at `center` along `axis` (default upright, Y)."""
    _positive("cylinder_mesh", radius, height)
    a = np.asarray(axis, np.float64)
    if np.linalg.norm(a) == 0:
        raise ContractError("cylinder_mesh.axis: expected a non-zero vector")
    m = trimesh.creation.cylinder(radius=float(radius), height=float(height), sections=int(sections))
    rot = trimesh.geometry.align_vectors([0.0, 0.0, 1.0], a / np.linalg.norm(a))
    m.apply_transform(rot)
    m.apply_translation(np.asarray(center, np.float64))
    return _out(m)


def concatenate_meshes(parts) -> tuple[np.ndarray, np.ndarray]:
    """Stack (vertices, triangles) pairs into one mesh."""
    vs, fs, off = [], [], 0
    for v, f in parts:
        vs.append(v)
        fs.append(f + off)
        off += v.shape[0]
    return np.concatenate(vs).astype(np.float64), np.concatenate(fs).astype(np.int32)


def load_obstacle_mesh(path, scale: float = 1.0, transform=None) -> tuple[np.ndarray, np.ndarray]:
    """Read an OBJ / PLY / STL / GLB / glTF mesh (all its geometry, node transforms applied) and
    return world (vertices, triangles): x_world = transform @ (scale * x_file).

    Closed meshes get consistent outward winding (trimesh.fix_normals); open ones keep the file's.
    Zero-area triangles and unused vertices are dropped. Raises InputError for a missing file, an
    unsupported suffix, an unreadable / corrupt file, a file with no triangles, non-finite
    coordinates, or a mesh with no triangle of non-zero area.
    """
    from stages.mesh_file import read_mesh_file

    p = Path(path)
    if p.suffix.lower() not in MESH_SUFFIXES:
        raise InputError(p, f"unsupported mesh format {p.suffix!r} (expected one of {', '.join(MESH_SUFFIXES)})")
    if not np.isfinite(scale) or scale <= 0:
        raise InputError(p, f"scale must be a positive number, got {scale}")
    loaded = read_mesh_file(p, what="obstacle mesh")
    faces = np.asarray(loaded.faces)
    if faces.ndim != 2 or faces.shape[0] == 0 or faces.shape[1] != 3:
        raise InputError(p, "the file holds no triangles")
    verts = np.asarray(loaded.vertices, dtype=np.float64)
    if verts.size == 0 or not np.isfinite(verts).all():
        raise InputError(p, "non-finite or missing vertex coordinates")
    if faces.min() < 0 or faces.max() >= verts.shape[0]:
        raise InputError(p, "triangle indices out of range")
    m = np.eye(4)
    if transform is not None:
        m = np.asarray(transform, dtype=np.float64)
        if m.shape != (4, 4) or not np.isfinite(m).all() or abs(np.linalg.det(m[:3, :3])) < 1e-12:
            raise InputError(p, "transform must be a finite, invertible 4x4 matrix")
    verts = (scale * verts) @ m[:3, :3].T + m[:3, 3]
    if np.linalg.det(m[:3, :3]) < 0:
        faces = faces[:, ::-1]  # a mirroring transform flips the winding
    a, b, c = verts[faces[:, 0]], verts[faces[:, 1]], verts[faces[:, 2]]
    area2 = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    extent = float(np.ptp(verts, axis=0).max())
    good = area2 > (1e-12 * extent * extent)
    if not good.any():
        raise InputError(p, "degenerate mesh: every triangle has zero area")
    mesh = trimesh.Trimesh(verts, faces[good], process=True)
    if mesh.is_watertight:
        mesh.fix_normals()
    mesh.remove_unreferenced_vertices()
    v, f = _out(mesh)
    area2 = np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    f = f[area2 > 0]
    if f.shape[0] == 0:
        raise InputError(p, "degenerate mesh: every triangle has zero area")
    return v, f


def make_obstacle(name: str, mesh: tuple[np.ndarray, np.ndarray], thickness: float = 0.005,
                  friction: float = 0.3, restitution: float = 0.0,
                  motion: ObstacleMotion | None = None) -> Obstacle:
    """An Obstacle from a (vertices, triangles) pair; zero-area triangles are dropped."""
    v = np.ascontiguousarray(mesh[0], dtype=np.float64)
    f = np.ascontiguousarray(mesh[1], dtype=np.int32)
    area2 = np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    f = f[area2 > 0]
    return Obstacle(name=name, vertices=v, triangles=f, thickness=float(thickness),
                    friction=float(friction), restitution=float(restitution), motion=motion)
