"""Kernels of the body audit (stages.sim.body_audit): edges of one mesh crossing triangles of another.

The crossing test is the cloth audit's (stages.sim.audit_kernels.segment_crosses_triangle: exact
orientation signs, a float64 filter with an expansion fallback; touching, coplanar and
through-an-edge contacts do not count) and so is the broad phase (build_triangle_grid, a uniform
grid of the triangles' boxes). What differs: the edges and the triangles belong to two surfaces
(body and cloth, disjoint rows of one position array), and per edge the kernel keeps the first
triangle it crosses, for the crossing's location and the joint nearest it.
"""
from __future__ import annotations

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)

# the crossing test and the grid are inlined from there: a change to them recompiles these kernels
NUMBA_CACHE_DEPENDS = ("stages.sim.audit_kernels",)

from numba import prange  # noqa: E402

from stages.jit import serial_and_parallel  # noqa: E402
from stages.sim.audit_kernels import (CROSS_NO, CROSS_UNKNOWN, CROSS_YES, _cell_range3,  # noqa: E402
                                      segment_crosses_triangle)


@serial_and_parallel(cache=True)
def first_crossings(x, edges, tris, lo, dims, cell, cell_start, cell_tris, status, hit):
    """Per edge e (rows of x): status[e] = CROSS_YES and hit[e] = the first triangle it crosses (in
    the grid's scan order, so the same every run), CROSS_UNKNOWN (hit -1) when no crossing is
    certain but a pair's sign could not be decided (decide those exactly), else CROSS_NO (hit -1).
    The grid (lo, dims, cell, cell_start, cell_tris) is build_triangle_grid's over `tris`; each
    (edge, triangle) pair is tested once, in the first cell of the overlap of their cell ranges;
    a triangle sharing a vertex with the edge is skipped."""
    for e in prange(edges.shape[0]):
        p = edges[e, 0]
        q = edges[e, 1]
        state = CROSS_NO
        first = -1
        e0, e1, e2, g0, g1, g2 = _cell_range3(x, p, q, q, lo, cell, dims)
        for u in range(e0, g0 + 1):
            for v in range(e1, g1 + 1):
                for w in range(e2, g2 + 1):
                    if first >= 0:
                        break
                    c = (u * dims[1] + v) * dims[2] + w
                    for k in range(cell_start[c], cell_start[c + 1]):
                        t = cell_tris[k]
                        a = tris[t, 0]
                        b = tris[t, 1]
                        d = tris[t, 2]
                        if p == a or p == b or p == d or q == a or q == b or q == d:
                            continue
                        t0, t1, t2, _, _, _ = _cell_range3(x, a, b, d, lo, cell, dims)
                        if u != max(e0, t0) or v != max(e1, t1) or w != max(e2, t2):
                            continue     # this pair is tested in another cell
                        r = segment_crosses_triangle(x, p, q, a, b, d)
                        if r == CROSS_YES:
                            state = CROSS_YES
                            first = t
                            break
                        if r == CROSS_UNKNOWN:
                            state = CROSS_UNKNOWN
        status[e] = state
        hit[e] = first
