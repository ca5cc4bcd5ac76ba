"""Numba kernels of the cloth step (paper A §1, §3.3) and the body penetration audit.

Layout: all garments concatenated into one particle system; flat float64 / int32 arrays.
x (N, 3) current positions, xp (N, 3) previous positions (Verlet), both in the relative frame.
Poses: fwd (J, 4, 4) bone-local -> relative frame at the END of the step, inv (J, 4, 4) its inverse,
inv0 (J, 4, 4) the inverse at the START of the step (for friction relative to a moving collider).

Determinism: every parallel loop writes only its own particle / triangle / spring partition, and
the spring partitions touch disjoint particles (see `partition_springs`), so results do not depend
on the thread count or scheduling.
"""
from __future__ import annotations

import math

import llvmlite.ir as ir
import numpy as np
from numba import njit, prange, types
from numba.core import cgutils
from numba.extending import intrinsic

from stages.maps.kernels import hull_collide

KIND_HULL = 0
KIND_SPHERE = 1
PUSH_EPS = 1e-7      # m: responded particles end this far outside, so the inclusive inside test says "out"
TOUCH_EPS = 1e-9     # m: a response moving a particle less than this is a touch, not a penetration
N_BINS = 64          # broad phase: horizontal slabs over the colliders' height range

# timer slots (CPU cycles; simulate.py converts to seconds)
T_INTEGRATE = 0
T_CONSTRAINTS = 1
T_COLLISIONS = 2


@intrinsic
def cycles(typingctx):
    """CPU cycle counter (llvm.readcyclecounter): a nanosecond-scale timer inside njit code."""
    sig = types.int64()

    def codegen(context, builder, signature, args):
        fnty = ir.FunctionType(ir.IntType(64), [])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "llvm.readcyclecounter")
        return builder.call(fn, [])

    return sig, codegen


@njit(cache=True)
def read_cycles():
    return cycles()


# -- small affine helpers -------------------------------------------------------------------------
@njit(cache=True, inline="always")
def _apply(m, x, y, z):
    return (m[0, 0] * x + m[0, 1] * y + m[0, 2] * z + m[0, 3],
            m[1, 0] * x + m[1, 1] * y + m[1, 2] * z + m[1, 3],
            m[2, 0] * x + m[2, 1] * y + m[2, 2] * z + m[2, 3])


# -- forces + Verlet ------------------------------------------------------------------------------
@njit(cache=True, parallel=True)
def aero_forces(x, xp, inv_mass, tris, h, s, d_prev, wind, k_drag, k_lift, out):
    """Per-triangle aerodynamic force (N) from the air velocity relative to the triangle.

    Vertex velocity v = (x - xp + s d_prev) / h (Verlet estimate, world velocity scaled by the
    inertia scale s). w = wind - mean v; n' = unit normal oriented along w; c = n'.w/|w|.
    drag = k_drag A c |w|^2 w/|w|; lift = k_lift A c |w|^2 (n' - c w/|w|)   (k = 0.5 rho C).
    """
    for t in prange(tris.shape[0]):
        a = tris[t, 0]
        b = tris[t, 1]
        c = tris[t, 2]
        wx = wind[0] - ((x[a, 0] - xp[a, 0]) + (x[b, 0] - xp[b, 0]) + (x[c, 0] - xp[c, 0])) / (3.0 * h) - s * d_prev[0] / h
        wy = wind[1] - ((x[a, 1] - xp[a, 1]) + (x[b, 1] - xp[b, 1]) + (x[c, 1] - xp[c, 1])) / (3.0 * h) - s * d_prev[1] / h
        wz = wind[2] - ((x[a, 2] - xp[a, 2]) + (x[b, 2] - xp[b, 2]) + (x[c, 2] - xp[c, 2])) / (3.0 * h) - s * d_prev[2] / h
        e1x = x[b, 0] - x[a, 0]
        e1y = x[b, 1] - x[a, 1]
        e1z = x[b, 2] - x[a, 2]
        e2x = x[c, 0] - x[a, 0]
        e2y = x[c, 1] - x[a, 1]
        e2z = x[c, 2] - x[a, 2]
        nx = e1y * e2z - e1z * e2y
        ny = e1z * e2x - e1x * e2z
        nz = e1x * e2y - e1y * e2x
        n2 = math.sqrt(nx * nx + ny * ny + nz * nz)   # = 2 area
        w2 = wx * wx + wy * wy + wz * wz
        if n2 <= 1e-20 or w2 <= 1e-20:
            out[t, 0] = 0.0
            out[t, 1] = 0.0
            out[t, 2] = 0.0
            continue
        wn = math.sqrt(w2)
        area = 0.5 * n2
        nx /= n2
        ny /= n2
        nz /= n2
        cs = (nx * wx + ny * wy + nz * wz) / wn
        if cs < 0.0:
            nx = -nx
            ny = -ny
            nz = -nz
            cs = -cs
        fd = k_drag * area * cs * w2 / wn
        fl = k_lift * area * cs * w2
        # explicit drag is unstable once it would more than stop the triangle within one step:
        # cap the force at (triangle mass) |w| / h
        mt = 0.0
        for v in (a, b, c):
            if inv_mass[v] > 0.0:
                mt += 1.0 / (3.0 * inv_mass[v])
        fmax = mt * wn / h
        ftot = math.sqrt(fd * fd * w2 + fl * fl * (1.0 - cs * cs))
        if mt > 0.0 and ftot > fmax:
            fd *= fmax / ftot
            fl *= fmax / ftot
        out[t, 0] = fd * wx + fl * (nx - cs * wx / wn)
        out[t, 1] = fd * wy + fl * (ny - cs * wy / wn)
        out[t, 2] = fd * wz + fl * (nz - cs * wz / wn)


