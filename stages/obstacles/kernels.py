"""Per-step cloth x obstacle collision kernels (paper B): k-DOP tree traversal, continuous
point-triangle test, response. All numba, flat float64 / int32 arrays.

How a cloth step loop uses this (Verlet, positions only)
-------------------------------------------------------
Once per scene:
    oset = stages.obstacles.build_obstacle_set(obstacles, k=18)
    coll = stages.obstacles.ObstacleCollider(oset, x_rest)      # builds the cloth particle tree
Every step, after Verlet integration + distance constraints (x_prev = start of step, x = end):
    n = coll.collide(x_prev, x, inv_mass, t0, t1)               # modifies x and x_prev in place
    coll.contacts()                                             # -> (particle, triangle, point, normal)
From inside a numba step loop instead, call the kernel directly with the collider's arrays:
    args = coll.kernel_args(t0, t1)                             # tuple, see collide_obstacles below
    n = collide_obstacles(x_prev, x, inv_mass, *args)

Contract of `collide_obstacles` (everything world frame, metres, unless said otherwise)
    x_prev (N, 3) f8  start-of-step positions; on contact rewritten so that x - x_prev is the
                      responded displacement (Verlet velocity * dt); for a moving obstacle it is
                      the start-of-step pose applied to the body-frame previous position, so a
                      resting particle inherits the obstacle's motion.
    x      (N, 3) f8  end-of-step (predicted) positions; on contact put back on the obstacle's
                      side at `thickness` from the triangle plane, tangential travel reduced by
                      friction * normal correction (clamped at zero).
    inv_mass (N,) f8  0 = pinned: never moved by a contact.
    c_min, c_max (n_c, h) f8, c_children (n_c, 2) i4, c_leaf (n_c,) i4: the cloth particle tree
                      (KdopTree arrays); c_min/c_max are overwritten (refit over x_prev -> x).
    o_min, o_max (n_o, h) f8, o_children, o_leaf, o_offsets (r+1,) i4: the obstacle forest
                      (leaf = global triangle id); bounds of MOVING obstacles are overwritten
                      (refit over their pose0 and pose1 vertices, inflated by thickness).
    directions (h, 3) f8  the shared k-DOP direction set.
    vertices (V, 3) f8 body frame, triangles (T, 3) i4, tri_obstacle (T,) i4,
    vertex_offsets, triangle_offsets (r+1,) i4: the ObstacleSet arrays.
    pose0, pose1 (r, 4, 4) f8: body -> world of each obstacle at the start / end of the step.
    moving (r,) bool: refit this obstacle's tree this step.
    thickness, friction, restitution (r,) f8: per obstacle.
    out_particle (N,) i4, out_triangle (N,) i4, out_toi (N,) f8, out_point (N, 3) f8 (responded
                      end position), out_normal (N, 3) f8 (world outward normal): the first
                      n_contacts rows are written, in increasing particle id.
    stats (4,) i8: [0] node pairs visited, [1] exact point-triangle tests, [2] contacts,
                      [3] candidate-buffer capacity used (for sizing).
    returns n_contacts.

Exact test (paper B §3.2, the inner-product test): with n the triangle's unit outward normal and
d(p) = n . (p - a) the particle's signed distance to its plane, a particle moving p0 -> p1 hits the
triangle when it ends inside the proximity band (d1 < h), starts no deeper than h/2 behind the plane
(d0 >= -h/2, so particles on the far side of a thin slab or two-sided plane are not pulled through),
and a point of its path projects inside the triangle (barycentric, tolerance 1e-9): where it
crosses the offset plane d = h (or its start, if it already starts inside the band), where it
or where it crosses the surface d = 0. Time of impact t = (d0 - h) / (d0 - d1), 0 when
starting in the band. Each particle keeps ONE contact per step: the earliest t; at equal t the
triangle it is most in front of (largest d0: a particle on top of a two-sided plane is not pushed
to the underside); then the lowest triangle id. Deterministic regardless of traversal order.
"""
from __future__ import annotations

