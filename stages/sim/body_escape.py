"""Where a particle inside colliders goes when a plain push will not do: out of a collider by the side
it came in (`_entry_side`, SimParams.entry_side), and out of the union of overlapping colliders when
the collision's pass budget is spent (`escape_union`); `_settle` keeps such a move from becoming
Verlet velocity. Called by stages.sim.body_collide.collide.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)
from stages.sim.collider_grid import KIND_SPHERE, apply12, rotate12
from stages.sim.collider_query import _penetrates

NUMBA_CACHE_DEPENDS = ("stages.sim.collider_query", "stages.maps.kernels", "stages.maps.types", "stages.affine",
                       "stages.sim.collider_grid")

PUSH_EPS = 1e-7      # m: responded particles end this far outside, so the inclusive inside test says "out"


@njit(cache=True, _nrt=False, forceinline=True)
def _entry_side(sphere, rad, face_start, planes, idx, q0, q1, q2, o0, o1, o2):
    """(found, r0, r1, r2, n0, n1, n2): where the query-frame point q, inside the convex collider,
    leaves it going back towards o (the particle's start-of-step position in the collider's frame),
    with the outward normal there; found False when o is not outside the collider along that path
    (the particle did not come in through it). The side it came in by: a thin limb pressing cloth onto
    the body takes a particle past its middle in one step, and the map's response (from the middle
    out) then puts it on the limb's far side, the cloth wrapped round the limb (issue 38)."""
    e0 = o0 - q0
    e1 = o1 - q1
    e2 = o2 - q2
    dist = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
    if dist < 1e-12:
        return False, q0, q1, q2, 0.0, 0.0, 0.0
    e0 /= dist
    e1 /= dist
    e2 /= dist
    if sphere:
        b = q0 * e0 + q1 * e1 + q2 * e2
        cc = q0 * q0 + q1 * q1 + q2 * q2 - rad * rad
        t = -b + math.sqrt(max(b * b - cc, 0.0))
        if not (0.0 <= t < dist):
            return False, q0, q1, q2, 0.0, 0.0, 0.0
        r0 = q0 + t * e0
        r1 = q1 + t * e1
        r2 = q2 + t * e2
        k = 1.0 / max(math.sqrt(r0 * r0 + r1 * r1 + r2 * r2), 1e-300)
        return True, r0, r1, r2, r0 * k, r1 * k, r2 * k
    t = np.inf
    best = -1
    for f in range(face_start[idx], face_start[idx + 1]):
        nd = planes[f, 0] * e0 + planes[f, 1] * e1 + planes[f, 2] * e2
        if nd > 0.0:
            tf = (planes[f, 3] - (planes[f, 0] * q0 + planes[f, 1] * q1 + planes[f, 2] * q2)) / nd
            if tf < t:
                t = tf
                best = f
    if best < 0 or not (0.0 <= t < dist):
        return False, q0, q1, q2, 0.0, 0.0, 0.0
    return True, q0 + t * e0, q1 + t * e1, q2 + t * e2, planes[best, 0], planes[best, 1], planes[best, 2]


# -- overlapping colliders: escape from their union when the pass budget is spent ------------------
@njit(cache=True, _nrt=False, forceinline=True)
def _outward(c, col_kind, face_start, planes, idx, tq, px, py, pz):
    """World unit direction out of collider c at the world point p: sphere, radial from its centre;
    hull, the normal of the face whose plane p is farthest in front of (the nearest face from inside).
    Normals go to world by the transpose of tq's linear part (inverse transpose of query -> world)."""
    q0, q1, q2 = apply12(tq, c, px, py, pz)
    if col_kind[c] == KIND_SPHERE:
        n0, n1, n2 = q0, q1, q2
        if n0 * n0 + n1 * n1 + n2 * n2 < 1e-24:
            n0, n1, n2 = 0.0, 1.0, 0.0
    else:
        best = -np.inf
        n0 = n1 = n2 = 0.0
        for f in range(face_start[idx], face_start[idx + 1]):
            s = planes[f, 0] * q0 + planes[f, 1] * q1 + planes[f, 2] * q2 - planes[f, 3]
            if s > best:
                best = s
                n0 = planes[f, 0]
                n1 = planes[f, 1]
                n2 = planes[f, 2]
    w0 = tq[c, 0] * n0 + tq[c, 4] * n1 + tq[c, 8] * n2
    w1 = tq[c, 1] * n0 + tq[c, 5] * n1 + tq[c, 9] * n2
    w2 = tq[c, 2] * n0 + tq[c, 6] * n1 + tq[c, 10] * n2
    k = 1.0 / max(math.sqrt(w0 * w0 + w1 * w1 + w2 * w2), 1e-300)
    return w0 * k, w1 * k, w2 * k


@njit(cache=True, _nrt=False, forceinline=True)
def _ray_exit(c, col_kind, face_start, planes, idx, sph_radius, tq, px, py, pz, dx, dy, dz):
    """Parameter t >= 0 where the world ray p + t d leaves convex collider c (0 if p is not inside).
    The query frame is affine in world, so t is the same in both frames: q(p + t d) = q(p) + t e."""
    q0, q1, q2 = apply12(tq, c, px, py, pz)
    e0, e1, e2 = rotate12(tq, c, dx, dy, dz)
    if col_kind[c] == KIND_SPHERE:
        r = sph_radius[idx]
        a = e0 * e0 + e1 * e1 + e2 * e2
        b = q0 * e0 + q1 * e1 + q2 * e2
        cc = q0 * q0 + q1 * q1 + q2 * q2 - r * r
        if cc >= 0.0 or a <= 0.0:
            return 0.0
        return (-b + math.sqrt(max(b * b - a * cc, 0.0))) / a
    t = np.inf
    for f in range(face_start[idx], face_start[idx + 1]):
        nd = planes[f, 0] * e0 + planes[f, 1] * e1 + planes[f, 2] * e2
        room = planes[f, 3] - (planes[f, 0] * q0 + planes[f, 1] * q1 + planes[f, 2] * q2)
        if nd > 0.0:
            t = min(t, room / nd)
        elif room < 0.0:        # outside this face's half-space and not moving towards it
            return 0.0
    return max(t, 0.0) if t < np.inf else 0.0