@njit(cache=True, parallel=True)
def integrate(x, xp, inv_mass, attach_joint, attach_local, fwd, h, gravity, damping, s, d_prev, d_next,
              use_aero, tri_force, vt_start, vt_tri):
    """Verlet step of every particle; attached particles follow their bone, pinned ones stay.

    x_new = x + (1 - damping) (x - xp + s d_prev) - s d_next + a h^2, a = g + F_aero / m,
    then xp <- x, x <- x_new. d_prev / d_next: root translation over the previous / this step.
    """
    hh = h * h
    keep = 1.0 - damping
    for i in prange(x.shape[0]):
        ox = x[i, 0]
        oy = x[i, 1]
        oz = x[i, 2]
        j = attach_joint[i]
        w = inv_mass[i]
        if j >= 0:
            nx, ny, nz = _apply(fwd[j], attach_local[i, 0], attach_local[i, 1], attach_local[i, 2])
        elif w == 0.0:
            nx = ox
            ny = oy
            nz = oz
        else:
            ax = gravity[0]
            ay = gravity[1]
            az = gravity[2]
            if use_aero:
                fx = 0.0
                fy = 0.0
                fz = 0.0
                for k in range(vt_start[i], vt_start[i + 1]):
                    t = vt_tri[k]
                    fx += tri_force[t, 0]
                    fy += tri_force[t, 1]
                    fz += tri_force[t, 2]
                ax += fx * w / 3.0
                ay += fy * w / 3.0
                az += fz * w / 3.0
            nx = ox + keep * (ox - xp[i, 0] + s * d_prev[0]) - s * d_next[0] + ax * hh
            ny = oy + keep * (oy - xp[i, 1] + s * d_prev[1]) - s * d_next[1] + ay * hh
            nz = oz + keep * (oz - xp[i, 2] + s * d_prev[2]) - s * d_next[2] + az * hh
        xp[i, 0] = ox
        xp[i, 1] = oy
        xp[i, 2] = oz
        x[i, 0] = nx
        x[i, 1] = ny
        x[i, 2] = nz


# -- springs --------------------------------------------------------------------------------------
@njit(cache=True, inline="always")
def _correct_range(x, si, sj, rest, wi, wj, k0, k1):
    """Gauss-Seidel position correction of springs k0..k1-1 in order (stretch and compression)."""
    for k in range(k0, k1):
        i = si[k]
        j = sj[k]
        dx = x[j, 0] - x[i, 0]
        dy = x[j, 1] - x[i, 1]
        dz = x[j, 2] - x[i, 2]
        d2 = dx * dx + dy * dy + dz * dz
        if d2 <= 1e-24:
            continue
        c = 1.0 - rest[k] / math.sqrt(d2)
        a = wi[k] * c
        b = wj[k] * c
        x[i, 0] += a * dx
        x[i, 1] += a * dy
        x[i, 2] += a * dz
        x[j, 0] -= b * dx
        x[j, 1] -= b * dy
        x[j, 2] -= b * dz