import numpy as np
from numba import njit

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)
from stages.affine import apply_affine, apply_rigid_inverse
from stages.geometry.kdop import refit_particle_tree, refit_range, triangle_bounds

# kernels below compile in code from these modules: their edits must invalidate the disk cache
NUMBA_CACHE_DEPENDS = ("stages.affine", "stages.geometry.kdop")

BARY_TOL = 1e-9
# a particle may start up to this fraction of the band BEHIND a plane and still be pushed out;
# < 1 so a particle resting at +h on one side of a two-sided plane is no candidate of the other.
BACK_FRACTION = 0.5
PUSH_TOL = 1e-10  # m: a particle already put at the band (previous pass) is not hit again


@njit(cache=True, inline="always")
def _disjoint(amin, amax, a, bmin, bmax, b, axis_order):
    # paper B §3.1: the motion direction first (it rejects most pairs), then every other one
    for j in range(axis_order.shape[0]):
        i = axis_order[j]
        if amax[a, i] < bmin[b, i] or bmax[b, i] < amin[a, i]:
            return True
    return False


@njit(cache=True)
def motion_axis_order(directions, x_prev, x):
    """(h,) int32 direction ids, the one most aligned with the cloth's mean motion first."""
    h = directions.shape[0]
    m0 = 0.0
    m1 = 0.0
    m2 = 0.0
    for p in range(x.shape[0]):
        m0 += x[p, 0] - x_prev[p, 0]
        m1 += x[p, 1] - x_prev[p, 1]
        m2 += x[p, 2] - x_prev[p, 2]
    best = 0
    best_v = -1.0
    for i in range(h):
        v = abs(m0 * directions[i, 0] + m1 * directions[i, 1] + m2 * directions[i, 2])
        if v > best_v:
            best_v = v
            best = i
    order = np.empty(h, dtype=np.int32)
    order[0] = best
    j = 1
    for i in range(h):
        if i != best:
            order[j] = i
            j += 1
    return order


@njit(cache=True)
def candidate_pairs(c_min, c_max, c_children, c_leaf, o_min, o_max, o_children, o_leaf, o_offsets,
                    axis_order, stats):
    """Tree-against-tree traversal (paper B §3), iterative with an explicit stack.

    Returns (pairs (m, 2) int32 [particle id, triangle id], m): every leaf pair whose k-DOPs
    overlap. stats[0] += node pairs visited.
    """
    cap = 1024
    pairs = np.empty((cap, 2), dtype=np.int32)
    m = 0
    h = c_min.shape[1]
    # depth-first, each pop pushes <= 2: stack depth <= depth(cloth) + depth(obstacle) + 2
    c_depth = 64
    stack = np.empty((2 * (c_depth + 64) + 8, 2), dtype=np.int32)
    visited = 0
    for r in range(o_offsets.shape[0] - 1):
        top = 0
        stack[0, 0] = 0
        stack[0, 1] = o_offsets[r]
        top = 1
        while top > 0:
            top -= 1
            a = stack[top, 0]
            b = stack[top, 1]
            visited += 1
            if _disjoint(c_min, c_max, a, o_min, o_max, b, axis_order):
                continue
            la = c_leaf[a] >= 0
            lb = o_leaf[b] >= 0
            if la and lb:
                if m == cap:
                    cap *= 2
                    grown = np.empty((cap, 2), dtype=np.int32)
                    grown[:m] = pairs[:m]
                    pairs = grown
                pairs[m, 0] = c_leaf[a]
                pairs[m, 1] = o_leaf[b]
                m += 1
                continue
            if top + 2 > stack.shape[0]:
                grown_s = np.empty((2 * stack.shape[0], 2), dtype=np.int32)
                grown_s[:top] = stack[:top]
                stack = grown_s
            descend_cloth = not la
            if not la and not lb:
                # both inner: descend the larger (longest extent over the directions)
                ea = 0.0
                eb = 0.0
                for i in range(h):
                    ea = max(ea, c_max[a, i] - c_min[a, i])
                    eb = max(eb, o_max[b, i] - o_min[b, i])
                descend_cloth = ea >= eb
            if descend_cloth:
                stack[top, 0] = c_children[a, 1]
                stack[top, 1] = b
                stack[top + 1, 0] = c_children[a, 0]
                stack[top + 1, 1] = b
            else:
                stack[top, 0] = a
                stack[top, 1] = o_children[b, 1]
                stack[top + 1, 0] = a
                stack[top + 1, 1] = o_children[b, 0]
            top += 2
    stats[0] += visited
    return pairs, m


