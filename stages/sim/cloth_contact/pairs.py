"""Cloth x cloth feature pairs: the exact test of one vertex-face or edge-edge pair with the layer
rule (stages.sim.cloth_contact.ccd does the geometry), the contact buffer, the features two
triangles own (each vertex and edge is owned by one incident triangle, `tri_owns`, so each feature
pair is tested once), and the brute-force reference over all pairs.

Arrays as in stages.sim.cloth_contact.setup.ClothContact; `topo`, `tree`, `work` are its kernel_args tuples.
"""
from __future__ import annotations

import numpy as np
from numba import njit

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)
from stages.affine import triangle_cross
from stages.sim.cloth_contact.ccd import (EE_CROSS, VF_CROSS, ee_apart, ee_clear, test_edge_edge, test_vertex_face,
                                          vf_apart)

NUMBA_CACHE_DEPENDS = ("stages.affine", "stages.sim.cloth_contact.ccd")

# counters (int64, accumulated with +=; the caller zeroes them)
N_CONTACTS = 0     # contacts found over all rounds
N_CORRECTED = 1    # particles moved by a response or the fail-safe (once per call each)
N_UNRESOLVED = 2   # CROSS contacts left after the response rounds (handed to the fail-safe)
N_REVERTED = 3     # particles the fail-safe put back to x_prev
N_LEFT = 4         # CROSS left after the fail-safe: 0 unless pinned particles force them, x_prev
                   # already had crossings, or failsafe_rounds ran out
N_ROUNDS = 5       # response rounds run
N_NODE_PAIRS = 6   # tree node pairs visited
N_TESTS = 7        # exact feature-pair tests
N_OVERFLOW = 8     # contacts dropped because the contact buffer was full
N_BUILDS = 9       # candidate lists built (stages.sim.cloth_contact.kernels.build_candidates)
N_CAND_OVERFLOW = 10  # candidate lists that overflowed their buffers (the tree search ran instead)
N_CYC_BUILD = 11   # CPU cycles in candidate list builds (the tree search that collects the pairs)
N_CYC_DETECT = 12  # CPU cycles in the response rounds' detections (lists checked, pairs tested), builds excluded
N_CYC_RESPOND = 13  # CPU cycles in the responses
N_CYC_FAILSAFE = 14  # CPU cycles in the fail-safe (its detections and reverts), builds excluded
N_INVALID_MOVE = 15  # candidate lists invalidated by a particle beyond its motion radius
N_INVALID_TURN = 16  # ... by a triangle normal beyond its allowed turn
N_LOCAL = 17       # candidate lists updated in place (stages.sim.cloth_contact.local), not built afresh
N_COUNTERS = 18

# ---------------------------------------------------------------------------------------------
# feature pairs of two triangles, the contact buffer

@njit(cache=True)
def _vf_forced(p, t, particle_garment, tri_garment, garment_layer, garment_outward):
    """The side the layers prescribe for particle p against triangle t (0: none)."""
    gp = particle_garment[p]
    gt = tri_garment[t]
    if garment_layer[gp] > garment_layer[gt]:
        return int(garment_outward[gt])   # p is outer: along t's outward normal
    if garment_layer[gp] < garment_layer[gt]:
        return -int(garment_outward[gt])  # p is inner: against the outer triangle's outward normal
    return 0


@njit(cache=True)
def triangle_normal(xx, triangles, t):
    """(b - a) x (c - a) of triangle t at positions xx."""
    return triangle_cross(xx, triangles[t, 0], triangles[t, 1], triangles[t, 2])


@njit(cache=True)
def _edge_outward(xe, e, edge_tris, triangles, tri_garment, garment_outward):
    """Outward normal of edge e at the end of the step: the sum of its triangles' outward normals."""
    ox = 0.0
    oy = 0.0
    oz = 0.0
    for j in range(2):
        t = edge_tris[e, j]
        if t < 0:
            continue
        nx, ny, nz = triangle_normal(xe, triangles, t)
        ln = np.sqrt(nx * nx + ny * ny + nz * nz)
        if ln > 0.0:
            sg = garment_outward[tri_garment[t]] / ln
            ox += sg * nx
            oy += sg * ny
            oz += sg * nz
    return ox, oy, oz


