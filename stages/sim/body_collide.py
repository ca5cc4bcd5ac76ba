"""Collision of the cloth with the character's colliders (paper A §2-3): the inside test and response
of spheres (eq. 5-6) and hulls (the maps' query, stages.maps.kernels.hull_query), Coulomb friction,
and the count of particles still inside; the single-collider queries are in stages.sim.collider_query,
the escape from overlapping colliders in stages.sim.body_escape.

The hull query is inlined: the hull response reports its exit face (the contact normal, no face
scan); a particle is transformed only after the world sphere test, a hull only queried inside its
OBB, and only the colliders in the particle's grid cell (stages.sim.collider_grid) are visited.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)
from stages.jit import serial_and_parallel
from stages.maps.kernels import (METHOD_NEAREST_PLANE, METHOD_PAPER, ZERO_DIR, _nearest_plane, hull_query,
                                query_arrays)
from stages.maps.types import KIND_CYLINDER as KIND_CYLINDER_MAP
from stages.sim.body_escape import PUSH_EPS, _entry_side, _outward, _settle, escape_union
from stages.sim.collider_grid import KIND_SPHERE, apply12, grid_cell, rotate12
from stages.sim.collider_query import IGNORED, TOUCH_EPS, _collider_hit, _inside_any, _penetrates, _sphere_hit

# the hull query is inlined from stages.maps.kernels: its edits must invalidate this module's cache
NUMBA_CACHE_DEPENDS = ("stages.maps.kernels", "stages.maps.types", "stages.affine", "stages.sim.collider_grid",
                       "stages.sim.collider_query", "stages.sim.body_escape")



@njit(cache=True, _nrt=False, forceinline=True)
def _push(c, q0, q1, q2, r0, r1, r2, n0, n1, n2, tq0, fq, xp, i, friction):
    """(pushed, px, py, pz): the world position after collider c's response r (query frame, contact
    normal n) to the point q, with Coulomb friction; moves xp[i] for a fully inelastic contact."""
    u0 = r0 - q0
    u1 = r1 - q1
    u2 = r2 - q2
    dn = math.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
    if dn < TOUCH_EPS:
        return False, 0.0, 0.0, 0.0
    depth = u0 * n0 + u1 * n1 + u2 * n2            # the push's normal part: the "normal force"
    e = PUSH_EPS / dn                              # nudge along the push, strictly outside
    r0 += e * u0
    r1 += e * u1
    r2 += e * u2
    # displacement relative to the collider over the step (start-of-step position in its frame now)
    o0, o1, o2 = apply12(tq0, c, xp[i, 0], xp[i, 1], xp[i, 2])
    v0 = r0 - o0
    v1 = r1 - o1
    v2 = r2 - o2
    vn = v0 * n0 + v1 * n1 + v2 * n2
    if friction > 0.0:
        # Coulomb: the tangential travel loses friction * depth (all of it if shorter: static).
        # Sliding along the contact plane keeps the point outside (convex collider).
        t0 = v0 - vn * n0
        t1 = v1 - vn * n1
        t2 = v2 - vn * n2
        tl = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
        if tl > 0.0:
            k = min(1.0, friction * max(depth, 0.0) / tl)
            r0 -= k * t0
            r1 -= k * t1
            r2 -= k * t2
    px, py, pz = apply12(fq, c, r0, r1, r2)
    if vn > 0.0:
        # fully inelastic: the push-out must not become an outward Verlet velocity,
        # so move xp along the (world) normal by the outward relative travel
        w0, w1, w2 = rotate12(fq, c, n0, n1, n2)
        xp[i, 0] += vn * w0
        xp[i, 1] += vn * w1
        xp[i, 2] += vn * w2
    return True, px, py, pz


EDGE_EPS = 1e-12     # m: slack of the exit-face containment test (rounding is ~1e-17 m here)


@njit(cache=True, _nrt=False, forceinline=True)
def _cached_face(mkind, half, planes, face_edges, src_range, h, f, q0, q1, q2):
    """(known, inside, r0, r1, r2): the paper's hull query answered from one remembered face f.

    In front of f's plane, q is outside the convex hull (a separating plane). Behind it: the map ray
    of q (paper A §2.4: from the OBB centre, or q's projection on the cylinder axis, through q)
    leaves the hull at exactly one point when its source is inside the hull (src_range: the source
    positions known to be strictly inside); if the ray meets face f's triangle (face_edges: three
    in-plane inward edge planes) that point is the exit, so q is inside and the point is the
    response, f the contact face: the same answer as hull_query, from one plane and three edge tests
    instead of the point location and the cell's face scan. known False: ask hull_query."""
    if planes[f, 0] * q0 + planes[f, 1] * q1 + planes[f, 2] * q2 > planes[f, 3]:
        return True, False, q0, q1, q2
    if mkind[h] == KIND_CYLINDER_MAP:
        s0 = q0
        d0 = 0.0
    else:
        s0 = 0.0
        d0 = q0
    if not (src_range[h, 0] < s0 < src_range[h, 1]):
        return False, False, q0, q1, q2
    nd = planes[f, 0] * d0 + planes[f, 1] * q1 + planes[f, 2] * q2
    z = ZERO_DIR * half[h, 0]
    if nd <= 0.0 or d0 * d0 + q1 * q1 + q2 * q2 <= z * z:
        return False, False, q0, q1, q2
    tau = (planes[f, 3] - planes[f, 0] * s0) / nd
    r0 = s0 + tau * d0
    r1 = tau * q1
    r2 = tau * q2
    for k in range(0, 12, 4):
        if face_edges[f, k] * r0 + face_edges[f, k + 1] * r1 + face_edges[f, k + 2] * r2 < face_edges[f, k + 3] - EDGE_EPS:
            return False, False, q0, q1, q2
    return True, True, r0, r1, r2


