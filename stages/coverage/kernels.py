"""Numba kernels of the collider fit audit: which collider holds a point, how far a point is from
the skin.

- `inside_colliders`: per point and collider, inside or not, by the collider's own geometry (hull
  face planes, sphere distance) in its bone-local frame: independent of the maps' queries.
- `inside_any_cells` / `inside_counts_cells`: the same test, per point inside any collider (one
  excluded) / per collider how many points are inside, over only the colliders whose bounding
  ball meets the point's cell of a uniform grid (`collider_cells`): CesiumMan's 1,013 colliders
  against 200 k surface samples a frame made the full matrix the audit's largest cost.
- `distance_to_mesh_tree`: exact distance from points to a triangle mesh, branch and bound over the
  winding-number tree (stages/geometry/winding.py: a ball per node holds the node's triangles, so
  max(0, |p - c| - r) is a lower bound of any of its triangles' distance).
- `distance_to_mesh_brute`: the same distance over every triangle (the reference of the tree).
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
def point_triangle_distance2(px, py, pz, vertices, a, b, c):
    """Squared distance from p to triangle (v[a], v[b], v[c]): closest point by Voronoi regions
    (Ericson, Real-Time Collision Detection, 5.1.5)."""
    ax, ay, az = vertices[a, 0], vertices[a, 1], vertices[a, 2]
    abx, aby, abz = vertices[b, 0] - ax, vertices[b, 1] - ay, vertices[b, 2] - az
    acx, acy, acz = vertices[c, 0] - ax, vertices[c, 1] - ay, vertices[c, 2] - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return apx * apx + apy * apy + apz * apz
    bpx, bpy, bpz = px - vertices[b, 0], py - vertices[b, 1], pz - vertices[b, 2]
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return bpx * bpx + bpy * bpy + bpz * bpz
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        qx, qy, qz = apx - v * abx, apy - v * aby, apz - v * abz
        return qx * qx + qy * qy + qz * qz
    cpx, cpy, cpz = px - vertices[c, 0], py - vertices[c, 1], pz - vertices[c, 2]
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return cpx * cpx + cpy * cpy + cpz * cpz
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        qx, qy, qz = apx - w * acx, apy - w * acy, apz - w * acz
        return qx * qx + qy * qy + qz * qz
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        qx = bpx - w * (vertices[c, 0] - vertices[b, 0])
        qy = bpy - w * (vertices[c, 1] - vertices[b, 1])
        qz = bpz - w * (vertices[c, 2] - vertices[b, 2])
        return qx * qx + qy * qy + qz * qz
    den = 1.0 / (va + vb + vc)
    v = vb * den
    w = vc * den
    qx = apx - abx * v - acx * w
    qy = apy - aby * v - acy * w
    qz = apz - abz * v - acz * w
    return qx * qx + qy * qy + qz * qz


@serial_and_parallel(cache=True)
def distance_to_mesh_brute(points, vertices, triangles, out):
    """out[i] = distance from points[i] to the nearest triangle, every triangle tried. O(N T)."""
    for i in prange(points.shape[0]):
        best = np.inf
        for t in range(triangles.shape[0]):
            d2 = point_triangle_distance2(points[i, 0], points[i, 1], points[i, 2], vertices,
                                          triangles[t, 0], triangles[t, 1], triangles[t, 2])
            best = min(best, d2)
        out[i] = math.sqrt(best)


@serial_and_parallel(cache=True)
def distance_to_mesh_tree(points, vertices, triangles, order, node_start, node_end, children, data, out):
    """out[i] = distance from points[i] to the nearest triangle (exact), over the refitted
    winding-number tree: nodes whose ball is farther than the best so far are skipped, the nearer
    child is opened first."""
    for i in prange(points.shape[0]):
        px = points[i, 0]
        py = points[i, 1]
        pz = points[i, 2]
        stack = np.empty(128, np.int64)
        stack[0] = 0
        top = 1
        best = np.inf
        while top > 0:
            top -= 1
            n = stack[top]
            dx = data[n, 0] - px
            dy = data[n, 1] - py
            dz = data[n, 2] - pz
            low = math.sqrt(dx * dx + dy * dy + dz * dz) - data[n, 6]
            if low > 0.0 and low * low >= best:
                continue
            if children[n, 0] < 0:
                for k in range(node_start[n], node_end[n]):
                    t = order[k]
                    d2 = point_triangle_distance2(px, py, pz, vertices, triangles[t, 0], triangles[t, 1],
                                                  triangles[t, 2])
                    best = min(best, d2)
            else:
                l = children[n, 0]
                r = children[n, 1]
                dl = (data[l, 0] - px) ** 2 + (data[l, 1] - py) ** 2 + (data[l, 2] - pz) ** 2
                dr = (data[r, 0] - px) ** 2 + (data[r, 1] - py) ** 2 + (data[r, 2] - pz) ** 2
                if dl < dr:  # push the far child first so the near one pops first
                    l, r = r, l
                stack[top] = l
                stack[top + 1] = r
                top += 2
        out[i] = math.sqrt(best)


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
