"""Cloth x cloth narrow phase over the candidate lists (stages.sim.cloth_contact.kernels builds them):
every listed vertex-face and edge-edge pair with a particle moved since the last detection is
filtered by its features' swept bounds and then tested exactly (stages.sim.cloth_contact.pairs).

The filter, cheapest first (each conservative; together they pass the pairs the tree search's own
filter passes, and a few more at float32's rounding):
  1. float32 axis-aligned boxes, one 32-byte row per particle, edge and triangle (pbox / ebox /
     tbox (., 8): min x y z, 0, max x y z, 0), rounded outwards: one row per feature and a
     short compare, where the k-DOP filter gathered the rows of 3-4 particles (measured on the
     shipped walk, 2026-11-24: 20 k candidates per detection, 730 k -> ~120 k cycles);
  2. the k-DOP's other directions (the 18-DOP's 6 diagonals; the axes are step 1's) in float32,
     rounded outwards, one 64-byte row per particle (pdiag: 8 lanes of minima, 8 of maxima, the
     unused lanes 0, which separate nothing): the float64 rows (pt_min / pt_max, 2 x 72 bytes a
     particle) cost 3-4 cache lines per particle gathered, and their writes a third of the bounds;
  3. for edge pairs, the conservative separation of stages.sim.cloth_contact.ccd (ee_apart, with each
     particle's move over the step computed once per detection, p_move; it drops about half of the
     edge pairs left, while vf_apart dropped none of the vertex-face pairs on the shipped walk: the
     VF test itself is cheaper than the edge-edge one).

Arrays: `tree` of stages.sim.cloth_contact.setup.ClothContact.kernel_args; tree[26:31] = (pbox (N, 8) f4,
ebox (E, 8) f4, tbox (T, 8) f4, p_move (N,) f8, feat_moved (E + T,) u1: the edges' then the triangles'
moved flags (the rounds after the first test only pairs with a moved feature: compact flags, whose
reads stay in the L1 cache)); tree[42] = pdiag (N, 2 D) f4 (D = DIAG_LANES lanes per half).
"""
from __future__ import annotations

import numpy as np
from numba import njit

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)
from stages.sim.cloth_contact.ccd import APART_SLACK, segment_distance
from stages.sim.cloth_contact.pairs import test_ee_pair, test_vf_pair

NUMBA_CACHE_DEPENDS = ("stages.affine", "stages.sim.cloth_contact.ccd", "stages.sim.cloth_contact.pairs")

ROUND32 = 1e-6   # relative widening of the float32 boxes: float32 rounds by at most 6e-8 of the value
DIAG_LANES = 8   # lanes per half of a pdiag row (k-DOP directions beyond the 3 axes, padded with 0)


@njit(cache=True)
def _lo32(v):
    """A float32 no larger than v."""
    return np.float32(v - (1e-12 + abs(v) * ROUND32))


@njit(cache=True)
def _hi32(v):
    """A float32 no smaller than v."""
    return np.float32(v + (1e-12 + abs(v) * ROUND32))


@njit(cache=True, _nrt=False)
def _particle_bounds(xs, xe, p, directions, margin, pdiag, pbox, p_move):
    """Particle p's bounds over its step xs -> xe inflated by `margin`: its float32 box (pbox), its
    k-DOP's other directions in float32 (pdiag: minima in lanes 0.., maxima in lanes D..; both
    rounded outwards) and how far it moves (p_move). The 6 diagonals of the 18-DOP
    (stages.geometry.kdop: (x+y, x+z, y+z, x-y, x-z, y-z) / sqrt 2) are projected without the
    multiplications by 0 and 1; other direction sets by their dot products."""
    ax = xs[p, 0]
    ay = xs[p, 1]
    az = xs[p, 2]
    bx = xe[p, 0]
    by = xe[p, 1]
    bz = xe[p, 2]
    h = directions.shape[0]
    hp = pdiag.shape[1] // 2
    if h == 9:
        s = directions[3, 0]
        for i in range(6):
            if i == 0:
                u = s * (ax + ay)
                v = s * (bx + by)
            elif i == 1:
                u = s * (ax + az)
                v = s * (bx + bz)
            elif i == 2:
                u = s * (ay + az)
                v = s * (by + bz)
            elif i == 3:
                u = s * (ax - ay)
                v = s * (bx - by)
            elif i == 4:
                u = s * (ax - az)
                v = s * (bx - bz)
            else:
                u = s * (ay - az)
                v = s * (by - bz)
            pdiag[p, i] = _lo32(min(u, v) - margin)
            pdiag[p, hp + i] = _hi32(max(u, v) + margin)
    else:
        for i in range(3, h):
            u = ax * directions[i, 0] + ay * directions[i, 1] + az * directions[i, 2]
            v = bx * directions[i, 0] + by * directions[i, 1] + bz * directions[i, 2]
            pdiag[p, i - 3] = _lo32(min(u, v) - margin)
            pdiag[p, hp + i - 3] = _hi32(max(u, v) + margin)
    pbox[p, 0] = _lo32(min(ax, bx) - margin)
    pbox[p, 1] = _lo32(min(ay, by) - margin)
    pbox[p, 2] = _lo32(min(az, bz) - margin)
    pbox[p, 4] = _hi32(max(ax, bx) + margin)
    pbox[p, 5] = _hi32(max(ay, by) + margin)
    pbox[p, 6] = _hi32(max(az, bz) + margin)
    p_move[p] = np.sqrt((bx - ax) ** 2 + (by - ay) ** 2 + (bz - az) ** 2)


