"""A garment worn over others: its points moved out beyond the garments under it, along rays from
the body's axis (make_garment: a waistband hugged over a tucked-in shirt, the whole garment outside
what it is worn over, stages.garments.separation)."""
from __future__ import annotations

import numpy as np


def farthest_hits(origins: np.ndarray, points: np.ndarray, positions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(N,) distance from each origin, along the ray through its point, to the ray's farthest hit on
    the triangle mesh (Moller-Trumbore), -inf where it misses."""
    tri = np.asarray(positions, np.float64)[np.asarray(triangles)]
    a, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    out = np.full(points.shape[0], -np.inf)
    for k in range(points.shape[0]):
        d = points[k] - origins[k]
        d = d / max(float(np.linalg.norm(d)), 1e-12)
        pv = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, pv)
        ok = np.abs(det) > 1e-15
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        tv = origins[k] - a
        u = np.einsum("ij,ij->i", tv, pv) * inv
        qv = np.cross(tv, e1)
        v = (qv @ d) * inv
        t = np.einsum("ij,ij->i", e2, qv) * inv
        hit = ok & (u >= 0.0) & (v >= 0.0) & (u + v <= 1.0) & (t > 0.0)
        if hit.any():
            out[k] = t[hit].max()
    return out


def push_over(points: np.ndarray, origins: np.ndarray, under, gap: float) -> np.ndarray:
    """(N, 3) points moved out along the rays from their origins (a band's hug targets on the body's
    axis) to `gap` beyond the farthest hit on any garment of `under` (Garments), where they are
    closer to the origin than that; the others as they are."""
    p = np.asarray(points, np.float64).copy()
    o = np.asarray(origins, np.float64)
    reach = np.full(p.shape[0], -np.inf)
    for g in under:
        reach = np.maximum(reach, farthest_hits(o, p, g.positions, g.triangles))
    d = p - o
    r = np.linalg.norm(d, axis=1)
    move = np.isfinite(reach) & (r < reach + gap)
    p[move] = o[move] + d[move] * ((reach[move] + gap) / np.maximum(r[move], 1e-12))[:, None]
    return p