@njit(cache=True)
def _store(work, n, kind, f0, f1, i0, i1, i2, i3, w0, w1, w2, w3, dx, dy, dz, counters):
    moved, corrected, c_kind, c_feat, c_idx, c_w, c_dir = work
    if n >= c_kind.shape[0]:
        counters[N_OVERFLOW] += 1
        return n
    c_kind[n] = kind
    c_feat[n, 0] = f0
    c_feat[n, 1] = f1
    c_idx[n, 0] = i0
    c_idx[n, 1] = i1
    c_idx[n, 2] = i2
    c_idx[n, 3] = i3
    c_w[n, 0] = w0
    c_w[n, 1] = w1
    c_w[n, 2] = w2
    c_w[n, 3] = w3
    c_dir[n, 0] = dx
    c_dir[n, 1] = dy
    c_dir[n, 2] = dz
    return n + 1


@njit(cache=True)
def test_vf_pair(xs, xe, p, t, topo, h, layer_depth, only_cross, work, n, counters):
    """Exact test of particle p against triangle t; stores a contact in the buffer. Returns n."""
    (triangles, edges, tri_edges, tri_owns, edge_tris, particle_garment, tri_garment, edge_garment,
     garment_layer, garment_outward) = topo
    a = triangles[t, 0]
    b = triangles[t, 1]
    c = triangles[t, 2]
    forced = _vf_forced(p, t, particle_garment, tri_garment, garment_layer, garment_outward)
    counters[N_TESTS] += 1
    kind, wa, wb, wc, dx, dy, dz = test_vertex_face(xs, xe, p, a, b, c, forced, h, layer_depth)
    if kind < 0 or (only_cross and kind != VF_CROSS):
        return n
    return _store(work, n, kind, p, t, p, a, b, c, 1.0, -wa, -wb, -wc, dx, dy, dz, counters)


@njit(cache=True)
def test_ee_pair(xs, xe, e, f, topo, h, layer_depth, only_cross, work, n, counters):
    """Exact test of edge e against edge f (e < f); stores a contact in the buffer. Returns n."""
    (triangles, edges, tri_edges, tri_owns, edge_tris, particle_garment, tri_garment, edge_garment,
     garment_layer, garment_outward) = topo
    a = edges[e, 0]
    b = edges[e, 1]
    c = edges[f, 0]
    d = edges[f, 1]
    counters[N_TESTS] += 1
    if ee_clear(xs, xe, a, b, c, d, max(h, layer_depth)):
        return n   # no crossing, ends apart: nothing whatever the layers' side (no outward normal needed)
    forced = 0
    ox = 0.0
    oy = 0.0
    oz = 0.0
    le = garment_layer[edge_garment[e]]
    lf = garment_layer[edge_garment[f]]
    if le != lf:
        inner = e if le < lf else f
        forced = 1 if le < lf else -1
        ox, oy, oz = _edge_outward(xe, inner, edge_tris, triangles, tri_garment, garment_outward)
    kind, v, u, _, dx, dy, dz = test_edge_edge(xs, xe, a, b, c, d, forced, ox, oy, oz, h, layer_depth)
    if kind < 0 or (only_cross and kind != EE_CROSS):
        return n
    return _store(work, n, kind, e, f, a, b, c, d, v - 1.0, -v, 1.0 - u, u, dx, dy, dz, counters)


@njit(cache=True)
def _in_triangle(triangles, p, t):
    return p == triangles[t, 0] or p == triangles[t, 1] or p == triangles[t, 2]


@njit(cache=True)
def _zoned_vf(zone, triangles, p, t):
    """The particle shares an exclusion zone (a bit of `zone`, ClothContact.exclude) with a corner of t."""
    return (zone[p] & (zone[triangles[t, 0]] | zone[triangles[t, 1]] | zone[triangles[t, 2]])) != 0


