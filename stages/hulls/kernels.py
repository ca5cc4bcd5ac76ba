"""Numba kernels of the constrained hull simplification (see simplify.py for the method).

- the LPs are solved by `stages.hulls.lp.seidel_lp3` (Seidel's randomised incremental LP).
- `collapse_rows`: the LP of one triangle collapse (for tests: compared against scipy's HiGHS).
- `simplify_kernel`: the whole greedy collapse loop over a flat face/vertex array mesh.
"""
from __future__ import annotations

import numpy as np
from numba import njit

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)
from stages.affine import triangle_cross
from stages.hulls.lp import LP_EPS, seidel_lp3, shuffled

NUMBA_CACHE_DEPENDS = ("stages.affine", "stages.hulls.lp")

BOX = 8.0            # LP box half-width, in units of the collapse region's radius
PRIO_QEM = 0
PRIO_VOLUME = 1


@njit(cache=True)
def _face_plane(verts, i0, i1, i2, out):
    """out[:3] = unit normal of triangle (i0, i1, i2), out[3] = offset; returns twice the area."""
    nx, ny, nz = triangle_cross(verts, i0, i1, i2)
    area2 = np.sqrt(nx * nx + ny * ny + nz * nz)
    if area2 > 0:
        nx /= area2
        ny /= area2
        nz /= area2
    out[0], out[1], out[2] = nx, ny, nz
    out[3] = nx * verts[i0, 0] + ny * verts[i0, 1] + nz * verts[i0, 2]
    return area2


@njit(cache=True)
def _region(t, faces, falive, rfaces, ring, es, ee):
    """Faces touching triangle t's corners (rfaces) and their boundary cycle (ring).

    Returns (n_region, k) with k = n_region - 4 ring vertices, or (-1, -1) if the region is not a
    disk bounded by a simple cycle (the collapse would make the mesh non-manifold).
    """
    a, b, c = faces[t, 0], faces[t, 1], faces[t, 2]
    nr = 0
    for f in range(faces.shape[0]):
        if not falive[f]:
            continue
        hit = False
        for e in range(3):
            q = faces[f, e]
            if q == a or q == b or q == c:
                hit = True
        if hit:
            rfaces[nr] = f
            nr += 1
    k = 0
    for ir in range(nr):
        f = rfaces[ir]
        for e in range(3):
            p = faces[f, e]
            q = faces[f, (e + 1) % 3]
            if p != a and p != b and p != c and q != a and q != b and q != c:
                es[k] = p
                ee[k] = q
                k += 1
    if k != nr - 4 or k < 3:
        return -1, -1
    # walk the boundary edges into one cycle; every vertex must start exactly one edge
    ring[0] = es[0]
    cur = ee[0]
    for i in range(1, k):
        found = -1
        for j in range(k):
            if es[j] == cur:
                if found >= 0:
                    return -1, -1
                found = j
        if found < 0:
            return -1, -1
        for q in range(i):
            if ring[q] == cur:
                return -1, -1
        ring[i] = cur
        cur = ee[found]
    if cur != ring[0]:
        return -1, -1
    return nr, k