@njit(cache=True, parallel=True)
def _correct_parts(x, si, sj, rest, wi, wj, part_start, n_parts):
    for p in prange(n_parts):
        _correct_range(x, si, sj, rest, wi, wj, part_start[p], part_start[p + 1])


@njit(cache=True)
def correct_springs(x, si, sj, rest, wi, wj, part_start, iterations):
    """`iterations` rounds; each: the partitions in parallel (disjoint particles), then the springs
    crossing partitions (last block of part_start) sequentially.

    wi, wj: per spring, stiffness * w_i / (w_i + w_j) and stiffness * w_j / (w_i + w_j).
    """
    n_parts = part_start.size - 2
    for _ in range(iterations):
        if n_parts > 1:
            _correct_parts(x, si, sj, rest, wi, wj, part_start, n_parts)
        else:
            _correct_range(x, si, sj, rest, wi, wj, part_start[0], part_start[1])
        _correct_range(x, si, sj, rest, wi, wj, part_start[n_parts], part_start[n_parts + 1])


def partition_springs(positions: np.ndarray, springs: np.ndarray, n_parts: int = 2):
    """Order springs for `correct_springs`: (order, part_start).

    Particles are split at the median of their longest axis into n_parts slabs; a spring whose two
    particles lie in one slab goes to that slab's block, the rest to the last (sequential) block.
    Inside a block springs are ordered by colour (spring_colours), then input order.
    """
    n = positions.shape[0]
    if n_parts < 2 or n < 64:
        n_parts = 1
    if n_parts == 1:
        block = np.zeros(springs.shape[0], np.int64)
    else:
        axis = int(np.argmax(np.ptp(positions, axis=0)))
        rank = np.empty(n, np.int64)
        rank[np.argsort(positions[:, axis], kind="stable")] = np.arange(n)
        part = (rank * n_parts) // n
        pa, pb = part[springs[:, 0]], part[springs[:, 1]]
        block = np.where(pa == pb, pa, n_parts)
    colour = spring_colours(springs.astype(np.int64), n)
    order = np.lexsort((np.arange(springs.shape[0]), colour, block))
    part_start = np.searchsorted(block[order], np.arange(n_parts + 2)).astype(np.int64)
    return order, part_start


@njit(cache=True)
def spring_colours(springs, n):
    """Greedy edge colouring: no two springs of one colour share a particle. Ordering springs by
    colour keeps Gauss-Seidel sequential but lets consecutive corrections overlap in the CPU
    (no dependency chain through a shared particle), ~3x faster than lexicographic order."""
    used = np.zeros(n, np.int64)          # bit c set: particle already has a spring of colour c
    out = np.empty(springs.shape[0], np.int64)
    for k in range(springs.shape[0]):
        m = used[springs[k, 0]] | used[springs[k, 1]]
        c = 0
        while c < 63 and (m >> c) & 1:
            c += 1
        out[k] = c
        if c < 63:
            used[springs[k, 0]] |= 1 << c
            used[springs[k, 1]] |= 1 << c
    return out


# -- collisions -----------------------------------------------------------------------------------
@njit(cache=True)
def build_bins(fwd, col_joint, col_bcenter, col_bradius, cw, bin_start, bin_items, bin_range):
    """World bounding spheres of the colliders (cw (C, 4): centre, radius^2) and the y slabs.

    bin_range (2,): y of the first slab and the slab height. bin_start (N_BINS + 1,), bin_items
    (C * N_BINS,): CSR list of the colliders whose sphere overlaps each slab.
    """
    nc = col_joint.size
    lo = np.inf
    hi = -np.inf
    for c in range(nc):
        px, py, pz = _apply(fwd[col_joint[c]], col_bcenter[c, 0], col_bcenter[c, 1], col_bcenter[c, 2])
        r = col_bradius[c]
        cw[c, 0] = px
        cw[c, 1] = py
        cw[c, 2] = pz
        cw[c, 3] = r * r
        lo = min(lo, py - r)
        hi = max(hi, py + r)
    nb = bin_start.size - 1
    if nc == 0:
        bin_start[:] = 0
        bin_range[0] = 0.0
        bin_range[1] = 1.0
        return
    bh = (hi - lo) / nb + 1e-12
    bin_range[0] = lo
    bin_range[1] = bh
    counts = np.zeros(nb, np.int64)
    for c in range(nc):
        r = col_bradius[c]
        b0 = max(0, int((cw[c, 1] - r - lo) / bh))
        b1 = min(nb - 1, int((cw[c, 1] + r - lo) / bh))
        for b in range(b0, b1 + 1):
            counts[b] += 1
    bin_start[0] = 0
    for b in range(nb):
        bin_start[b + 1] = bin_start[b] + counts[b]
    fill = bin_start[:-1].copy()
    for c in range(nc):
        r = col_bradius[c]
        b0 = max(0, int((cw[c, 1] - r - lo) / bh))
        b1 = min(nb - 1, int((cw[c, 1] + r - lo) / bh))
        for b in range(b0, b1 + 1):
            bin_items[fill[b]] = c
            fill[b] += 1