@njit(cache=True)
def point_off_triangle(pt_min, pt_max, p, tri_min, tri_max, t):
    """The particle's and the triangle's inflated swept k-DOPs are disjoint."""
    for i in range(pt_min.shape[1]):
        if pt_max[p, i] < tri_min[t, i] or tri_max[t, i] < pt_min[p, i]:
            return True
    return False


@njit(cache=True)
def edges_apart_bounds(pt_min, pt_max, a, b, c, d):
    """The two edges' inflated swept k-DOPs (unions of their particles') are disjoint."""
    for i in range(pt_min.shape[1]):
        if max(pt_max[a, i], pt_max[b, i]) < min(pt_min[c, i], pt_min[d, i]):
            return True
        if max(pt_max[c, i], pt_max[d, i]) < min(pt_min[a, i], pt_min[b, i]):
            return True
    return False


@njit(cache=True)
def _append(cand, cand_n, slot, a, b):
    """Append the pair (a, b) to a candidate list (cand_n[slot] its count; cand_n[2] = 1 on overflow)."""
    k = cand_n[slot]
    if k >= cand.shape[0]:
        cand_n[2] = 1
        return
    cand[k, 0] = a
    cand[k, 1] = b
    cand_n[slot] = k + 1


@njit(cache=True)
def vf_candidate(xs, xe, p, t, topo, h, layer_depth, only_cross, work, n, counters):
    """test_vf_pair unless the pair provably stays apart (vf_apart: beyond max(h, layer_depth))."""
    tri = topo[0]
    if vf_apart(xs, xe, p, tri[t, 0], tri[t, 1], tri[t, 2], max(h, layer_depth)):
        return n
    return test_vf_pair(xs, xe, p, t, topo, h, layer_depth, only_cross, work, n, counters)


@njit(cache=True)
def ee_candidate(xs, xe, e, f, topo, h, layer_depth, only_cross, work, n, counters):
    """test_ee_pair unless the pair provably stays apart (ee_apart: beyond max(h, layer_depth))."""
    edges = topo[1]
    if ee_apart(xs, xe, edges[e, 0], edges[e, 1], edges[f, 0], edges[f, 1], max(h, layer_depth)):
        return n
    return test_ee_pair(xs, xe, e, f, topo, h, layer_depth, only_cross, work, n, counters)


@njit(cache=True)
def _vf(xs, xe, p, t, topo, tree, h, layer_depth, only_cross, work, n, counters, collect):
    """Test the pair, or with `collect` append it to the candidate list (tree[18], counts tree[20])."""
    if not collect:
        return vf_candidate(xs, xe, p, t, topo, h, layer_depth, only_cross, work, n, counters)
    _append(tree[18], tree[20], 0, p, t)
    return n


@njit(cache=True)
def _ee(xs, xe, e, f, topo, tree, h, layer_depth, only_cross, work, n, counters, collect):
    """Test the pair (e < f), or with `collect` append it to the candidate list (tree[19])."""
    if not collect:
        return ee_candidate(xs, xe, e, f, topo, h, layer_depth, only_cross, work, n, counters)
    _append(tree[19], tree[20], 1, e, f)
    return n


