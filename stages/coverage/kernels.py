"""Numba kernels of the collider fit audit: which collider holds a point (how far a point is from the
skin: stages/geometry/skin_distance.py).

- `inside_colliders`: per point and collider, inside or not, by the collider's own geometry (hull
  face planes, sphere distance) in its bone-local frame: independent of the maps' queries.
- `inside_any_cells` / `inside_counts_cells`: the same test, per point inside any collider (one
  excluded) / per collider how many points are inside, over only the colliders whose bounding
  ball meets the point's cell of a uniform grid (`collider_cells`): CesiumMan's 1,013 colliders
  against 200 k surface samples a frame made the full matrix the audit's largest cost.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)
from stages.jit import serial_and_parallel
from stages.affine import apply_affine

NUMBA_CACHE_DEPENDS = ("stages.affine",)

KIND_HULL = 0
KIND_SPHERE = 1
CELL_PAD = 1e-9   # m: collider_cells lists a ball in the cells of its box widened by this (rounding of the ball test)


@njit(cache=True, forceinline=True)
def _inside_one(c, px, py, pz, to_local, kind, wcenter, bradius, plane_start, planes, sph_center, sph_radius):
    """Point p (relative frame) inside collider c: inside_colliders' test of one pair."""
    dx = px - wcenter[c, 0]
    dy = py - wcenter[c, 1]
    dz = pz - wcenter[c, 2]
    if dx * dx + dy * dy + dz * dz > bradius[c] * bradius[c]:
        return False
    qx, qy, qz = apply_affine(to_local[c], px, py, pz)
    if kind[c] == KIND_SPHERE:
        ex = qx - sph_center[c, 0]
        ey = qy - sph_center[c, 1]
        ez = qz - sph_center[c, 2]
        return ex * ex + ey * ey + ez * ez <= sph_radius[c] * sph_radius[c]
    for f in range(plane_start[c], plane_start[c + 1]):
        if planes[f, 0] * qx + planes[f, 1] * qy + planes[f, 2] * qz > planes[f, 3]:
            return False
    return True


@serial_and_parallel(cache=True)
def inside_colliders(points, to_local, kind, bcenter, wcenter, bradius, plane_start, planes, sph_center, sph_radius,
                     out):
    """out[i, c] = 1 if points[i] (relative frame) is inside collider c, else 0 (boundary = inside).

    to_local (C, 4, 4): relative frame -> the collider's bone-local frame at this pose.
    kind (C,): KIND_HULL (faces plane_start[c]..plane_start[c+1] of planes (F, 4), bone-local unit
    outward normal and offset, inside iff n.q <= d) or KIND_SPHERE (sph_center[c], sph_radius[c]).
    bcenter (C, 3), bradius (C,): a bone-local ball holding the collider; wcenter (C, 3): its centre
    posed (relative frame), so most pairs are rejected before the point is transformed.
    """
    nc = kind.size
    for i in prange(points.shape[0]):
        for c in range(nc):
            out[i, c] = 1 if _inside_one(c, points[i, 0], points[i, 1], points[i, 2], to_local, kind, wcenter, bradius,
                                         plane_start, planes, sph_center, sph_radius) else 0


@njit(cache=True)
def collider_cells(wcenter, bradius, lo, cell, dims):
    """A uniform grid over the colliders' posed bounding balls (centres wcenter (C, 3), radii (C,)):
    cells of edge `cell` from `lo` (3,), dims (3,) of them; each collider is listed in every cell
    its ball's box (widened by CELL_PAD) meets. Returns (start (X*Y*Z + 1,) int64, items (K,) int32):
    the colliders of cell (i, j, k) are items[start[n]:start[n + 1]], n = (i * Y + j) * Z + k."""
    nc = bradius.size
    ncell = dims[0] * dims[1] * dims[2]
    rng = np.empty((nc, 6), np.int64)
    count = np.zeros(ncell + 1, np.int64)
    for c in range(nc):
        for a in range(3):
            r = bradius[c] + CELL_PAD
            rng[c, a] = min(max(int(math.floor((wcenter[c, a] - r - lo[a]) / cell)), 0), dims[a] - 1)
            rng[c, 3 + a] = min(max(int(math.floor((wcenter[c, a] + r - lo[a]) / cell)), 0), dims[a] - 1)
        for i in range(rng[c, 0], rng[c, 3] + 1):
            for j in range(rng[c, 1], rng[c, 4] + 1):
                for k in range(rng[c, 2], rng[c, 5] + 1):
                    count[(i * dims[1] + j) * dims[2] + k + 1] += 1
    for n in range(ncell):
        count[n + 1] += count[n]
    items = np.empty(count[ncell], np.int32)
    fill = count[:-1].copy()
    for c in range(nc):     # in collider order within each cell
        for i in range(rng[c, 0], rng[c, 3] + 1):
            for j in range(rng[c, 1], rng[c, 4] + 1):
                for k in range(rng[c, 2], rng[c, 5] + 1):
                    n = (i * dims[1] + j) * dims[2] + k
                    items[fill[n]] = c
                    fill[n] += 1
    return count, items



@njit(cache=True, forceinline=True)
def _cell_of(px, py, pz, lo, cell, dims):
    """The grid cell index of a point, -1 outside the grid (then outside every collider's ball) or
    not finite (compared before any integer conversion)."""
    fi = (px - lo[0]) / cell
    fj = (py - lo[1]) / cell
    fk = (pz - lo[2]) / cell
    if not (fi >= 0.0 and fj >= 0.0 and fk >= 0.0 and fi < dims[0] and fj < dims[1] and fk < dims[2]):
        return -1
    return (int(fi) * dims[1] + int(fj)) * dims[2] + int(fk)


@serial_and_parallel(cache=True)
def inside_any_cells(points, exclude, to_local, kind, wcenter, bradius, plane_start, planes, sph_center, sph_radius,
                     lo, cell, dims, start, items, out):
    """out[i] = 1 if points[i] is inside some collider other than exclude[i] (-1: none excluded),
    else 0: inside_colliders' test over the colliders listed in the point's cell (collider_cells)."""
    for i in prange(points.shape[0]):
        px = points[i, 0]
        py = points[i, 1]
        pz = points[i, 2]
        n = _cell_of(px, py, pz, lo, cell, dims)
        hit = 0
        if n >= 0:
            for s in range(start[n], start[n + 1]):
                c = items[s]
                if c != exclude[i] and _inside_one(c, px, py, pz, to_local, kind, wcenter, bradius, plane_start,
                                                   planes, sph_center, sph_radius):
                    hit = 1
                    break
        out[i] = hit


@njit(cache=True)
def inside_counts_cells(points, to_local, kind, wcenter, bradius, plane_start, planes, sph_center, sph_radius,
                        lo, cell, dims, start, items, counts):
    """counts[c] += the number of points inside collider c (the column sums of inside_colliders'
    matrix), over the colliders listed in each point's cell."""
    for i in range(points.shape[0]):
        px = points[i, 0]
        py = points[i, 1]
        pz = points[i, 2]
        n = _cell_of(px, py, pz, lo, cell, dims)
        if n < 0:
            continue
        for s in range(start[n], start[n + 1]):
            c = items[s]
            if _inside_one(c, px, py, pz, to_local, kind, wcenter, bradius, plane_start, planes, sph_center,
                           sph_radius):
                counts[c] += 1