@njit(cache=True, inline="always")
def _projects_inside(p0, p1, t, a, e1x, e1y, e1z, e2x, e2y, e2z):
    """Whether p0 + t (p1 - p0), projected on the triangle's plane, lies inside it."""
    wx = p0[0] + t * (p1[0] - p0[0]) - a[0]
    wy = p0[1] + t * (p1[1] - p0[1]) - a[1]
    wz = p0[2] + t * (p1[2] - p0[2]) - a[2]
    d11 = e1x * e1x + e1y * e1y + e1z * e1z
    d12 = e1x * e2x + e1y * e2y + e1z * e2z
    d22 = e2x * e2x + e2y * e2y + e2z * e2z
    dw1 = wx * e1x + wy * e1y + wz * e1z
    dw2 = wx * e2x + wy * e2y + wz * e2z
    den = d11 * d22 - d12 * d12
    v = (d22 * dw1 - d12 * dw2) / den
    w = (d11 * dw2 - d12 * dw1) / den
    return v >= -BARY_TOL and w >= -BARY_TOL and 1.0 - v - w >= -BARY_TOL


@njit(cache=True)
def point_triangle_ccd(p0, p1, a, b, c, h):
    """Continuous test of a particle moving p0 -> p1 against triangle abc with band h.

    All (3,) float64 in one frame. Returns (hit, toi, d0, nx, ny, nz): d0 is the start distance
    to the plane along the unit outward normal n = (b-a) x (c-a) / |..|.
    """
    e1x = b[0] - a[0]
    e1y = b[1] - a[1]
    e1z = b[2] - a[2]
    e2x = c[0] - a[0]
    e2y = c[1] - a[1]
    e2z = c[2] - a[2]
    nx = e1y * e2z - e1z * e2y
    ny = e1z * e2x - e1x * e2z
    nz = e1x * e2y - e1y * e2x
    ln = np.sqrt(nx * nx + ny * ny + nz * nz)
    if ln == 0.0:
        return False, 0.0, 0.0, 0.0, 0.0, 0.0
    nx /= ln
    ny /= ln
    nz /= ln
    d0 = nx * (p0[0] - a[0]) + ny * (p0[1] - a[1]) + nz * (p0[2] - a[2])
    d1 = nx * (p1[0] - a[0]) + ny * (p1[1] - a[1]) + nz * (p1[2] - a[2])
    # the inner-product (sign) test of paper B, against the plane offset by the band
    if not (d1 < h - PUSH_TOL and d0 >= -BACK_FRACTION * h):
        return False, 0.0, d0, nx, ny, nz
    t = 0.0
    if d0 > h:
        t = (d0 - h) / (d0 - d1)
    # the crossing of the offset plane, or of the surface itself (an oblique path near an edge
    # can cross the band outside the triangle yet the surface inside it)
    if _projects_inside(p0, p1, t, a, e1x, e1y, e1z, e2x, e2y, e2z):
        return True, t, d0, nx, ny, nz
    if d1 < 0.0 and d0 > 0.0 and _projects_inside(p0, p1, d0 / (d0 - d1), a, e1x, e1y, e1z, e2x, e2y, e2z):
        return True, t, d0, nx, ny, nz
    return False, t, d0, nx, ny, nz


