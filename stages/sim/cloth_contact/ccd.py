"""Exact continuous tests of cloth x cloth collision: vertex-face and edge-edge pairs moving on
straight lines over a step, with a thickness; and the static edge-triangle crossing test.

- Features: a vertex-face pair (particle p, triangle abc) and an edge-edge pair (ab, cd). Every
  particle moves on the straight line xs -> xe, so f(t) = det(b-a, c-a, p-a) (VF) or
  det(b-a, d-c, c-a) (EE) is a cubic in t; a zero of f is a time the four points are coplanar.
- Crossing: a root of f in [0, 1] at which the features touch (p inside the triangle, or both edge
  parameters in [0, 1] with the edges not parallel; tolerance CROSS_TOL).
- Side s (+-1) the pair belongs on: the sign of f at the end, flipped by each crossing (the sign of
  f is no side by itself: it also changes where p passes the triangle's plane outside it, and for
  EE where the lines meet outside the segments or the edges turn through parallel). VF roots are
  searched only when the sign changes over the step (a point through and back within one step
  ends where it started); EE roots always. For a pair between garments of different layers the
  side is the one the layers prescribe (outer garment along the inner one's outward normal),
  unless the pair ends deeper than `layer_depth` on the wrong side (the far side of the body, not an
  interpenetration).
- CROSS: a crossing and the pair ends on the wrong side of s. NEAR: otherwise, closer than the
  thickness h on side s at the end, -gate <= s d1 < h, with p's projection inside the triangle
  (VF) or the closest points inside both edges (EE); gate = h, or `layer_depth` for a layered pair.
Each test returns (kind or -1, w1, w2, w3, dx, dy, dz): dir = s times the unit normal at the end
(the contact constraint is dir . sum_k w_k x_k >= h, see the kernels module) and the weights.
"""
from __future__ import annotations

import numpy as np
from numba import njit

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)
from stages.affine import triangle_cross

NUMBA_CACHE_DEPENDS = ("stages.affine",)

BARY_TOL = 1e-9      # NEAR: projection inside the triangle / closest points inside the edges
CROSS_TOL = 1e-6     # CROSS: generous, so a path through a shared edge is caught by both sides
PARALLEL_TOL = 1e-8  # |e1 x e2|^2 <= tol |e1|^2 |e2|^2: parallel edges, left to the VF tests

VF_NEAR = 0
VF_CROSS = 1
EE_NEAR = 2
EE_CROSS = 3

# ---------------------------------------------------------------------------------------------
# geometry helpers

@njit(cache=True)
def _det(ax, ay, az, bx, by, bz, cx, cy, cz):
    """det[a, b, c] = (a x b) . c"""
    return (ay * bz - az * by) * cx + (az * bx - ax * bz) * cy + (ax * by - ay * bx) * cz


@njit(cache=True)
def _at(xs, xe, i, t):
    """Particle i at time t of the step (straight line xs -> xe)."""
    return (xs[i, 0] + t * (xe[i, 0] - xs[i, 0]), xs[i, 1] + t * (xe[i, 1] - xs[i, 1]),
            xs[i, 2] + t * (xe[i, 2] - xs[i, 2]))


