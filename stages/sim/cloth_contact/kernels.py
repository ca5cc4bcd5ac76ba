"""Cloth x cloth collision kernels (garment-garment and self): a k-DOP forest over the cloth's
triangles (paper B; one tree per garment), the exact tests of `stages.sim.cloth_contact.ccd`, a
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
shares no vertex (adjacent features are skipped) nor an exclusion zone (ClothContact.exclude) and whose
own swept k-DOPs overlap (conservative).
With `cull`, a garment's subtree that is a connected, flat patch is not tested against itself.
"""
from __future__ import annotations

import numpy as np
from numba import njit

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)
from stages.geometry.kdop import refit_range
from stages.sim.cloth_contact.narrow import narrow
from stages.sim.cloth_contact.local import (LOCAL_MAX, MAX_MOTION_STEPS, STEPS_AHEAD, box_bounds,  # noqa: F401
                                            particle_box, tri_bounds, update_candidates)
from stages.sim.cloth_contact.response import contact_velocity, keep_contacts, respond, revert, settled  # noqa: F401
from stages.sim.simd import cycles
from stages.sim.cloth_contact.cull import FLAT_COS, UNION_COS, flat_patch, flat_union, patch_nodes  # noqa: F401
from stages.sim.cloth_contact.ccd import (EE_CROSS, EE_NEAR, VF_CROSS, VF_NEAR,  # noqa: F401
                                          count_edge_triangle_crossings, cubic_roots01,
                                          segment_crosses_triangle, test_edge_edge, test_vertex_face,
                                          triple_cubic)
from stages.sim.cloth_contact.pairs import (N_BUILDS, N_CAND_OVERFLOW, N_CONTACTS, N_CORRECTED,  # noqa: F401
                                            N_COUNTERS, N_CYC_BUILD, N_CYC_DETECT, N_CYC_FAILSAFE, N_CYC_RESPOND, N_INVALID_MOVE, N_INVALID_TURN, N_LEFT, N_LOCAL, N_NODE_PAIRS, N_OVERFLOW, N_REVERTED, N_ROUNDS,
                                            N_TESTS, N_UNRESOLVED, brute_force_contacts, edges_apart_bounds,
                                            ee_candidate, point_off_triangle, test_ee_pair, test_triangle_pair, test_vf_pair,
                                            triangle_normal,
                                            vf_candidate)

# kernels below compile in code from these modules: their edits must invalidate the disk cache
NUMBA_CACHE_DEPENDS = ("stages.affine", "stages.geometry.kdop", "stages.sim.cloth_contact.ccd", "stages.sim.cloth_contact.cull",
                       "stages.sim.cloth_contact.local",
                       "stages.sim.cloth_contact.narrow", "stages.sim.cloth_contact.pairs",
                       "stages.sim.cloth_contact.response", "stages.sim.simd")

MIN_TURN = 0.5       # rad: a candidate list culls only patches whose normals can turn this far and stay flat
# A culled list a normal's turn undoes within YOUNG_LIST detections of its build: the next PLAIN_BUILDS
# builds cull nothing (lists only a move undoes). Where responses or pinches turn triangles every round
# (bvh_walk, the T-shirt tucked in the shorts: 2.2 builds a sub-step, 52 M cycles) a culled list
# lasted less than a round; without culling, 0.2 builds a sub-step (2.1 -> 7.8 frames/s).
YOUNG_LIST = 4
PLAIN_BUILDS = 8
PUSH_OVER = 1.02     # responses push to 1.02 h so a contact just resolved is not found again at h
SWEEPS = 3           # Gauss-Seidel sweeps over a round's contacts before the next detection
# (the response, the settled test and the fail-safe's revert: stages.sim.cloth_contact.response)

# ---------------------------------------------------------------------------------------------
# tree: refit and self-traversal