@njit(cache=True, _nrt=False)
def _escape_along(col_kind, col_index, sph_radius, method, tq, cw,
                  half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes, cell_base,
                  cell_start, cell_tris, loc_base, loc_x, loc_start, loc_y, loc_face,
                  px, py, pz, dx, dy, dz):
    """(ok, s): the distance s along the world unit direction d at which p + s d is outside every
    collider (the detection's inside test), walking from exit to exit: a ray leaves a convex
    collider once and never re-enters it, so each round passes at least one collider for good and
    nc + 1 rounds suffice (ok False only on round-off)."""
    nc = cw.shape[0]
    s = 0.0
    for _ in range(nc + 1):
        x0 = px + s * dx
        x1 = py + s * dy
        x2 = pz + s * dz
        step = -1.0
        for c in range(nc):
            if _penetrates(c, col_kind, col_index, sph_radius, method, tq, cw,
                           half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes, cell_base,
                           cell_start, cell_tris, loc_base, loc_x, loc_start, loc_y, loc_face, x0, x1, x2):
                step = max(step, _ray_exit(c, col_kind, face_start, planes, col_index[c], sph_radius, tq,
                                           x0, x1, x2, dx, dy, dz))
        if step < 0.0:
            return True, s
        s += step + PUSH_EPS
    return False, s


@njit(cache=True, _nrt=False, forceinline=True)
def _settle(xp, i, px, py, pz, wx, wy, wz):
    """After the escape p -> w: fully inelastic along its direction d (as _push): xp[i] moves along
    d by the outward part of the travel w - xp[i], so the escape is no outward Verlet velocity."""
    dx = wx - px
    dy = wy - py
    dz = wz - pz
    dl = math.sqrt(dx * dx + dy * dy + dz * dz)
    if dl <= 0.0:
        return
    dx /= dl
    dy /= dl
    dz /= dl
    vn = (wx - xp[i, 0]) * dx + (wy - xp[i, 1]) * dy + (wz - xp[i, 2]) * dz
    if vn > 0.0:
        xp[i, 0] += vn * dx
        xp[i, 1] += vn * dy
        xp[i, 2] += vn * dz


@njit(cache=True, _nrt=False)
def escape_union(c, last, col_kind, col_index, sph_radius, method, tq, cw,
                 half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes, cell_base,
                 cell_start, cell_tris, loc_base, loc_x, loc_start, loc_y, loc_face,
                 px, py, pz):
    """(ok, x, y, z): a world point outside every collider near p, for a particle still inside
    collider c when collide's pass budget is spent (pushed back and forth between overlapping
    colliders; `last` the collider of its last push, -1 if none). Candidate directions: out of
    `last` at p (the last push), out of c, their bisector, and the four directions perpendicular to
    the first (the crease between two colliders pressing from opposite sides); along each, the
    exit of the union of the colliders (_escape_along); the shortest wins (first on ties)."""
    ax, ay, az = _outward(c, col_kind, face_start, planes, col_index[c], tq, px, py, pz)
    if last >= 0:
        bx, by, bz = _outward(last, col_kind, face_start, planes, col_index[last], tq, px, py, pz)
    else:
        bx, by, bz = ax, ay, az
    # a unit vector perpendicular to b: cross with the world axis least aligned with it
    if abs(bx) <= abs(by) and abs(bx) <= abs(bz):
        ux, uy, uz = 0.0, bz, -by
    elif abs(by) <= abs(bz):
        ux, uy, uz = -bz, 0.0, bx
    else:
        ux, uy, uz = by, -bx, 0.0
    k = 1.0 / math.sqrt(ux * ux + uy * uy + uz * uz)
    ux *= k
    uy *= k
    uz *= k
    vx = by * uz - bz * uy
    vy = bz * ux - bx * uz
    vz = bx * uy - by * ux
    mx = ax + bx
    my = ay + by
    mz = az + bz
    ml = math.sqrt(mx * mx + my * my + mz * mz)
    best = np.inf
    ex = ey = ez = 0.0
    for kcand in range(7):
        if kcand == 0:
            dx, dy, dz = bx, by, bz
        elif kcand == 1:
            dx, dy, dz = ax, ay, az
        elif kcand == 2:
            if ml < 0.1:      # (nearly) opposite: no bisector
                continue
            dx, dy, dz = mx / ml, my / ml, mz / ml
        elif kcand == 3:
            dx, dy, dz = ux, uy, uz
        elif kcand == 4:
            dx, dy, dz = -ux, -uy, -uz
        elif kcand == 5:
            dx, dy, dz = vx, vy, vz
        else:
            dx, dy, dz = -vx, -vy, -vz
        ok, s = _escape_along(col_kind, col_index, sph_radius, method, tq, cw,
                              half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes, cell_base,
                              cell_start, cell_tris, loc_base, loc_x, loc_start, loc_y, loc_face,
                              px, py, pz, dx, dy, dz)
        if ok and s < best:
            best = s
            ex = dx
            ey = dy
            ez = dz
    if best == np.inf:
        return False, px, py, pz
    return True, px + best * ex, py + best * ey, pz + best * ez
