"""Seidel's randomised incremental linear program in R^3 (numba), for the hull simplification's
collapse LPs (stages.hulls.kernels): `seidel_lp3` minimises c.x subject to A x <= b inside the box
|x_k| <= box (rows of A unit vectors, so b is a distance); `shuffled` the random order it adds
the constraints in.
"""
from __future__ import annotations

import numpy as np
from numba import njit

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)

LP_EPS = 1e-10       # feasibility slack of the LP, in the LP's normalised units


@njit(cache=True)
def _lp1(a2, b2, m, px, py, dx, dy, c1):
    """Minimise c1*t on the 2D line p + t d subject to rows 0..m-1 of a2 x <= b2."""
    lo = -1e300
    hi = 1e300
    for j in range(m):
        ad = a2[j, 0] * dx + a2[j, 1] * dy
        r = b2[j] - (a2[j, 0] * px + a2[j, 1] * py)
        if abs(ad) < 1e-13:
            if r < -LP_EPS:
                return False, 0.0
            continue
        t = r / ad
        if ad > 0:
            if t < hi:
                hi = t
        elif t > lo:
            lo = t
    if lo > hi + LP_EPS:
        return False, 0.0
    if c1 < 0:
        return True, hi
    return True, lo


@njit(cache=True)
def _lp2(a2, b2, m, cx, cy, box2):
    """2D Seidel. Rows 0..3 of a2/b2 must be the box |u|, |w| <= box2."""
    u = -box2 if cx > 0 else box2
    w = -box2 if cy > 0 else box2
    for j in range(4, m):
        if a2[j, 0] * u + a2[j, 1] * w <= b2[j] + LP_EPS:
            continue
        px = a2[j, 0] * b2[j]
        py = a2[j, 1] * b2[j]
        dx = -a2[j, 1]
        dy = a2[j, 0]
        ok, t = _lp1(a2, b2, j, px, py, dx, dy, cx * dx + cy * dy)
        if not ok:
            return False, 0.0, 0.0
        u = px + t * dx
        w = py + t * dy
    return True, u, w


@njit(cache=True)
def seidel_lp3(a, b, c, box, order):
    """Minimise c.x s.t. a[i].x <= b[i] for i in `order` (unit rows), |x_k| <= box.

    Returns (feasible, x). Expected O(n) time for a random order.
    """
    m = order.shape[0]
    x = np.empty(3)
    for k in range(3):
        x[k] = -box if c[k] > 0 else box
    a2 = np.empty((m + 10, 2))
    b2 = np.empty(m + 10)
    e1 = np.empty(3)
    e2 = np.empty(3)
    box2 = 2.0 * box * np.sqrt(3.0)
    for ii in range(m):
        i = order[ii]
        ai = a[i]
        if ai[0] * x[0] + ai[1] * x[1] + ai[2] * x[2] <= b[i] + LP_EPS:
            continue
        # orthonormal basis of the plane ai.x = b[i]
        if abs(ai[0]) < 0.6:
            t0, t1, t2 = 0.0, -ai[2], ai[1]      # ai x (1,0,0)
        else:
            t0, t1, t2 = ai[2], 0.0, -ai[0]      # ai x (0,1,0)
        nt = np.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
        e1[0], e1[1], e1[2] = t0 / nt, t1 / nt, t2 / nt
        e2[0] = ai[1] * e1[2] - ai[2] * e1[1]
        e2[1] = ai[2] * e1[0] - ai[0] * e1[2]
        e2[2] = ai[0] * e1[1] - ai[1] * e1[0]
        p0 = ai * b[i]
        a2[0, 0], a2[0, 1], b2[0] = 1.0, 0.0, box2
        a2[1, 0], a2[1, 1], b2[1] = -1.0, 0.0, box2
        a2[2, 0], a2[2, 1], b2[2] = 0.0, 1.0, box2
        a2[3, 0], a2[3, 1], b2[3] = 0.0, -1.0, box2
        cnt = 4
        # the 3D box, then the earlier rows, projected into the plane
        for jj in range(-6, ii):
            if jj < 0:
                k = (jj + 6) // 2
                s = 1.0 if (jj + 6) % 2 == 0 else -1.0
                g0, g1 = s * e1[k], s * e2[k]
                r = box - s * p0[k]
            else:
                j = order[jj]
                aj = a[j]
                g0 = aj[0] * e1[0] + aj[1] * e1[1] + aj[2] * e1[2]
                g1 = aj[0] * e2[0] + aj[1] * e2[1] + aj[2] * e2[2]
                r = b[j] - (aj[0] * p0[0] + aj[1] * p0[1] + aj[2] * p0[2])
            ng = np.sqrt(g0 * g0 + g1 * g1)
            if ng < 1e-12:
                if r < -LP_EPS:
                    return False, x
                continue
            a2[cnt, 0] = g0 / ng
            a2[cnt, 1] = g1 / ng
            b2[cnt] = r / ng
            cnt += 1
        cu = c[0] * e1[0] + c[1] * e1[1] + c[2] * e1[2]
        cw = c[0] * e2[0] + c[1] * e2[1] + c[2] * e2[2]
        ok, u, w = _lp2(a2, b2, cnt, cu, cw, box2)
        if not ok:
            return False, x
        for k in range(3):
            x[k] = p0[k] + u * e1[k] + w * e2[k]
    return True, x


@njit(cache=True)
def shuffled(n, state):
    """Deterministic Fisher-Yates permutation driven by a 64-bit xorshift state (1-element array)."""
    order = np.arange(n)
    s = state[0]
    for i in range(n - 1, 0, -1):
        s ^= (s << np.uint64(13))
        s ^= (s >> np.uint64(7))
        s ^= (s << np.uint64(17))
        j = np.int64(s % np.uint64(i + 1))
        order[i], order[j] = order[j], order[i]
    state[0] = s
    return order
