"""Cloth x cloth collision kernels (garment-garment and self): a k-DOP forest over the cloth's
triangles (paper B; one tree per garment), the exact tests of `stages.sim.cloth_contact_ccd`, a
position response and a fail-safe.

Everything is numba over flat arrays, world frame, metres; the arrays are built once per scene by
`stages.sim.cloth_contact.build_cloth_contact` (their shapes and dtypes are documented there).
The entry is `collide_cloth`: see its docstring for the contract.

Every contact is the constraint C = dir . sum_k w_k x_k - h >= 0 over its 4 particles (dir = s times
the unit normal at the end of the step; w the barycentric / edge weights), projected by inverse
mass (PBD); pinned particles (inv_mass 0) never move.

Which pairs are tested: the traversal pairs triangles whose swept, inflated k-DOPs overlap. Each
vertex and each edge is owned by one incident triangle (`tri_owns`), and a triangle pair tests only
the features it owns, so each feature pair is tested once: every vertex-face and edge-edge pair that
shares no vertex (adjacent features are skipped) and whose own swept k-DOPs overlap (conservative).
With `cull`, a garment's subtree that is a connected, flat patch is not tested against itself.
"""
from __future__ import annotations

import numpy as np
from numba import njit

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)
from stages.obstacles.kdop import refit_range, triangle_bounds
from stages.sim.cloth_contact_ccd import (EE_CROSS, EE_NEAR, VF_CROSS, VF_NEAR,  # noqa: F401
                                          count_edge_triangle_crossings, cubic_roots01,
                                          segment_crosses_triangle, test_edge_edge, test_vertex_face,
                                          triple_cubic)

# kernels below compile in code from these modules: their edits must invalidate the disk cache
NUMBA_CACHE_DEPENDS = ("stages.obstacles.kdop", "stages.sim.cloth_contact_ccd")

PUSH_OVER = 1.02     # responses push to 1.02 h so a contact just resolved is not found again at h
SWEEPS = 3           # Gauss-Seidel sweeps over a round's contacts before the next detection
FLAT_COS = 0.05      # a patch is flat when its unit normals project beyond this on one direction

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
N_COUNTERS = 9


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
def _edge_outward(xe, e, edge_tris, triangles, tri_garment, garment_outward):
    """Outward normal of edge e at the end of the step: the sum of its triangles' outward normals."""
    ox = 0.0
    oy = 0.0
    oz = 0.0
    for j in range(2):
        t = edge_tris[e, j]
        if t < 0:
            continue
        a = triangles[t, 0]
        b = triangles[t, 1]
        c = triangles[t, 2]
        e1x = xe[b, 0] - xe[a, 0]
        e1y = xe[b, 1] - xe[a, 1]
        e1z = xe[b, 2] - xe[a, 2]
        e2x = xe[c, 0] - xe[a, 0]
        e2y = xe[c, 1] - xe[a, 1]
        e2z = xe[c, 2] - xe[a, 2]
        nx = e1y * e2z - e1z * e2y
        ny = e1z * e2x - e1x * e2z
        nz = e1x * e2y - e1y * e2x
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
    counters[N_TESTS] += 1
    kind, v, u, _, dx, dy, dz = test_edge_edge(xs, xe, a, b, c, d, forced, ox, oy, oz, h, layer_depth)
    if kind < 0 or (only_cross and kind != EE_CROSS):
        return n
    return _store(work, n, kind, e, f, a, b, c, d, v - 1.0, -v, 1.0 - u, u, dx, dy, dz, counters)


@njit(cache=True)
def _in_triangle(triangles, p, t):
    return p == triangles[t, 0] or p == triangles[t, 1] or p == triangles[t, 2]


@njit(cache=True)
def _point_off_triangle(pt_min, pt_max, p, tri_min, tri_max, t):
    """The particle's and the triangle's inflated swept k-DOPs are disjoint."""
    for i in range(pt_min.shape[1]):
        if pt_max[p, i] < tri_min[t, i] or tri_max[t, i] < pt_min[p, i]:
            return True
    return False


@njit(cache=True)
def _edges_apart(pt_min, pt_max, a, b, c, d):
    """The two edges' inflated swept k-DOPs (unions of their particles') are disjoint."""
    for i in range(pt_min.shape[1]):
        if max(pt_max[a, i], pt_max[b, i]) < min(pt_min[c, i], pt_min[d, i]):
            return True
        if max(pt_max[c, i], pt_max[d, i]) < min(pt_min[a, i], pt_min[b, i]):
            return True
    return False