@njit(cache=True, _nrt=False)
def _segment_bounds(xs, xe, directions, margin, pt_min, pt_max):
    """Each particle's k-DOP over its step xs -> xe, inflated by `margin`."""
    h = directions.shape[0]
    for p in range(xs.shape[0]):
        for i in range(h):
            a = xs[p, 0] * directions[i, 0] + xs[p, 1] * directions[i, 1] + xs[p, 2] * directions[i, 2]
            b = xe[p, 0] * directions[i, 0] + xe[p, 1] * directions[i, 1] + xe[p, 2] * directions[i, 2]
            pt_min[p, i] = min(a, b) - margin
            pt_max[p, i] = max(a, b) + margin


@njit(cache=True, _nrt=False)
def _triangle_bounds(triangles, pt_min, pt_max, tri_min, tri_max):
    """Every triangle's bounds from its corners' (stages.sim.cloth_contact.local.tri_bounds)."""
    for t in range(triangles.shape[0]):
        tri_bounds(triangles, t, pt_min, pt_max, tri_min, tri_max)


@njit(cache=True, _nrt=False)
def _refit_nodes(xs, xe, topo, tree, moved, all_dirty):
    """Node bounds from tri_min / tri_max; node_dirty (every node with all_dirty); nrm_min/max bound
    the projections of the node's triangles' unit normals (over the step: _step_normal) on the directions."""
    triangles = topo[0]
    (directions, axis_order, roots, node_min, node_max, children, leaf_prim, node_dirty, tri_min, tri_max, pt_min,
     pt_max, nrm_min, nrm_max, node_patch, stack, border_start, border_vert) = tree[:18]
    h = directions.shape[0]
    refit_range(node_min, node_max, children, leaf_prim, tri_min, tri_max, 0, node_min.shape[0])
    for node in range(node_min.shape[0] - 1, -1, -1):
        t = leaf_prim[node]
        if t >= 0:
            dirty = moved[triangles[t, 0]] | moved[triangles[t, 1]] | moved[triangles[t, 2]]
            node_dirty[node] = 1 if all_dirty else dirty
            for i in range(h):
                nrm_min[node, i] = np.inf
                nrm_max[node, i] = -np.inf
            for j in range(3):   # the normal over the step lies in the cone of these three
                nx, ny, nz = _step_normal(xs, xe, triangles, t, j)
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
def _step_normal(xs, xe, triangles, t, j):
    """The normal of triangle t moving linearly xs -> xe is n(u) = (1-u)^2 n0 + 2u(1-u) nm + u^2 n1
    (Bernstein form, u in [0, 1]): a positive combination of n0 (j = 0, at xs), nm (j = 1) and n1
    (j = 2, at xe), so every normal over the step lies in the cone of these three (n0 and n1
    alone miss a triangle that turns and comes back, or turns far, within the step)."""
    if j == 0:
        return triangle_normal(xs, triangles, t)
    if j == 2:
        return triangle_normal(xe, triangles, t)
    a = triangles[t, 0]
    b = triangles[t, 1]
    c = triangles[t, 2]
    s1x = xs[b, 0] - xs[a, 0]
    s1y = xs[b, 1] - xs[a, 1]
    s1z = xs[b, 2] - xs[a, 2]
    s2x = xs[c, 0] - xs[a, 0]
    s2y = xs[c, 1] - xs[a, 1]
    s2z = xs[c, 2] - xs[a, 2]
    e1x = xe[b, 0] - xe[a, 0]
    e1y = xe[b, 1] - xe[a, 1]
    e1z = xe[b, 2] - xe[a, 2]
    e2x = xe[c, 0] - xe[a, 0]
    e2y = xe[c, 1] - xe[a, 1]
    e2z = xe[c, 2] - xe[a, 2]
    # (s1 x e2 + e1 x s2) / 2
    mx = 0.5 * (s1y * e2z - s1z * e2y + e1y * s2z - e1z * s2y)
    my = 0.5 * (s1z * e2x - s1x * e2z + e1z * s2x - e1x * s2z)
    mz = 0.5 * (s1x * e2y - s1y * e2x + e1x * s2y - e1y * s2x)
    return mx, my, mz


