"""Cloth x cloth collision by conservative displacement bounds (the `offset` phase; after Offset
Geometric Contact, Chen et al. 2025): no continuous collision detection, one proximity query
(stages.sim.cloth_contact.proximity) reused over as many calls as the bounds hold.

Why it keeps every crossing out: the query runs at positions x_q free of crossings and lists every
vertex-facet and edge-edge pair sharing no vertex closer than the radius r, with its distance d. A
cloth edge can only come to cross a triangle it shares no vertex with through such a pair touching
(d = 0). Along the straight path x_q -> x, a point of a feature moves by a convex combination of
its vertices' displacements D_i, so two features' distance stays above d - max |D_a - D_b| over
their vertices a, b. Hence x is as free of crossings as x_q when
  - every listed pair has max |D_a - D_b| < d, and
  - every vertex has |D_i - c| < r / 2 for one common vector c (an unlisted pair is at least r apart
    and |D_a - D_b| <= |D_a - c| + |D_b - c|; c follows the pinned particles, `_spread`).
Each call checks that; where it fails it moves the vertex back towards x_q until |D_i - c| is at
most its bound gamma * dmin_i (gamma < 1/2; dmin_i: its nearest listed pair, r without one), under
which no pair of it can fail (OGC's bound). Only a vertex over its bound needs its pairs checked, so
a call costs O(N) plus the few such vertices' pairs; the query reruns when a vertex was held back
or one has used RENEW of its r / 2.

The response: every listed pair that may now be closer than the thickness is measured and pushed
apart to it along its closest points (PBD by inverse mass); the correction is not turned into
velocity beyond dropping the approach (stages.sim.cloth_contact.response.contact_velocity).

State tuple (`OffsetContact.state()`; its length, 5, tells the step loop which phase it is):
    (x_q, topo, work, prm, counters)
    topo = (tris (T, 3) i4, edges (E, 2) i4, tri_edges (T, 3) i4, tri_owns (T,) u1, cinv (N,) f8)
    work = (box (T, 6), node_box (2T - 1, 6), children (2T - 1, 2) i4, leaf_prim (2T - 1,) i4 (the
            query's tree: stages.sim.cloth_contact.proximity), kind (C,) i1, idx (C, 4) i4,
            dist (C,) f8, dmin (N,), vstart (N + 1,) i8, vpair (4 C,) i4, m (N,), flag (N,) u1,
            x_before (N, 3), n_pairs (1,) i8 (listed pairs), radius (1,) f8 (the last query's: below
            prm's where the pair list would have overflowed), corrected (N,) u1, stack (4T + 6, 2) i4)
    prm = (radius m, thickness m, gamma, every)
"""
from __future__ import annotations

import numpy as np
from numba import njit

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)
from stages.sim.cloth_contact.proximity import KIND_VF, point_triangle, query_pairs, segment_segment, triangle_tree
from stages.sim.cloth_contact.response import contact_velocity
from stages.sim.simd import cycles

NUMBA_CACHE_DEPENDS = ("stages.sim.cloth_contact.proximity", "stages.sim.cloth_contact.response", "stages.sim.simd")

GAMMA = 0.45          # a vertex held back keeps |D - c| <= GAMMA * its nearest pair's distance (< 1/2)
RENEW = 0.6           # the query reruns once a vertex has used this share of r / 2
HELD_REQUERY = 0.01   # ... or once a call held back more than this share of the particles (held ones lose motion)
SAFE = 0.98           # strict inequalities kept with this margin (rounding)
MIN_GAP = 1e-5        # m: pairs are kept this much apart beyond the proof (the recording is float32)
MAX_PASSES = 16       # passes over the vertices over their bounds (each settles most of the rest)
SWEEPS = 2            # Gauss-Seidel sweeps of the response
MOVE_BOUND = 3.0      # no particle of a pushed pair moves farther than this many times the pair's depth

# counters
O_QUERIES = 0
O_PAIRS = 1           # pairs listed, summed over the queries
O_HELD = 2            # vertices moved back to their bound
O_CHECKED = 3         # pairs checked against their vertices' displacements
O_PUSHED = 4          # pairs pushed apart
O_UNPROVEN = 5        # pairs left unproven (only pinned particles over their bounds)
O_OVERFLOW = 6        # queries rerun with a smaller radius (the pair list would have overflowed)
O_CYC_QUERY = 7
O_CYC_RESPOND = 8
O_CYC_CHECK = 9
O_CALLS = 10
N_OFFSET_COUNTERS = 11


