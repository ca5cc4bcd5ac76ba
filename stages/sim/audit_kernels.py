"""Kernels of the cloth audit (stages.sim.audit): cloth edges crossing cloth triangles.

Exact test. An edge pq *crosses* a triangle abc when p and q lie strictly on opposite sides of the
triangle's plane and the line pq passes strictly inside the triangle: orient3d(a, b, c, p) and
orient3d(a, b, c, q) have opposite signs and orient3d(p, q, a, b), orient3d(p, q, b, c),
orient3d(p, q, c, a) one common sign, all five nonzero. Degenerate contacts do not count: an
endpoint on the plane, a coplanar edge, an edge through a triangle's edge or vertex (a touch, not
a crossing; for simulated float32 positions these have measure zero). Edges sharing a vertex with
the triangle are skipped (they meet at the mesh by construction).

Signs are exact: each orient3d is evaluated in float64 with Shewchuk's static error bound
(o3derrboundA, which covers the rounding of the differences too); where the bound cannot certify
the sign (nearly or exactly coplanar points: a flat sheet at rest), the determinant is summed
exactly as a floating-point expansion (Dekker's two-product, Shewchuk's grow-expansion) from the
coordinate differences. Those are exact for float32 positions of similar magnitude; when one is
not (checked), the pair is reported unknown and the caller decides it in rational arithmetic
(stages.sim.audit.crosses_exact).

Broad phase: a uniform grid over the triangles' bounding boxes (cell lists); an edge visits the
cells its box overlaps and tests each pair once, in the first cell of the overlap of both boxes.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from stages.jit import serial_and_parallel

# Shewchuk's o3derrboundA = (7 + 56 eps) eps, eps = 2^-53
O3D_ERRBOUND = (7.0 + 56.0 * 2.0 ** -53) * 2.0 ** -53
GRID_MAX_CELLS = 1 << 21     # at most this many grid cells (the cell size grows to fit)
CROSS_NO = 0
CROSS_YES = 1
CROSS_UNKNOWN = 2


SPLITTER = 134217729.0        # 2^27 + 1: Dekker's split of a float64 into two 26-bit halves


@njit(cache=True, forceinline=True)
def _two_sum(a, b):
    """(s, e): s = fl(a + b) and a + b = s + e exactly."""
    s = a + b
    bv = s - a
    av = s - bv
    return s, (a - av) + (b - bv)


@njit(cache=True, forceinline=True)
def _two_product(a, b):
    """(p, e): p = fl(a b) and a b = p + e exactly (Dekker, no FMA needed)."""
    p = a * b
    c = SPLITTER * a
    ah = c - (c - a)
    al = a - ah
    c = SPLITTER * b
    bh = c - (c - b)
    bl = b - bh
    return p, al * bl - (((p - ah * bh) - al * bh) - ah * bl)


@njit(cache=True, forceinline=True)
def _exact_diff(a, b):
    """(a - b, exact?): the float64 difference and whether it has no rounding error."""
    d = a - b
    s, e = _two_sum(a, -b)
    return d, e == 0.0


@njit(cache=True)
def orient3d_exact(a0, a1, a2, b0, b1, b2, c0, c1, c2, d0, d1, d2):
    """Exact sign of det[a - d, b - d, c - d]: 1, -1, 0, or 2 when a coordinate difference is not
    exact in float64 (never for float32 positions of similar magnitude). The six triple products of
    the determinant, each an exact sum of four doubles, are summed into a nonoverlapping expansion
    whose largest component has the sign of the whole."""
    adx, ok0 = _exact_diff(a0, d0)
    ady, ok1 = _exact_diff(a1, d1)
    adz, ok2 = _exact_diff(a2, d2)
    bdx, ok3 = _exact_diff(b0, d0)
    bdy, ok4 = _exact_diff(b1, d1)
    bdz, ok5 = _exact_diff(b2, d2)
    cdx, ok6 = _exact_diff(c0, d0)
    cdy, ok7 = _exact_diff(c1, d1)
    cdz, ok8 = _exact_diff(c2, d2)
    if not (ok0 and ok1 and ok2 and ok3 and ok4 and ok5 and ok6 and ok7 and ok8):
        return 2
    # det = adx bdy cdz - adx bdz cdy + bdx cdy adz - bdx cdz ady + cdx ady bdz - cdx adz bdy
    us = (adx, -adx, bdx, -bdx, cdx, -cdx)
    vs = (bdy, bdz, cdy, cdz, ady, adz)
    ws = (cdz, cdy, adz, ady, bdz, bdy)
    h = np.zeros(24)
    n = 0
    for k in range(6):
        p, e = _two_product(us[k], vs[k])
        p1, e1 = _two_product(p, ws[k])
        p2, e2 = _two_product(e, ws[k])
        for term in (e2, p2, e1, p1):
            q = term                 # grow-expansion: add term to h[0..n)
            for i in range(n):
                q, h[i] = _two_sum(q, h[i])
            h[n] = q
            n += 1
    for i in range(n - 1, -1, -1):
        if h[i] > 0.0:
            return 1
        if h[i] < 0.0:
            return -1
    return 0


@njit(cache=True, forceinline=True)
def orient3d_sign(a0, a1, a2, b0, b1, b2, c0, c1, c2, d0, d1, d2):
    """Sign of det[a - d, b - d, c - d] (Shewchuk's orient3d): 1, -1, 0 (exactly zero), or 2 when it
    cannot be decided in float64 (see orient3d_exact)."""
    adx = a0 - d0
    bdx = b0 - d0
    cdx = c0 - d0
    ady = a1 - d1
    bdy = b1 - d1
    cdy = c1 - d1
    adz = a2 - d2
    bdz = b2 - d2
    cdz = c2 - d2
    bdxcdy = bdx * cdy
    cdxbdy = cdx * bdy
    cdxady = cdx * ady
    adxcdy = adx * cdy
    adxbdy = adx * bdy
    bdxady = bdx * ady
    det = adz * (bdxcdy - cdxbdy) + bdz * (cdxady - adxcdy) + cdz * (adxbdy - bdxady)
    perm = ((abs(bdxcdy) + abs(cdxbdy)) * abs(adz) + (abs(cdxady) + abs(adxcdy)) * abs(bdz)
            + (abs(adxbdy) + abs(bdxady)) * abs(cdz))
    bound = O3D_ERRBOUND * perm
    if det > bound:
        return 1
    if det < -bound:
        return -1
    return orient3d_exact(a0, a1, a2, b0, b1, b2, c0, c1, c2, d0, d1, d2)


@njit(cache=True)
def segment_crosses_triangle(x, p, q, a, b, c):
    """CROSS_YES / CROSS_NO / CROSS_UNKNOWN for edge (p, q) and triangle (a, b, c), rows of x (see
    the module docstring). A certified NO wins over an unknown sign elsewhere."""
    sp = orient3d_sign(x[a, 0], x[a, 1], x[a, 2], x[b, 0], x[b, 1], x[b, 2], x[c, 0], x[c, 1], x[c, 2],
                       x[p, 0], x[p, 1], x[p, 2])
    if sp == 0:
        return CROSS_NO
    sq = orient3d_sign(x[a, 0], x[a, 1], x[a, 2], x[b, 0], x[b, 1], x[b, 2], x[c, 0], x[c, 1], x[c, 2],
                       x[q, 0], x[q, 1], x[q, 2])
    if sq == 0 or (sq == sp and sp != 2):
        return CROSS_NO
    s1 = orient3d_sign(x[p, 0], x[p, 1], x[p, 2], x[q, 0], x[q, 1], x[q, 2], x[a, 0], x[a, 1], x[a, 2],
                       x[b, 0], x[b, 1], x[b, 2])
    if s1 == 0:
        return CROSS_NO
    s2 = orient3d_sign(x[p, 0], x[p, 1], x[p, 2], x[q, 0], x[q, 1], x[q, 2], x[b, 0], x[b, 1], x[b, 2],
                       x[c, 0], x[c, 1], x[c, 2])
    if s2 == 0 or (s1 != 2 and s2 != 2 and s1 != s2):
        return CROSS_NO
    s3 = orient3d_sign(x[p, 0], x[p, 1], x[p, 2], x[q, 0], x[q, 1], x[q, 2], x[c, 0], x[c, 1], x[c, 2],
                       x[a, 0], x[a, 1], x[a, 2])
    if s3 == 0 or (s3 != 2 and ((s1 != 2 and s1 != s3) or (s2 != 2 and s2 != s3))):
        return CROSS_NO
    if sp == 2 or sq == 2 or s1 == 2 or s2 == 2 or s3 == 2:
        return CROSS_UNKNOWN
    return CROSS_YES


@njit(cache=True)
def build_triangle_grid(x, tris, cell):
    """Uniform grid of the triangles' bounding boxes: (origin (3,), dims (3,) int64, cell_start
    (C + 1,) int64, cell_tris (M,) int32). cell: the cell edge, metres (> 0)."""
    lo = np.empty(3)
    hi = np.empty(3)
    for k in range(3):
        lo[k] = x[:, k].min()
        hi[k] = x[:, k].max()
    dims = np.empty(3, np.int64)
    for k in range(3):
        dims[k] = max(1, int((hi[k] - lo[k]) / cell) + 1)
    n_cells = dims[0] * dims[1] * dims[2]
    count = np.zeros(n_cells + 1, np.int64)
    for pass_ in range(2):
        if pass_ == 1:
            for i in range(n_cells):
                count[i + 1] += count[i]
            cell_tris = np.empty(count[n_cells], np.int32)
            fill = count[:n_cells].copy()
        for t in range(tris.shape[0]):
            i0, i1, i2, j0, j1, j2 = _cell_range3(x, tris[t, 0], tris[t, 1], tris[t, 2], lo, cell, dims)
            for u in range(i0, j0 + 1):
                for v in range(i1, j1 + 1):
                    for w in range(i2, j2 + 1):
                        c = (u * dims[1] + v) * dims[2] + w
                        if pass_ == 0:
                            count[c + 1] += 1
                        else:
                            cell_tris[fill[c]] = t
                            fill[c] += 1
    return lo, dims, count, cell_tris


@njit(cache=True, forceinline=True)
def _cell_of(value, lo, cell, dim):
    return min(dim - 1, max(0, int((value - lo) / cell)))


@njit(cache=True, forceinline=True)
def _cell_range3(x, a, b, c, lo, cell, dims):
    """Cell index ranges (first0, first1, first2, last0, last1, last2) of the box of points a, b, c."""
    f0 = _cell_of(min(x[a, 0], x[b, 0], x[c, 0]), lo[0], cell, dims[0])
    f1 = _cell_of(min(x[a, 1], x[b, 1], x[c, 1]), lo[1], cell, dims[1])
    f2 = _cell_of(min(x[a, 2], x[b, 2], x[c, 2]), lo[2], cell, dims[2])
    l0 = _cell_of(max(x[a, 0], x[b, 0], x[c, 0]), lo[0], cell, dims[0])
    l1 = _cell_of(max(x[a, 1], x[b, 1], x[c, 1]), lo[1], cell, dims[1])
    l2 = _cell_of(max(x[a, 2], x[b, 2], x[c, 2]), lo[2], cell, dims[2])
    return f0, f1, f2, l0, l1, l2


@serial_and_parallel(cache=True)
def edge_crossings(x, edges, edge_group, tris, tri_group, lo, dims, cell, cell_start, cell_tris, out):
    """Per edge e: out[e, 0] / out[e, 1] = CROSS_YES if it crosses a triangle of its own group / of
    another group, CROSS_UNKNOWN if no crossing is certain but a pair's sign is (decide those
    exactly), else CROSS_NO. Triangles sharing a vertex with the edge are skipped; each (edge,
    triangle) pair is tested once (in the first cell of the overlap of their cell ranges)."""
    for e in prange(edges.shape[0]):
        p = edges[e, 0]
        q = edges[e, 1]
        own = CROSS_NO
        other = CROSS_NO
        e0, e1, e2, g0, g1, g2 = _cell_range3(x, p, q, q, lo, cell, dims)
        for u in range(e0, g0 + 1):
            for v in range(e1, g1 + 1):
                for w in range(e2, g2 + 1):
                    c = (u * dims[1] + v) * dims[2] + w
                    for k in range(cell_start[c], cell_start[c + 1]):
                        t = cell_tris[k]
                        same = tri_group[t] == edge_group[e]
                        if (own if same else other) == CROSS_YES:
                            continue
                        a = tris[t, 0]
                        b = tris[t, 1]
                        d = tris[t, 2]
                        if p == a or p == b or p == d or q == a or q == b or q == d:
                            continue
                        t0, t1, t2, _, _, _ = _cell_range3(x, a, b, d, lo, cell, dims)
                        if u != max(e0, t0) or v != max(e1, t1) or w != max(e2, t2):
                            continue     # this pair is tested in another cell
                        r = segment_crosses_triangle(x, p, q, a, b, d)
                        if r == CROSS_NO:
                            continue
                        if same:
                            own = r if r == CROSS_YES or own == CROSS_NO else own
                        else:
                            other = r if r == CROSS_YES or other == CROSS_NO else other
        out[e, 0] = own
        out[e, 1] = other