@njit(cache=True)
def triple_cubic(xs, xe, ua, ub, va, vb, wa, wb):
    """Coefficients (c0, c1, c2, c3) of f(t) = det(U, V, W) with U = x[ua] - x[ub], V = x[va] - x[vb],
    W = x[wa] - x[wb] and x(t) = xs + t (xe - xs)."""
    u0x = xs[ua, 0] - xs[ub, 0]
    u0y = xs[ua, 1] - xs[ub, 1]
    u0z = xs[ua, 2] - xs[ub, 2]
    v0x = xs[va, 0] - xs[vb, 0]
    v0y = xs[va, 1] - xs[vb, 1]
    v0z = xs[va, 2] - xs[vb, 2]
    w0x = xs[wa, 0] - xs[wb, 0]
    w0y = xs[wa, 1] - xs[wb, 1]
    w0z = xs[wa, 2] - xs[wb, 2]
    dux = xe[ua, 0] - xe[ub, 0] - u0x
    duy = xe[ua, 1] - xe[ub, 1] - u0y
    duz = xe[ua, 2] - xe[ub, 2] - u0z
    dvx = xe[va, 0] - xe[vb, 0] - v0x
    dvy = xe[va, 1] - xe[vb, 1] - v0y
    dvz = xe[va, 2] - xe[vb, 2] - v0z
    dwx = xe[wa, 0] - xe[wb, 0] - w0x
    dwy = xe[wa, 1] - xe[wb, 1] - w0y
    dwz = xe[wa, 2] - xe[wb, 2] - w0z
    c0 = _det(u0x, u0y, u0z, v0x, v0y, v0z, w0x, w0y, w0z)
    c1 = (_det(dux, duy, duz, v0x, v0y, v0z, w0x, w0y, w0z) + _det(u0x, u0y, u0z, dvx, dvy, dvz, w0x, w0y, w0z)
          + _det(u0x, u0y, u0z, v0x, v0y, v0z, dwx, dwy, dwz))
    c2 = (_det(dux, duy, duz, dvx, dvy, dvz, w0x, w0y, w0z) + _det(dux, duy, duz, v0x, v0y, v0z, dwx, dwy, dwz)
          + _det(u0x, u0y, u0z, dvx, dvy, dvz, dwx, dwy, dwz))
    c3 = _det(dux, duy, duz, dvx, dvy, dvz, dwx, dwy, dwz)
    return c0, c1, c2, c3


@njit(cache=True)
def _poly(c0, c1, c2, c3, t):
    return ((c3 * t + c2) * t + c1) * t + c0


@njit(cache=True)
def _root_in(c0, c1, c2, c3, lo, hi, flo, fhi):
    """A root of the cubic in [lo, hi] given a sign change (or a zero) at its ends: bisection."""
    if flo == 0.0:
        return lo
    if fhi == 0.0:
        return hi
    for _ in range(64):
        mid = 0.5 * (lo + hi)
        if mid <= lo or mid >= hi:
            break
        fm = _poly(c0, c1, c2, c3, mid)
        if fm == 0.0:
            return mid
        if (fm < 0.0) == (flo < 0.0):
            lo = mid
            flo = fm
        else:
            hi = mid
    return 0.5 * (lo + hi)


@njit(cache=True)
def cubic_roots01(c0, c1, c2, c3, f0, f1):
    """Up to 3 roots of c0 + c1 t + c2 t^2 + c3 t^3 in [0, 1], ascending: (r0, r1, r2, count).

    The cubic is cut at its critical points into monotone pieces; a piece whose ends differ in sign
    (or touch zero) holds exactly one root, found by bisection. f0, f1: the values at 0 and 1 (passed
    in so the end signs agree with the caller's direct evaluations). A double root that does not
    change sign (a touch) is not reported: it is no crossing.
    """
    a = 3.0 * c3
    b = 2.0 * c2
    c = c1
    t1 = 2.0
    t2 = 2.0
    if a != 0.0:
        disc = b * b - 4.0 * a * c
        if disc >= 0.0:
            sq = np.sqrt(disc)
            q = -0.5 * (b + (sq if b >= 0.0 else -sq))
            if q != 0.0:
                t1 = q / a
                t2 = c / q
            else:
                t1 = 0.0
                t2 = 0.0
    elif b != 0.0:
        t1 = -c / b
    if t1 > t2:
        t1, t2 = t2, t1
    if not (0.0 < t1 < 1.0):
        t1 = 2.0
    if not (0.0 < t2 < 1.0):
        t2 = 2.0
    if t1 > t2:
        t1, t2 = t2, t1
    r = (2.0, 2.0, 2.0)
    n = 0
    lo = 0.0
    flo = f0
    for piece in range(3):
        if piece == 0:
            hi = t1
        elif piece == 1:
            hi = t2
        else:
            hi = 1.0
        if hi > 1.0:
            hi = 1.0
        if hi < lo or (hi == lo and piece < 2):
            continue
        fhi = f1 if hi == 1.0 else _poly(c0, c1, c2, c3, hi)
        if flo == 0.0 or fhi == 0.0 or (flo < 0.0) != (fhi < 0.0):
            root = _root_in(c0, c1, c2, c3, lo, hi, flo, fhi)
            if n == 0 or root > (r[0] if n == 1 else r[1]):
                if n == 0:
                    r = (root, 2.0, 2.0)
                elif n == 1:
                    r = (r[0], root, 2.0)
                else:
                    r = (r[0], r[1], root)
                n += 1
        lo = hi
        flo = fhi
        if hi == 1.0:
            break
    return r[0], r[1], r[2], n


