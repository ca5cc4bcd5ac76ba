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
from stages.obstacles.kdop import refit_range
from stages.sim.cloth_contact_cull import flat_patch, flat_union, patch_nodes  # noqa: F401
from stages.sim.cloth_contact_ccd import (EE_CROSS, EE_NEAR, VF_CROSS, VF_NEAR,  # noqa: F401
                                          count_edge_triangle_crossings, cubic_roots01,
                                          segment_crosses_triangle, test_edge_edge, test_vertex_face,
                                          triple_cubic)
from stages.sim.cloth_contact_pairs import (N_CONTACTS, N_CORRECTED, N_COUNTERS, N_LEFT,  # noqa: F401
                                            N_NODE_PAIRS, N_OVERFLOW, N_REVERTED, N_ROUNDS, N_TESTS,
                                            N_UNRESOLVED, brute_force_contacts, test_ee_pair,
                                            test_triangle_pair, test_vf_pair)

# kernels below compile in code from these modules: their edits must invalidate the disk cache
NUMBA_CACHE_DEPENDS = ("stages.obstacles.kdop", "stages.sim.cloth_contact_ccd", "stages.sim.cloth_contact_cull",
                       "stages.sim.cloth_contact_pairs")

PUSH_OVER = 1.02     # responses push to 1.02 h so a contact just resolved is not found again at h
SWEEPS = 3           # Gauss-Seidel sweeps over a round's contacts before the next detection

# ---------------------------------------------------------------------------------------------
# tree: refit and self-traversal

@njit(cache=True, _nrt=False)
def refit_cloth_tree(xs, xe, topo, tree, moved, margin):
    """Leaves bound each triangle over the step (xs and xe) inflated by `margin`; a node is dirty
    when a particle of its triangles moved since the last detection (moved[p] != 0); nrm_min/max
    bound the projections of its triangles' unit normals (at xs and at xe) on the directions."""
    triangles = topo[0]
    (directions, axis_order, roots, node_min, node_max, children, leaf_prim, node_dirty, tri_min, tri_max, pt_min,
     pt_max, nrm_min, nrm_max, node_patch, stack, border_start, border_vert) = tree
    h = directions.shape[0]
    for p in range(xs.shape[0]):
        for i in range(h):
            a = xs[p, 0] * directions[i, 0] + xs[p, 1] * directions[i, 1] + xs[p, 2] * directions[i, 2]
            b = xe[p, 0] * directions[i, 0] + xe[p, 1] * directions[i, 1] + xe[p, 2] * directions[i, 2]
            pt_min[p, i] = min(a, b) - margin
            pt_max[p, i] = max(a, b) + margin
    # a triangle's bounds from its corners' (as stages.obstacles.kdop.triangle_bounds, exactly:
    # min(p - m, q - m) == min(p, q) - m), 3 times fewer projections
    for t in range(triangles.shape[0]):
        a = triangles[t, 0]
        b = triangles[t, 1]
        c = triangles[t, 2]
        for i in range(h):
            tri_min[t, i] = min(pt_min[a, i], min(pt_min[b, i], pt_min[c, i]))
            tri_max[t, i] = max(pt_max[a, i], max(pt_max[b, i], pt_max[c, i]))
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


@njit(cache=True, _nrt=False)
def detect(xs, xe, topo, tree, work, h, layer_depth, only_cross, cull, counters):
    """Self-traversal of the (refit) cloth tree: every pair of overlapping leaves with at least one
    dirty side is tested exactly (`test_triangle_pair`); with `cull`, a subtree that is a flat
    patch (`flat_patch`) is not tested against itself, nor two neighbouring nodes that together are one
    (`flat_union`, stages.sim.cloth_contact_cull). Returns the number of contacts stored."""
    (directions, axis_order, roots, node_min, node_max, children, leaf_prim, node_dirty, tri_min, tri_max, pt_min,
     pt_max, nrm_min, nrm_max, node_patch, stack, border_start, border_vert) = tree
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
            if cull and flat_patch(nrm_min, nrm_max, node_patch, a):
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
        if cull and flat_union(nrm_min, nrm_max, node_patch, border_start, border_vert, a, b):
            continue   # neighbouring nodes of one garment that together are a flat patch
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
           flat patches in the self test (stages.sim.cloth_contact_cull).
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