@njit(cache=True, _nrt=False)
def refit_cloth_tree(xs, xe, topo, tree, moved, margin):
    """Leaves bound each triangle over the step (xs and xe) inflated by `margin`; a node is dirty
    when a particle of its triangles moved since the last detection (moved[p] != 0); nrm_min/max
    bound the projections of its triangles' unit normals (over the step: _step_normal) on the directions."""
    _segment_bounds(xs, xe, tree[0], margin, tree[10], tree[11])
    _triangle_bounds(topo[0], tree[10], tree[11], tree[8], tree[9])
    _refit_nodes(xs, xe, topo, tree, moved, False)


@njit(cache=True)
def _disjoint(node_min, node_max, a, b, axis_order):
    for j in range(axis_order.shape[0]):
        i = axis_order[j]
        if node_max[a, i] < node_min[b, i] or node_max[b, i] < node_min[a, i]:
            return True
    return False


@njit(cache=True)
def _note_cull(tree, a, b):
    """Nodes a and b (a == b: one node) were culled as one flat patch: note in node_slack (tree[25])
    how far (rad) their normals may turn and keep it flat, the margin of their normal cone."""
    nrm_min = tree[12]
    nrm_max = tree[13]
    node_slack = tree[25]
    c = -1.0
    for i in range(nrm_min.shape[1]):
        c = max(c, min(nrm_min[a, i], nrm_min[b, i]), -max(nrm_max[a, i], nrm_max[b, i]))
    slack = np.arccos(FLAT_COS if a == b else UNION_COS) - np.arccos(min(c, 1.0))
    node_slack[a] = min(node_slack[a], slack)
    node_slack[b] = min(node_slack[b], slack)
    if a == b:
        tree[41][a] = 1   # no pair within it is listed (update_candidates skips it too)


@njit(cache=True, _nrt=False)
def detect(xs, xe, topo, tree, work, h, layer_depth, only_cross, cull, counters, collect=False, turn=0.0):
    """Self-traversal of the (refit) cloth tree: every pair of overlapping leaves with at least one
    dirty side is tested exactly (`test_triangle_pair`); with `cull`, a subtree that is a flat
    patch (`flat_patch`) is not tested against itself, nor two neighbouring nodes that together are one
    (`flat_union`, stages.sim.cloth_contact.cull; with room for the normals to turn by `turn` rad).
    Returns the number of contacts stored; with
    `collect`, the feature pairs are appended to the candidate lists instead and each culled node
    notes how far its normals may turn and keep it flat (`_note_cull`)."""
    (directions, axis_order, roots, node_min, node_max, children, leaf_prim, node_dirty, tri_min, tri_max, pt_min,
     pt_max, nrm_min, nrm_max, node_patch, stack, border_start, border_vert) = tree[:18]
    flat_cos = np.cos(np.arccos(FLAT_COS) - turn)
    union_cos = np.cos(np.arccos(UNION_COS) - turn)
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
            if cull and flat_patch(nrm_min, nrm_max, node_patch, a, flat_cos):
                if collect:
                    _note_cull(tree, a, a)
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
        if cull and flat_union(nrm_min, nrm_max, node_patch, border_start, border_vert, a, b, union_cos):
            if collect:
                _note_cull(tree, a, b)
            continue   # neighbouring nodes of one garment that together are a flat patch
        la = leaf_prim[a] >= 0
        lb = leaf_prim[b] >= 0
        if la and lb:
            n = test_triangle_pair(xs, xe, leaf_prim[a], leaf_prim[b], topo, tree, pt_min, pt_max, h, layer_depth,
                                   only_cross, work, n, counters, collect, False)
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
# candidate lists: the tree search once for several steps, only the exact tests every step.
# tree[18:25] = (cand_vf (Cv, 2) (particle, triangle), cand_ee (Ce, 2) (edge, edge), cand_n (4,)
# i8 (VF count, EE count, overflowed, state: 0 invalid, 1 valid, 2 valid with the build's bounds in
# pt_min ..., detections since the build, builds left without culling: YOUNG_LIST), cand_f (2,) f8
# (margin, motion built with), box_lo / box_hi (N, 4) each particle's box
# at the build (box_lo[:, 3]: how far it may move from it), nrm_ref (T, 4) unit normals at the build
# and the cosine of how far each may turn, node_slack (n,) f8 the culled nodes' turn margins);
# tree[31:42]: the in-place updates' arrays (stages.sim.cloth_contact.local); tree[42]: pdiag
# (stages.sim.cloth_contact.narrow); tree[43]: the exclusion zones (ClothContact.exclude)