@njit(cache=True, _nrt=False)
def query(x, og):
    """The proximity query at x (free of crossings): x_q = x, the pair list, each vertex's dmin and
    the vertex -> pairs table."""
    xq, topo, work, prm, counters = og
    tris, edges, tri_edges, tri_owns, cinv = topo
    box, node_box, children, leaf_prim, kind, idx, dist, dmin, vstart, vpair, m, flag, x_before, n_pairs, rq, _, \
        stack = work
    radius = prm[0]
    t0 = cycles()
    while True:
        n = query_pairs(x, tris, edges, tri_edges, tri_owns, radius, box, children, leaf_prim, node_box, stack, kind,
                        idx, dist, dmin)
        if n <= kind.shape[0]:
            break
        radius *= 0.7       # more pairs than the list holds: a smaller radius for this query
        counters[O_OVERFLOW] += 1
    rq[0] = radius
    n_pairs[0] = n
    for i in range(x.shape[0]):
        xq[i, 0] = x[i, 0]
        xq[i, 1] = x[i, 1]
        xq[i, 2] = x[i, 2]
    # vertex -> pairs (CSR)
    nv = x.shape[0]
    for i in range(nv + 1):
        vstart[i] = 0
    for p in range(n):
        for k in range(4):
            vstart[idx[p, k] + 1] += 1
    for i in range(nv):
        vstart[i + 1] += vstart[i]
    for p in range(n):
        for k in range(4):
            v = idx[p, k]
            vpair[vstart[v]] = p
            vstart[v] += 1
    for i in range(nv, 0, -1):
        vstart[i] = vstart[i - 1]
    vstart[0] = 0
    counters[O_QUERIES] += 1
    counters[O_PAIRS] += n
    counters[O_CYC_QUERY] += cycles() - t0


@njit(cache=True, _nrt=False, inline="always")
def _closest(x, kind, idx, p):
    """(dx, dy, dz, w0, w1, w2, w3) for pair p at positions x: the vector from the second feature's
    closest point to the first's, and the four particles' weights (sum w_k x_k = that vector)."""
    i0, i1, i2, i3 = idx[p, 0], idx[p, 1], idx[p, 2], idx[p, 3]
    if kind[p] == KIND_VF:
        _, wa, wb, wc = point_triangle(x[i0, 0], x[i0, 1], x[i0, 2], x, i1, i2, i3)
        w0, w1, w2, w3 = 1.0, -wa, -wb, -wc
    else:
        _, s, u = segment_segment(x, i0, i1, i2, i3)
        w0, w1, w2, w3 = 1.0 - s, s, u - 1.0, -u
    dx = w0 * x[i0, 0] + w1 * x[i1, 0] + w2 * x[i2, 0] + w3 * x[i3, 0]
    dy = w0 * x[i0, 1] + w1 * x[i1, 1] + w2 * x[i2, 1] + w3 * x[i3, 1]
    dz = w0 * x[i0, 2] + w1 * x[i1, 2] + w2 * x[i2, 2] + w3 * x[i3, 2]
    return dx, dy, dz, w0, w1, w2, w3


@njit(cache=True, _nrt=False, inline="always")
def _push(x, k, s, nx, ny, nz):
    x[k, 0] += s * nx
    x[k, 1] += s * ny
    x[k, 2] += s * nz