@njit(cache=True)
def collapse_rows(t, verts, valive, faces, falive, planes, keep, keep_vertex, nr, k, rfaces, ring, vmark, stamp,
                  eps_convex, near, bound):
    """The LP of collapsing triangle t onto one new vertex v, in normalised coordinates.

    Unknown y = (v - origin) / scale. Rows (unit normals, so b is a distance in scale units):
    - convexity: v at least eps_convex behind every face outside the region that touches the ring,
      and every ring vertex w_j at least eps_convex behind each new face (v, w_i, w_i+1) (rows
      with j = i-1 or i+2 are the spoke edges' own convexity: `local`; the others are rarely binding);
    - containment: t's corners and every `keep` point near the region on or behind each new face
      (keep points that are still mesh vertices are covered by the convexity rows and skipped).
    vmark[w] == stamp must flag the ring vertices.
    "p behind the plane of (v, w_i, w_i+1)" is linear in v: ((w_i - p) x (w_i+1 - p)) . (v - p) >= 0.
    - bound (q, 4) planes n.x <= d (unit n): v must stay behind them (the caller's error bound; these
      rows are `local` False, i.e. only added when violated).
    Objective: the volume of the new faces' cone, sum_i (v - o) . ((w_i - o) x (w_i+1 - o)) / 6.
    Returns (a, b, c, origin, scale, local) with local[r] False for the non-local ring rows.
    """
    a0, b0, c0 = faces[t, 0], faces[t, 1], faces[t, 2]
    origin = (verts[a0] + verts[b0] + verts[c0]) / 3.0
    scale = 0.0
    for i in range(k + 3):
        q = faces[t, i] if i < 3 else ring[i - 3]
        d = np.sqrt((verts[q, 0] - origin[0]) ** 2 + (verts[q, 1] - origin[1]) ** 2 + (verts[q, 2] - origin[2]) ** 2)
        scale = max(scale, d)
    # keep points near the region's surface (the far ones cannot be uncovered by this collapse)
    nkeep_near = 0
    near_idx = np.empty(keep.shape[0], dtype=np.int64)
    for p in range(keep.shape[0]):
        kv = keep_vertex[p]
        if kv >= 0 and valive[kv]:
            continue  # a current vertex: a ring vertex, a corner of t (rows below) or far away
        best = -1e300
        for ir in range(nr):
            f = rfaces[ir]
            s = planes[f, 0] * keep[p, 0] + planes[f, 1] * keep[p, 1] + planes[f, 2] * keep[p, 2] - planes[f, 3]
            if s > best:
                best = s
        if best > -near:
            near_idx[nkeep_near] = p
            nkeep_near += 1
    # outside faces touching the ring
    nfaces = faces.shape[0]
    outside = np.empty(nfaces, dtype=np.int64)
    nout = 0
    for f in range(nfaces):
        if not falive[f]:
            continue
        inreg = False
        touch = False
        for e in range(3):
            q = faces[f, e]
            if q == a0 or q == b0 or q == c0:
                inreg = True
            if vmark[q] == stamp:
                touch = True
        if touch and not inreg:
            outside[nout] = f
            nout += 1
    nrows = nout + k * (k - 2) + k * (3 + nkeep_near) + bound.shape[0]
    a = np.empty((nrows, 3))
    b = np.empty(nrows)
    local = np.ones(nrows, dtype=np.bool_)
    m = 0
    for q in range(bound.shape[0]):
        a[m, 0], a[m, 1], a[m, 2] = bound[q, 0], bound[q, 1], bound[q, 2]
        b[m] = (bound[q, 3] - (bound[q, 0] * origin[0] + bound[q, 1] * origin[1] + bound[q, 2] * origin[2])) / scale
        local[m] = False
        m += 1
    for io in range(nout):
        f = outside[io]
        a[m, 0], a[m, 1], a[m, 2] = planes[f, 0], planes[f, 1], planes[f, 2]
        b[m] = (planes[f, 3] - (planes[f, 0] * origin[0] + planes[f, 1] * origin[1] + planes[f, 2] * origin[2])
                - eps_convex) / scale
        m += 1
    pt = np.empty(3)
    for i in range(k):
        wi = verts[ring[i]]
        wj = verts[ring[(i + 1) % k]]
        for kind in range(3):
            if kind == 0:
                count = k
            elif kind == 1:
                count = 3
            else:
                count = nkeep_near
            for q in range(count):
                margin = 0.0
                if kind == 0:
                    if q == i or q == (i + 1) % k:
                        continue
                    local[m] = q == (i + k - 1) % k or q == (i + 2) % k
                    pt[:] = verts[ring[q]]
                    margin = eps_convex
                elif kind == 1:
                    pt[:] = verts[faces[t, q]]
                else:
                    pt[:] = keep[near_idx[q]]
                ux, uy, uz = wi[0] - pt[0], wi[1] - pt[1], wi[2] - pt[2]
                vx, vy, vz = wj[0] - pt[0], wj[1] - pt[1], wj[2] - pt[2]
                gx = uy * vz - uz * vy
                gy = uz * vx - ux * vz
                gz = ux * vy - uy * vx
                ng = np.sqrt(gx * gx + gy * gy + gz * gz)
                if ng <= 1e-9 * np.sqrt((ux * ux + uy * uy + uz * uz) * (vx * vx + vy * vy + vz * vz)):
                    continue  # p (nearly) on the ring edge's line: on the new plane whatever v is
                gx /= ng
                gy /= ng
                gz /= ng
                # g.(o + s y - p) >= margin  <=>  -g.y <= (g.(o - p) - margin) / s
                a[m, 0], a[m, 1], a[m, 2] = -gx, -gy, -gz
                b[m] = (gx * (origin[0] - pt[0]) + gy * (origin[1] - pt[1]) + gz * (origin[2] - pt[2]) - margin) / scale
                m += 1
    c = np.zeros(3)
    for i in range(k):
        u = (verts[ring[i]] - origin) / scale
        w = (verts[ring[(i + 1) % k]] - origin) / scale
        c[0] += u[1] * w[2] - u[2] * w[1]
        c[1] += u[2] * w[0] - u[0] * w[2]
        c[2] += u[0] * w[1] - u[1] * w[0]
    return a[:m], b[:m], c, origin, scale, local[:m]