@njit(cache=True)
def _hull_normal(m, h, x, y, z):
    """Bone-local outward unit normal of the face of hull h whose plane is nearest in front of /
    least behind the bone-local point (x, y, z) (the face a surface point lies on)."""
    c = m.center[h]
    r = m.axes[h]
    dx = x - c[0]
    dy = y - c[1]
    dz = z - c[2]
    q0 = r[0, 0] * dx + r[0, 1] * dy + r[0, 2] * dz
    q1 = r[1, 0] * dx + r[1, 1] * dy + r[1, 2] * dz
    q2 = r[2, 0] * dx + r[2, 1] * dy + r[2, 2] * dz
    best = -np.inf
    bf = m.face_start[h]
    for f in range(m.face_start[h], m.face_start[h + 1]):
        pl = m.planes[f]
        s = pl[0] * q0 + pl[1] * q1 + pl[2] * q2 - pl[3]
        if s > best:
            best = s
            bf = f
    pl = m.planes[bf]
    return (r[0, 0] * pl[0] + r[1, 0] * pl[1] + r[2, 0] * pl[2],
            r[0, 1] * pl[0] + r[1, 1] * pl[1] + r[2, 1] * pl[2],
            r[0, 2] * pl[0] + r[1, 2] * pl[1] + r[2, 2] * pl[2])


@njit(cache=True, inline="always")
def _collide_one(m, kind, idx, method, sph_center, sph_radius, lx, ly, lz):
    """(inside, qx, qy, qz): the response of one collider in its bone-local frame."""
    if kind == KIND_SPHERE:
        cx = sph_center[idx, 0]
        cy = sph_center[idx, 1]
        cz = sph_center[idx, 2]
        r = sph_radius[idx]
        dx = lx - cx
        dy = ly - cy
        dz = lz - cz
        d2 = dx * dx + dy * dy + dz * dz
        if d2 >= r * r:                   # paper eq. 5: inside iff |x - c| < r
            return False, lx, ly, lz
        d = math.sqrt(d2)
        if d < 1e-12:                     # at the centre: no direction, push up (deterministic)
            return True, cx, cy + r, cz
        f = r / d                         # paper eq. 6: c + r (x - c) / |x - c|
        return True, cx + f * dx, cy + f * dy, cz + f * dz
    return hull_collide(m, idx, (lx, ly, lz), method)


