"""Per-step collider frames and the broad phase of the body collision (a uniform grid over the
colliders' world boxes).

Per step each collider gets a world bounding sphere and one 3x4 matrix world -> *query frame*
(hulls: the OBB-local frame of the maps; spheres: bone-local with the centre at the origin);
a particle visits only the colliders listed in its cell of the grid (build_grid).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)
from stages.affine import apply_affine
from stages.maps.kernels import METHOD_NEAREST_PLANE

NUMBA_CACHE_DEPENDS = ("stages.maps.kernels", "stages.maps.types", "stages.affine")

KIND_HULL = 0
KIND_SPHERE = 1
GRID_CELLS = 4096    # broad phase: at most this many grid cells over the colliders' world boxes
_EYE3 = np.eye(3)    # the query frame of a sphere is not rotated


# -- small affine helpers -------------------------------------------------------------------------
@njit(cache=True, _nrt=False, forceinline=True)
def apply12(a, c, x, y, z):
    """Row c of a (C, 12) array of row-major 3x4 affine matrices applied to (x, y, z)."""
    return (a[c, 0] * x + a[c, 1] * y + a[c, 2] * z + a[c, 3],
            a[c, 4] * x + a[c, 5] * y + a[c, 6] * z + a[c, 7],
            a[c, 8] * x + a[c, 9] * y + a[c, 10] * z + a[c, 11])


@njit(cache=True, _nrt=False, forceinline=True)
def rotate12(a, c, x, y, z):
    return (a[c, 0] * x + a[c, 1] * y + a[c, 2] * z,
            a[c, 4] * x + a[c, 5] * y + a[c, 6] * z,
            a[c, 8] * x + a[c, 9] * y + a[c, 10] * z)



# -- collisions -----------------------------------------------------------------------------------
@njit(cache=True, _nrt=False)
def collider_frames(fwd, inv, inv0, m, col_joint, col_kind, col_index, col_bcenter, col_bradius, sph_center,
                    tq, tq0, fq, cw):
    """Per collider c, for one step: tq[c] / tq0[c] (12,) the 3x4 map world (end / start of the step)
    -> query frame, fq[c] query frame -> world (end), cw[c] = world bounding sphere (centre, r, r^2).

    Query frame: hulls, the OBB-local frame of the maps (q = axes (inv p - center)); spheres, bone-local
    shifted so the sphere's centre is the origin. The bounding radius grows with the pose's largest
    axis scale (scaled rigs)."""
    for c in range(col_joint.size):
        j = col_joint[c]
        if col_kind[c] == KIND_HULL:
            h = col_index[c]
            r = m.axes[h]
            ctr = m.center[h]
        else:
            r = _EYE3
            ctr = sph_center[col_index[c]]
        for dst, src in ((tq, inv[j]), (tq0, inv0[j])):
            for a in range(3):
                for b in range(3):
                    dst[c, 4 * a + b] = r[a, 0] * src[0, b] + r[a, 1] * src[1, b] + r[a, 2] * src[2, b]
                dst[c, 4 * a + 3] = (r[a, 0] * (src[0, 3] - ctr[0]) + r[a, 1] * (src[1, 3] - ctr[1])
                                     + r[a, 2] * (src[2, 3] - ctr[2]))
        f = fwd[j]
        for a in range(3):
            for b in range(3):
                fq[c, 4 * a + b] = f[a, 0] * r[b, 0] + f[a, 1] * r[b, 1] + f[a, 2] * r[b, 2]
            fq[c, 4 * a + 3] = f[a, 0] * ctr[0] + f[a, 1] * ctr[1] + f[a, 2] * ctr[2] + f[a, 3]
        px, py, pz = apply_affine(f, col_bcenter[c, 0], col_bcenter[c, 1], col_bcenter[c, 2])
        sc = 0.0
        for b in range(3):
            sc = max(sc, f[0, b] * f[0, b] + f[1, b] * f[1, b] + f[2, b] * f[2, b])
        rad = col_bradius[c] * math.sqrt(sc) * (1.0 + 1e-9)
        cw[c, 0] = px
        cw[c, 1] = py
        cw[c, 2] = pz
        cw[c, 3] = rad
        cw[c, 4] = rad * rad


@njit(cache=True, _nrt=False)
def swept_spheres(fwd, k0, k1, col_joint, col_bcenter, col_bradius, cws):
    """cws[c] = (centre, r, r^2): a world sphere holding collider c's world bounding sphere (as
    collider_frames computes it) at the end of each step k0..k1-1 (poses fwd[k]): the broad phase
    of a whole frame (build_grid over cws without the query-frame boxes, METHOD_NEAREST_PLANE),
    whose cell lists are then supersets of every step's. Centre: the middle of the box of the
    step centres; radius: the largest distance to a step centre plus that step's radius."""
    for c in range(col_joint.size):
        j = col_joint[c]
        lo0 = lo1 = lo2 = np.inf
        hi0 = hi1 = hi2 = -np.inf
        for k in range(k0, k1):
            px, py, pz = apply_affine(fwd[k, j], col_bcenter[c, 0], col_bcenter[c, 1], col_bcenter[c, 2])
            lo0 = min(lo0, px)
            lo1 = min(lo1, py)
            lo2 = min(lo2, pz)
            hi0 = max(hi0, px)
            hi1 = max(hi1, py)
            hi2 = max(hi2, pz)
        m0 = 0.5 * (lo0 + hi0)
        m1 = 0.5 * (lo1 + hi1)
        m2 = 0.5 * (lo2 + hi2)
        rad = 0.0
        for k in range(k0, k1):
            f = fwd[k, j]
            px, py, pz = apply_affine(f, col_bcenter[c, 0], col_bcenter[c, 1], col_bcenter[c, 2])
            sc = 0.0
            for b in range(3):
                sc = max(sc, f[0, b] * f[0, b] + f[1, b] * f[1, b] + f[2, b] * f[2, b])
            r = col_bradius[c] * math.sqrt(sc) * (1.0 + 1e-9)
            rad = max(rad, math.sqrt((px - m0) ** 2 + (py - m1) ** 2 + (pz - m2) ** 2) + r)
        rad *= 1.0 + 1e-9
        cws[c, 0] = m0
        cws[c, 1] = m1
        cws[c, 2] = m2
        cws[c, 3] = rad
        cws[c, 4] = rad * rad