PINCHED = 4         # collide's mark in inside[i]: held in the overlap of two bones' colliders pressing on it
PINCH_ESCAPE = 0    # collide's `pinch` codes (SimParams.pinch, stages.sim.types.PINCH_RULES order)
PINCH_MIDPOINT = 1
PINCH_LIMB = 2


@njit(cache=True, _nrt=False, forceinline=True)
def _outranked(c, i, family, contact, col_kind, col_index, sph_radius, method, tq, fq, cw, grid_start, grid_items,
               grid_box, grid_dims, half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes,
               cell_base, cell_start, cell_tris, loc_base, loc_x, loc_start, loc_y, loc_face,
               px, py, pz, wx, wy, wz):
    """(rank, e): whether collider c must not push particle i from p to w (world) because a collider h
    of a deeper joint, not c's parent or child (a forearm over the torso, a hand over the hip, a knee
    over the other thigh), holds it: 1, h holds p too (e: where h would push it out, world); 2, h
    holds w only (p is between them: c's push would put it into h); 0, neither (the 'limb' pinch
    rule). h is looked for among the colliders of p's grid cell."""
    bb = grid_cell(grid_box, grid_dims, px, py, pz)
    if bb < 0:
        return 0, px, py, pz
    oc = family[c, 0]
    found = 0
    for j in range(grid_start[bb], grid_start[bb + 1]):
        h = grid_items[j]
        if family[h, 2] <= family[c, 2] or contact[i, h] == IGNORED:
            continue
        oh = family[h, 0]
        if oh == oc or family[h, 1] == oc or family[c, 1] == oh:
            continue
        dx = px - cw[h, 0]
        dy = py - cw[h, 1]
        dz = pz - cw[h, 2]
        if dx * dx + dy * dy + dz * dz < cw[h, 4]:
            q0, q1, q2 = apply12(tq, h, px, py, pz)
            hit, r0, r1, r2, n0, n1, n2 = _collider_hit(
                h, col_kind, col_index, sph_radius, method, half, mkind, n_theta, n_second, second_lo, second_hi,
                face_start, planes, cell_base, cell_start, cell_tris, loc_base, loc_x, loc_start, loc_y, loc_face,
                q0, q1, q2)
            if hit and (r0 - q0) ** 2 + (r1 - q1) ** 2 + (r2 - q2) ** 2 >= TOUCH_EPS * TOUCH_EPS:
                ex, ey, ez = apply12(fq, h, r0, r1, r2)
                return 1, ex, ey, ez
        if found == 0 and _penetrates(h, col_kind, col_index, sph_radius, method, tq, cw, half, mkind, n_theta,
                                      n_second, second_lo, second_hi, face_start, planes, cell_base, cell_start,
                                      cell_tris, loc_base, loc_x, loc_start, loc_y, loc_face, wx, wy, wz):
            found = 2
    return found, px, py, pz