BERNSTEIN_TOL = 1e-12  # relative to sum |c_k|: far above the rounding of the Bernstein coefficients and of
                       # a Horner evaluation (a few 1e-16 of sum |c_k|)


@njit(cache=True)
def cubic_clear01(c0, c1, c2, c3, f1):
    """The cubic c0 + c1 t + c2 t^2 + c3 t^3 keeps one strict sign on [0, 1], with margin (Tang et al.
    2010, non-penetration filters): its Bernstein coefficients on [0, 1] (b0 = c0, b1 = c0 + c1 / 3,
    b2 = c0 + (2 c1 + c2) / 3, b3 = c0 + c1 + c2 + c3; the cubic lies in their convex hull) and f1 (the
    caller's value at 1) all share one sign and exceed BERNSTEIN_TOL sum |c_k| in size. Then
    cubic_roots01 finds no root either: every value it evaluates has that sign."""
    tol = BERNSTEIN_TOL * (abs(c0) + abs(c1) + abs(c2) + abs(c3))
    b1 = c0 + c1 / 3.0
    b2 = c0 + (2.0 * c1 + c2) / 3.0
    b3 = c0 + c1 + c2 + c3
    if c0 > tol:
        return b1 > tol and b2 > tol and b3 > tol and f1 > 0.0
    if c0 < -tol:
        return b1 < -tol and b2 < -tol and b3 < -tol and f1 < 0.0
    return False