@njit(cache=True, _nrt=False, forceinline=True)
def _world_box(c, m, col_kind, col_index, sph_radius, use_obb, fq, cw):
    """(lo0, lo1, lo2, hi0, hi1, hi2): a world axis-aligned box holding every point collider c can
    report inside: its world sphere's box, cut to the box of its query-frame box (hull: the OBB
    widened by the maps' convexity tolerance; sphere: the cube around it) when use_obb; widened by
    1e-9 of its size and position against round-off between fq and tq."""
    r = cw[c, 3]
    e = 1e-9 * (r + abs(cw[c, 0]) + abs(cw[c, 1]) + abs(cw[c, 2]))
    lo0 = cw[c, 0] - r
    lo1 = cw[c, 1] - r
    lo2 = cw[c, 2] - r
    hi0 = cw[c, 0] + r
    hi1 = cw[c, 1] + r
    hi2 = cw[c, 2] + r
    if use_obb:
        b0, b1, b2 = _query_box(c, m, col_kind, col_index, sph_radius)
        x0 = abs(fq[c, 0]) * b0 + abs(fq[c, 1]) * b1 + abs(fq[c, 2]) * b2
        x1 = abs(fq[c, 4]) * b0 + abs(fq[c, 5]) * b1 + abs(fq[c, 6]) * b2
        x2 = abs(fq[c, 8]) * b0 + abs(fq[c, 9]) * b1 + abs(fq[c, 10]) * b2
        lo0 = max(lo0, fq[c, 3] - x0)
        lo1 = max(lo1, fq[c, 7] - x1)
        lo2 = max(lo2, fq[c, 11] - x2)
        hi0 = min(hi0, fq[c, 3] + x0)
        hi1 = min(hi1, fq[c, 7] + x1)
        hi2 = min(hi2, fq[c, 11] + x2)
    return lo0 - e, lo1 - e, lo2 - e, hi0 + e, hi1 + e, hi2 + e


@njit(cache=True, _nrt=False, forceinline=True)
def _query_box(c, m, col_kind, col_index, sph_radius):
    """Half extents of a query-frame box around collider c: hull, its OBB widened by the maps'
    convexity tolerance (CONVEX_TOL = 1e-6 of the longest half extent: a face plane may pass that
    far outside a vertex); sphere, the cube around it."""
    idx = col_index[c]
    if col_kind[c] == KIND_SPHERE:
        r = sph_radius[idx] * (1.0 + 1e-9)
        return r, r, r
    e = 1e-6 * m.half[idx, 0]
    return m.half[idx, 0] + e, m.half[idx, 1] + e, m.half[idx, 2] + e