@njit(cache=True)
def refit_obstacles(o_min, o_max, o_children, o_leaf, directions, vertices, triangles,
                    vertex_offsets, triangle_offsets, o_offsets, pose0, pose1, moving, thickness):
    """Refit the trees of moving obstacles over their start- and end-of-step world vertices."""
    h = directions.shape[0]
    for r in range(moving.shape[0]):
        if not moving[r]:
            continue
        v_lo = vertex_offsets[r]
        v_hi = vertex_offsets[r + 1]
        t_lo = triangle_offsets[r]
        t_hi = triangle_offsets[r + 1]
        w0 = np.empty((v_hi - v_lo, 3))
        w1 = np.empty((v_hi - v_lo, 3))
        for v in range(v_lo, v_hi):
            w0[v - v_lo, 0], w0[v - v_lo, 1], w0[v - v_lo, 2] = apply_affine(pose0[r], vertices[v, 0], vertices[v, 1], vertices[v, 2])
            w1[v - v_lo, 0], w1[v - v_lo, 1], w1[v - v_lo, 2] = apply_affine(pose1[r], vertices[v, 0], vertices[v, 1], vertices[v, 2])
        local_tris = triangles[t_lo:t_hi] - v_lo
        pmin = np.empty((t_hi - t_lo, h))
        pmax = np.empty((t_hi - t_lo, h))
        triangle_bounds(directions, w0, w1, local_tris, thickness[r], pmin, pmax)
        # leaf_prim holds global triangle ids: shift to this obstacle's rows
        lo = o_offsets[r]
        hi = o_offsets[r + 1]
        leaf_local = o_leaf[lo:hi].copy()
        for i in range(leaf_local.shape[0]):
            if leaf_local[i] >= 0:
                leaf_local[i] -= t_lo
        children_local = o_children[lo:hi].copy()
        for i in range(children_local.shape[0]):
            if children_local[i, 0] >= 0:
                children_local[i, 0] -= lo
                children_local[i, 1] -= lo
        refit_range(o_min[lo:hi], o_max[lo:hi], children_local, leaf_local, pmin, pmax, 0, hi - lo)


@njit(cache=True)
def best_contacts(x_prev, x, inv_mass, pairs, n_pairs, vertices, triangles, tri_obstacle,
                  pose0, pose1, thickness, best_tri, best_t, best_d0, prev_normal, has_prev):
    """Exact tests over candidate pairs; keeps per particle the earliest contact (see module doc).

    best_tri (N,) i4 must come in as -1. A particle with has_prev (pushed along the world normal
    prev_normal earlier in this step) skips triangles facing against that normal, so a later pass
    never pushes it back through (the underside of a two-sided plane or of a thin slab).
    Returns the number of exact tests run.
    """
    p0 = np.empty(3)
    p1 = np.empty(3)
    a = np.empty(3)
    b = np.empty(3)
    c = np.empty(3)
    tests = 0
    for k in range(n_pairs):
        p = pairs[k, 0]
        tri = pairs[k, 1]
        if inv_mass[p] == 0.0:
            continue
        r = tri_obstacle[tri]
        p0[0], p0[1], p0[2] = apply_rigid_inverse(pose0[r], x_prev[p, 0], x_prev[p, 1], x_prev[p, 2])
        p1[0], p1[1], p1[2] = apply_rigid_inverse(pose1[r], x[p, 0], x[p, 1], x[p, 2])
        for j in range(3):
            a[j] = vertices[triangles[tri, 0], j]
            b[j] = vertices[triangles[tri, 1], j]
            c[j] = vertices[triangles[tri, 2], j]
        tests += 1
        hit, t, d0, nx, ny, nz = point_triangle_ccd(p0, p1, a, b, c, thickness[r])
        if not hit:
            continue
        if has_prev[p]:
            m = pose1[r]
            wx = m[0, 0] * nx + m[0, 1] * ny + m[0, 2] * nz
            wy = m[1, 0] * nx + m[1, 1] * ny + m[1, 2] * nz
            wz = m[2, 0] * nx + m[2, 1] * ny + m[2, 2] * nz
            if wx * prev_normal[p, 0] + wy * prev_normal[p, 1] + wz * prev_normal[p, 2] < 0.0:
                continue
        cur = best_tri[p]
        better = cur < 0 or t < best_t[p] or (t == best_t[p] and (d0 > best_d0[p] or (d0 == best_d0[p] and tri < cur)))
        if better:
            best_tri[p] = tri
            best_t[p] = t
            best_d0[p] = d0
    return tests