@njit(cache=True)
def _bary(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """Barycentric (wa, wb, wc) of p's projection on the plane of abc; ok False if degenerate."""
    e1x = bx - ax
    e1y = by - ay
    e1z = bz - az
    e2x = cx - ax
    e2y = cy - ay
    e2z = cz - az
    wx = px - ax
    wy = py - ay
    wz = pz - az
    d11 = e1x * e1x + e1y * e1y + e1z * e1z
    d12 = e1x * e2x + e1y * e2y + e1z * e2z
    d22 = e2x * e2x + e2y * e2y + e2z * e2z
    dw1 = wx * e1x + wy * e1y + wz * e1z
    dw2 = wx * e2x + wy * e2y + wz * e2z
    den = d11 * d22 - d12 * d12
    if not (den > 1e-30 * d11 * d22) or den == 0.0:
        return False, 0.0, 0.0, 0.0
    v = (d22 * dw1 - d12 * dw2) / den
    w = (d11 * dw2 - d12 * dw1) / den
    return True, 1.0 - v - w, v, w


@njit(cache=True)
def _edge_params(ax, ay, az, bx, by, bz, cx, cy, cz, dx, dy, dz):
    """Closest points of the lines ab and cd: (ok, v on ab, u on cd); ok False if parallel."""
    e1x = bx - ax
    e1y = by - ay
    e1z = bz - az
    e2x = dx - cx
    e2y = dy - cy
    e2z = dz - cz
    rx = ax - cx
    ry = ay - cy
    rz = az - cz
    aa = e1x * e1x + e1y * e1y + e1z * e1z
    bb = e1x * e2x + e1y * e2y + e1z * e2z
    cc = e2x * e2x + e2y * e2y + e2z * e2z
    dd = e1x * rx + e1y * ry + e1z * rz
    ee = e2x * rx + e2y * ry + e2z * rz
    den = aa * cc - bb * bb
    if not (den > PARALLEL_TOL * aa * cc):
        return False, 0.0, 0.0
    return True, (bb * ee - cc * dd) / den, (aa * ee - bb * dd) / den


@njit(cache=True)
def _inside(w0, w1, w2, tol):
    return w0 >= -tol and w1 >= -tol and w2 >= -tol


# ---------------------------------------------------------------------------------------------
# exact pair tests. Return (kind or -1, w1, w2, w3, dx, dy, dz) with the constraint weights of the
# 2nd..4th particle (the 1st: 1 for VF; EE weights below) and dir = s * unit normal at the end.

@njit(cache=True)
def _sign(v, fallback):
    if v > 0.0:
        return 1.0
    if v < 0.0:
        return -1.0
    return fallback


@njit(cache=True)
def test_vertex_face(xs, xe, p, a, b, c, forced, h, layer_depth):
    """Particle p against triangle abc. forced: 0, or the side (+-1) the layers prescribe for p
    relative to the triangle's normal (b-a) x (c-a). Weights returned: (wa, wb, wc) barycentric;
    the constraint is dir . (p - wa a - wb b - wc c) >= h."""
    n1x, n1y, n1z = triangle_cross(xe, a, b, c)
    l1sq = n1x * n1x + n1y * n1y + n1z * n1z
    if l1sq == 0.0:
        return -1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    f1 = n1x * (xe[p, 0] - xe[a, 0]) + n1y * (xe[p, 1] - xe[a, 1]) + n1z * (xe[p, 2] - xe[a, 2])
    n0x, n0y, n0z = triangle_cross(xs, a, b, c)
    f0 = n0x * (xs[p, 0] - xs[a, 0]) + n0y * (xs[p, 1] - xs[a, 1]) + n0z * (xs[p, 2] - xs[a, 2])
    sg1 = _sign(f1, -_sign(f0, 1.0))
    # crossings: roots of the coplanarity cubic with p inside the triangle. Searched only when the
    # side changes (a point passing through and back within one step ends where it started).
    crossings = 0
    wa = 0.0
    wb = 0.0
    wc = 0.0
    if _sign(f0, -sg1) != sg1:
        c0, c1, c2, c3 = triple_cubic(xs, xe, b, a, c, a, p, a)
        r0, r1, r2, nr = cubic_roots01(c0, c1, c2, c3, f0, f1)
        for k in range(nr):
            t = r0 if k == 0 else (r1 if k == 1 else r2)
            px, py, pz = _at(xs, xe, p, t)
            ax, ay, az = _at(xs, xe, a, t)
            bx, by, bz = _at(xs, xe, b, t)
            cx, cy, cz = _at(xs, xe, c, t)
            ok, ua, ub, uc = _bary(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz)
            if ok and _inside(ua, ub, uc, CROSS_TOL):
                if crossings == 0:
                    wa, wb, wc = ua, ub, uc
                crossings += 1
    # the side p belongs on: where it ends, flipped by each crossing; or the layers' side, unless
    # p ends deeper than layer_depth on the wrong side of it (the far side of the body)
    s = sg1 if crossings % 2 == 0 else -sg1
    gate = h
    if forced != 0 and (forced * f1 >= 0.0 or f1 * f1 <= layer_depth * layer_depth * l1sq):
        s = float(forced)
        gate = layer_depth
    if crossings > 0 and s * f1 < 0.0:
        l1 = np.sqrt(l1sq)
        return VF_CROSS, wa, wb, wc, s * n1x / l1, s * n1y / l1, s * n1z / l1
    # common case, without a square root: on its side and beyond the thickness
    if s * f1 >= 0.0 and f1 * f1 >= h * h * l1sq:
        return -1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    l1 = np.sqrt(l1sq)
    sd1 = s * f1 / l1
    if -gate <= sd1 < h:
        ok, wa, wb, wc = _bary(xe[p, 0], xe[p, 1], xe[p, 2], xe[a, 0], xe[a, 1], xe[a, 2],
                               xe[b, 0], xe[b, 1], xe[b, 2], xe[c, 0], xe[c, 1], xe[c, 2])
        if ok and _inside(wa, wb, wc, BARY_TOL):
            return VF_NEAR, wa, wb, wc, s * n1x / l1, s * n1y / l1, s * n1z / l1
    return -1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0


@njit(cache=True)
def _edges_end(xe, a, b, c, d):
    """Edges ab and cd at the end of the step: their normal n1 = (b-a) x (d-c), its squared length,
    f1 = n1 . (c - a) and whether they are (nearly) parallel (PARALLEL_TOL)."""
    e1x = xe[b, 0] - xe[a, 0]
    e1y = xe[b, 1] - xe[a, 1]
    e1z = xe[b, 2] - xe[a, 2]
    e2x = xe[d, 0] - xe[c, 0]
    e2y = xe[d, 1] - xe[c, 1]
    e2z = xe[d, 2] - xe[c, 2]
    n1x = e1y * e2z - e1z * e2y
    n1y = e1z * e2x - e1x * e2z
    n1z = e1x * e2y - e1y * e2x
    l1sq = n1x * n1x + n1y * n1y + n1z * n1z
    parallel1 = not (l1sq > PARALLEL_TOL * (e1x * e1x + e1y * e1y + e1z * e1z) * (e2x * e2x + e2y * e2y + e2z * e2z))
    f1 = n1x * (xe[c, 0] - xe[a, 0]) + n1y * (xe[c, 1] - xe[a, 1]) + n1z * (xe[c, 2] - xe[a, 2])
    return n1x, n1y, n1z, l1sq, f1, parallel1


@njit(cache=True)
def test_edge_edge(xs, xe, a, b, c, d, forced, ox, oy, oz, h, layer_depth):
    """Edge ab against edge cd. forced: 0; +1 if cd is the outer garment's edge and ab the inner's,
    -1 the other way round; (ox, oy, oz): the inner edge's outward normal at the end of the step.
    Weights returned: (v, u, 0) with v on ab, u on cd; the constraint is
    dir . ((c + u (d - c)) - (a + v (b - a))) >= h.

    Unlike a triangle's normal, n = (b-a) x (d-c) flips whenever the edges turn through parallel, and
    f = n . (c - a) also changes sign where the lines meet outside the segments: the sign of f is no
    side. So the cubic's roots are always searched, and the side is the end's sign of f flipped by
    each real crossing (segments meeting, edges not parallel)."""
    n1x, n1y, n1z, l1sq, f1, parallel1 = _edges_end(xe, a, b, c, d)
    c0, c1, c2, c3 = triple_cubic(xs, xe, b, a, d, c, c, a)
    r0, r1, r2, nr = 2.0, 2.0, 2.0, 0
    if not cubic_clear01(c0, c1, c2, c3, f1):
        r0, r1, r2, nr = cubic_roots01(c0, c1, c2, c3, c0, f1)
    crossings = 0
    v = 0.0
    u = 0.0
    cross_dir = 0.0
    cnx = 0.0
    cny = 0.0
    cnz = 0.0
    for k in range(nr):
        t = r0 if k == 0 else (r1 if k == 1 else r2)
        ax, ay, az = _at(xs, xe, a, t)
        bx, by, bz = _at(xs, xe, b, t)
        cx, cy, cz = _at(xs, xe, c, t)
        qx, qy, qz = _at(xs, xe, d, t)
        ok, vk, uk = _edge_params(ax, ay, az, bx, by, bz, cx, cy, cz, qx, qy, qz)
        if ok and -CROSS_TOL <= vk <= 1.0 + CROSS_TOL and -CROSS_TOL <= uk <= 1.0 + CROSS_TOL:
            if crossings == 0:
                v = min(max(vk, 0.0), 1.0)
                u = min(max(uk, 0.0), 1.0)
                # the normal at the crossing, towards the side the pair came from (f' < 0: from +)
                cnx = (by - ay) * (qz - cz) - (bz - az) * (qy - cy)
                cny = (bz - az) * (qx - cx) - (bx - ax) * (qz - cz)
                cnz = (bx - ax) * (qy - cy) - (by - ay) * (qx - cx)
                cross_dir = -_sign(c1 + t * (2.0 * c2 + 3.0 * c3 * t), 1.0)
            crossings += 1
    if parallel1:
        # no end normal: only a crossing is answered, along the normal where it happened
        if crossings % 2 == 0:
            return -1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        ln = np.sqrt(cnx * cnx + cny * cny + cnz * cnz)
        return EE_CROSS, v, u, 0.0, cross_dir * cnx / ln, cross_dir * cny / ln, cross_dir * cnz / ln
    sg1 = _sign(f1, 1.0)
    s = sg1 if crossings % 2 == 0 else -sg1
    gate = h
    if forced != 0:
        # the outer edge must lie along the inner edge's outward normal o: s = forced * sign(n1 . o)
        on = n1x * ox + n1y * oy + n1z * oz
        if on * on > 0.01 * l1sq * (ox * ox + oy * oy + oz * oz):
            sf = forced * (1.0 if on > 0.0 else -1.0)
            if sf * f1 >= 0.0 or f1 * f1 <= layer_depth * layer_depth * l1sq:
                s = sf
                gate = layer_depth
    if crossings > 0 and s * f1 < 0.0:
        l1 = np.sqrt(l1sq)
        return EE_CROSS, v, u, 0.0, s * n1x / l1, s * n1y / l1, s * n1z / l1
    if s * f1 >= 0.0 and f1 * f1 >= h * h * l1sq:
        return -1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    l1 = np.sqrt(l1sq)
    sd1 = s * f1 / l1
    if -gate <= sd1 < h:
        ok, v, u = _edge_params(xe[a, 0], xe[a, 1], xe[a, 2], xe[b, 0], xe[b, 1], xe[b, 2],
                                xe[c, 0], xe[c, 1], xe[c, 2], xe[d, 0], xe[d, 1], xe[d, 2])
        if ok and -BARY_TOL <= v <= 1.0 + BARY_TOL and -BARY_TOL <= u <= 1.0 + BARY_TOL:
            return EE_NEAR, v, u, 0.0, s * n1x / l1, s * n1y / l1, s * n1z / l1
    return -1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0


@njit(cache=True)
def ee_clear(xs, xe, a, b, c, d, reach):
    """test_edge_edge reports nothing for edges ab and cd, whatever the layers prescribe: the
    coplanarity cubic keeps its sign over the step (cubic_clear01: no crossing) and the edges end
    parallel or farther than `reach` (>= max(h, layer_depth)) apart along their normal. The first
    half of test_edge_edge, so a caller can skip what the rest needs (the inner edge's outward normal)."""
    _, _, _, l1sq, f1, parallel1 = _edges_end(xe, a, b, c, d)
    if not (parallel1 or f1 * f1 > reach * reach * l1sq):
        return False
    c0, c1, c2, c3 = triple_cubic(xs, xe, b, a, d, c, c, a)
    return cubic_clear01(c0, c1, c2, c3, f1)


# ---------------------------------------------------------------------------------------------
# conservative separation: pairs that can neither cross nor end within `reach` over the step.
# A feature's points are fixed convex combinations of its corners, so over the step each moves at
# most as far as its farthest corner: the pair's distance at any time is at least its distance at
# the start minus the two features' largest corner moves. Both exact tests report only pairs that
# touch at some time (CROSS) or end closer than max(h, layer_depth) (NEAR, the projection inside
# the features): a pair whose bound stays above that reach is neither.

APART_SLACK = 1e-6   # m added to the reach: the exact tests' inside tolerances (CROSS_TOL, BARY_TOL)


@njit(cache=True)
def _move(xs, xe, i):
    return np.sqrt((xe[i, 0] - xs[i, 0]) ** 2 + (xe[i, 1] - xs[i, 1]) ** 2 + (xe[i, 2] - xs[i, 2]) ** 2)


@njit(cache=True)
def vf_apart(xs, xe, p, a, b, c, reach):
    """Particle p and triangle abc stay farther apart than `reach` over the step xs -> xe (so
    test_vertex_face reports nothing): the distance from p to the triangle's bounding sphere about
    its centroid at the start, less the moves of p and of the triangle's farthest-moving corner."""
    cx = (xs[a, 0] + xs[b, 0] + xs[c, 0]) / 3.0
    cy = (xs[a, 1] + xs[b, 1] + xs[c, 1]) / 3.0
    cz = (xs[a, 2] + xs[b, 2] + xs[c, 2]) / 3.0
    r2 = 0.0
    for i in (a, b, c):
        r2 = max(r2, (xs[i, 0] - cx) ** 2 + (xs[i, 1] - cy) ** 2 + (xs[i, 2] - cz) ** 2)
    d = np.sqrt((xs[p, 0] - cx) ** 2 + (xs[p, 1] - cy) ** 2 + (xs[p, 2] - cz) ** 2) - np.sqrt(r2)
    room = reach + APART_SLACK
    if d <= room:
        return False
    return d > room + _move(xs, xe, p) + max(_move(xs, xe, a), max(_move(xs, xe, b), _move(xs, xe, c)))


@njit(cache=True)
def segment_distance(x, a, b, c, d):
    """Distance between the segments x[a] x[b] and x[c] x[d] (closest points clamped to both)."""
    d1x = x[b, 0] - x[a, 0]
    d1y = x[b, 1] - x[a, 1]
    d1z = x[b, 2] - x[a, 2]
    d2x = x[d, 0] - x[c, 0]
    d2y = x[d, 1] - x[c, 1]
    d2z = x[d, 2] - x[c, 2]
    rx = x[a, 0] - x[c, 0]
    ry = x[a, 1] - x[c, 1]
    rz = x[a, 2] - x[c, 2]
    aa = d1x * d1x + d1y * d1y + d1z * d1z
    ee = d2x * d2x + d2y * d2y + d2z * d2z
    ff = d2x * rx + d2y * ry + d2z * rz
    s = 0.0
    t = 0.0
    if aa <= 1e-30 and ee <= 1e-30:
        pass
    elif aa <= 1e-30:
        t = min(max(ff / ee, 0.0), 1.0)
    else:
        cc = d1x * rx + d1y * ry + d1z * rz
        if ee <= 1e-30:
            s = min(max(-cc / aa, 0.0), 1.0)
        else:
            bb = d1x * d2x + d1y * d2y + d1z * d2z
            den = aa * ee - bb * bb
            s = min(max((bb * ff - cc * ee) / den, 0.0), 1.0) if den > 0.0 else 0.0
            t = (bb * s + ff) / ee
            if t < 0.0:
                t = 0.0
                s = min(max(-cc / aa, 0.0), 1.0)
            elif t > 1.0:
                t = 1.0
                s = min(max((bb - cc) / aa, 0.0), 1.0)
    qx = rx + s * d1x - t * d2x
    qy = ry + s * d1y - t * d2y
    qz = rz + s * d1z - t * d2z
    return np.sqrt(qx * qx + qy * qy + qz * qz)


@njit(cache=True)
def ee_apart(xs, xe, a, b, c, d, reach):
    """Edges ab and cd stay farther apart than `reach` over the step xs -> xe (so test_edge_edge
    reports nothing): their distance at the start less each edge's farthest corner move."""
    room = reach + APART_SLACK
    d0 = segment_distance(xs, a, b, c, d)
    if d0 <= room:
        return False
    return d0 > room + max(_move(xs, xe, a), _move(xs, xe, b)) + max(_move(xs, xe, c), _move(xs, xe, d))


@njit(cache=True)
def segment_crosses_triangle(x, i, j, a, b, c):
    """Static exact test: segment x[i] x[j] crosses triangle abc (orientation signs; touching
    counts as no crossing)."""
    oi = _det(x[a, 0] - x[i, 0], x[a, 1] - x[i, 1], x[a, 2] - x[i, 2],
              x[b, 0] - x[i, 0], x[b, 1] - x[i, 1], x[b, 2] - x[i, 2],
              x[c, 0] - x[i, 0], x[c, 1] - x[i, 1], x[c, 2] - x[i, 2])
    oj = _det(x[a, 0] - x[j, 0], x[a, 1] - x[j, 1], x[a, 2] - x[j, 2],
              x[b, 0] - x[j, 0], x[b, 1] - x[j, 1], x[b, 2] - x[j, 2],
              x[c, 0] - x[j, 0], x[c, 1] - x[j, 1], x[c, 2] - x[j, 2])
    if not ((oi > 0.0 and oj < 0.0) or (oi < 0.0 and oj > 0.0)):
        return False
    # the line ij passes inside abc iff the three edge orientations about it agree in sign
    s0 = _det(x[a, 0] - x[i, 0], x[a, 1] - x[i, 1], x[a, 2] - x[i, 2],
              x[b, 0] - x[i, 0], x[b, 1] - x[i, 1], x[b, 2] - x[i, 2],
              x[j, 0] - x[i, 0], x[j, 1] - x[i, 1], x[j, 2] - x[i, 2])
    s1 = _det(x[b, 0] - x[i, 0], x[b, 1] - x[i, 1], x[b, 2] - x[i, 2],
              x[c, 0] - x[i, 0], x[c, 1] - x[i, 1], x[c, 2] - x[i, 2],
              x[j, 0] - x[i, 0], x[j, 1] - x[i, 1], x[j, 2] - x[i, 2])
    s2 = _det(x[c, 0] - x[i, 0], x[c, 1] - x[i, 1], x[c, 2] - x[i, 2],
              x[a, 0] - x[i, 0], x[a, 1] - x[i, 1], x[a, 2] - x[i, 2],
              x[j, 0] - x[i, 0], x[j, 1] - x[i, 1], x[j, 2] - x[i, 2])
    return (s0 > 0.0 and s1 > 0.0 and s2 > 0.0) or (s0 < 0.0 and s1 < 0.0 and s2 < 0.0)


@njit(cache=True)
def count_edge_triangle_crossings(x, edges, triangles, edge_mask, tri_mask):
    """Cloth edges crossing a cloth triangle they share no vertex with (brute force, O(E T)),
    counting only edges with edge_mask and triangles with tri_mask set."""
    count = 0
    for e in range(edges.shape[0]):
        if not edge_mask[e]:
            continue
        i = edges[e, 0]
        j = edges[e, 1]
        for t in range(triangles.shape[0]):
            if not tri_mask[t]:
                continue
            a = triangles[t, 0]
            b = triangles[t, 1]
            c = triangles[t, 2]
            if i == a or i == b or i == c or j == a or j == b or j == c:
                continue
            if segment_crosses_triangle(x, i, j, a, b, c):
                count += 1
    return count