@njit(cache=True, _nrt=False)
def respond_pairs(x, xq, cinv, kind, idx, dist, n, m, target, counters):
    """Push every listed pair closer than `target` apart to it (Gauss-Seidel, SWEEPS), skipping pairs
    whose query distance minus twice their vertices' largest |D - c| (m) is already past it."""
    for _ in range(SWEEPS):
        for p in range(n):
            i0, i1, i2, i3 = idx[p, 0], idx[p, 1], idx[p, 2], idx[p, 3]
            mm = max(max(m[i0], m[i1]), max(m[i2], m[i3]))
            if dist[p] - 2.0 * mm >= target:
                continue
            dx, dy, dz, w0, w1, w2, w3 = _closest(x, kind, idx, p)
            d = np.sqrt(dx * dx + dy * dy + dz * dz)
            if d >= target:
                continue
            if d < 1e-9 * target:   # touching: the side the pair had at the query
                dx, dy, dz, _, _, _, _ = _closest(xq, kind, idx, p)
                d = np.sqrt(dx * dx + dy * dy + dz * dz)
                if d == 0.0:
                    continue
                depth = target
            else:
                depth = target - d
            nx, ny, nz = dx / d, dy / d, dz / d
            den = w0 * w0 * cinv[i0] + w1 * w1 * cinv[i1] + w2 * w2 * cinv[i2] + w3 * w3 * cinv[i3]
            if den <= 0.0:
                continue
            lam = depth / den
            big = max(max(abs(w0) * cinv[i0], abs(w1) * cinv[i1]), max(abs(w2) * cinv[i2], abs(w3) * cinv[i3])) * lam
            if big > MOVE_BOUND * depth:
                lam *= MOVE_BOUND * depth / big
            _push(x, i0, w0 * cinv[i0] * lam, nx, ny, nz)
            _push(x, i1, w1 * cinv[i1] * lam, nx, ny, nz)
            _push(x, i2, w2 * cinv[i2] * lam, nx, ny, nz)
            _push(x, i3, w3 * cinv[i3] * lam, nx, ny, nz)
            counters[O_PUSHED] += 1


@njit(cache=True, _nrt=False, inline="always")
def _pair_ok(x, xq, idx, kind, p, dist):
    """max |D_a - D_b| over the pair's two features' vertices < its query distance (SAFE, MIN_GAP)."""
    lim = SAFE * dist[p] - MIN_GAP
    if lim <= 0.0:
        return False
    lim2 = lim * lim
    na = 1 if kind[p] == KIND_VF else 2
    for a in range(na):
        ia = idx[p, a]
        for b in range(na, 4):
            ib = idx[p, b]
            ddx = (x[ia, 0] - xq[ia, 0]) - (x[ib, 0] - xq[ib, 0])
            ddy = (x[ia, 1] - xq[ia, 1]) - (x[ib, 1] - xq[ib, 1])
            ddz = (x[ia, 2] - xq[ia, 2]) - (x[ib, 2] - xq[ib, 2])
            if ddx * ddx + ddy * ddy + ddz * ddz >= lim2:
                return False
    return True


@njit(cache=True, _nrt=False, inline="always")
def _spread(x, xq, cinv, m):
    """c and m_i = |D_i - c| for every vertex; returns c and max m. c: the centre of the box of the
    pinned particles' displacements (they cannot be held back: this keeps them nearest their bounds;
    attached ones move with the body, as the cloth around them), or of every particle's without any."""
    lo0 = lo1 = lo2 = np.inf
    hi0 = hi1 = hi2 = -np.inf
    for pass_ in range(2):
        for i in range(x.shape[0]):
            if pass_ == 0 and cinv[i] > 0.0:
                continue
            d0 = x[i, 0] - xq[i, 0]
            d1 = x[i, 1] - xq[i, 1]
            d2 = x[i, 2] - xq[i, 2]
            lo0, hi0 = min(lo0, d0), max(hi0, d0)
            lo1, hi1 = min(lo1, d1), max(hi1, d1)
            lo2, hi2 = min(lo2, d2), max(hi2, d2)
        if lo0 <= hi0:
            break
    c0, c1, c2 = 0.5 * (lo0 + hi0), 0.5 * (lo1 + hi1), 0.5 * (lo2 + hi2)
    mx = 0.0
    for i in range(x.shape[0]):
        d0 = x[i, 0] - xq[i, 0] - c0
        d1 = x[i, 1] - xq[i, 1] - c1
        d2 = x[i, 2] - xq[i, 2] - c2
        m[i] = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        mx = max(mx, m[i])
    return c0, c1, c2, mx