OPEN = 2            # collide's screening mark in inside[i]: the particle may be inside a collider
SCREEN_MAX = 4      # collide screens every particle against every collider up to this many colliders


@serial_and_parallel(cache=True, _nrt=False)
def collide(x, xp, inv_mass, m, method, col_kind, col_index, sph_radius, tq, tq0, fq, cw,
            grid_start, grid_items, grid_box, grid_dims, face_edges, src_range, friction, passes, corrected, inside,
            speed2, contact, h, col_joint, pinch, entry, family):
    """Collision detection and response of every free particle against every collider.

    Per particle: the colliders listed in its grid cell (build_grid) whose world bounding sphere
    holds it are tested in their query frame (spheres: paper eq. 5-6; hulls: OBB rejection, then
    stages.maps.kernels.hull_query with `method`). After a push by collider c the particle is outside c
    (by PUSH_EPS; friction slides it along the contact plane); the colliders of the cell of its new
    position are then visited cyclically after c (world sphere test first) until every one has been
    checked at the current position without a push, at most `passes` x (number of colliders) visits.
    A particle still inside one when the budget is spent is being pushed back and forth between
    overlapping colliders. With `pinch` PINCH_LIMB, that rarely happens: a push by collider c is not
    made when a collider of a deeper joint that is not c's parent or child (family (C, 3): joint,
    parent, depth) holds the particle or would hold it after the push (_outranked): the limb pressing
    the cloth onto the body wins, the cloth stays on the limb's side it was on, inside the body's
    collider, and is marked PINCHED (counted apart from penetrations). With `pinch` PINCH_MIDPOINT (or
    PINCH_LIMB, between colliders of equal depth), if collider c (holding it) and the collider of its
    last push belong to different joints (col_joint (C,) int) and c's push points into the last one
    (they press from opposite sides: an arm lowered onto the torso), it is pinched: it moves halfway
    along c's push, to the middle of their overlap (no friction, inelastic; inside[i] = PINCHED).
    Otherwise `escape_union` moves it to a point outside all of them (no friction, inelastic along
    the escape). With `entry` (bool), a push the map's response would make away from where the
    particle came from (its start-of-step position in the collider's frame, o: (r - q) . (o - q) < 0)
    goes instead to where the path back towards o leaves the collider, when o is outside it
    (_entry_side): the cloth stays on the side of the limb it was on. The response gets Coulomb friction relative to the collider: its tangential travel
    over the step loses up to `friction` times the push's normal depth.
    corrected[i] |= 1 if the particle was pushed; inside[i] = 1 if it is still inside a collider at
    the end (PINCHED if pinched); speed2[i] = |x - xp|^2 / h^2 at the end (divergence check).
    Colliders a particle's garment ignores (contact[i, c] == IGNORED, set by simulate: a limb the
    animation swings through the garment) are skipped, as if absent (kept in the face cache's array:
    the entry a visit reads anyway, no second (N, C) array).
    Temporal coherence (METHOD_PAPER): contact (N, C) int32 holds per particle and hull the face of
    its last verdict (the exit face of a push, or a separating face), -1 unknown; the next query of
    that hull first tries that face (_cached_face: the same answer when it gives one), which is right
    again for a particle resting on, sliding over or hovering near the hull. A point an outline
    rejected (no face) gets the plane it is farthest in front of, stored as -2 - face: tried as a
    separating plane only. face_edges (F, 12), src_range (H, 2): see _cached_face and
    stages/sim/simulate.py.
    With at most SCREEN_MAX colliders, the particles a first pass finds outside all of them (the
    first visit's tests without a query) are done there (speed2 only); the visiting loop, as
    described, runs for the others.
    """
    (half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes, cell_base, cell_start, cell_tris,
     loc_base, loc_x, loc_start, loc_y, loc_face) = query_arrays(m)
    nc = cw.shape[0]
    ih2 = 1.0 / (h * h)
    # Speed: with few colliders, a first pass finds the particles that may be inside one (the tests
    # of the visiting loop's first visit, without a query: world sphere; sphere, its radius; hull,
    # its OBB and, METHOD_PAPER, the plane of its remembered face; the same arithmetic, combined
    # without a branch, one collider at a time with its data read once) and the visiting loop runs
    # for those only: its data-dependent branches and the grid's chain of dependent loads cost
    # ~20 ns a particle even when it found nothing (drape, one hull, at frame 100: collisions 48.5
    # -> 38.7 us a step; one collider at a time, its data in registers: 32.5 -> 29.2 us; the speeds
    # in the first collider's pass: -> 28.0 us).
    screen = 0 < nc <= SCREEN_MAX
    if screen:
        for c in range(nc):
            s0, s1, s2, r2 = cw[c, 0], cw[c, 1], cw[c, 2], cw[c, 4]
            a0, a1, a2, a3, a4, a5, a6, a7, a8, a9, a10, a11 = (
                tq[c, 0], tq[c, 1], tq[c, 2], tq[c, 3], tq[c, 4], tq[c, 5], tq[c, 6], tq[c, 7], tq[c, 8], tq[c, 9],
                tq[c, 10], tq[c, 11])
            idx = col_index[c]
            sphere = col_kind[c] == KIND_SPHERE
            rad = sph_radius[idx] if sphere else 0.0
            b0, b1, b2 = (np.inf, np.inf, np.inf) if sphere or method == METHOD_NEAREST_PLANE else (
                half[idx, 0], half[idx, 1], half[idx, 2])
            faces = not sphere and method == METHOD_PAPER
            for i in prange(x.shape[0]):   # particles are independent: any thread count, same result
                px = x[i, 0]
                py = x[i, 1]
                pz = x[i, 2]
                dx = px - s0
                dy = py - s1
                dz = pz - s2
                may = (dx * dx + dy * dy + dz * dz < r2) & (inv_mass[i] > 0.0) & (contact[i, c] != IGNORED)
                q0 = a0 * px + a1 * py + a2 * pz + a3       # apply12
                q1 = a4 * px + a5 * py + a6 * pz + a7
                q2 = a8 * px + a9 * py + a10 * pz + a11
                if sphere:
                    may &= q0 * q0 + q1 * q1 + q2 * q2 < rad * rad
                else:
                    may &= (abs(q0) <= b0) & (abs(q1) <= b1) & (abs(q2) <= b2)
                    f = contact[i, c]
                    fs = max(f, -2 - f, 0) if f != IGNORED else 0   # the remembered face (>= 0: a verdict's, <= -2: separating) or 0
                    ahead = planes[fs, 0] * q0 + planes[fs, 1] * q1 + planes[fs, 2] * q2 > planes[fs, 3]
                    may &= (not faces) | (f == -1) | (not ahead)
                if c == 0:      # the first collider's pass also sets the speed (and clears the mark)
                    inside[i] = OPEN if may else 0
                    vx = px - xp[i, 0]
                    vy = py - xp[i, 1]
                    vz = pz - xp[i, 2]
                    speed2[i] = (vx * vx + vy * vy + vz * vz) * ih2
                else:
                    inside[i] |= OPEN if may else 0
    for i in prange(x.shape[0]):
        if screen and inside[i] != OPEN:
            continue
        px = x[i, 0]
        py = x[i, 1]
        pz = x[i, 2]
        inside[i] = 0
        b = grid_cell(grid_box, grid_dims, px, py, pz) if inv_mass[i] > 0.0 else -1
        if b >= 0:
            # one visiting loop (a single inlined query site keeps the loop small):
            # stage 0, the cell's colliders; stage 1, after a push, the others cyclically until all
            # were seen without a push; stage 2, the budget spent: only detect (no push).
            e = grid_start[b]
            e1 = grid_start[b + 1]
            stage = 0
            last = np.int64(-1)     # not the literal -1: numba would compile escape_union for it too
            streak = 0
            budget = passes * nc
            c = 0
            k = k0 = k1 = 0             # stages 1-2: the cell list of the current position, its cursor
            while True:
                if stage == 0:
                    if e == e1:
                        if last < 0 or nc == 1:
                            break
                        stage = 1
                        streak = -1
                        continue
                    c = grid_items[e]
                    e += 1
                else:
                    if streak < 0:      # a new position: cycle over its cell's colliders (no other can hold it)
                        bb = grid_cell(grid_box, grid_dims, px, py, pz)
                        if bb < 0:
                            break
                        k0 = grid_start[bb]
                        k1 = grid_start[bb + 1]
                        k = k1 - 1      # the cursor before the first collider after `last` (cyclic)
                        streak = 0
                        for j in range(k0, k1):
                            if grid_items[j] <= last:
                                k = j
                                streak = int(grid_items[j] == last)     # `last` is left outside by its push: seen
                    if streak >= k1 - k0:
                        break
                    k = k + 1 if k + 1 < k1 else k0
                    c = grid_items[k]
                    if stage == 1:
                        budget -= 1
                        if budget < 0:
                            stage = 2
                            streak = -1
                            continue
                dx = px - cw[c, 0]
                dy = py - cw[c, 1]
                dz = pz - cw[c, 2]
                if dx * dx + dy * dy + dz * dz < cw[c, 4] and contact[i, c] != IGNORED:
                    q0, q1, q2 = apply12(tq, c, px, py, pz)
                    idx = col_index[c]
                    hit = False
                    r0 = r1 = r2 = n0 = n1 = n2 = 0.0
                    if col_kind[c] == KIND_SPHERE:
                        hit, r0, r1, r2, n0, n1, n2 = _sphere_hit(sph_radius[idx], q0, q1, q2)
                    elif method == METHOD_NEAREST_PLANE or (abs(q0) <= half[idx, 0] and abs(q1) <= half[idx, 1]
                                                            and abs(q2) <= half[idx, 2]):
                        known = False
                        face = contact[i, c]
                        if method == METHOD_PAPER and face >= 0:
                            known, hit, r0, r1, r2 = _cached_face(mkind, half, planes, face_edges, src_range, idx,
                                                                  face, q0, q1, q2)
                        elif method == METHOD_PAPER and face <= -2:     # a separating face: its plane only
                            f = -2 - face
                            known = planes[f, 0] * q0 + planes[f, 1] * q1 + planes[f, 2] * q2 > planes[f, 3]
                        if not known:
                            hit, r0, r1, r2, face = hull_query(
                                half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes, cell_base,
                                cell_start, cell_tris, loc_base, loc_x, loc_start, loc_y, loc_face,
                                idx, method, q0, q1, q2)
                            if face >= 0:
                                contact[i, c] = face
                            elif method == METHOD_PAPER and not hit:
                                # rejected by an outline (no face): remember the plane q is farthest in
                                # front of as -2 - face, for the plane test above and the first pass
                                ahead, f = _nearest_plane(planes, face_start, idx, q0, q1, q2)
                                if ahead > 0.0:
                                    contact[i, c] = -2 - f
                        if hit:
                            n0 = planes[face, 0]
                            n1 = planes[face, 1]
                            n2 = planes[face, 2]
                    if hit and pinch == PINCH_LIMB:
                        wx, wy, wz = apply12(fq, c, r0, r1, r2)
                        rank, ex, ey, ez = _outranked(
                            c, i, family, contact, col_kind, col_index, sph_radius, method, tq, fq, cw, grid_start,
                            grid_items, grid_box, grid_dims, half, mkind, n_theta, n_second, second_lo, second_hi,
                            face_start, planes, cell_base, cell_start, cell_tris, loc_base, loc_x, loc_start, loc_y,
                            loc_face, px, py, pz, wx, wy, wz)
                        if rank != 0:
                            # in both: midway between the two exits (the middle of their overlap, whichever
                            # was visited first); between them: halfway out of c
                            if rank == 2:
                                ex = px
                                ey = py
                                ez = pz
                            wx = ex + 0.5 * (wx - ex)
                            wy = ey + 0.5 * (wy - ey)
                            wz = ez + 0.5 * (wz - ez)
                            _settle(xp, i, px, py, pz, wx, wy, wz)
                            px = wx
                            py = wy
                            pz = wz
                            last = c
                            inside[i] = PINCHED
                            break
                    if hit:
                        if stage == 2:
                            if (r0 - q0) ** 2 + (r1 - q1) ** 2 + (r2 - q2) ** 2 >= TOUCH_EPS * TOUCH_EPS:
                                if pinch != PINCH_ESCAPE and last >= 0 and col_joint[c] != col_joint[last]:
                                    wx, wy, wz = apply12(fq, c, r0, r1, r2)
                                    ux = wx - px
                                    uy = wy - py
                                    uz = wz - pz
                                    nx, ny, nz = _outward(last, col_kind, face_start, planes, col_index[last], tq,
                                                          px, py, pz)
                                    if ux * nx + uy * ny + uz * nz < 0.0:
                                        # pinched between two bones pressing from opposite sides
                                        wx = px + 0.5 * ux
                                        wy = py + 0.5 * uy
                                        wz = pz + 0.5 * uz
                                        _settle(xp, i, px, py, pz, wx, wy, wz)
                                        px = wx
                                        py = wy
                                        pz = wz
                                        inside[i] = PINCHED
                                        break
                                # budget spent between overlapping colliders: leave their union
                                ok, wx, wy, wz = escape_union(
                                    c, last, col_kind, col_index, sph_radius, method, tq, cw,
                                    half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes,
                                    cell_base, cell_start, cell_tris, loc_base, loc_x, loc_start, loc_y, loc_face,
                                    px, py, pz)
                                if ok:
                                    _settle(xp, i, px, py, pz, wx, wy, wz)
                                    px = wx
                                    py = wy
                                    pz = wz
                                    last = c
                                else:
                                    inside[i] = 1
                                break
                        else:
                            if entry:
                                # the map pushes it away from where it came from: out the side it came in by
                                o0, o1, o2 = apply12(tq0, c, xp[i, 0], xp[i, 1], xp[i, 2])
                                if (r0 - q0) * (o0 - q0) + (r1 - q1) * (o1 - q1) + (r2 - q2) * (o2 - q2) < 0.0:
                                    sph = col_kind[c] == KIND_SPHERE
                                    found, s0, s1, s2, m0, m1, m2 = _entry_side(
                                        sph, sph_radius[idx] if sph else 0.0, face_start, planes, idx,
                                        q0, q1, q2, o0, o1, o2)
                                    if found:
                                        r0, r1, r2, n0, n1, n2 = s0, s1, s2, m0, m1, m2
                            pushed, wx, wy, wz = _push(c, q0, q1, q2, r0, r1, r2, n0, n1, n2, tq0, fq, xp, i, friction)
                            if pushed:
                                px = wx
                                py = wy
                                pz = wz
                                last = c
                                streak = -1
                                continue
                streak += 1
            if last >= 0:
                corrected[i] |= 1
                x[i, 0] = px
                x[i, 1] = py
                x[i, 2] = pz
        vx = px - xp[i, 0]
        vy = py - xp[i, 1]
        vz = pz - xp[i, 2]
        speed2[i] = (vx * vx + vy * vy + vz * vz) * ih2


@njit(cache=True, _nrt=False)
def count_inside(x, inv_mass, m, method, col_kind, col_index, sph_radius, tq, cw, contact, inside):
    """inside[i] = 1 if free particle i is inside any collider it does not ignore (contact (N, C), see
    collide; no response)."""
    (half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes, cell_base, cell_start, cell_tris,
     loc_base, loc_x, loc_start, loc_y, loc_face) = query_arrays(m)
    for i in range(x.shape[0]):
        inside[i] = 0
        if inv_mass[i] > 0.0:
            inside[i] = _inside_any(
                col_kind, col_index, sph_radius, method, tq, cw, contact, i,
                half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes, cell_base,
                cell_start, cell_tris, loc_base, loc_x, loc_start, loc_y, loc_face, x[i, 0], x[i, 1], x[i, 2])