@njit(cache=True)
def _place_and_verify(t, verts, valive, nv, faces, falive, planes, keep, keep_vertex, tol, eps_convex, near,
                      min_height, rfaces, ring, nr, k, newplanes, vout, rng, vmark, stamp, bound):
    """Solve the collapse LP for v (into vout) and verify the result exactly.

    Returns (ok, why): why = 1 LP infeasible / degenerate face / containment, 2 a vertex in front
    of a new face (convexity), 3 v in front of an unchanged face.
    """
    a, b, c, origin, scale, local = collapse_rows(t, verts, valive, faces, falive, planes, keep, keep_vertex,
                                                  nr, k, rfaces, ring, vmark, stamp, eps_convex, near, bound)
    # a tiny fixed tilt breaks ties between equal-volume optima deterministically
    cn = np.sqrt(np.sum(c * c)) + 1e-300
    c[0] += 1e-9 * cn
    c[1] += 2e-9 * cn
    c[2] += 3e-9 * cn
    # cutting planes: solve with the local rows, add the violated others, solve again
    perm = shuffled(a.shape[0], rng)
    order = np.empty(a.shape[0], dtype=np.int64)
    nact = 0
    for r in perm:
        if local[r]:
            order[nact] = r
            nact += 1
    for it in range(a.shape[0]):
        ok, y = seidel_lp3(a, b, c, BOX, order[:nact])
        if not ok:
            return False, 1
        added = 0
        for r in perm:
            if not local[r] and a[r, 0] * y[0] + a[r, 1] * y[1] + a[r, 2] * y[2] > b[r] + 10 * LP_EPS:
                local[r] = True
                order[nact] = r
                nact += 1
                added += 1
        if added == 0:
            break
    for q in range(3):
        if abs(y[q]) > BOX * (1 - 1e-9):
            return False, 1
    v = origin + scale * y
    vout[:] = v
    # exact checks: new faces non-degenerate; every vertex behind every new plane; v behind every
    # other face; every keep point behind every new plane
    a0, b0, c0 = faces[t, 0], faces[t, 1], faces[t, 2]
    tmpv = np.empty((3, 3))
    for i in range(k):
        tmpv[0] = v
        tmpv[1] = verts[ring[i]]
        tmpv[2] = verts[ring[(i + 1) % k]]
        area2 = _face_plane(tmpv, 0, 1, 2, newplanes[i])
        longest = 0.0
        for e in range(3):
            e2 = (e + 1) % 3
            d = np.sqrt((tmpv[e, 0] - tmpv[e2, 0]) ** 2 + (tmpv[e, 1] - tmpv[e2, 1]) ** 2
                        + (tmpv[e, 2] - tmpv[e2, 2]) ** 2)
            longest = max(longest, d)
        if area2 <= 0 or area2 / longest < min_height:
            return False, 1
    for q in range(nv):
        if not valive[q] or q == a0 or q == b0 or q == c0:
            continue
        for i in range(k):
            s = (newplanes[i, 0] * verts[q, 0] + newplanes[i, 1] * verts[q, 1] + newplanes[i, 2] * verts[q, 2]
                 - newplanes[i, 3])
            if s > tol:
                return False, 2
    for f in range(faces.shape[0]):
        if not falive[f]:
            continue
        if faces[f, 0] == a0 or faces[f, 0] == b0 or faces[f, 0] == c0 or faces[f, 1] == a0 or faces[f, 1] == b0 \
                or faces[f, 1] == c0 or faces[f, 2] == a0 or faces[f, 2] == b0 or faces[f, 2] == c0:
            continue
        if planes[f, 0] * v[0] + planes[f, 1] * v[1] + planes[f, 2] * v[2] - planes[f, 3] > tol:
            return False, 3
    for p in range(keep.shape[0]):
        kv = keep_vertex[p]
        if kv >= 0 and valive[kv] and kv != a0 and kv != b0 and kv != c0:
            continue  # still a vertex: checked above
        for i in range(k):
            s = (newplanes[i, 0] * keep[p, 0] + newplanes[i, 1] * keep[p, 1] + newplanes[i, 2] * keep[p, 2]
                 - newplanes[i, 3])
            if s > tol:
                return False, 1
    return True, 0