@njit(cache=True, _nrt=False, inline="always")
def _hold(x, xq, i, c0, c1, c2, m, b):
    """Move vertex i back along D_i - c until |D_i - c| = b."""
    s = b / m[i]
    x[i, 0] = xq[i, 0] + c0 + (x[i, 0] - xq[i, 0] - c0) * s
    x[i, 1] = xq[i, 1] + c1 + (x[i, 1] - xq[i, 1] - c1) * s
    x[i, 2] = xq[i, 2] + c2 + (x[i, 2] - xq[i, 2] - c2) * s
    m[i] = b


@njit(cache=True, _nrt=False, inline="always")
def _bound(gamma, d):
    """A vertex held back keeps |D - c| within this of x_q: two held features of a pair d apart stay
    (1 - 2 gamma) d + MIN_GAP apart (a pair already closer than MIN_GAP keeps its distance)."""
    return max(0.0, gamma * d - 0.5 * MIN_GAP)


@njit(cache=True, _nrt=False)
def keep_apart(x, xq, cinv, kind, idx, dist, dmin, vstart, vpair, m, flag, half, gamma, counters):
    """Make the path xq -> x provably free of new crossings (module docstring): returns the number of
    vertices held back. A failing pair whose vertices over their bounds cannot be held (pinned, or
    already following a pinned one) has its other free vertices follow that vertex (the same
    displacement: the pair then moves as one). flag (N,) u1 work array (left 0): 1 over its bound,
    3 following a pinned vertex, 2 given up."""
    c0, c1, c2, _ = _spread(x, xq, cinv, m)
    held = 0
    over = 0
    for i in range(x.shape[0]):
        b = _bound(gamma, dmin[i])
        if m[i] <= b:
            continue
        if m[i] >= SAFE * half:   # its unlisted pairs are not proven: back to its bound
            if cinv[i] > 0.0:
                _hold(x, xq, i, c0, c1, c2, m, b)
                held += 1
                continue
            counters[O_UNPROVEN] += 1
        flag[i] = 1     # over its bound: its pairs are checked
        over += 1
    changed = over > 0
    passes = 0
    while changed and passes < MAX_PASSES:
        changed = False
        passes += 1
        for i in range(x.shape[0]):
            if flag[i] != 1 and flag[i] != 3:
                continue
            for r in range(vstart[i], vstart[i + 1]):
                p = vpair[r]
                counters[O_CHECKED] += 1
                if _pair_ok(x, xq, idx, kind, p, dist):
                    continue
                fixed = False
                for k in range(4):
                    v = idx[p, k]
                    if flag[v] == 1 and cinv[v] > 0.0:
                        _hold(x, xq, v, c0, c1, c2, m, _bound(gamma, dmin[v]))
                        flag[v] = 0
                        held += 1
                        fixed = True
                if not fixed:      # over-bound vertices that cannot be held: the rest follows the farthest
                    pv = -1
                    for k in range(4):
                        v = idx[p, k]
                        if (flag[v] == 1 or flag[v] == 3) and (pv < 0 or m[v] > m[pv]):
                            pv = v
                    for k in range(4):
                        v = idx[p, k]
                        if pv >= 0 and v != pv and cinv[v] > 0.0 and flag[v] != 3:
                            x[v, 0] = xq[v, 0] + (x[pv, 0] - xq[pv, 0])
                            x[v, 1] = xq[v, 1] + (x[pv, 1] - xq[pv, 1])
                            x[v, 2] = xq[v, 2] + (x[pv, 2] - xq[pv, 2])
                            m[v] = m[pv]
                            flag[v] = 3
                            held += 1
                            fixed = True
                if fixed:
                    changed = True
                else:
                    flag[i] = 2    # pinned particles on both sides over their bounds: cannot be helped here
                    counters[O_UNPROVEN] += 1
                    break
                if flag[i] != 1 and flag[i] != 3:
                    break
    if changed:
        counters[O_UNPROVEN] += 1
    for i in range(x.shape[0]):
        flag[i] = 0
    counters[O_HELD] += held
    return held