@njit(cache=True, _nrt=False)
def feature_bounds(xs, xe, topo, tree, moved, margin, full):
    """The filter's bounds over the step xs -> xe: every particle's (full) or only the moved ones'
    (the others' are the last call's: same xs, and xe where it was), then the edges' and triangles'
    boxes from their particles', and their moved flags (feat_moved)."""
    triangles = topo[0]
    edges = topo[1]
    directions = tree[0]
    pdiag = tree[42]
    pbox = tree[26]
    ebox = tree[27]
    tbox = tree[28]
    p_move = tree[29]
    feat_moved = tree[30]
    ne = edges.shape[0]
    for p in range(xs.shape[0]):
        m = moved[p]
        if full or m:
            _particle_bounds(xs, xe, p, directions, margin, pdiag, pbox, p_move)
    for e in range(edges.shape[0]):
        a = edges[e, 0]
        b = edges[e, 1]
        m = moved[a] | moved[b]
        feat_moved[e] = m
        if full or m:
            for k in range(3):
                ebox[e, k] = min(pbox[a, k], pbox[b, k])
                ebox[e, 4 + k] = max(pbox[a, 4 + k], pbox[b, 4 + k])
    for t in range(triangles.shape[0]):
        a = triangles[t, 0]
        b = triangles[t, 1]
        c = triangles[t, 2]
        m = moved[a] | moved[b] | moved[c]
        feat_moved[ne + t] = m
        if full or m:
            for k in range(3):
                tbox[t, k] = min(pbox[a, k], min(pbox[b, k], pbox[c, k]))
                tbox[t, 4 + k] = max(pbox[a, 4 + k], max(pbox[b, 4 + k], pbox[c, 4 + k]))


@njit(cache=True)
def _boxes_apart(b1, i, b2, j):
    return (b1[i, 4] < b2[j, 0] or b2[j, 4] < b1[i, 0] or b1[i, 5] < b2[j, 1] or b2[j, 5] < b1[i, 1]
            or b1[i, 6] < b2[j, 2] or b2[j, 6] < b1[i, 2])


@njit(cache=True)
def _point_off_diag(pdiag, p, a, b, c):
    """Particle p's and triangle abc's pdiag bounds are disjoint along a direction (the triangle's
    from its corners')."""
    hp = pdiag.shape[1] // 2
    for i in range(hp):
        if pdiag[p, hp + i] < min(pdiag[a, i], min(pdiag[b, i], pdiag[c, i])):
            return True
        if max(pdiag[a, hp + i], max(pdiag[b, hp + i], pdiag[c, hp + i])) < pdiag[p, i]:
            return True
    return False


@njit(cache=True)
def _edges_apart_diag(pdiag, a, b, c, d):
    """Edges ab's and cd's pdiag bounds (their particles' unions) are disjoint along a direction."""
    hp = pdiag.shape[1] // 2
    for i in range(hp):
        if max(pdiag[a, hp + i], pdiag[b, hp + i]) < min(pdiag[c, i], pdiag[d, i]):
            return True
        if max(pdiag[c, hp + i], pdiag[d, hp + i]) < min(pdiag[a, i], pdiag[b, i]):
            return True
    return False


@njit(cache=True)
def ee_apart_moves(xs, p_move, a, b, c, d, reach):
    """stages.sim.cloth_contact.ccd.ee_apart with the particles' moves precomputed (p_move)."""
    room = reach + APART_SLACK
    d0 = segment_distance(xs, a, b, c, d)
    if d0 <= room:
        return False
    return d0 > room + max(p_move[a], p_move[b]) + max(p_move[c], p_move[d])


@njit(cache=True, _nrt=False)
def narrow(xs, xe, topo, tree, work, margin, h, layer_depth, only_cross, counters, full):
    """The tree search's tests over the candidate lists: every candidate with a particle moved since
    the last detection (work[0]) whose features' bounds over xs -> xe, inflated by `margin`, overlap
    (the same filter as the tree search's) and that may come within max(h, layer_depth) is tested
    exactly. full: recompute every particle's bounds (else only the moved ones'). Returns the
    number of contacts stored."""
    triangles = topo[0]
    edges = topo[1]
    cand_vf = tree[18]
    cand_ee = tree[19]
    cand_n = tree[20]
    pbox = tree[26]
    ebox = tree[27]
    tbox = tree[28]
    p_move = tree[29]
    feat_moved = tree[30]
    pdiag = tree[42]
    moved = work[0]
    ne = edges.shape[0]
    feature_bounds(xs, xe, topo, tree, moved, margin, full)
    reach = max(h, layer_depth)
    n = 0
    for k in range(cand_n[0]):
        p = cand_vf[k, 0]
        t = cand_vf[k, 1]
        if not (moved[p] or feat_moved[ne + t]):
            continue   # neither moved
        if _boxes_apart(pbox, p, tbox, t):
            continue
        a = triangles[t, 0]
        b = triangles[t, 1]
        c = triangles[t, 2]
        if _point_off_diag(pdiag, p, a, b, c):
            continue   # (no vf_apart: on the shipped walk it dropped none of the pairs left here)
        n = test_vf_pair(xs, xe, p, t, topo, h, layer_depth, only_cross, work, n, counters)
    for k in range(cand_n[1]):
        e = cand_ee[k, 0]
        f = cand_ee[k, 1]
        if not (feat_moved[e] or feat_moved[f]):
            continue
        if _boxes_apart(ebox, e, ebox, f):
            continue
        a = edges[e, 0]
        b = edges[e, 1]
        c = edges[f, 0]
        d = edges[f, 1]
        if _edges_apart_diag(pdiag, a, b, c, d) or ee_apart_moves(xs, p_move, a, b, c, d, reach):
            continue
        n = test_ee_pair(xs, xe, e, f, topo, h, layer_depth, only_cross, work, n, counters)
    return n