@njit(cache=True, _nrt=False)
def build_candidates(xs, xe, topo, tree, work, margin, motion, rotation, cull, counters):
    """Candidate lists for every step while each particle stays within `motion` (m) of the box it
    spans from xs to xe, and each triangle's normal close enough to its normal at xe to keep every
    culled patch it is in flat (at most `rotation` rad; `candidates_valid`): the tree search over
    those boxes widened by margin + motion collects every feature pair whose bounds overlap there,
    a superset of what it would test at any such step."""
    triangles = topo[0]
    directions = tree[0]
    pt_min = tree[10]
    pt_max = tree[11]
    cand_n = tree[20]
    cand_f = tree[21]
    box_lo = tree[22]
    box_hi = tree[23]
    nrm_ref = tree[24]
    for p in range(xs.shape[0]):
        particle_box(xs, xe, p, motion, box_lo, box_hi)
        box_bounds(p, directions, margin, box_lo, box_hi, pt_min, pt_max)
    _triangle_bounds(triangles, pt_min, pt_max, tree[8], tree[9])
    _refit_nodes(xs, xe, topo, tree, work[0], True)
    for t in range(triangles.shape[0]):
        nx, ny, nz = triangle_normal(xe, triangles, t)
        ln = np.sqrt(nx * nx + ny * ny + nz * nz)
        ln = 1.0 / ln if ln > 0.0 else 0.0   # degenerate: its nodes are not flat (no limit below)
        nrm_ref[t, 0] = nx * ln
        nrm_ref[t, 1] = ny * ln
        nrm_ref[t, 2] = nz * ln
    cand_n[0] = 0
    cand_n[1] = 0
    cand_n[2] = 0
    node_slack = tree[25]
    children = tree[5]
    leaf_prim = tree[6]
    node_slack[:] = np.inf
    tree[41][:] = 0
    # culled only with room to turn (MIN_TURN), else a list would last a step
    detect(xs, xe, topo, tree, work, 0.0, 0.0, False, cull, counters, True, MIN_TURN)
    # a triangle may turn as far as the tightest culled node above it allows (at most `rotation`);
    # nrm_ref[:, 3] the cosine of that, -2 under no culled node (no limit)
    for node in range(children.shape[0]):   # parents before children
        if leaf_prim[node] >= 0:
            t = leaf_prim[node]
            turn = min(node_slack[node], rotation)
            nrm_ref[t, 3] = np.cos(turn) if node_slack[node] < np.inf else -2.0
            continue
        for j in range(2):
            ch = children[node, j]
            node_slack[ch] = min(node_slack[ch], node_slack[node])
    bld_min = tree[37]   # the lists' bounds, for update_candidates (narrow() reuses pt_min)
    bld_max = tree[38]
    for p in range(pt_min.shape[0]):
        for i in range(pt_min.shape[1]):
            bld_min[p, i] = pt_min[p, i]
            bld_max[p, i] = pt_max[p, i]
    cand_n[3] = 2   # valid, the bounds now the build's
    cand_n[4] = 0
    cand_f[0] = margin
    cand_f[1] = motion
    counters[N_BUILDS] += 1
    counters[N_CAND_OVERFLOW] += cand_n[2]