@njit(cache=True)
def test_triangle_pair(xs, xe, t1, t2, topo, tree, h, layer_depth, only_cross, work, n, counters):
    """Every pair of features owned by the two triangles that share no vertex themselves (see the
    module doc), after a k-DOP check of the two features' own bounds (refit_cloth_tree)."""
    triangles = topo[0]
    edges = topo[1]
    tri_edges = topo[2]
    tri_owns = topo[3]
    tri_min = tree[8]
    tri_max = tree[9]
    pt_min = tree[10]
    pt_max = tree[11]
    o1 = tri_owns[t1]
    o2 = tri_owns[t2]
    for k in range(3):
        if o1 & (1 << k):
            p = triangles[t1, k]
            if not _in_triangle(triangles, p, t2) and not _point_off_triangle(pt_min, pt_max, p, tri_min, tri_max, t2):
                n = test_vf_pair(xs, xe, p, t2, topo, h, layer_depth, only_cross, work, n, counters)
        if o2 & (1 << k):
            p = triangles[t2, k]
            if not _in_triangle(triangles, p, t1) and not _point_off_triangle(pt_min, pt_max, p, tri_min, tri_max, t1):
                n = test_vf_pair(xs, xe, p, t1, topo, h, layer_depth, only_cross, work, n, counters)
    for i in range(3):
        if not (o1 & (8 << i)):
            continue
        for j in range(3):
            if not (o2 & (8 << j)):
                continue
            e = tri_edges[t1, i]
            f = tri_edges[t2, j]
            if (edges[e, 0] == edges[f, 0] or edges[e, 0] == edges[f, 1] or edges[e, 1] == edges[f, 0]
                    or edges[e, 1] == edges[f, 1]):
                continue
            if _edges_apart(pt_min, pt_max, edges[e, 0], edges[e, 1], edges[f, 0], edges[f, 1]):
                continue
            if e < f:
                n = test_ee_pair(xs, xe, e, f, topo, h, layer_depth, only_cross, work, n, counters)
            else:
                n = test_ee_pair(xs, xe, f, e, topo, h, layer_depth, only_cross, work, n, counters)
    return n


# ---------------------------------------------------------------------------------------------
# tree: refit and self-traversal

@njit(cache=True, _nrt=False)
def refit_cloth_tree(xs, xe, topo, tree, moved, margin):
    """Leaves bound each triangle over the step (xs and xe) inflated by `margin`; a node is dirty
    when a particle of its triangles moved since the last detection (moved[p] != 0); nrm_min/max
    bound the projections of its triangles' unit normals (at xs and at xe) on the directions."""
    triangles = topo[0]
    (directions, axis_order, roots, node_min, node_max, children, leaf_prim, node_dirty, tri_min, tri_max, pt_min,
     pt_max, nrm_min, nrm_max, node_patch, stack) = tree
    triangle_bounds(directions, xs, xe, triangles, margin, tri_min, tri_max)
    h = directions.shape[0]
    for p in range(xs.shape[0]):
        for i in range(h):
            a = xs[p, 0] * directions[i, 0] + xs[p, 1] * directions[i, 1] + xs[p, 2] * directions[i, 2]
            b = xe[p, 0] * directions[i, 0] + xe[p, 1] * directions[i, 1] + xe[p, 2] * directions[i, 2]
            pt_min[p, i] = min(a, b) - margin
            pt_max[p, i] = max(a, b) + margin
    refit_range(node_min, node_max, children, leaf_prim, tri_min, tri_max, 0, node_min.shape[0])
    for node in range(node_min.shape[0] - 1, -1, -1):
        t = leaf_prim[node]
        if t >= 0:
            node_dirty[node] = moved[triangles[t, 0]] | moved[triangles[t, 1]] | moved[triangles[t, 2]]
            for i in range(h):
                nrm_min[node, i] = np.inf
                nrm_max[node, i] = -np.inf
            for xx in (xs, xe):
                a = triangles[t, 0]
                e1x = xx[triangles[t, 1], 0] - xx[a, 0]
                e1y = xx[triangles[t, 1], 1] - xx[a, 1]
                e1z = xx[triangles[t, 1], 2] - xx[a, 2]
                e2x = xx[triangles[t, 2], 0] - xx[a, 0]
                e2y = xx[triangles[t, 2], 1] - xx[a, 1]
                e2z = xx[triangles[t, 2], 2] - xx[a, 2]
                nx = e1y * e2z - e1z * e2y
                ny = e1z * e2x - e1x * e2z
                nz = e1x * e2y - e1y * e2x
                ln = np.sqrt(nx * nx + ny * ny + nz * nz)
                if ln == 0.0:
                    ln = 1.0  # a degenerate triangle: normal 0 makes no cone flat
                for i in range(h):
                    q = (nx * directions[i, 0] + ny * directions[i, 1] + nz * directions[i, 2]) / ln
                    nrm_min[node, i] = min(nrm_min[node, i], q)
                    nrm_max[node, i] = max(nrm_max[node, i], q)
        else:
            l = children[node, 0]
            r = children[node, 1]
            node_dirty[node] = node_dirty[l] | node_dirty[r]
            for i in range(h):
                nrm_min[node, i] = min(nrm_min[l, i], nrm_min[r, i])
                nrm_max[node, i] = max(nrm_max[l, i], nrm_max[r, i])