@njit(cache=True, _nrt=False, forceinline=True)
def _k_range(q, s, inv_s, lim, ka, kb):
    """[ka, kb] narrowed to the reals k with |q + k s| <= lim (empty: ka > kb); inv_s = 1 / s."""
    if s > 0.0:
        return max(ka, (-lim - q) * inv_s), min(kb, (lim - q) * inv_s)
    if s < 0.0:
        return max(ka, (lim - q) * inv_s), min(kb, (-lim - q) * inv_s)
    if abs(q) > lim:
        return ka, ka - 1.0
    return ka, kb


@njit(cache=True, _nrt=False)
def _collider_runs(c, m, col_kind, col_index, sph_radius, use_obb, tq, fq, cw, grid_start, grid_runs, nr, grid_box,
                   grid_dims):
    """Append to grid_runs[nr:] the runs (c, first cell, cells) of consecutive cells (along axis 2)
    that collider c may reach, counting each cell into grid_start[cell]; returns the new run count.
    Per row (i, j) of the collider's world box, the k whose cell (widened against round-off) meets
    its world sphere and, when use_obb, its query-frame box: on each query axis the cell, a
    parallelepiped there, has half-width hc sum|tq row| around its centre, which moves linearly in k."""
    g0 = grid_box[0]
    g1 = grid_box[1]
    g2 = grid_box[2]
    inv = grid_box[3]
    cs = 1.0 / inv
    n1 = grid_dims[1]
    n2 = grid_dims[2]
    hc = 0.5 * cs + 1e-9 * (cs + abs(g0) + abs(g1) + abs(g2))   # cells widened against round-off
    lo0, lo1, lo2, hi0, hi1, hi2 = _world_box(c, m, col_kind, col_index, sph_radius, use_obb, fq, cw)
    b0, b1, b2 = _query_box(c, m, col_kind, col_index, sph_radius)
    l0 = b0 + hc * (abs(tq[c, 0]) + abs(tq[c, 1]) + abs(tq[c, 2]))
    l1 = b1 + hc * (abs(tq[c, 4]) + abs(tq[c, 5]) + abs(tq[c, 6]))
    l2 = b2 + hc * (abs(tq[c, 8]) + abs(tq[c, 9]) + abs(tq[c, 10]))
    s0 = cs * tq[c, 2]
    s1 = cs * tq[c, 6]
    s2 = cs * tq[c, 10]
    i0 = 1.0 / s0 if s0 != 0.0 else 0.0
    i1 = 1.0 / s1 if s1 != 0.0 else 0.0
    i2 = 1.0 / s2 if s2 != 0.0 else 0.0
    r2 = cw[c, 4]
    z0 = g2 + 0.5 * cs          # the centre of cell k = 0 along axis 2
    k0 = float(int((lo2 - g2) * inv))
    k1 = float(int((hi2 - g2) * inv))
    for i in range(int((lo0 - g0) * inv), int((hi0 - g0) * inv) + 1):
        x = g0 + (i + 0.5) * cs
        d0 = max(abs(x - cw[c, 0]) - hc, 0.0)
        for j in range(int((lo1 - g1) * inv), int((hi1 - g1) * inv) + 1):
            y = g1 + (j + 0.5) * cs
            d1 = max(abs(y - cw[c, 1]) - hc, 0.0)
            rem = r2 - d0 * d0 - d1 * d1
            if rem <= 0.0:
                continue
            ka, kb = _k_range((z0 - cw[c, 2]) * inv, 1.0, 1.0, (hc + math.sqrt(rem)) * inv, k0, k1)
            if use_obb:
                q0, q1, q2 = apply12(tq, c, x, y, z0)
                ka, kb = _k_range(q0, s0, i0, l0, ka, kb)
                ka, kb = _k_range(q1, s1, i1, l1, ka, kb)
                ka, kb = _k_range(q2, s2, i2, l2, ka, kb)
            ka = math.ceil(ka)
            kb = math.floor(kb)
            if ka > kb:
                continue
            first = (i * n1 + j) * n2 + int(ka)
            count = int(kb) - int(ka) + 1
            grid_runs[nr, 0] = c
            grid_runs[nr, 1] = first
            grid_runs[nr, 2] = count
            nr += 1
            for cell in range(first, first + count):
                grid_start[cell] += 1
    return nr


