"""Cloth x cloth candidate lists updated in place when a few particles leave their motion boxes
(stages.sim.cloth_contact.kernels.find_contacts): instead of a full build (a tree search over every
triangle, ~10 M cycles on the shipped walk), the particles that left (`loc_list`) get new boxes,
every listed pair with one of their features is dropped, and the triangles around them are searched
against the tree alone for their pairs again.

Why the lists then still cover the step: a pair with no particle that left keeps the boxes it was
listed (or culled) with; a pair with one is searched afresh over the new boxes, without culling
(the result is a superset of what a build would list: culling only drops pairs). The tree's node
bounds are refit from the updated triangle bounds first.

Arrays: `tree` of stages.sim.cloth_contact.setup.ClothContact.kernel_args; tree[31:37] = (loc_list (L,)
int32 the particles that left, loc_n (2,) int64 (how many, 1 if a normal turned too far: a full
build), vt_start (N + 1,) int64 / vt_tri (3T,) int32 each particle's triangles, ring (T,) int32 a
work list, flag (N + T,) uint8 work flags: the particles that left, then their triangles, bld_min /
bld_max (N, h) float64 the particles' bounds the lists were made with (pt_min / pt_max of the
build: the narrow phase reuses those), parent (n,) int32 each tree node's parent (-1 at a root),
tri_leaf (T,) int32 each triangle's leaf, self_cull (n,) uint8 the nodes the build culled as one
flat patch (a pair within one is not listed, nor added here: culling is positions-free, its
normals' turn is checked as before)).
"""
from __future__ import annotations

import numpy as np
from numba import njit

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)
from stages.sim.cloth_contact.pairs import test_triangle_pair

NUMBA_CACHE_DEPENDS = ("stages.affine", "stages.geometry.kdop", "stages.sim.cloth_contact.ccd",
                       "stages.sim.cloth_contact.pairs")

STEPS_AHEAD = 8       # a particle's box is wide enough for this many steps at its speed,
MAX_MOTION_STEPS = 4  # but at most this many times the motion margin
LOCAL_MAX = 64        # more particles out of their boxes than this: a full build


@njit(cache=True)
def particle_box(xs, xe, p, motion, box_lo, box_hi):
    """Particle p's box over xs -> xe and (box_lo[p, 3]) how far it may move from it: `motion`,
    more for one moving fast now (its step x STEPS_AHEAD, at most MAX_MOTION_STEPS x motion)."""
    step2 = 0.0
    for k in range(3):
        box_lo[p, k] = min(xs[p, k], xe[p, k])
        box_hi[p, k] = max(xs[p, k], xe[p, k])
        step2 += (xe[p, k] - xs[p, k]) ** 2
    box_lo[p, 3] = max(motion, min(STEPS_AHEAD * np.sqrt(step2), MAX_MOTION_STEPS * motion))


@njit(cache=True)
def box_bounds(p, directions, margin, box_lo, box_hi, pt_min, pt_max):
    """Particle p's k-DOP over its box widened by margin + its motion radius (the build's bounds)."""
    grow = margin + box_lo[p, 3]
    for i in range(directions.shape[0]):
        lo = 0.0
        hi = 0.0
        for k in range(3):   # the box's extent along a direction: its extreme corners
            d = directions[i, k]
            if d >= 0.0:
                lo += d * box_lo[p, k]
                hi += d * box_hi[p, k]
            else:
                lo += d * box_hi[p, k]
                hi += d * box_lo[p, k]
        pt_min[p, i] = lo - grow
        pt_max[p, i] = hi + grow


@njit(cache=True, _nrt=False)
def tri_bounds(triangles, t, pt_min, pt_max, tri_min, tri_max):
    """Triangle t's bounds from its corners' (as stages.geometry.kdop.triangle_bounds, exactly:
    min(p - m, q - m) == min(p, q) - m), 3 times fewer projections."""
    a = triangles[t, 0]
    b = triangles[t, 1]
    c = triangles[t, 2]
    for i in range(pt_min.shape[1]):
        tri_min[t, i] = min(pt_min[a, i], min(pt_min[b, i], pt_min[c, i]))
        tri_max[t, i] = max(pt_max[a, i], max(pt_max[b, i], pt_max[c, i]))


@njit(cache=True)
def _overlap(node_min, node_max, a, tri_min, tri_max, t):
    for i in range(node_min.shape[1]):
        if node_max[a, i] < tri_min[t, i] or tri_max[t, i] < node_min[a, i]:
            return False
    return True