@njit(cache=True)
def _evaluate(t, verts, valive, nv, faces, falive, planes, quad, keep, keep_vertex, tol, eps_convex, near,
              min_height, prio, rfaces, ring, es, ee, newplanes, vout, rng, vmark, stamp, bound):
    """Best legal collapse of triangle t: returns (ok, cost, n_region, k); v in vout."""
    nr, k = _region(t, faces, falive, rfaces, ring, es, ee)
    if nr < 0:
        return False, np.inf, nr, k
    stamp[0] += 1
    for i in range(k):
        vmark[ring[i]] = stamp[0]
    ok, why = _place_and_verify(t, verts, valive, nv, faces, falive, planes, keep, keep_vertex, tol,
                                eps_convex, near, min_height, rfaces, ring, nr, k, newplanes, vout, rng,
                                vmark, stamp[0], bound)
    if not ok:
        return False, np.inf, nr, k
    v = vout
    a0, b0, c0 = faces[t, 0], faces[t, 1], faces[t, 2]
    if prio == PRIO_QEM:
        h = np.array([v[0], v[1], v[2], 1.0])
        q4 = quad[a0] + quad[b0] + quad[c0]
        cost = 0.0
        for r in range(4):
            for s2 in range(4):
                cost += h[r] * q4[r, s2] * h[s2]
    else:
        # added volume = new cone volume - removed region volume (they share the boundary cycle,
        # so the difference is a closed surface's volume and any origin will do)
        origin = (verts[a0] + verts[b0] + verts[c0]) / 3.0
        cost = 0.0
        for i in range(k):
            u = verts[ring[i]] - origin
            w = verts[ring[(i + 1) % k]] - origin
            z = v - origin
            cost += (z[0] * (u[1] * w[2] - u[2] * w[1]) + z[1] * (u[2] * w[0] - u[0] * w[2])
                     + z[2] * (u[0] * w[1] - u[1] * w[0])) / 6.0
        for ir in range(nr):
            f = rfaces[ir]
            u = verts[faces[f, 0]] - origin
            w = verts[faces[f, 1]] - origin
            z = verts[faces[f, 2]] - origin
            cost -= (u[0] * (w[1] * z[2] - w[2] * z[1]) + u[1] * (w[2] * z[0] - w[0] * z[2])
                     + u[2] * (w[0] * z[1] - w[1] * z[0])) / 6.0
    return True, max(cost, 0.0), nr, k