@njit(cache=True)
def _disjoint(node_min, node_max, a, b, axis_order):
    for j in range(axis_order.shape[0]):
        i = axis_order[j]
        if node_max[a, i] < node_min[b, i] or node_max[b, i] < node_min[a, i]:
            return True
    return False


@njit(cache=True)
def _flat_patch(nrm_min, nrm_max, node_patch, a):
    """Normal-cone culling (Volino & Magnenat-Thalmann 1994): one edge-connected patch whose
    normals all lie strictly on one side of a plane through the origin cannot fold onto itself.
    (Their contour test, that the patch's outline does not overlap itself in projection, is left
    out: a median-split patch of a cloth mesh is compact.)"""
    if not node_patch[a]:
        return False
    for i in range(nrm_min.shape[1]):
        if nrm_min[a, i] > FLAT_COS or nrm_max[a, i] < -FLAT_COS:
            return True
    return False


@njit(cache=True, _nrt=False)
def detect(xs, xe, topo, tree, work, h, layer_depth, only_cross, cull, counters):
    """Self-traversal of the (refit) cloth tree: every pair of overlapping leaves with at least one
    dirty side is tested exactly (`test_triangle_pair`); with `cull`, a subtree that is a flat
    patch (`_flat_patch`) is not tested against itself. Returns the number of contacts stored."""
    (directions, axis_order, roots, node_min, node_max, children, leaf_prim, node_dirty, tri_min, tri_max, pt_min,
     pt_max, nrm_min, nrm_max, node_patch, stack) = tree
    n = 0
    # every garment's tree against itself and against every later one (roots: tree offsets)
    top = 0
    for g in range(roots.shape[0] - 1):
        for q in range(g, roots.shape[0] - 1):
            stack[top, 0] = roots[g]
            stack[top, 1] = roots[q]
            top += 1
    visited = 0
    cap = stack.shape[0]
    while top > 0:
        top -= 1
        a = stack[top, 0]
        b = stack[top, 1]
        visited += 1
        if a == b:
            # a subtree against itself: its two halves against themselves and each other
            if leaf_prim[a] >= 0 or not node_dirty[a]:
                continue
            if cull and _flat_patch(nrm_min, nrm_max, node_patch, a):
                continue
            if top + 3 > cap:
                counters[N_OVERFLOW] += 1
                continue
            l = children[a, 0]
            r = children[a, 1]
            stack[top, 0] = l
            stack[top, 1] = r
            stack[top + 1, 0] = r
            stack[top + 1, 1] = r
            stack[top + 2, 0] = l
            stack[top + 2, 1] = l
            top += 3
            continue
        if not (node_dirty[a] or node_dirty[b]):
            continue
        if _disjoint(node_min, node_max, a, b, axis_order):
            continue
        la = leaf_prim[a] >= 0
        lb = leaf_prim[b] >= 0
        if la and lb:
            n = test_triangle_pair(xs, xe, leaf_prim[a], leaf_prim[b], topo, tree, h, layer_depth, only_cross,
                                   work, n, counters)
            continue
        if top + 2 > cap:
            counters[N_OVERFLOW] += 1
            continue
        descend_a = not la
        if not la and not lb:
            # both inner: descend the larger (sum of the axis extents: directions 0-2 are the axes)
            ea = node_max[a, 0] - node_min[a, 0] + node_max[a, 1] - node_min[a, 1] + node_max[a, 2] - node_min[a, 2]
            eb = node_max[b, 0] - node_min[b, 0] + node_max[b, 1] - node_min[b, 1] + node_max[b, 2] - node_min[b, 2]
            descend_a = ea >= eb
        if descend_a:
            stack[top, 0] = children[a, 1]
            stack[top, 1] = b
            stack[top + 1, 0] = children[a, 0]
            stack[top + 1, 1] = b
        else:
            stack[top, 0] = a
            stack[top, 1] = children[b, 1]
            stack[top + 1, 0] = a
            stack[top + 1, 1] = children[b, 0]
        top += 2
    counters[N_NODE_PAIRS] += visited
    return n