@njit(cache=True, parallel=True)
def collide(x, xp, inv_mass, fwd, inv, inv0, m, method, col_joint, col_kind, col_index, sph_center, sph_radius,
            cw, bin_start, bin_items, bin_range, friction, passes, corrected, inside, speed2, h):
    """Collision detection and response of every free particle against every collider.

    Per particle: up to `passes` passes over the colliders whose world bounding sphere holds it
    (found through the y slabs); each collider inside test and response runs in the collider's
    bone-local frame (spheres: paper eq. 5-6; hulls: stages.maps.kernels.hull_collide, `method`
    METHOD_PAPER = map ray, METHOD_NEAREST_PLANE = baseline). A responded particle is nudged
    PUSH_EPS outward and gets friction: its displacement relative to the collider (bone-local now
    minus bone-local of xp at the step start) loses `friction` of its tangential part. Passes stop
    when nothing moved; if the last pass still moved the particle, one more check decides whether
    it is still inside a collider.
    corrected[i] |= 1 if the particle was moved; inside[i] = 1 if it is still inside after the
    passes; speed2[i] = |x - xp|^2 / h^2 at the end (divergence check).
    """
    y0 = bin_range[0]
    bh = bin_range[1]
    nb = bin_start.size - 1
    for i in prange(x.shape[0]):
        px = x[i, 0]
        py = x[i, 1]
        pz = x[i, 2]
        inside[i] = 0
        if inv_mass[i] > 0.0:
            moved = False
            for ps in range(passes + 1):
                b = int(math.floor((py - y0) / bh))
                if b < 0 or b >= nb:
                    moved = False
                    break
                moved = False
                for e in range(bin_start[b], bin_start[b + 1]):
                    c = bin_items[e]
                    dx = px - cw[c, 0]
                    dy = py - cw[c, 1]
                    dz = pz - cw[c, 2]
                    if dx * dx + dy * dy + dz * dz >= cw[c, 3]:
                        continue
                    j = col_joint[c]
                    lx, ly, lz = _apply(inv[j], px, py, pz)
                    hit, qx, qy, qz = _collide_one(m, col_kind[c], col_index[c], method, sph_center, sph_radius, lx, ly, lz)
                    if not hit:
                        continue
                    nx = qx - lx
                    ny = qy - ly
                    nz = qz - lz
                    dn = math.sqrt(nx * nx + ny * ny + nz * nz)
                    if dn < TOUCH_EPS:
                        continue
                    if ps == passes:          # verification pass: still inside, leave it
                        inside[i] = 1
                        break
                    nx /= dn
                    ny /= dn
                    nz /= dn
                    qx += PUSH_EPS * nx
                    qy += PUSH_EPS * ny
                    qz += PUSH_EPS * nz
                    if col_kind[c] == KIND_HULL:  # the ray is not the surface normal: use the exit face's
                        nx, ny, nz = _hull_normal(m, col_index[c], qx, qy, qz)
                    ox, oy, oz = _apply(inv0[j], xp[i, 0], xp[i, 1], xp[i, 2])
                    ux = qx - ox
                    uy = qy - oy
                    uz = qz - oz
                    un = ux * nx + uy * ny + uz * nz
                    if friction > 0.0:
                        qx -= friction * (ux - un * nx)
                        qy -= friction * (uy - un * ny)
                        qz -= friction * (uz - un * nz)
                    px, py, pz = _apply(fwd[j], qx, qy, qz)
                    if un > 0.0:
                        # fully inelastic: the push-out must not become an outward Verlet velocity,
                        # so move xp along the (world) normal by the outward relative travel
                        f = fwd[j]
                        wx = f[0, 0] * nx + f[0, 1] * ny + f[0, 2] * nz
                        wy = f[1, 0] * nx + f[1, 1] * ny + f[1, 2] * nz
                        wz = f[2, 0] * nx + f[2, 1] * ny + f[2, 2] * nz
                        xp[i, 0] += un * wx
                        xp[i, 1] += un * wy
                        xp[i, 2] += un * wz
                    moved = True
                    corrected[i] = 1
                if not moved or inside[i]:
                    break
            x[i, 0] = px
            x[i, 1] = py
            x[i, 2] = pz
        vx = px - xp[i, 0]
        vy = py - xp[i, 1]
        vz = pz - xp[i, 2]
        speed2[i] = (vx * vx + vy * vy + vz * vz) / (h * h)


# -- one frame -------------------------------------------------------------------------------------
@njit(cache=True)
def run_steps(x, xp, inv_mass, attach_joint, attach_local,
              si, sj, rest, wi, wj, part_start, iterations,
              tris, vt_start, vt_tri, tri_force, use_aero,
              h, gravity, damping, wind, k_drag, k_lift, s, d_prev, d_next,
              fwd, inv, inv0, m, method, col_joint, col_kind, col_index, col_bcenter, col_bradius,
              sph_center, sph_radius, friction, passes,
              cw, bin_start, bin_items, bin_range, corrected, inside, speed2, timers):
    """Steps k = 0..K-1 of one frame in the paper's order: forces, Verlet (+ attachments), spring
    corrections, collisions. Per step k: fwd[k] / inv[k] (J, 4, 4) the pose at its end, inv0[k] at
    its start; d_prev[k] / d_next[k] (3,) the root translation over the previous / this step.
    timers (3,) int64 accumulate cycles of integrate / constraints / collisions.
    """
    for k in range(fwd.shape[0]):
        t0 = cycles()
        if use_aero:
            aero_forces(x, xp, inv_mass, tris, h, s, d_prev[k], wind, k_drag, k_lift, tri_force)
        integrate(x, xp, inv_mass, attach_joint, attach_local, fwd[k], h, gravity, damping, s,
                  d_prev[k], d_next[k], use_aero, tri_force, vt_start, vt_tri)
        t1 = cycles()
        correct_springs(x, si, sj, rest, wi, wj, part_start, iterations)
        t2 = cycles()
        build_bins(fwd[k], col_joint, col_bcenter, col_bradius, cw, bin_start, bin_items, bin_range)
        collide(x, xp, inv_mass, fwd[k], inv[k], inv0[k], m, method, col_joint, col_kind, col_index,
                sph_center, sph_radius, cw, bin_start, bin_items, bin_range, friction, passes,
                corrected, inside, speed2, h)
        t3 = cycles()
        timers[T_INTEGRATE] += t1 - t0
        timers[T_CONSTRAINTS] += t2 - t1
        timers[T_COLLISIONS] += t3 - t2