@njit(cache=True, _nrt=False)
def candidates_valid(xs, xe, topo, tree, work, margin, motion, rotation, counters):
    """The candidate lists cover the step xs -> xe: built for this margin and motion, every particle
    within its motion radius (box_lo[:, 3]) of its box at the build (at xs and at xe; its straight
    path between them then too) and every triangle's normal within its allowed turn of its normal
    at the build (nrm_ref[:, 3]: the cosine; the build's culled patches then stay flat). Checked for the particles moved since the last check (work[0]) and their triangles.
    When only particles out of their boxes (up to LOCAL_MAX) make them fail, those are left in
    loc_list (tree[31]) with loc_n = (count, 0) for update_candidates; else loc_n[1] = 1."""
    triangles = topo[0]
    cand_n = tree[20]
    cand_f = tree[21]
    box_lo = tree[22]
    box_hi = tree[23]
    nrm_ref = tree[24]
    loc_list = tree[31]
    loc_n = tree[32]
    loc_n[0] = 0
    loc_n[1] = 1
    if cand_n[3] == 0 or cand_f[0] != margin or cand_f[1] != motion:
        return False
    moved = work[0]
    nout = 0
    for p in range(xs.shape[0]):
        if not moved[p]:
            continue   # where it was at the last check
        m2 = box_lo[p, 3] * box_lo[p, 3]
        for xx in (xs, xe):
            d2 = 0.0
            for k in range(3):
                v = xx[p, k]
                if v < box_lo[p, k]:
                    d2 += (box_lo[p, k] - v) ** 2
                elif v > box_hi[p, k]:
                    d2 += (v - box_hi[p, k]) ** 2
            if d2 > m2:
                if nout < loc_list.shape[0]:
                    loc_list[nout] = p
                nout += 1
                break
        if nout > LOCAL_MAX:
            counters[N_INVALID_MOVE] += 1
            return False   # too many out of their boxes: a full build
    for t in range(triangles.shape[0]):
        cr = nrm_ref[t, 3]
        if cr < -1.5 or not (moved[triangles[t, 0]] | moved[triangles[t, 1]] | moved[triangles[t, 2]]):
            continue
        for j in range(3):   # the normals over the step: the cone of these three (_step_normal)
            nx, ny, nz = _step_normal(xs, xe, triangles, t, j)
            dot = nx * nrm_ref[t, 0] + ny * nrm_ref[t, 1] + nz * nrm_ref[t, 2]
            # dot < cr |n| (turned too far), without the square root
            q = cr * cr * (nx * nx + ny * ny + nz * nz)
            if (dot < 0.0 or dot * dot < q) if cr >= 0.0 else (dot < 0.0 and dot * dot > q):
                counters[N_INVALID_TURN] += 1
                if cand_n[4] < YOUNG_LIST:
                    cand_n[5] = PLAIN_BUILDS
                return False
    if nout > 0:
        counters[N_INVALID_MOVE] += 1
        loc_n[0] = nout   # a few out of their boxes: update_candidates may do
        loc_n[1] = 0
        return False
    return True


@njit(cache=True, _nrt=False)
def find_contacts(xs, xe, topo, tree, work, prm, only_cross, counters):
    """One detection over xs -> xe into the contact buffer: over the candidate lists (rebuilt when
    they no longer cover the step; updated in place when only up to LOCAL_MAX particles left their
    boxes, stages.sim.cloth_contact.local) when prm's motion margin is > 0, else by the tree search."""
    thickness, layer_depth, rounds, failsafe_rounds, cull, motion, rotation = prm
    margin = 0.5 * max(thickness, layer_depth)
    if motion > 0.0:
        # the bounds narrow() keeps are stale after a build or a tree search: then all afresh
        full = tree[20][3] == 0 or tree[20][3] == 2
        if not candidates_valid(xs, xe, topo, tree, work, margin, motion, rotation, counters):
            c0 = cycles()
            if not (tree[32][1] == 0 and tree[20][2] == 0
                    and update_candidates(xs, xe, topo, tree, work, margin, motion, counters)):
                plain = tree[20][5] > 0
                if plain:
                    tree[20][5] -= 1
                build_candidates(xs, xe, topo, tree, work, margin, motion, rotation, cull and not plain, counters)
                full = True
            else:
                counters[N_LOCAL] += 1
            counters[N_CYC_BUILD] += cycles() - c0
        if tree[20][2] == 0:
            tree[20][3] = 1
            tree[20][4] += 1
            return narrow(xs, xe, topo, tree, work, margin, thickness, layer_depth, only_cross, counters, full)
        tree[20][3] = 0   # overflowed: the tree search this time, a new build next time
    refit_cloth_tree(xs, xe, topo, tree, work[0], margin)
    return detect(xs, xe, topo, tree, work, thickness, layer_depth, only_cross, cull, counters)


# ---------------------------------------------------------------------------------------------
# response, fail-safe, entry