@njit(cache=True, _nrt=False)
def update_candidates(xs, xe, topo, tree, work, margin, motion, counters):
    """The lists after the particles in loc_list (tree[31], count tree[32][0]) left their boxes:
    new boxes for them, their pairs dropped and searched again (module doc). Returns False if the
    stack ran out (the caller then builds the lists afresh)."""
    triangles = topo[0]
    edges = topo[1]
    directions = tree[0]
    roots = tree[2]
    node_min = tree[3]
    node_max = tree[4]
    children = tree[5]
    leaf_prim = tree[6]
    tri_min = tree[8]
    tri_max = tree[9]
    stack = tree[15]
    cand_vf = tree[18]
    cand_ee = tree[19]
    cand_n = tree[20]
    box_lo = tree[22]
    box_hi = tree[23]
    loc_list = tree[31]
    loc_n = tree[32]
    vt_start = tree[33]
    vt_tri = tree[34]
    ring = tree[35]
    flag = tree[36]
    bld_min = tree[37]
    bld_max = tree[38]
    parent = tree[39]
    tri_leaf = tree[40]
    self_cull = tree[41]
    n = xs.shape[0]
    for j in range(loc_n[0]):
        p = loc_list[j]
        flag[p] = 1
        particle_box(xs, xe, p, motion, box_lo, box_hi)
        box_bounds(p, directions, margin, box_lo, box_hi, bld_min, bld_max)
    nr = 0
    for j in range(loc_n[0]):
        p = loc_list[j]
        for k in range(vt_start[p], vt_start[p + 1]):
            t = vt_tri[k]
            if not flag[n + t]:
                flag[n + t] = 1
                ring[nr] = t
                nr += 1
                tri_bounds(triangles, t, bld_min, bld_max, tri_min, tri_max)
    h = node_min.shape[1]
    for j in range(nr):   # refit the leaves' ancestors (all leaves first: see the walk's merge)
        t = ring[j]
        node = tri_leaf[t]
        for i in range(h):
            node_min[node, i] = tri_min[t, i]
            node_max[node, i] = tri_max[t, i]
    for j in range(nr):
        node = parent[tri_leaf[ring[j]]]
        while node >= 0:
            l = children[node, 0]
            r = children[node, 1]
            for i in range(h):
                node_min[node, i] = min(node_min[l, i], node_min[r, i])
                node_max[node, i] = max(node_max[l, i], node_max[r, i])
            node = parent[node]
    # drop the pairs with a flagged particle (kept in order)
    m = 0
    for k in range(cand_n[0]):
        p = cand_vf[k, 0]
        t = cand_vf[k, 1]
        if flag[p] | flag[triangles[t, 0]] | flag[triangles[t, 1]] | flag[triangles[t, 2]]:
            continue
        cand_vf[m, 0] = p
        cand_vf[m, 1] = t
        m += 1
    cand_n[0] = m
    m = 0
    for k in range(cand_n[1]):
        e = cand_ee[k, 0]
        f = cand_ee[k, 1]
        if flag[edges[e, 0]] | flag[edges[e, 1]] | flag[edges[f, 0]] | flag[edges[f, 1]]:
            continue
        cand_ee[m, 0] = e
        cand_ee[m, 1] = f
        m += 1
    cand_n[1] = m
    # each triangle around them against every tree; a pair of two such triangles once
    ok = True
    cap = stack.shape[0]
    for j in range(nr):
        t = ring[j]
        skip = -1   # the flat patch the build culled t in: no pair within it is listed
        node = tri_leaf[t]
        while node >= 0:
            if self_cull[node]:
                skip = node
            node = parent[node]
        top = 0
        for g in range(roots.shape[0] - 1):
            stack[top, 0] = roots[g]
            top += 1
        while top > 0:
            top -= 1
            a = stack[top, 0]
            if a == skip or not _overlap(node_min, node_max, a, tri_min, tri_max, t):
                continue
            t2 = leaf_prim[a]
            if t2 >= 0:
                if t2 != t and not (flag[n + t2] and t2 < t):
                    # the tree search's collection (stages.sim.cloth_contact.pairs), for the new pairs only
                    test_triangle_pair(xs, xe, t, t2, topo, tree, bld_min, bld_max, 0.0, 0.0, False, work, 0,
                                       counters, True, True)
                continue
            if top + 2 > cap:
                ok = False
                break
            stack[top, 0] = children[a, 1]
            stack[top + 1, 0] = children[a, 0]
            top += 2
    for j in range(loc_n[0]):
        flag[loc_list[j]] = 0
    for j in range(nr):
        flag[n + ring[j]] = 0
    return ok