# ---------------------------------------------------------------------------------------------
# response, fail-safe, entry

@njit(cache=True, _nrt=False)
def respond(x, inv_mass, work, n, target):
    """Project contacts 0..n-1 in buffer order (Gauss-Seidel): C = dir . sum_k w_k x_k - target;
    if C < 0 each particle moves by -C w_k inv_mass_k / sum_j w_j^2 inv_mass_j along dir."""
    moved, corrected, c_kind, c_feat, c_idx, c_w, c_dir = work
    for k in range(n):
        dx = c_dir[k, 0]
        dy = c_dir[k, 1]
        dz = c_dir[k, 2]
        cval = -target
        den = 0.0
        for j in range(4):
            i = c_idx[k, j]
            w = c_w[k, j]
            cval += w * (dx * x[i, 0] + dy * x[i, 1] + dz * x[i, 2])
            den += w * w * inv_mass[i]
        if cval >= 0.0 or den == 0.0:
            continue
        lam = -cval / den
        for j in range(4):
            i = c_idx[k, j]
            sc = lam * c_w[k, j] * inv_mass[i]
            if sc == 0.0:
                continue
            x[i, 0] += sc * dx
            x[i, 1] += sc * dy
            x[i, 2] += sc * dz
            moved[i] = 1
            corrected[i] = 1


@njit(cache=True, _nrt=False)
def revert(x_prev, x, inv_mass, work, n):
    """Fail-safe: every movable particle of contacts 0..n-1 goes back to x_prev. Returns how many
    particles changed."""
    moved, corrected, c_kind, c_feat, c_idx, c_w, c_dir = work
    changed = 0
    for k in range(n):
        for j in range(4):
            i = c_idx[k, j]
            if inv_mass[i] == 0.0:
                continue
            if x[i, 0] != x_prev[i, 0] or x[i, 1] != x_prev[i, 1] or x[i, 2] != x_prev[i, 2]:
                x[i, 0] = x_prev[i, 0]
                x[i, 1] = x_prev[i, 1]
                x[i, 2] = x_prev[i, 2]
                moved[i] = 1
                corrected[i] = 1
                changed += 1
    return changed


@njit(cache=True, _nrt=False)
def collide_cloth(x_prev, x, inv_mass, topo, tree, work, prm, counters):
    """Cloth x cloth collision over one step (self and between garments); corrects x in place.

    x_prev (N, 3) f8: positions at the start of the step (read only; must be free of crossings).
    x      (N, 3) f8: predicted positions at its end; corrected so no particle passes through a
           cloth triangle and no cloth edge through a cloth edge on the way x_prev -> x.
    inv_mass (N,) f8: 0 = pinned, never moved here.
    topo, tree, work: tuples of arrays from `ClothContact.kernel_args()` (stages.sim.cloth_contact).
    prm: (thickness m, layer_depth m, rounds, failsafe_rounds, cull): cull = normal-cone culling of
           flat patches in the self test (`_flat_patch`).
    counters (N_COUNTERS,) i8: accumulated (+=), see N_* above.

    Rounds: refit the tree over x_prev -> x, find contacts (all pairs in round 1, then only pairs
    with a particle the previous round moved), project them; stop when a round finds none. If the
    rounds run out, the fail-safe finds the pairs that still pass through (CROSS) and puts their
    movable particles back at x_prev, repeated until none is left: as x_prev has no crossing, the
    worst case is the whole cloth at rest, which has none.
    """
    thickness, layer_depth, rounds, failsafe_rounds, cull = prm
    moved = work[0]
    corrected = work[1]
    margin = 0.5 * max(thickness, layer_depth)
    target = PUSH_OVER * thickness
    moved[:] = 1
    corrected[:] = 0
    clean = False
    for _ in range(rounds):
        dropped = counters[N_OVERFLOW]
        refit_cloth_tree(x_prev, x, topo, tree, moved, margin)
        n = detect(x_prev, x, topo, tree, work, thickness, layer_depth, False, cull, counters)
        counters[N_ROUNDS] += 1
        counters[N_CONTACTS] += n
        if n == 0 and counters[N_OVERFLOW] == dropped:
            clean = True
            break
        moved[:] = 0
        for _sweep in range(SWEEPS):  # coupled contacts (a particle in several) need a few sweeps
            respond(x, inv_mass, work, n, target)
        if counters[N_OVERFLOW] != dropped:
            moved[:] = 1  # dropped contacts: look everywhere again
    if not clean:
        for it in range(failsafe_rounds + 1):
            dropped = counters[N_OVERFLOW]
            refit_cloth_tree(x_prev, x, topo, tree, moved, margin)
            n = detect(x_prev, x, topo, tree, work, thickness, layer_depth, True, cull, counters)
            if it == 0:
                counters[N_UNRESOLVED] += n
            if n == 0 and counters[N_OVERFLOW] == dropped:
                break
            if it == failsafe_rounds:
                counters[N_LEFT] += n
                break
            moved[:] = 0
            changed = revert(x_prev, x, inv_mass, work, n)
            counters[N_REVERTED] += changed
            if counters[N_OVERFLOW] != dropped:
                moved[:] = 1  # dropped crossings: look everywhere again
            if changed == 0 and counters[N_OVERFLOW] == dropped:
                counters[N_LEFT] += n  # only pinned particles left to move
                break
    nc = 0
    for i in range(corrected.shape[0]):
        nc += corrected[i]
    counters[N_CORRECTED] += nc