@njit(cache=True)
def simplify_kernel(verts0, faces0, keep, keep_vertex, min_faces, tol, eps_convex, near, min_height, prio,
                    dirty_depth, bound):
    """Greedy constrained triangle collapses, cheapest first, until min_faces or none is legal.

    keep_vertex[p]: index of the input vertex equal to keep[p], or -1.
    Returns (verts, valive, faces, falive, n_collapses, n_evaluations). Dead slots are flagged.
    """
    nv0 = verts0.shape[0]
    nf = faces0.shape[0]
    cap = nv0 + nf // 4 + 1
    verts = np.zeros((cap, 3))
    verts[:nv0] = verts0
    valive = np.zeros(cap, dtype=np.bool_)
    valive[:nv0] = True
    nv = nv0
    faces = faces0.copy()
    falive = np.ones(nf, dtype=np.bool_)
    planes = np.empty((nf, 4))
    quad = np.zeros((cap, 4, 4))
    for f in range(nf):
        area2 = _face_plane(verts, faces[f, 0], faces[f, 1], faces[f, 2], planes[f])
        h = np.array([planes[f, 0], planes[f, 1], planes[f, 2], -planes[f, 3]])
        for e in range(3):
            q = faces[f, e]
            for r in range(4):
                for s in range(4):
                    quad[q, r, s] += 0.5 * area2 * h[r] * h[s]
    rfaces = np.empty(nf, dtype=np.int64)
    ring = np.empty(nf, dtype=np.int64)
    es = np.empty(nf, dtype=np.int64)
    ee = np.empty(nf, dtype=np.int64)
    newplanes = np.empty((nf, 4))
    vout = np.empty(3)
    rng = np.array([np.uint64(0x9E3779B97F4A7C15)])
    cost = np.full(nf, np.inf)
    emark = np.zeros(cap, dtype=np.int64)
    estamp = np.zeros(1, dtype=np.int64)
    nevals = nf
    for f in range(nf):
        ok, cst, nr, k = _evaluate(f, verts, valive, nv, faces, falive, planes, quad, keep, keep_vertex, tol,
                                   eps_convex, near, min_height, prio, rfaces, ring, es, ee, newplanes, vout, rng,
                                   emark, estamp, bound)
        cost[f] = cst
    nalive = nf
    ncollapse = 0
    swept = False
    vmark = np.zeros(cap, dtype=np.int64)
    stamp = 0
    while nalive - 4 >= min_faces:
        best = np.int64(-1)     # not the literal -1: numba would compile _evaluate for Literal[int](-1) too
        bc = np.inf
        for f in range(nf):
            if falive[f] and cost[f] < bc:
                bc = cost[f]
                best = f
        if best < 0:
            if swept:
                break
            # stale costs may hide legal collapses: re-evaluate everything once before giving up
            swept = True
            for f in range(nf):
                if falive[f]:
                    ok, cst, nr, k = _evaluate(f, verts, valive, nv, faces, falive, planes, quad, keep, keep_vertex,
                                               tol, eps_convex, near, min_height, prio, rfaces, ring, es, ee,
                                               newplanes, vout, rng, emark, estamp, bound)
                    cost[f] = cst
                    nevals += 1
            continue
        swept = False
        ok, cst, nr, k = _evaluate(best, verts, valive, nv, faces, falive, planes, quad, keep, keep_vertex, tol,
                                   eps_convex, near, min_height, prio, rfaces, ring, es, ee, newplanes, vout, rng,
                                   emark, estamp, bound)
        if not ok:
            cost[best] = np.inf
            continue
        if cst > bc * (1 + 1e-9) + 1e-300:
            cost[best] = cst  # stale priority: requeue with the fresh cost
            continue
        a0, b0, c0 = faces[best, 0], faces[best, 1], faces[best, 2]
        verts[nv] = vout
        valive[nv] = True
        quad[nv] = quad[a0] + quad[b0] + quad[c0]
        valive[a0] = False
        valive[b0] = False
        valive[c0] = False
        for i in range(k):
            f = rfaces[i]
            faces[f, 0] = nv
            faces[f, 1] = ring[i]
            faces[f, 2] = ring[(i + 1) % k]
            planes[f] = newplanes[i]
        for i in range(k, nr):
            falive[rfaces[i]] = False
            cost[rfaces[i]] = np.inf
        nalive -= 4
        ncollapse += 1
        # re-evaluate every face with a corner within `dirty_depth` rings of the new vertex (others
        # may hold a stale cost; the winner is always re-evaluated before it is applied)
        stamp += 1
        vmark[nv] = stamp
        for i in range(k):
            vmark[ring[i]] = stamp
        stamp += 1
        for f in range(nf):
            if not falive[f] or dirty_depth < 2:
                continue
            if vmark[faces[f, 0]] == stamp - 1 or vmark[faces[f, 1]] == stamp - 1 or vmark[faces[f, 2]] == stamp - 1:
                for e in range(3):
                    if vmark[faces[f, e]] != stamp - 1:
                        vmark[faces[f, e]] = stamp
        for f in range(nf):
            if not falive[f]:
                continue
            if vmark[faces[f, 0]] >= stamp - 1 or vmark[faces[f, 1]] >= stamp - 1 or vmark[faces[f, 2]] >= stamp - 1:
                ok, cst, nr2, k2 = _evaluate(f, verts, valive, nv + 1, faces, falive, planes, quad, keep, keep_vertex,
                                             tol, eps_convex, near, min_height, prio, rfaces, ring, es, ee,
                                             newplanes, vout, rng, emark, estamp, bound)
                nevals += 1
                cost[f] = cst
        nv += 1
    return verts[:nv], valive[:nv], faces, falive, ncollapse, nevals


