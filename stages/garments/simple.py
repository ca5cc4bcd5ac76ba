"""Simple garment meshes: a rectangular cloth and a tube / cone skirt.

Both return (vertices (N, 3) float64 metres, triangles (T, 3) int32) in the relative frame at
frame 0 (Y up); pass them to `stages.garments.types.build_garment` with the attachments.
"""
from __future__ import annotations

import numpy as np

from stages.errors import InputError


def _grid_triangles(nu: int, nv: int, wrap_u: bool) -> np.ndarray:
    """Triangles of an nu x nv vertex grid (vertex (i, j) = i * nv + j), diagonals alternating so
    the cloth has no preferred shear direction."""
    cols = nu if wrap_u else nu - 1
    i, j = np.meshgrid(np.arange(cols), np.arange(nv - 1), indexing="ij")
    i, j = i.ravel(), j.ravel()
    i1 = (i + 1) % nu
    a, b, c, d = i * nv + j, i1 * nv + j, i1 * nv + j + 1, i * nv + j + 1
    flip = (i + j) % 2 == 1
    t1 = np.where(flip[:, None], np.stack([a, b, d], 1), np.stack([a, b, c], 1))
    t2 = np.where(flip[:, None], np.stack([b, c, d], 1), np.stack([a, c, d], 1))
    return np.concatenate([t1, t2]).astype(np.int32)


def _rotation_y_to(normal) -> np.ndarray:
    """Rotation matrix taking +Y to the unit vector `normal` (shortest arc)."""
    n = np.asarray(normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    y = np.array([0.0, 1.0, 0.0])
    v = np.cross(y, n)
    c = float(y @ n)
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + k + k @ k / (1.0 + c)


def rectangle_cloth(width: float, height: float, nx: int, ny: int, center=(0.0, 0.0, 0.0),
                    normal=(0.0, 1.0, 0.0), rotation=None):
    """A flat width x height rectangle of nx x ny vertices.

    Unrotated it lies in the XZ plane (normal +Y, width along X, height along Z) centred on
    `center`; `normal` turns +Y to that direction, or `rotation` (3, 3) replaces it.
    Vertex (i, j) (i along width, j along height) has index i * ny + j.
    """
    if not (width > 0 and height > 0) or nx < 2 or ny < 2:
        raise InputError("rectangle_cloth", f"need width, height > 0 and nx, ny >= 2, got {width}, {height}, {nx}, {ny}")
    u = np.linspace(-width / 2, width / 2, nx)
    v = np.linspace(-height / 2, height / 2, ny)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    p = np.stack([uu.ravel(), np.zeros(nx * ny), vv.ravel()], axis=1)
    r = np.asarray(rotation, dtype=np.float64) if rotation is not None else _rotation_y_to(normal)
    # (a, b, c) with b = +x and c = +z make the triangle normal (c - a) x ... : orient to +Y
    tri = _grid_triangles(nx, ny, wrap_u=False)[:, ::-1].copy()
    return p @ r.T + np.asarray(center, dtype=np.float64), np.ascontiguousarray(tri)


def tube_skirt(radius_top: float, radius_bottom: float, length: float, n_around: int, n_down: int,
               center=(0.0, 1.0, 0.0)):
    """An open cone / tube around the vertical axis through `center`.

    The top ring (radius_top) is at center's height; the bottom ring (radius_bottom) `length` lower.
    n_around vertices per ring, n_down rings; vertex (ring k, angle i) has index i * n_down + k, so
    the top loop is indices i * n_down. Triangle normals point outwards.
    """
    if not (radius_top > 0 and radius_bottom > 0 and length > 0) or n_around < 3 or n_down < 2:
        raise InputError("tube_skirt", "need positive radii and length, n_around >= 3, n_down >= 2")
    theta = 2 * np.pi * np.arange(n_around) / n_around
    t = np.linspace(0.0, 1.0, n_down)
    th, tt = np.meshgrid(theta, t, indexing="ij")
    r = radius_top + (radius_bottom - radius_top) * tt
    p = np.stack([r * np.cos(th), -length * tt, -r * np.sin(th)], axis=-1).reshape(-1, 3)
    tri = _grid_triangles(n_around, n_down, wrap_u=True)[:, ::-1].copy()
    return p + np.asarray(center, dtype=np.float64), np.ascontiguousarray(tri)