# ---------------------------------------------------------------------------------------------
# brute force (references for the tests and a static audit)

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


@njit(cache=True)
def _find(parent, v):
    while parent[v] != v:
        parent[v] = parent[parent[v]]
        v = parent[v]
    return v


@njit(cache=True)
def patch_nodes(children, leaf_prim, triangles, tri_garment, n_particles):
    """(n,) uint8: 1 where a node's triangles form one connected patch (through shared vertices) of
    one garment. Setup only."""
    n = children.shape[0]
    out = np.zeros(n, dtype=np.uint8)
    parent = np.arange(n_particles)
    tris = np.empty(triangles.shape[0], dtype=np.int64)
    stack = np.empty(n, dtype=np.int64)
    for node in range(n):
        m = 0
        stack[0] = node
        top = 1
        while top > 0:
            top -= 1
            q = stack[top]
            if leaf_prim[q] >= 0:
                tris[m] = leaf_prim[q]
                m += 1
            else:
                stack[top] = children[q, 0]
                stack[top + 1] = children[q, 1]
                top += 2
        ok = True
        for j in range(m):
            t = tris[j]
            if tri_garment[t] != tri_garment[tris[0]]:
                ok = False
            for k in range(1, 3):
                ra = _find(parent, triangles[t, 0])
                rb = _find(parent, triangles[t, k])
                if ra != rb:
                    parent[max(ra, rb)] = min(ra, rb)
        root = _find(parent, triangles[tris[0], 0])
        for j in range(m):
            if _find(parent, triangles[tris[j], 0]) != root:
                ok = False
        out[node] = 1 if ok else 0
        for j in range(m):  # reset the touched vertices
            for k in range(3):
                parent[triangles[tris[j], k]] = triangles[tris[j], k]
    return out


@njit(cache=True, _nrt=False)
def contact_velocity(x_before, x, xp, corrected):
    """Verlet velocity after a `collide_cloth` called once per frame (or whenever the correction should
    not become velocity): for each corrected particle, with d = x - x_before its correction and
    v = x_before - xp its velocity (times dt) before it, drop the part of v that approaches along d
    (inelastic along the contact normal, tangential kept) and set xp = x - v. Uncorrected particles
    keep xp. corrected: work[1] of the call."""
    for i in range(x.shape[0]):
        if not corrected[i]:
            continue
        dx = x[i, 0] - x_before[i, 0]
        dy = x[i, 1] - x_before[i, 1]
        dz = x[i, 2] - x_before[i, 2]
        vx = x_before[i, 0] - xp[i, 0]
        vy = x_before[i, 1] - xp[i, 1]
        vz = x_before[i, 2] - xp[i, 2]
        dd = dx * dx + dy * dy + dz * dz
        if dd > 0.0:
            vn = (vx * dx + vy * dy + vz * dz) / dd
            if vn < 0.0:
                vx -= vn * dx
                vy -= vn * dy
                vz -= vn * dz
        xp[i, 0] = x[i, 0] - vx
        xp[i, 1] = x[i, 1] - vy
        xp[i, 2] = x[i, 2] - vz