@njit(cache=True, _nrt=False)
def collide_cloth(x_prev, x, inv_mass, topo, tree, work, prm, counters, keep=None):
    """Cloth x cloth collision over one step (self and between garments); corrects x in place.

    x_prev (N, 3) f8: positions at the start of the step (read only; must be free of crossings).
    x      (N, 3) f8: predicted positions at its end; corrected so no particle passes through a
           cloth triangle and no cloth edge through a cloth edge on the way x_prev -> x.
    inv_mass (N,) f8: 0 = pinned, never moved here.
    topo, tree, work: tuples of arrays from `ClothContact.kernel_args()` (stages.sim.cloth_contact.setup).
    prm: (thickness m, layer_depth m, rounds, failsafe_rounds, cull, motion m, rotation rad): cull =
           normal-cone culling of flat patches in the self test (stages.sim.cloth_contact.cull);
           motion > 0: detection over candidate lists kept while particles stay within `motion`
           and normals within what keeps the culled patches flat (at most `rotation`) of where the
           lists were built (`find_contacts`).
    counters (N_COUNTERS,) i8: accumulated (+=), see N_* above.
    keep: None, or a kept-contact buffer (work's 7 arrays, a count (1,) i8 and a reach (1,) f8 m, see
           stages.sim.cloth_contact.response.keep_contacts): emptied, then every round's contacts
           are appended, for the sub-steps until the next call (stages.sim.step.cloth_phase). The
           detection then lists the pairs within `reach` (> thickness): those between the thickness
           and it need no response now (their constraint holds) but may close in before the next call.

    Rounds: refit the tree over x_prev -> x (or check the candidate lists), find contacts (all pairs in round 1, then only pairs
    with a particle the previous round moved), project them; stop when a round finds none or only
    pairs nearly a thickness apart (`settled`: no crossing, none closer than (1 - SETTLED) h). If the
    rounds run out, the fail-safe finds the pairs that still pass through (CROSS) and puts their
    movable particles back at x_prev, repeated until none is left: as x_prev has no crossing, the
    worst case is the whole cloth at rest, which has none.
    """
    thickness, layer_depth, rounds, failsafe_rounds, cull, motion, rotation = prm
    moved = work[0]
    corrected = work[1]
    target = PUSH_OVER * thickness
    moved[:] = 1
    corrected[:] = 0
    clean = False
    dprm = prm
    if keep is not None:
        keep[7][0] = 0
        dprm = (max(thickness, keep[8][0]), layer_depth, rounds, failsafe_rounds, cull, motion, rotation)
    for _ in range(rounds):
        dropped = counters[N_OVERFLOW]
        c0 = cycles()
        b0 = counters[N_CYC_BUILD]
        n = find_contacts(x_prev, x, topo, tree, work, dprm, False, counters)
        counters[N_CYC_DETECT] += cycles() - c0 - (counters[N_CYC_BUILD] - b0)
        if keep is not None:
            keep_contacts(work, n, keep)
        counters[N_ROUNDS] += 1
        counters[N_CONTACTS] += n
        if counters[N_OVERFLOW] == dropped and (n == 0 or settled(x, inv_mass, work, n, thickness)):
            clean = True
            break
        moved[:] = 0
        c0 = cycles()
        for _sweep in range(SWEEPS):  # coupled contacts (a particle in several) need a few sweeps
            respond(x, inv_mass, work, n, target)
        counters[N_CYC_RESPOND] += cycles() - c0
        if counters[N_OVERFLOW] != dropped:
            moved[:] = 1  # dropped contacts: look everywhere again
    c0 = cycles()
    b0 = counters[N_CYC_BUILD]
    if not clean:
        for it in range(failsafe_rounds + 1):
            dropped = counters[N_OVERFLOW]
            n = find_contacts(x_prev, x, topo, tree, work, dprm, True, counters)
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
    counters[N_CYC_FAILSAFE] += cycles() - c0 - (counters[N_CYC_BUILD] - b0)
    nc = 0
    for i in range(corrected.shape[0]):
        nc += corrected[i]
    counters[N_CORRECTED] += nc