@njit(cache=True, _nrt=False)
def offset_call(x, xp, og):
    """One call of the phase after a sub-step (stages.sim.step.cloth_phase): respond, keep the path
    from x_q free of crossings, requery when needed; the correction kept out of the velocity."""
    xq, topo, work, prm, counters = og
    tris, edges, tri_edges, tri_owns, cinv = topo
    box, node_box, children, leaf_prim, kind, idx, dist, dmin, vstart, vpair, m, flag, x_before, n_pairs, rq, corrected, \
        stack = work
    radius, thickness, gamma, every = prm
    counters[O_CALLS] += 1
    n = x.shape[0]
    for i in range(n):
        x_before[i, 0] = x[i, 0]
        x_before[i, 1] = x[i, 1]
        x_before[i, 2] = x[i, 2]
    t0 = cycles()
    _spread(x, xq, cinv, m)
    respond_pairs(x, xq, cinv, kind, idx, dist, n_pairs[0], m, thickness, counters)
    t1 = cycles()
    half = 0.5 * rq[0]
    held = keep_apart(x, xq, cinv, kind, idx, dist, dmin, vstart, vpair, m, flag, half, gamma,
                      counters)
    _, _, _, mx = _spread(x, xq, cinv, m)
    t2 = cycles()
    counters[O_CYC_RESPOND] += t1 - t0
    counters[O_CYC_CHECK] += t2 - t1
    if held > HELD_REQUERY * n or mx > RENEW * half:
        query(x, og)
    for i in range(n):
        corrected[i] = (x[i, 0] != x_before[i, 0]) or (x[i, 1] != x_before[i, 1]) or (x[i, 2] != x_before[i, 2])
    contact_velocity(x_before, x, xp, corrected)


RADIUS = 3.0          # the query radius in thicknesses: unlisted pairs stay farther than (1 - RENEW) of it,
                      # above the thickness, so every pair the response needs is listed


def offset_state(x: np.ndarray, triangles: np.ndarray, cinv: np.ndarray, thickness: float, every: int,
                 radius: float | None = None, gamma: float = GAMMA, pair_capacity: int | None = None) -> tuple:
    """The phase's state tuple (module docstring) for the cloth x (N, 3) (free of crossings: the
    first query runs here), triangles (T, 3) global ids, cinv (N,) inverse masses (0: never moved
    here), thickness m, every: sub-steps per call; radius m (default RADIUS thicknesses)."""
    from stages.checks import ContractError
    from stages.sim.cloth_contact.setup import feature_owners, mesh_edges

    x = np.ascontiguousarray(x, np.float64)
    tris = np.ascontiguousarray(triangles, np.int32)
    n, t = x.shape[0], tris.shape[0]
    r = RADIUS * thickness if radius is None else float(radius)
    if not (thickness > 0 and r > thickness / (1.0 - RENEW) and 0 < gamma < 0.5 and every >= 1):
        raise ContractError(f"offset_state: needs thickness > 0, radius > thickness / (1 - {RENEW}), 0 < gamma < 1/2, "
                            f"every >= 1; got {thickness}, {r}, {gamma}, {every}")
    edges, tri_edges, _ = mesh_edges(tris)
    owns = feature_owners(tris, tri_edges, n, edges.shape[0])
    children, leaf_prim = triangle_tree(x, tris)      # the topology of the cloth at the start, refitted per query
    nodes = children.shape[0]
    cap = pair_capacity if pair_capacity is not None else max(1024, 64 * n)
    work = (np.zeros((t, 6)), np.zeros((nodes, 6)), children, leaf_prim,
            np.zeros(cap, np.int8), np.zeros((cap, 4), np.int32), np.zeros(cap), np.zeros(n),
            np.zeros(n + 1, np.int64), np.zeros(4 * cap, np.int32), np.zeros(n), np.zeros(n, np.uint8),
            np.zeros((n, 3)), np.zeros(1, np.int64), np.array([r]), np.zeros(n, np.uint8),
            np.zeros((2 * nodes + 8, 2), np.int32))
    topo = (tris, edges, tri_edges, owns, np.ascontiguousarray(cinv, np.float64))
    og = (np.zeros((n, 3)), topo, work, (r, float(thickness), float(gamma), int(every)),
          np.zeros(N_OFFSET_COUNTERS, np.int64))
    query(x, og)
    return og


def offset_summary(counters: np.ndarray) -> dict:
    """The counters by name (summed over the calls)."""
    names = ("queries", "pairs", "held", "checked", "pushed", "unproven", "overflow", "cycles_query",
             "cycles_respond", "cycles_check", "calls")
    return {k: int(counters[i]) for i, k in enumerate(names)}