# -- body penetration audit: generalised winding number ------------------------------------------
@njit(cache=True, inline="always")
def _solid_angle(ax, ay, az, bx, by, bz, cx, cy, cz):
    """Signed solid angle of triangle (a, b, c) seen from the origin (Van Oosterom & Strackee)."""
    la = math.sqrt(ax * ax + ay * ay + az * az)
    lb = math.sqrt(bx * bx + by * by + bz * bz)
    lc = math.sqrt(cx * cx + cy * cy + cz * cz)
    det = ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx)
    den = la * lb * lc + (ax * bx + ay * by + az * bz) * lc + (bx * cx + by * cy + bz * cz) * la \
        + (cx * ax + cy * ay + cz * az) * lb
    return 2.0 * math.atan2(det, den)


@njit(cache=True, parallel=True)
def winding_numbers_brute(points, vertices, triangles, out):
    """Exact generalised winding number of every point: sum of solid angles / 4 pi. O(N T)."""
    for i in prange(points.shape[0]):
        qx = points[i, 0]
        qy = points[i, 1]
        qz = points[i, 2]
        acc = 0.0
        for t in range(triangles.shape[0]):
            a = triangles[t, 0]
            b = triangles[t, 1]
            c = triangles[t, 2]
            acc += _solid_angle(vertices[a, 0] - qx, vertices[a, 1] - qy, vertices[a, 2] - qz,
                                vertices[b, 0] - qx, vertices[b, 1] - qy, vertices[b, 2] - qz,
                                vertices[c, 0] - qx, vertices[c, 1] - qy, vertices[c, 2] - qz)
        out[i] = acc / (4.0 * math.pi)


@njit(cache=True)
def refit_winding_tree(vertices, triangles, order, node_start, node_end, children, data):
    """Per node (children after parents in index order): data[n] = area-weighted centroid (3),
    area-weighted normal sum (3), radius of a ball around the centroid holding the node's
    triangles (1). Recomputed from the current (skinned) vertices."""
    nn = node_start.size
    for n in range(nn - 1, -1, -1):
        if children[n, 0] < 0:
            ax = 0.0
            cx = 0.0
            cy = 0.0
            cz = 0.0
            sx = 0.0
            sy = 0.0
            sz = 0.0
            for k in range(node_start[n], node_end[n]):
                t = order[k]
                a = triangles[t, 0]
                b = triangles[t, 1]
                c = triangles[t, 2]
                e1x = vertices[b, 0] - vertices[a, 0]
                e1y = vertices[b, 1] - vertices[a, 1]
                e1z = vertices[b, 2] - vertices[a, 2]
                e2x = vertices[c, 0] - vertices[a, 0]
                e2y = vertices[c, 1] - vertices[a, 1]
                e2z = vertices[c, 2] - vertices[a, 2]
                nx = 0.5 * (e1y * e2z - e1z * e2y)
                ny = 0.5 * (e1z * e2x - e1x * e2z)
                nz = 0.5 * (e1x * e2y - e1y * e2x)
                ar = math.sqrt(nx * nx + ny * ny + nz * nz) + 1e-300
                sx += nx
                sy += ny
                sz += nz
                ax += ar
                cx += ar * (vertices[a, 0] + vertices[b, 0] + vertices[c, 0]) / 3.0
                cy += ar * (vertices[a, 1] + vertices[b, 1] + vertices[c, 1]) / 3.0
                cz += ar * (vertices[a, 2] + vertices[b, 2] + vertices[c, 2]) / 3.0
            cx /= ax
            cy /= ax
            cz /= ax
            r = 0.0
            for k in range(node_start[n], node_end[n]):
                t = order[k]
                for q in range(3):
                    v = triangles[t, q]
                    dx = vertices[v, 0] - cx
                    dy = vertices[v, 1] - cy
                    dz = vertices[v, 2] - cz
                    r = max(r, math.sqrt(dx * dx + dy * dy + dz * dz))
            data[n, 7] = ax
        else:
            l = children[n, 0]
            rr = children[n, 1]
            al = data[l, 7]
            ar = data[rr, 7]
            ax = al + ar
            cx = (al * data[l, 0] + ar * data[rr, 0]) / ax
            cy = (al * data[l, 1] + ar * data[rr, 1]) / ax
            cz = (al * data[l, 2] + ar * data[rr, 2]) / ax
            sx = data[l, 3] + data[rr, 3]
            sy = data[l, 4] + data[rr, 4]
            sz = data[l, 5] + data[rr, 5]
            r = 0.0
            for ch in (l, rr):
                dx = data[ch, 0] - cx
                dy = data[ch, 1] - cy
                dz = data[ch, 2] - cz
                r = max(r, math.sqrt(dx * dx + dy * dy + dz * dz) + data[ch, 6])
            data[n, 7] = ax
        data[n, 0] = cx
        data[n, 1] = cy
        data[n, 2] = cz
        data[n, 3] = sx
        data[n, 4] = sy
        data[n, 5] = sz
        data[n, 6] = r