@njit(cache=True, _nrt=False)
def build_grid(m, method, col_kind, col_index, sph_radius, tq, fq, cw, grid_start, grid_items, grid_runs, grid_box,
               grid_dims):
    """Broad phase: a uniform grid over the colliders' world boxes (_world_box), rebuilt per step.

    grid_box (4,): the grid's low corner and 1 / cell size; grid_dims (3,): cells per axis, at most
    grid_start.size - 1 cells in all; cell (i, j, k) = (i n1 + j) n2 + k holds the world points p
    with int((p - low) / size) = (i, j, k). grid_start (cells + 1,), grid_items (C cells,): CSR
    list per cell, ascending c, of every collider whose world sphere and query-frame box (not with
    METHOD_NEAREST_PLANE, which does not test the OBB) meet the cell: no other can hold a point of
    it. A point off the grid is outside every collider. Cells of about the smallest collider's
    world radius, larger when that would exceed the cell budget. grid_runs (C cells, 3): scratch.
    """
    nc = cw.shape[0]
    grid_dims[:] = 0
    grid_start[0] = 0
    if nc == 0:
        return
    use_obb = method != METHOD_NEAREST_PLANE
    g0 = g1 = g2 = np.inf
    t0 = t1 = t2 = -np.inf
    rmin = np.inf
    for c in range(nc):
        lo0, lo1, lo2, hi0, hi1, hi2 = _world_box(c, m, col_kind, col_index, sph_radius, use_obb, fq, cw)
        g0 = min(g0, lo0)
        g1 = min(g1, lo1)
        g2 = min(g2, lo2)
        t0 = max(t0, hi0)
        t1 = max(t1, hi1)
        t2 = max(t2, hi2)
        rmin = min(rmin, cw[c, 3])
    cap = grid_start.size - 1
    inv = 1.0 / max(rmin, ((t0 - g0) * (t1 - g1) * (t2 - g2) / cap) ** (1.0 / 3.0))
    while True:
        n0 = int((t0 - g0) * inv) + 1
        n1 = int((t1 - g1) * inv) + 1
        n2 = int((t2 - g2) * inv) + 1
        if n0 * n1 * n2 <= cap:
            break
        inv *= 0.9
    grid_box[0] = g0
    grid_box[1] = g1
    grid_box[2] = g2
    grid_box[3] = inv
    grid_dims[0] = n0
    grid_dims[1] = n1
    grid_dims[2] = n2
    nce = n0 * n1 * n2
    grid_start[:nce + 1] = 0
    nr = np.int64(0)    # not the literal 0: numba would compile _collider_runs for Literal[int](0) too
    for c in range(nc):     # count each cell's colliders into grid_start[cell]
        nr = _collider_runs(c, m, col_kind, col_index, sph_radius, use_obb, tq, fq, cw, grid_start, grid_runs, nr,
                            grid_box, grid_dims)
    for b in range(1, nce):     # grid_start[b]: the end of cell b's list
        grid_start[b] += grid_start[b - 1]
    grid_start[nce] = grid_start[nce - 1]
    for r in range(nr - 1, -1, -1):     # descending c, each list filled from its end: ascending lists,
        c = grid_runs[r, 0]             # and grid_start[b] moves back to the start of cell b's list
        for cell in range(grid_runs[r, 1], grid_runs[r, 1] + grid_runs[r, 2]):
            grid_start[cell] -= 1
            grid_items[grid_start[cell]] = c


@njit(cache=True, _nrt=False, forceinline=True)
def grid_cell(grid_box, grid_dims, px, py, pz):
    """The grid cell of the world point (build_grid), -1 off the grid (non-finite points too)."""
    u0 = (px - grid_box[0]) * grid_box[3]
    u1 = (py - grid_box[1]) * grid_box[3]
    u2 = (pz - grid_box[2]) * grid_box[3]
    if not (0.0 <= u0 < grid_dims[0] and 0.0 <= u1 < grid_dims[1] and 0.0 <= u2 < grid_dims[2]):
        return -1
    return (int(u0) * grid_dims[1] + int(u1)) * grid_dims[2] + int(u2)


def collider_family(owner: np.ndarray, parents=None) -> np.ndarray:
    """(C, 3) int32 per collider: its joint, that joint's parent (-1: none), its depth in the skeleton
    (root 0; deeper: a limb further out). The 'limb' pinch rule lets a collider act over another it
    overlaps only when it is deeper and their joints are not parent and child (body_collide.collide).
    parents None: every collider at depth 0 (no collider outranks another)."""
    out = np.zeros((owner.size, 3), np.int32)
    out[:, 0] = owner
    out[:, 1] = -1
    if parents is not None and owner.size:
        parents = np.asarray(parents, np.int64)
        depth = np.zeros(parents.size, np.int32)
        for j in range(1, parents.size):       # parents[j] < j: topological order
            depth[j] = depth[parents[j]] + 1 if parents[j] >= 0 else 0
        out[:, 1] = parents[owner]
        out[:, 2] = depth[owner]
    return out