@njit(cache=True)
def respond(x_prev, x, best_tri, best_t, vertices, triangles, tri_obstacle, pose0, pose1,
            thickness, friction, restitution, prev_normal, has_prev):
    """Paper B response for each particle with a contact (modifies x, x_prev); returns the count.

    Geometry of the push: the particle's end x against the chosen triangle's plane. Velocity:
    the Verlet displacement currently encoded by x - x_prev (both in the obstacle's body frame).
    """
    n = 0
    for p in range(x.shape[0]):
        tri = best_tri[p]
        if tri < 0:
            continue
        r = tri_obstacle[tri]
        h = thickness[r]
        ax = vertices[triangles[tri, 0], 0]
        ay = vertices[triangles[tri, 0], 1]
        az = vertices[triangles[tri, 0], 2]
        e1x = vertices[triangles[tri, 1], 0] - ax
        e1y = vertices[triangles[tri, 1], 1] - ay
        e1z = vertices[triangles[tri, 1], 2] - az
        e2x = vertices[triangles[tri, 2], 0] - ax
        e2y = vertices[triangles[tri, 2], 1] - ay
        e2z = vertices[triangles[tri, 2], 2] - az
        nx = e1y * e2z - e1z * e2y
        ny = e1z * e2x - e1x * e2z
        nz = e1x * e2y - e1y * e2x
        ln = np.sqrt(nx * nx + ny * ny + nz * nz)
        nx /= ln
        ny /= ln
        nz /= ln
        # body frame of the obstacle: the relative motion of particle and obstacle
        # velocity (Verlet displacement) as currently encoded by x - x_prev
        s0x, s0y, s0z = apply_rigid_inverse(pose0[r], x_prev[p, 0], x_prev[p, 1], x_prev[p, 2])
        s1x, s1y, s1z = apply_rigid_inverse(pose1[r], x[p, 0], x[p, 1], x[p, 2])
        d1 = nx * (s1x - ax) + ny * (s1y - ay) + nz * (s1z - az)
        vx = s1x - s0x
        vy = s1y - s0y
        vz = s1z - s0z
        vn = vx * nx + vy * ny + vz * nz
        tx = vx - vn * nx
        ty = vy - vn * ny
        tz = vz - vn * nz
        push = h - d1  # > 0: normal position correction
        if push < 0.0:
            push = 0.0
        # Coulomb-like: tangential travel loses friction * push, never reverses
        tl = np.sqrt(tx * tx + ty * ty + tz * tz)
        keep = 1.0
        if tl > 0.0:
            keep = 1.0 - friction[r] * push / tl
            if keep < 0.0:
                keep = 0.0
        vn_new = vn
        if vn < 0.0:
            vn_new = -restitution[r] * vn
        e1 = s1x + push * nx - (1.0 - keep) * tx
        e2 = s1y + push * ny - (1.0 - keep) * ty
        e3 = s1z + push * nz - (1.0 - keep) * tz
        # the previous position that makes the Verlet velocity the responded one
        q1 = e1 - (keep * tx + vn_new * nx)
        q2 = e2 - (keep * ty + vn_new * ny)
        q3 = e3 - (keep * tz + vn_new * nz)
        x[p, 0], x[p, 1], x[p, 2] = apply_affine(pose1[r], e1, e2, e3)
        x_prev[p, 0], x_prev[p, 1], x_prev[p, 2] = apply_affine(pose0[r], q1, q2, q3)
        m = pose1[r]
        prev_normal[p, 0] = m[0, 0] * nx + m[0, 1] * ny + m[0, 2] * nz
        prev_normal[p, 1] = m[1, 0] * nx + m[1, 1] * ny + m[1, 2] * nz
        prev_normal[p, 2] = m[2, 0] * nx + m[2, 1] * ny + m[2, 2] * nz
        has_prev[p] = True
        n += 1
    return n