@njit(cache=True)
def _point_triangle_distance(px, py, pz, a, b, c):
    """Distance from point p to triangle (a, b, c) (Ericson, Real-Time Collision Detection 5.1.5)."""
    abx, aby, abz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    acx, acy, acz = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    apx, apy, apz = px - a[0], py - a[1], pz - a[2]
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0 and d2 <= 0:
        qx, qy, qz = a[0], a[1], a[2]
    else:
        bpx, bpy, bpz = px - b[0], py - b[1], pz - b[2]
        d3 = abx * bpx + aby * bpy + abz * bpz
        d4 = acx * bpx + acy * bpy + acz * bpz
        cpx, cpy, cpz = px - c[0], py - c[1], pz - c[2]
        d5 = abx * cpx + aby * cpy + abz * cpz
        d6 = acx * cpx + acy * cpy + acz * cpz
        vc = d1 * d4 - d3 * d2
        vb = d5 * d2 - d1 * d6
        va = d3 * d6 - d5 * d4
        if d3 >= 0 and d4 <= d3:
            qx, qy, qz = b[0], b[1], b[2]
        elif d6 >= 0 and d5 <= d6:
            qx, qy, qz = c[0], c[1], c[2]
        elif vc <= 0 and d1 >= 0 and d3 <= 0:
            t = d1 / (d1 - d3)
            qx, qy, qz = a[0] + t * abx, a[1] + t * aby, a[2] + t * abz
        elif vb <= 0 and d2 >= 0 and d6 <= 0:
            t = d2 / (d2 - d6)
            qx, qy, qz = a[0] + t * acx, a[1] + t * acy, a[2] + t * acz
        elif va <= 0 and (d4 - d3) >= 0 and (d5 - d6) >= 0:
            t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
            qx, qy, qz = b[0] + t * (c[0] - b[0]), b[1] + t * (c[1] - b[1]), b[2] + t * (c[2] - b[2])
        else:
            den = va + vb + vc
            v = vb / den
            w = vc / den
            qx, qy, qz = a[0] + v * abx + w * acx, a[1] + v * aby + w * acy, a[2] + v * abz + w * acz
    return np.sqrt((px - qx) ** 2 + (py - qy) ** 2 + (pz - qz) ** 2)


@njit(cache=True)
def distance_to_convex(points, verts, faces, planes):
    """(P,) distance from each point to a solid convex polytope (0 inside).

    An outside point's closest boundary point lies on a face whose plane the point is in front
    of (p - q is in the normal cone at q), so only those faces are measured.
    """
    out = np.zeros(points.shape[0])
    for p in range(points.shape[0]):
        px, py, pz = points[p, 0], points[p, 1], points[p, 2]
        best = np.inf
        for f in range(faces.shape[0]):
            if planes[f, 0] * px + planes[f, 1] * py + planes[f, 2] * pz - planes[f, 3] <= 0:
                continue
            d = _point_triangle_distance(px, py, pz, verts[faces[f, 0]], verts[faces[f, 1]], verts[faces[f, 2]])
            if d < best:
                best = d
        out[p] = 0.0 if best == np.inf else best
    return out
