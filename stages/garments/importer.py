"""Garment meshes from files (OBJ / PLY / GLB / ... through trimesh), scaled and placed.

Repairs with a warning: non-triangle faces (triangulated by trimesh), duplicate vertices (merged),
degenerate and duplicate faces (dropped), unused vertices (removed). Refused with InputError: a
missing or unreadable file, no triangles left, non-finite vertices, non-manifold edges (shared by
more than two faces).
"""
from __future__ import annotations

import warnings
from pathlib import Path
from typing import NamedTuple

import numpy as np

from stages.errors import InputError


class GarmentMesh(NamedTuple):
    """A garment mesh file as read: x (N, 3) float64 metres, tri (T, 3) int32 into x; the file's
    texture coordinates per corner (a seam has two UVs for one vertex): uv (U, 2) float32 and
    uv_faces (T, 3) int32 into uv, or None when the file has none."""

    x: np.ndarray
    tri: np.ndarray
    uv: np.ndarray | None = None
    uv_faces: np.ndarray | None = None


def import_garment_mesh(path, *, scale: float = 1.0, transform=None) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (N, 3) float64 metres, triangles (T, 3) int32) of the mesh file at `path`,
    multiplied by `scale`, then by the (4, 4) `transform` (default identity)."""
    return read_garment_mesh(path, scale=scale, transform=transform, part="all")[:2]


def read_garment_mesh(path, *, scale: float = 1.0, transform=None, part=None) -> GarmentMesh:
    """The mesh file at `path` (see import_garment_mesh) with its texture coordinates. part: of a
    glTF holding several meshes, which one (stages.mesh_file.read_mesh_file; None: it must hold one)."""
    import trimesh

    from stages.mesh_file import read_mesh_file

    p = Path(path)
    if not (np.isfinite(scale) and scale > 0):
        raise InputError(p, f"scale must be positive, got {scale}")
    m4 = np.eye(4) if transform is None else np.asarray(transform, dtype=np.float64)
    if m4.shape != (4, 4) or not np.isfinite(m4).all():
        raise InputError(p, "transform must be a finite 4x4 matrix")
    loaded = read_mesh_file(p, what="garment mesh", part=part)
    v = np.asarray(loaded.vertices, dtype=np.float64)
    f = np.asarray(loaded.faces, dtype=np.int64)
    if not np.isfinite(v).all():
        raise InputError(p, "non-finite vertex coordinates")
    notes = []
    file_uv = getattr(loaded.visual, "uv", None)   # per vertex: trimesh splits the vertices at UV seams
    corner_uv = (np.asarray(file_uv, np.float32)[f] if file_uv is not None and len(file_uv) == len(v)
                 and np.isfinite(file_uv).all() else None)
    mesh = trimesh.Trimesh(v, f, process=False)
    mesh.face_attributes["source_face"] = np.arange(len(f))   # follows the faces dropped below
    n0, f0 = len(mesh.vertices), len(mesh.faces)
    mesh.merge_vertices()
    if len(mesh.vertices) < n0:
        notes.append(f"merged {n0 - len(mesh.vertices)} duplicate vertices")
    ok = mesh.nondegenerate_faces() if hasattr(mesh, "nondegenerate_faces") else mesh.remove_degenerate_faces()
    if ok is not None and not np.all(ok):
        mesh.update_faces(ok)
    uniq = mesh.unique_faces()
    if len(uniq) < len(mesh.faces):
        mesh.update_faces(uniq)
    if len(mesh.faces) < f0:
        notes.append(f"dropped {f0 - len(mesh.faces)} degenerate or duplicate faces")
    n1 = len(mesh.vertices)
    mesh.remove_unreferenced_vertices()
    if len(mesh.vertices) < n1:
        notes.append(f"removed {n1 - len(mesh.vertices)} unused vertices")
    if len(mesh.faces) == 0:
        raise InputError(p, "no non-degenerate triangle left")
    e = np.sort(mesh.edges, axis=1)
    _, cnt = np.unique(e, axis=0, return_counts=True)
    if np.any(cnt > 2):
        raise InputError(p, f"non-manifold: {int(np.sum(cnt > 2))} edges shared by more than two faces")
    if notes:
        warnings.warn(f"{p}: " + "; ".join(notes), stacklevel=2)
    x = np.asarray(mesh.vertices, dtype=np.float64) * scale
    x = x @ m4[:3, :3].T + m4[:3, 3]
    uv = uv_faces = None
    if corner_uv is not None:   # the kept faces' corners, the same UV stored once
        kept = corner_uv[np.asarray(mesh.face_attributes["source_face"])].reshape(-1, 2)
        uv, inverse = np.unique(kept, axis=0, return_inverse=True)
        uv, uv_faces = uv.astype(np.float32), inverse.reshape(-1, 3).astype(np.int32)
    return GarmentMesh(np.ascontiguousarray(x), np.ascontiguousarray(mesh.faces, dtype=np.int32), uv, uv_faces)