@njit(cache=True)
def collide_obstacles(x_prev, x, inv_mass,
                      c_min, c_max, c_children, c_leaf,
                      o_min, o_max, o_children, o_leaf, o_offsets,
                      directions, vertices, triangles, tri_obstacle, vertex_offsets, triangle_offsets,
                      pose0, pose1, moving, thickness, friction, restitution,
                      out_particle, out_triangle, out_toi, out_point, out_normal, stats, passes=2):
    """One step of cloth x obstacle collision; see the module docstring for the contract."""
    refit_obstacles(o_min, o_max, o_children, o_leaf, directions, vertices, triangles,
                    vertex_offsets, triangle_offsets, o_offsets, pose0, pose1, moving, thickness)
    n = x.shape[0]
    x_start = x_prev.copy()  # the swept segments always start here, across passes
    best_tri = np.full(n, -1, dtype=np.int32)
    best_t = np.zeros(n)
    best_d0 = np.zeros(n)
    final_tri = np.full(n, -1, dtype=np.int32)
    final_t = np.zeros(n)
    prev_normal = np.zeros((n, 3))
    has_prev = np.zeros(n, dtype=np.bool_)
    for _ in range(passes):
        refit_particle_tree(c_min, c_max, c_children, c_leaf, directions, x_start, x)
        order = motion_axis_order(directions, x_start, x)
        pairs, m = candidate_pairs(c_min, c_max, c_children, c_leaf, o_min, o_max, o_children, o_leaf,
                                   o_offsets, order, stats)
        stats[3] = max(stats[3], pairs.shape[0])
        best_tri[:] = -1
        stats[1] += best_contacts(x_start, x, inv_mass, pairs, m, vertices, triangles, tri_obstacle,
                                  pose0, pose1, thickness, best_tri, best_t, best_d0, prev_normal, has_prev)
        k = respond(x_prev, x, best_tri, best_t, vertices, triangles, tri_obstacle, pose0, pose1,
                    thickness, friction, restitution, prev_normal, has_prev)
        if k == 0:
            break
        for p in range(n):
            if best_tri[p] >= 0 and final_tri[p] < 0:
                final_tri[p] = best_tri[p]  # report the first (earliest) contact of the step
                final_t[p] = best_t[p]
    # the step's contact list: one row per particle touched in any pass, increasing particle id
    c = 0
    for p in range(n):
        if final_tri[p] < 0:
            continue
        r = tri_obstacle[final_tri[p]]
        out_particle[c] = p
        out_triangle[c] = final_tri[p]
        out_toi[c] = final_t[p]
        for j in range(3):
            out_point[c, j] = x[p, j]
        a = triangles[final_tri[p], 0]
        e1x = vertices[triangles[final_tri[p], 1], 0] - vertices[a, 0]
        e1y = vertices[triangles[final_tri[p], 1], 1] - vertices[a, 1]
        e1z = vertices[triangles[final_tri[p], 1], 2] - vertices[a, 2]
        e2x = vertices[triangles[final_tri[p], 2], 0] - vertices[a, 0]
        e2y = vertices[triangles[final_tri[p], 2], 1] - vertices[a, 1]
        e2z = vertices[triangles[final_tri[p], 2], 2] - vertices[a, 2]
        nx = e1y * e2z - e1z * e2y
        ny = e1z * e2x - e1x * e2z
        nz = e1x * e2y - e1y * e2x
        ln = np.sqrt(nx * nx + ny * ny + nz * nz)
        for j in range(3):
            out_normal[c, j] = (pose1[r][j, 0] * nx + pose1[r][j, 1] * ny + pose1[r][j, 2] * nz) / ln
        c += 1
    stats[2] += c
    return c