@njit(cache=True)
def test_triangle_pair(xs, xe, t1, t2, topo, tree, pt_min, pt_max, h, layer_depth, only_cross, work, n, counters,
                       collect, flagged_only):
    """Every pair of features owned by the two triangles that share no vertex themselves (see the
    module doc) nor an exclusion zone (tree[43], ClothContact.exclude), after a k-DOP check of the two features' own bounds (pt_min / pt_max per particle,
    the triangles' in tree[8:10]): tested, or with `collect` appended to the candidate lists (the
    bounds then span the lists' lifetime). flagged_only: only the feature pairs with a particle
    flagged in tree[36] (the in-place list updates, stages.sim.cloth_contact.local: the others are
    listed already)."""
    triangles = topo[0]
    edges = topo[1]
    tri_edges = topo[2]
    tri_owns = topo[3]
    tri_min = tree[8]
    tri_max = tree[9]
    o1 = tri_owns[t1]
    o2 = tri_owns[t2]
    flag = tree[36]
    zone = tree[43]
    f1 = True
    f2 = True
    if flagged_only:
        f1 = (flag[triangles[t1, 0]] | flag[triangles[t1, 1]] | flag[triangles[t1, 2]]) != 0
        f2 = (flag[triangles[t2, 0]] | flag[triangles[t2, 1]] | flag[triangles[t2, 2]]) != 0
    for k in range(3):
        if o1 & (1 << k):
            p = triangles[t1, k]
            if ((f2 or flag[p] != 0) and not _in_triangle(triangles, p, t2) and not _zoned_vf(zone, triangles, p, t2)
                    and not point_off_triangle(pt_min, pt_max, p, tri_min, tri_max, t2)):
                n = _vf(xs, xe, p, t2, topo, tree, h, layer_depth, only_cross, work, n, counters, collect)
        if o2 & (1 << k):
            p = triangles[t2, k]
            if ((f1 or flag[p] != 0) and not _in_triangle(triangles, p, t1) and not _zoned_vf(zone, triangles, p, t1)
                    and not point_off_triangle(pt_min, pt_max, p, tri_min, tri_max, t1)):
                n = _vf(xs, xe, p, t1, topo, tree, h, layer_depth, only_cross, work, n, counters, collect)
    for i in range(3):
        if not (o1 & (8 << i)):
            continue
        for j in range(3):
            if not (o2 & (8 << j)):
                continue
            e = tri_edges[t1, i]
            f = tri_edges[t2, j]
            if flagged_only and not (flag[edges[e, 0]] | flag[edges[e, 1]] | flag[edges[f, 0]] | flag[edges[f, 1]]):
                continue
            if (edges[e, 0] == edges[f, 0] or edges[e, 0] == edges[f, 1] or edges[e, 1] == edges[f, 0]
                    or edges[e, 1] == edges[f, 1]):
                continue
            if ((zone[edges[e, 0]] | zone[edges[e, 1]]) & (zone[edges[f, 0]] | zone[edges[f, 1]])) != 0:
                continue
            if edges_apart_bounds(pt_min, pt_max, edges[e, 0], edges[e, 1], edges[f, 0], edges[f, 1]):
                continue
            if e < f:
                n = _ee(xs, xe, e, f, topo, tree, h, layer_depth, only_cross, work, n, counters, collect)
            else:
                n = _ee(xs, xe, f, e, topo, tree, h, layer_depth, only_cross, work, n, counters, collect)
    return n


@njit(cache=True)
def brute_force_contacts(xs, xe, topo, h, layer_depth, only_cross, work, counters):
    """Every vertex-face and edge-edge pair that shares no vertex, tested exactly: O(P T + E E).
    Same buffer as `detect` (order differs). Returns the number of contacts stored."""
    (triangles, edges, tri_edges, tri_owns, edge_tris, particle_garment, tri_garment, edge_garment,
     garment_layer, garment_outward) = topo
    used = np.zeros(xs.shape[0], dtype=np.bool_)
    for t in range(triangles.shape[0]):
        for k in range(3):
            used[triangles[t, k]] = True
    n = 0
    for p in range(xs.shape[0]):
        if not used[p]:
            continue
        for t in range(triangles.shape[0]):
            if not _in_triangle(triangles, p, t):
                n = test_vf_pair(xs, xe, p, t, topo, h, layer_depth, only_cross, work, n, counters)
    for e in range(edges.shape[0]):
        for f in range(e + 1, edges.shape[0]):
            a = edges[e, 0]
            b = edges[e, 1]
            if a != edges[f, 0] and a != edges[f, 1] and b != edges[f, 0] and b != edges[f, 1]:
                n = test_ee_pair(xs, xe, e, f, topo, h, layer_depth, only_cross, work, n, counters)
    return n