@njit(cache=True, parallel=True)
def winding_numbers_tree(points, vertices, triangles, order, node_start, node_end, children, data, beta, out):
    """Fast generalised winding number (Barill et al. 2018, first-order dipole far field).

    A node farther than beta * radius from the query contributes (c - q) . N / (4 pi |c - q|^3)
    (its area-weighted normal sum N as a dipole at its centroid c); nearer leaves are summed exactly.
    """
    inv4pi = 1.0 / (4.0 * math.pi)
    for i in prange(points.shape[0]):
        qx = points[i, 0]
        qy = points[i, 1]
        qz = points[i, 2]
        stack = np.empty(64, np.int64)
        top = 0
        stack[0] = 0
        top = 1
        acc = 0.0
        while top > 0:
            top -= 1
            n = stack[top]
            dx = data[n, 0] - qx
            dy = data[n, 1] - qy
            dz = data[n, 2] - qz
            d2 = dx * dx + dy * dy + dz * dz
            r = data[n, 6] * beta
            if d2 > r * r:
                d = math.sqrt(d2)
                acc += (dx * data[n, 3] + dy * data[n, 4] + dz * data[n, 5]) / (d2 * d) * inv4pi
            elif children[n, 0] < 0:
                s = 0.0
                for k in range(node_start[n], node_end[n]):
                    t = order[k]
                    a = triangles[t, 0]
                    b = triangles[t, 1]
                    c = triangles[t, 2]
                    s += _solid_angle(vertices[a, 0] - qx, vertices[a, 1] - qy, vertices[a, 2] - qz,
                                      vertices[b, 0] - qx, vertices[b, 1] - qy, vertices[b, 2] - qz,
                                      vertices[c, 0] - qx, vertices[c, 1] - qy, vertices[c, 2] - qz)
                acc += s * inv4pi
            else:
                stack[top] = children[n, 0]
                stack[top + 1] = children[n, 1]
                top += 2
        out[i] = acc


def build_winding_tree(vertices: np.ndarray, triangles: np.ndarray, leaf_size: int = 8):
    """Topology of the winding-number tree, from the bind pose: median splits of triangle centroids
    along the longest axis. Returns (order, node_start, node_end, children) with node 0 the root
    and children after their parent; refit it per frame with `refit_winding_tree`."""
    cent = vertices[triangles].mean(axis=1)
    order = np.arange(triangles.shape[0])
    starts, ends, kids = [], [], []

    def node(lo, hi):
        idx = len(starts)
        starts.append(lo)
        ends.append(hi)
        kids.append([-1, -1])
        if hi - lo > leaf_size:
            sub = order[lo:hi]
            ax = int(np.argmax(np.ptp(cent[sub], axis=0)))
            order[lo:hi] = sub[np.argsort(cent[sub, ax], kind="stable")]
            mid = (lo + hi) // 2
            kids[idx] = [node(lo, mid), node(mid, hi)]
        return idx

    node(0, triangles.shape[0])
    return (order.astype(np.int64), np.array(starts, np.int64), np.array(ends, np.int64),
            np.array(kids, np.int64))
