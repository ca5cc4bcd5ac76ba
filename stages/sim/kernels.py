"""Numba kernels of the cloth step (paper A §1, §3.3) and the body penetration audit.

Layout: all garments concatenated into one particle system; flat float64 / int32 arrays.
x (N, 3) current positions, xp (N, 3) previous positions (Verlet), both in the relative frame.
Poses: fwd (J, 4, 4) bone-local -> relative frame at the END of the step, inv (J, 4, 4) its inverse,
inv0 (J, 4, 4) the inverse at the START of the step (for friction relative to a moving collider).

Speed (issue 6): a whole chunk of frames runs in one call (`run_frames`): nothing is allocated and
no Python runs between steps. The per-step phases are parallel loops (prange) over disjoint
particles / triangles / spring blocks, so the result is the same for any thread count (OpenMP
regions cost ~1 us each; the caller picks the threads, 1 by default). Hot kernels are compiled with
`_nrt=False`: numba otherwise increments / decrements (atomically) the reference count of every
array argument of each helper inlined into the loop, which cost more than the hull query itself.
Collisions: per step each collider gets a world bounding sphere and one 3x4 matrix world ->
*query frame* (hulls: the OBB-local frame of the maps; spheres: bone-local with the centre at the
origin); a particle is transformed only after the world sphere test, a hull only queried inside
its OBB, the hull response reports its exit face (the contact normal, no face scan), and a particle
visits only the colliders listed in its cell of a per-step uniform grid (build_grid).

Cloth-side argument tuples (built once by simulate.py, unpacked for free inside njit):
    cloth = (x, xp, inv_mass, attach_joint, attach_local, ij, sp, group_start, ti, ta, tl, tris,
             tri_mass, tri_force, vt_table, x4)
    cols  = (col_joint, col_kind, col_index, col_bcenter, col_bradius, sph_center, sph_radius,
             tq, tq0, fq, cw, grid_start, grid_items, grid_runs, grid_box, grid_dims, face_edges, src_range)
    prm   = (h, damping, s, k_drag, k_lift, friction, use_aero, iterations, passes, method)
    flags = (corrected, inside, speed2, contact)
"""
from __future__ import annotations

import math

import llvmlite.ir as ir
import numpy as np
from numba import njit, prange, types
from numba.core import cgutils
from numba.extending import intrinsic

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)
from stages.affine import apply_affine, triangle_cross
from stages.fastmath import V4, inv_sqrt, inv_sqrt_v4, v4_const
from stages.maps.kernels import METHOD_NEAREST_PLANE, METHOD_PAPER, ZERO_DIR, hull_query, query_arrays
from stages.maps.types import KIND_CYLINDER as KIND_CYLINDER_MAP

# the hull query is inlined from stages.maps.kernels: its edits must invalidate this module's cache
NUMBA_CACHE_DEPENDS = ("stages.maps.kernels", "stages.maps.types", "stages.affine", "stages.fastmath")

KIND_HULL = 0
KIND_SPHERE = 1
PUSH_EPS = 1e-7      # m: responded particles end this far outside, so the inclusive inside test says "out"
TOUCH_EPS = 1e-9     # m: a response moving a particle less than this is a touch, not a penetration
GRID_CELLS = 4096    # broad phase: at most this many grid cells over the colliders' world boxes
_EYE3 = np.eye(3)    # the query frame of a sphere is not rotated

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
def _apply12(a, c, x, y, z):
    """Row c of a (C, 12) array of row-major 3x4 affine matrices applied to (x, y, z)."""
    return (a[c, 0] * x + a[c, 1] * y + a[c, 2] * z + a[c, 3],
            a[c, 4] * x + a[c, 5] * y + a[c, 6] * z + a[c, 7],
            a[c, 8] * x + a[c, 9] * y + a[c, 10] * z + a[c, 11])


@njit(cache=True, inline="always")
def _rotate12(a, c, x, y, z):
    return (a[c, 0] * x + a[c, 1] * y + a[c, 2] * z,
            a[c, 4] * x + a[c, 5] * y + a[c, 6] * z,
            a[c, 8] * x + a[c, 9] * y + a[c, 10] * z)


# -- vector IR helpers (intrinsics on 4 lanes of <4 x double>) ---------------------------------------
def _shuffle(builder, a, b, lanes):
    return builder.shuffle_vector(a, b, ir.Constant(ir.VectorType(ir.IntType(32), len(lanes)), lanes))


def _fmuladd(builder, a, b, c):
    """a b + c, fused where the CPU has FMA (as fastmath contracts the scalar loop)."""
    fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(V4, [V4] * 3), "llvm.fmuladd.v4f64")
    return builder.call(fn, [a, b, c])


def _splat(builder, value):
    """A float64 scalar on 4 lanes."""
    return _shuffle(builder, builder.insert_element(ir.Constant(V4, None), value, ir.Constant(ir.IntType(32), 0)),
                    ir.Constant(V4, None), [0, 0, 0, 0])


def _transpose(builder, r0, r1, r2, r3):
    """Rows (x, y, z, _) of 4 items -> the x, y, z of the 4 items."""
    xz01 = _shuffle(builder, r0, r1, [0, 4, 2, 6])
    y_01 = _shuffle(builder, r0, r1, [1, 5, 3, 7])
    xz23 = _shuffle(builder, r2, r3, [0, 4, 2, 6])
    y_23 = _shuffle(builder, r2, r3, [1, 5, 3, 7])
    return (_shuffle(builder, xz01, xz23, [0, 1, 4, 5]), _shuffle(builder, y_01, y_23, [0, 1, 4, 5]),
            _shuffle(builder, xz01, xz23, [2, 3, 6, 7]))


# -- forces + Verlet ------------------------------------------------------------------------------
# Speed: the aerodynamic force is computed for 4 triangles at a time on <4 x double> (one masked
# 3-double load per vertex row of x and xp, row-wise velocity sum and edges, transposes, the
# formula on 4 lanes with inv_sqrt_v4). Integrate phase (forces + Verlet), one thread: drape
# 107 -> 51 us a step, walk 110 -> 66 us.
@intrinsic
def _aero_group(typingctx, x, xp, tris, tri_mass, out, t0, ih, c3x, c3y, c3z, wind_x, wind_y, wind_z, kd2, kl2, ihh):
    """Aerodynamic force (N) on triangles t0..t0+3 (those < T) into out, as documented in
    `aero_forces`; ih = 1/(3h), c3 = 3 s d_prev, kd2 / kl2 = k_drag / k_lift over 2, ihh = 1/h^2.

    Per triangle (a, b, c), in this order (fma = one rounding, where the CPU has FMA):
    V = ((x_a - xp_a) + (x_b - xp_b)) + (x_c - xp_c), E1 = x_b - x_a, E2 = x_c - x_a (per axis);
    w = wind - (V + 3 s d_prev) / (3h); N = E1 x E2 with N_x = fma(E1y, E2z, -(E1z E2y)) and cyclic;
    n2 = fma(Nz, Nz, fma(Ny, Ny, Nx Nx)), w2 and nw = N.w alike; r = inv_sqrt(w2 n2);
    fd = k_drag/2 |nw|, fl = ((k_lift/2 nw) w2) r, g = ((nw n2) r) r;
    F = fma(fd, w, fl fma(-g, w, N)); zero if n2 <= 1e-40 or w2 <= 1e-20; if m > 0 and
    |F|^2 > cap2 = ((m m) w2) / h^2: F *= sqrt(cap2 / |F|^2)."""
    def codegen(context, builder, signature, args):
        x_data, xp_data, tri_data, mass_data, out_data = (context.make_array(ty)(context, builder, a).data
                                                          for ty, a in zip(signature.args[:5], args[:5]))
        t0 = context.cast(builder, args[5], signature.args[5], types.int64)
        n_tri = context.make_array(signature.args[2])(context, builder, args[2]).shape
        n_tri = builder.extract_value(n_tri, 0)
        i64 = t0.type
        last = builder.sub(n_tri, ir.Constant(i64, 1))
        c = [_splat(builder, a) for a in args[6:]]
        ih, c3, wind, kd2, kl2, ihh = c[0], c[1:4], c[4:7], c[7], c[8], c[9]
        mask3 = ir.Constant(ir.VectorType(ir.IntType(1), 4), [1, 1, 1, 0])
        row_load = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(V4, [x_data.type, ir.IntType(32), mask3.type, V4]),
            "llvm.masked.load.v4f64.p0")

        def row(data, vertex):
            """(x, y, z, 0) of row vertex of an (N, 3) array: a masked load stays inside the array."""
            ptr = builder.gep(data, [builder.mul(vertex, ir.Constant(i64, 3))])
            return builder.call(row_load, [ptr, ir.Constant(ir.IntType(32), 8), mask3, ir.Constant(V4, None)])

        tri = []     # per lane: its triangle, clamped to the last one (lanes past T compute it again)
        for lane in range(4):
            t = builder.add(t0, ir.Constant(i64, lane))
            tri.append(builder.select(builder.icmp_signed("<", t, n_tri), t, last))
        vel, e1, e2, mass = [], [], [], ir.Constant(V4, None)
        for lane, t in enumerate(tri):
            xr, pr = [], []
            for q in range(3):
                v = builder.load(builder.gep(tri_data, [builder.add(builder.mul(t, ir.Constant(i64, 3)),
                                                                    ir.Constant(i64, q))]))
                v = builder.sext(v, i64) if v.type.width < 64 else v
                xr.append(row(x_data, v))
                pr.append(row(xp_data, v))
            vel.append(builder.fadd(builder.fadd(builder.fsub(xr[0], pr[0]), builder.fsub(xr[1], pr[1])),
                                    builder.fsub(xr[2], pr[2])))
            e1.append(builder.fsub(xr[1], xr[0]))
            e2.append(builder.fsub(xr[2], xr[0]))
            mass = builder.insert_element(mass, builder.load(builder.gep(mass_data, [t])),
                                          ir.Constant(ir.IntType(32), lane))
        vel = _transpose(builder, *vel)
        e1x, e1y, e1z = _transpose(builder, *e1)
        e2x, e2y, e2z = _transpose(builder, *e2)
        wx, wy, wz = (builder.fsub(wind[k], builder.fmul(builder.fadd(vel[k], c3[k]), ih)) for k in range(3))

        def cross_lane(a1, b2, a2, b1):      # a1 b2 - a2 b1
            return _fmuladd(builder, a1, b2, builder.fneg(builder.fmul(a2, b1)))

        def dot(ax, ay, az, bx, by, bz):
            return _fmuladd(builder, az, bz, _fmuladd(builder, ay, by, builder.fmul(ax, bx)))

        nx = cross_lane(e1y, e2z, e1z, e2y)
        ny = cross_lane(e1z, e2x, e1x, e2z)
        nz = cross_lane(e1x, e2y, e1y, e2x)
        n2 = dot(nx, ny, nz, nx, ny, nz)
        w2 = dot(wx, wy, wz, wx, wy, wz)
        nw = dot(nx, ny, nz, wx, wy, wz)
        live = builder.and_(builder.fcmp_unordered(">", n2, v4_const(1e-40)),
                            builder.fcmp_unordered(">", w2, v4_const(1e-20)))
        r = inv_sqrt_v4(builder, builder.select(live, builder.fmul(w2, n2), v4_const(1.0)))
        fabs = cgutils.get_or_insert_function(builder.module, ir.FunctionType(V4, [V4]), "llvm.fabs.v4f64")
        fd = builder.fmul(kd2, builder.call(fabs, [nw]))
        fl = builder.fmul(builder.fmul(builder.fmul(kl2, nw), w2), r)
        minus_g = builder.fneg(builder.fmul(builder.fmul(builder.fmul(nw, n2), r), r))
        f = [_fmuladd(builder, fd, wk, builder.fmul(fl, _fmuladd(builder, minus_g, wk, nk)))
             for wk, nk in ((wx, nx), (wy, ny), (wz, nz))]
        f = [builder.select(live, fk, ir.Constant(V4, None)) for fk in f]
        f2 = dot(*f, *f)
        cap2 = builder.fmul(builder.fmul(builder.fmul(mass, mass), w2), ihh)
        capped = builder.and_(builder.fcmp_ordered(">", mass, ir.Constant(V4, None)),
                              builder.fcmp_ordered(">", f2, cap2))
        any_capped = builder.icmp_unsigned("!=", builder.bitcast(capped, ir.IntType(4)), ir.Constant(ir.IntType(4), 0))
        start = builder.block
        with builder.if_then(any_capped, likely=False):
            sqrt = cgutils.get_or_insert_function(builder.module, ir.FunctionType(V4, [V4]), "llvm.sqrt.v4f64")
            k = builder.select(capped, builder.call(sqrt, [builder.fdiv(cap2, f2)]), v4_const(1.0))
            scaled = [builder.fmul(fk, k) for fk in f]
            capped_block = builder.block
        out_f = []
        for fk, sk in zip(f, scaled):
            phi = builder.phi(V4)
            phi.add_incoming(fk, start)
            phi.add_incoming(sk, capped_block)
            out_f.append(phi)
        fx, fy, fz = out_f
        # (T + 1, 4) rows (x, y, z, 0) of the 4 triangles: 16 consecutive doubles
        zero = ir.Constant(V4, None)
        xy01 = _shuffle(builder, fx, fy, [0, 4, 1, 5])
        xy23 = _shuffle(builder, fx, fy, [2, 6, 3, 7])
        z01 = _shuffle(builder, fz, zero, [0, 4, 1, 5])
        z23 = _shuffle(builder, fz, zero, [2, 6, 3, 7])
        rows = (_shuffle(builder, xy01, z01, [0, 1, 4, 5]), _shuffle(builder, xy01, z01, [2, 3, 6, 7]),
                _shuffle(builder, xy23, z23, [0, 1, 4, 5]), _shuffle(builder, xy23, z23, [2, 3, 6, 7]))
        base = builder.mul(t0, ir.Constant(i64, 4))
        full = builder.icmp_signed("<=", builder.add(t0, ir.Constant(i64, 4)), n_tri)
        with builder.if_else(full, likely=True) as (whole, tail):
            with whole:
                for lane, v in enumerate(rows):
                    ptr = builder.gep(out_data, [builder.add(base, ir.Constant(i64, 4 * lane))])
                    builder.store(v, builder.bitcast(ptr, V4.as_pointer()), align=8)
            with tail:
                for lane, v in enumerate(rows):
                    with builder.if_then(builder.icmp_signed("<", builder.add(t0, ir.Constant(i64, lane)), n_tri)):
                        ptr = builder.gep(out_data, [builder.add(base, ir.Constant(i64, 4 * lane))])
                        builder.store(v, builder.bitcast(ptr, V4.as_pointer()), align=8)
        return context.get_dummy_value()

    arrays = ((x, types.float64, 2), (xp, types.float64, 2), (tri_mass, types.float64, 1), (out, types.float64, 2))
    consts = (ih, c3x, c3y, c3z, wind_x, wind_y, wind_z, kd2, kl2, ihh)
    if not (all(isinstance(a, types.Array) and a.ndim == d and a.layout == "C" and a.dtype == t for a, t, d in arrays)
            and isinstance(tris, types.Array) and tris.ndim == 2 and tris.layout == "C"
            and tris.dtype in (types.int32, types.int64) and isinstance(t0, types.Integer)
            and all(c == types.float64 for c in consts)):
        return None     # the codegen addresses contiguous arrays of these types
    return types.void(x, xp, tris, tri_mass, out, t0, *consts), codegen


@njit(cache=True, parallel=True, fastmath=True, _nrt=False)
def aero_forces(x, xp, tri_mass, tris, h, s, d_prev, wind, k_drag, k_lift, out):
    """Per-triangle aerodynamic forces (N) into rows 0..T-1 of out (rows (x, y, z, 0), 4 columns), from
    the air velocity relative to each triangle. tri_mass (T,): the mass of the triangle's free vertices
    (a third of each free vertex's lumped mass), kg.

    Vertex velocity v = (x - xp + s d_prev) / h (Verlet estimate, world velocity scaled by the
    inertia scale s). w = wind - mean v; n' = unit normal oriented along w; c = n'.w/|w|.
    drag = k_drag A c |w|^2 w/|w|; lift = k_lift A c |w|^2 (n' - c w/|w|)   (k = 0.5 rho C).
    With N = (b - a) x (c - a) (|N| = 2A) these are drag = k_drag/2 |N.w| w and
    lift = k_lift/2 (N.w) |w|/|N| (N - (N.w)/|w|^2 w), from one r = 1/sqrt(|w|^2 |N|^2):
    |w|/|N| = |w|^2 r, 1/|w|^2 = |N|^2 r^2. Explicit drag
    is unstable once it would more than stop the triangle within a step: |F| is capped at m |w| / h.
    Computed 4 triangles at a time (`_aero_group`, its docstring: the exact operation order).
    """
    if out.shape[1] != 4 or out.shape[0] < tris.shape[0]:
        raise ValueError("aero_forces: out must have (T, 4) rows")
    ih = 1.0 / (3.0 * h)
    ihh = 1.0 / (h * h)
    c3x = 3.0 * s * d_prev[0]
    c3y = 3.0 * s * d_prev[1]
    c3z = 3.0 * s * d_prev[2]
    for g in prange((tris.shape[0] + 3) // 4):
        _aero_group(x, xp, tris, tri_mass, out, 4 * g, ih, c3x, c3y, c3z, wind[0], wind[1], wind[2],
                    0.5 * k_drag, 0.5 * k_lift, ihh)


def vertex_triangles(tris: np.ndarray, n_particles: int) -> np.ndarray:
    """(N, W) int32: the triangles of each vertex in ascending order, padded with T (the zero row of
    the force array); W the largest vertex degree (at least 1)."""
    flat = tris.ravel()
    order = np.argsort(flat, kind="stable")
    start = np.searchsorted(flat[order], np.arange(n_particles + 1))
    table = np.full((n_particles, max(1, int(np.diff(start).max(initial=0)))), tris.shape[0], np.int32)
    slot = np.arange(flat.size) - start[flat[order]]
    table[flat[order], slot] = order // 3
    return table


@intrinsic
def _force_sums(typingctx, tri_force, vt_table, i0):
    """(x, y, z) of vertices i0..i0+3 (those < N; later lanes repeat the last vertex): each the sum of
    the tri_force rows listed in its row of vt_table, in the table's order. One <4 x double> load and
    add per row, 4 independent sums interleaved (each is a chain of dependent additions), a fixed
    trip count (no mispredicted loop exit)."""
    def codegen(context, builder, signature, args):
        force, table = (context.make_array(ty)(context, builder, a) for ty, a in zip(signature.args[:2], args[:2]))
        i64 = ir.IntType(64)
        i0 = context.cast(builder, args[2], signature.args[2], types.int64)
        n = builder.extract_value(table.shape, 0)
        width = builder.extract_value(table.shape, 1)
        last = builder.sub(n, ir.Constant(i64, 1))
        rows = []
        for lane in range(4):
            i = builder.add(i0, ir.Constant(i64, lane))
            rows.append(builder.mul(builder.select(builder.icmp_signed("<", i, n), i, last), width))
        acc = [cgutils.alloca_once_value(builder, ir.Constant(V4, None)) for _ in range(4)]
        with cgutils.for_range(builder, width) as loop:
            for row, sum_ptr in zip(rows, acc):
                t = builder.load(builder.gep(table.data, [builder.add(row, loop.index)]))
                ptr = builder.gep(force.data, [builder.mul(builder.sext(t, i64), ir.Constant(i64, 4))])
                f = builder.load(builder.bitcast(ptr, V4.as_pointer()), align=8)
                builder.store(builder.fadd(builder.load(sum_ptr), f), sum_ptr)
        sums = [builder.load(p) for p in acc]
        xyz = [builder.extract_element(v, ir.Constant(ir.IntType(32), k)) for v in sums for k in range(3)]
        return context.make_tuple(builder, signature.return_type, xyz)

    if not (isinstance(tri_force, types.Array) and tri_force.ndim == 2 and tri_force.layout == "C"
            and tri_force.dtype == types.float64 and isinstance(vt_table, types.Array) and vt_table.ndim == 2
            and vt_table.layout == "C" and vt_table.dtype == types.int32 and isinstance(i0, types.Integer)):
        return None     # the codegen addresses contiguous arrays of these types
    return types.UniTuple(types.float64, 12)(tri_force, vt_table, i0), codegen


@njit(cache=True, inline="always")
def _verlet(x, xp, inv_mass, attach_joint, attach_local, fwd, i, hh, keep, gx, gy, gz, rx, ry, rz,
            use_aero, fx, fy, fz):
    """One particle of `integrate`; (fx, fy, fz) the sum of its triangles' forces."""
    ox = x[i, 0]
    oy = x[i, 1]
    oz = x[i, 2]
    j = attach_joint[i]
    w = inv_mass[i]
    if j >= 0:
        nx, ny, nz = apply_affine(fwd[j], attach_local[i, 0], attach_local[i, 1], attach_local[i, 2])
    elif w == 0.0:
        nx = ox
        ny = oy
        nz = oz
    else:
        ax = gx
        ay = gy
        az = gz
        if use_aero:
            ax += fx * (w * hh / 3.0)
            ay += fy * (w * hh / 3.0)
            az += fz * (w * hh / 3.0)
        nx = ox + keep * (ox - xp[i, 0]) + rx + ax
        ny = oy + keep * (oy - xp[i, 1]) + ry + ay
        nz = oz + keep * (oz - xp[i, 2]) + rz + az
    xp[i, 0] = ox
    xp[i, 1] = oy
    xp[i, 2] = oz
    x[i, 0] = nx
    x[i, 1] = ny
    x[i, 2] = nz


# Speed: the gather of the triangle forces of a vertex reads whole (x, y, z, 0) rows as one vector,
# 4 vertices interleaved (each sum is a chain of dependent additions) over a fixed-width table; the
# same additions in the same order, so bit-identical to the CSR loop it replaced. Integrate phase
# (forces + Verlet), one thread: drape 51 -> 43 us a step, walk 66 -> 57 us.
@njit(cache=True, parallel=True, _nrt=False)
def integrate(x, xp, inv_mass, attach_joint, attach_local, fwd, h, gravity, damping, s, d_prev, d_next,
              use_aero, tri_force, vt_table):
    """Verlet step of every particle; attached particles follow their bone, pinned ones stay.

    x_new = x + (1 - damping) (x - xp + s d_prev) - s d_next + a h^2, a = g + force / m,
    then xp <- x, x <- x_new. d_prev / d_next: root translation over the previous / this step.
    tri_force (T + 1, 4): aerodynamic force per triangle (x, y, z, 0), row T zero, a third to each
    vertex (read only when use_aero); vt_table = `vertex_triangles(tris, N)`.
    """
    if use_aero and (tri_force.shape[1] != 4 or vt_table.shape[0] != x.shape[0]):
        raise ValueError("integrate: tri_force must have (T + 1, 4) rows, vt_table one row per particle")
    hh = h * h
    keep = 1.0 - damping
    gx = gravity[0] * hh
    gy = gravity[1] * hh
    gz = gravity[2] * hh
    # root-translation terms shared by every free particle
    rx = keep * s * d_prev[0] - s * d_next[0]
    ry = keep * s * d_prev[1] - s * d_next[1]
    rz = keep * s * d_prev[2] - s * d_next[2]
    n = x.shape[0]
    for g in prange((n + 3) // 4):
        i = 4 * g
        f = _force_sums(tri_force, vt_table, i) if use_aero else (0.0,) * 12
        _verlet(x, xp, inv_mass, attach_joint, attach_local, fwd, i, hh, keep, gx, gy, gz, rx, ry, rz,
                use_aero, f[0], f[1], f[2])
        if i + 1 < n:
            _verlet(x, xp, inv_mass, attach_joint, attach_local, fwd, i + 1, hh, keep, gx, gy, gz, rx, ry, rz,
                    use_aero, f[3], f[4], f[5])
        if i + 2 < n:
            _verlet(x, xp, inv_mass, attach_joint, attach_local, fwd, i + 2, hh, keep, gx, gy, gz, rx, ry, rz,
                    use_aero, f[6], f[7], f[8])
        if i + 3 < n:
            _verlet(x, xp, inv_mass, attach_joint, attach_local, fwd, i + 3, hh, keep, gx, gy, gz, rx, ry, rz,
                    use_aero, f[9], f[10], f[11])


# -- springs --------------------------------------------------------------------------------------
# Speed (the largest phase of a step): positions are corrected in a (N + 1, 4) float64 scratch,
# a particle one 256-bit row (x, y, z, 0), and springs 4 at a time, as groups of 4 springs on 8
# distinct particles (colour order makes nearly every run of 4 such a group): one vector load /
# store per particle, the 4 lengths and their inverse square roots as vectors (no gather: AVX-512
# gathers / scatters were slower on the benchmark CPU). Per spring it is the same arithmetic in the
# same order as the scalar loop, so the result is bit-identical to it (drape: 138 -> 79 us a step).


def padded_rows(n_rows: int) -> np.ndarray:
    """(n + 1, 4) float64 zeros, rows 32-byte aligned (a row across two cache lines costs ~8 %):
    the layout of `correct_springs`' position scratch (row N: the dummy particle of padding springs)
    and of the per-triangle aerodynamic forces (row T: the padding of `vertex_triangles`)."""
    size = 4 * (n_rows + 1)
    buf = np.zeros(size + 4)
    skip = (-buf.ctypes.data % 32) // 8
    return buf[skip:skip + size].reshape(n_rows + 1, 4)


@njit(cache=True)
def _group_springs(si, sj, part_start, lane_spring, group_start):
    """The springs of each block (part_start), in order, into groups of 4 lanes: lane_spring[4 g + l]
    = the spring in lane l of group g (left -1: padding). A group is closed early before a spring
    that shares a particle with one in it. group_start[b] = block b's first group; returns the
    number of groups."""
    g = 0
    for b in range(part_start.size - 1):
        group_start[b] = g
        lane = 0
        for k in range(part_start[b], part_start[b + 1]):
            shared = lane == 4
            for q in range(4 * g, 4 * g + lane):
                kq = lane_spring[q]
                shared = shared or si[k] == si[kq] or si[k] == sj[kq] or sj[k] == si[kq] or sj[k] == sj[kq]
            if shared:
                g += 1
                lane = 0
            lane_spring[4 * g + lane] = k
            lane += 1
        if lane > 0:
            g += 1
    group_start[part_start.size - 1] = g
    return g


def pack_springs(si, sj, rest, wi, wj, part_start, n_particles):
    """Springs in the layout of `correct_springs`: (ij, sp, group_start).

    The springs of each block of `partition_springs` (part_start), in order, go in groups of 4 on 8
    distinct particles (a group is closed early, padded with dummy springs, before a spring that
    shares a particle with it; in colour order that happens only where the colour changes).
    ij (8 G,) uint32: per group 4 si then 4 sj, as offsets 4 i into the flat scratch (unsigned: no
    negative-index wraparound); sp (12 G,) float64: per group 4 rest, 4 wi, 4 wj; dummy springs join
    the scratch's row N to itself with rest = wi = wj = 0 (they move nothing); group_start (B + 1,):
    block b is groups group_start[b]..group_start[b + 1] - 1.
    """
    si = np.ascontiguousarray(si, np.int64)
    sj = np.ascontiguousarray(sj, np.int64)
    if 4 * n_particles + 3 >= 2 ** 32:
        raise ValueError("pack_springs: too many particles for uint32 offsets")
    lane_spring = np.full(4 * si.size, -1, np.int64)     # at most one group per spring
    group_start = np.zeros(part_start.size, np.int64)
    n_groups = _group_springs(si, sj, np.ascontiguousarray(part_start, np.int64), lane_spring, group_start)
    lane_spring = lane_spring[:4 * n_groups].reshape(n_groups, 4)
    real = lane_spring >= 0
    k = lane_spring[real]
    ij = np.full((n_groups, 2, 4), 4 * n_particles, np.uint32)
    sp = np.zeros((n_groups, 3, 4))
    for row, values in enumerate((4 * si, 4 * sj)):
        ij[:, row][real] = values[k]
    for row, values in enumerate((rest, wi, wj)):
        sp[:, row][real] = np.asarray(values, np.float64)[k]
    return ij.reshape(-1), sp.reshape(-1), group_start


@intrinsic
def _correct_group(typingctx, xf, ij, sp, g):
    """Gauss-Seidel correction of the 4 springs of group g (`pack_springs`) in the flat scratch xf.
    Per spring, as the scalar loop: d = x_j - x_i, d2 = fma(dz, dz, fma(dy, dy, dx dx)); if
    d2 > 1e-24: c = 1 - rest inv_sqrt(d2), x_i += wi c d, x_j -= wj c d."""
    def codegen(context, builder, signature, args):
        x_data, ij_data, sp_data = (context.make_array(ty)(context, builder, a).data
                                    for ty, a in zip(signature.args[:3], args[:3]))
        g = args[3]

        def at(k):
            return ir.Constant(g.type, k)

        rows = []
        for lane in range(8):       # 4 particles i, then 4 particles j
            offset = builder.zext(builder.load(builder.gep(ij_data, [builder.add(builder.mul(g, at(8)), at(lane))])),
                                  ir.IntType(64))
            rows.append(builder.bitcast(builder.gep(x_data, [offset]), V4.as_pointer()))
        xi = [builder.load(rows[k], align=8) for k in range(4)]
        xj = [builder.load(rows[4 + k], align=8) for k in range(4)]
        d = [builder.fsub(xj[k], xi[k]) for k in range(4)]
        # transpose the 4 (dx, dy, dz, 0) into dx, dy, dz over the 4 springs
        xz01 = _shuffle(builder, d[0], d[1], [0, 4, 2, 6])
        y_01 = _shuffle(builder, d[0], d[1], [1, 5, 3, 7])
        xz23 = _shuffle(builder, d[2], d[3], [0, 4, 2, 6])
        y_23 = _shuffle(builder, d[2], d[3], [1, 5, 3, 7])
        dx = _shuffle(builder, xz01, xz23, [0, 1, 4, 5])
        dy = _shuffle(builder, y_01, y_23, [0, 1, 4, 5])
        dz = _shuffle(builder, xz01, xz23, [2, 3, 6, 7])
        d2 = _fmuladd(builder, dz, dz, _fmuladd(builder, dy, dy, builder.fmul(dx, dx)))
        live = builder.fcmp_unordered(">", d2, v4_const(1e-24))       # not (d2 <= 1e-24)
        d2 = builder.select(live, d2, v4_const(1.0))                 # no inf / nan in dead lanes
        rest, wi, wj = (builder.load(builder.bitcast(builder.gep(sp_data, [builder.add(builder.mul(g, at(12)), at(4 * q))]),
                                                     V4.as_pointer()), align=8) for q in range(3))
        c = builder.fsub(v4_const(1.0), builder.fmul(rest, inv_sqrt_v4(builder, d2)))
        c = builder.select(live, c, ir.Constant(V4, None))
        a = builder.fmul(wi, c)
        b = builder.fneg(builder.fmul(wj, c))
        for k in range(4):
            builder.store(_fmuladd(builder, _shuffle(builder, a, a, [k] * 4), d[k], xi[k]), rows[k], align=8)
            builder.store(_fmuladd(builder, _shuffle(builder, b, b, [k] * 4), d[k], xj[k]), rows[4 + k], align=8)
        return context.get_dummy_value()

    arrays = ((xf, types.float64), (ij, types.uint32), (sp, types.float64))
    if not all(isinstance(a, types.Array) and a.ndim == 1 and a.layout == "C" and a.dtype == t for a, t in arrays):
        return None     # the codegen addresses flat contiguous arrays of these types
    return types.void(xf, ij, sp, g), codegen


@njit(cache=True, parallel=True, fastmath=True, _nrt=False)
def correct_springs(x, x4, ij, sp, group_start, ti, ta, tl, iterations):
    """`iterations` rounds of Gauss-Seidel position correction (stretch and compression), each: the
    spring blocks of `partition_springs` in parallel (they touch disjoint particles, so the result
    does not depend on the thread count), then the springs crossing blocks (last block) in order,
    then the tethers. x (N, 3) C-contiguous, worked on in x4 = `padded_rows(N)`; ij, sp,
    group_start from `pack_springs` with wi, wj per spring: stiffness * w_i / (w_i + w_j) and
    stiffness * w_j / (w_i + w_j).

    Tethers (long-range attachments, Kim, Chentanez & Mueller 2012): free particle ti[k] is put
    back on the sphere of radius tl[k] around its anchor ta[k] (an attached / pinned particle) when
    it is farther; a one-sided constraint that stops hanging cloth from stretching far more than
    a few Gauss-Seidel rounds can correct. Each tether moves only its own particle.
    """
    n = x.shape[0]
    for i in range(n):
        x4[i, 0] = x[i, 0]
        x4[i, 1] = x[i, 1]
        x4[i, 2] = x[i, 2]
        x4[i, 3] = 0.0
    x4[n, :] = 0.0
    xf = x4.reshape(x4.size)
    n_parts = group_start.size - 2
    for _ in range(iterations):
        for p in prange(n_parts):
            for g in range(group_start[p], group_start[p + 1]):
                _correct_group(xf, ij, sp, g)
        for g in range(group_start[n_parts], group_start[n_parts + 1]):
            _correct_group(xf, ij, sp, g)
        if ti.size == 0:    # no parallel region (fork / join) for nothing
            continue
        for k in prange(ti.size):
            i = ti[k]
            a = ta[k]
            dx = x4[i, 0] - x4[a, 0]
            dy = x4[i, 1] - x4[a, 1]
            dz = x4[i, 2] - x4[a, 2]
            d2 = dx * dx + dy * dy + dz * dz
            if d2 > tl[k] * tl[k]:
                f = tl[k] * inv_sqrt(d2)
                x4[i, 0] = x4[a, 0] + f * dx
                x4[i, 1] = x4[a, 1] + f * dy
                x4[i, 2] = x4[a, 2] + f * dz
    for i in range(n):
        x[i, 0] = x4[i, 0]
        x[i, 1] = x4[i, 1]
        x[i, 2] = x4[i, 2]


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
    colour = spring_colours(np.ascontiguousarray(springs, dtype=np.int64), n)
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
@njit(cache=True, _nrt=False)
def collider_frames(fwd, inv, inv0, m, col_joint, col_kind, col_index, col_bcenter, col_bradius, sph_center,
                    tq, tq0, fq, cw):
    """Per collider c, for one step: tq[c] / tq0[c] (12,) the 3x4 map world (end / start of the step)
    -> query frame, fq[c] query frame -> world (end), cw[c] = world bounding sphere (centre, r, r^2).

    Query frame: hulls, the OBB-local frame of the maps (q = axes (inv p - center)); spheres, bone-local
    shifted so the sphere's centre is the origin. The bounding radius grows with the pose's largest
    axis scale (scaled rigs)."""
    for c in range(col_joint.size):
        j = col_joint[c]
        if col_kind[c] == KIND_HULL:
            h = col_index[c]
            r = m.axes[h]
            ctr = m.center[h]
        else:
            r = _EYE3
            ctr = sph_center[col_index[c]]
        for dst, src in ((tq, inv[j]), (tq0, inv0[j])):
            for a in range(3):
                for b in range(3):
                    dst[c, 4 * a + b] = r[a, 0] * src[0, b] + r[a, 1] * src[1, b] + r[a, 2] * src[2, b]
                dst[c, 4 * a + 3] = (r[a, 0] * (src[0, 3] - ctr[0]) + r[a, 1] * (src[1, 3] - ctr[1])
                                     + r[a, 2] * (src[2, 3] - ctr[2]))
        f = fwd[j]
        for a in range(3):
            for b in range(3):
                fq[c, 4 * a + b] = f[a, 0] * r[b, 0] + f[a, 1] * r[b, 1] + f[a, 2] * r[b, 2]
            fq[c, 4 * a + 3] = f[a, 0] * ctr[0] + f[a, 1] * ctr[1] + f[a, 2] * ctr[2] + f[a, 3]
        px, py, pz = apply_affine(f, col_bcenter[c, 0], col_bcenter[c, 1], col_bcenter[c, 2])
        sc = 0.0
        for b in range(3):
            sc = max(sc, f[0, b] * f[0, b] + f[1, b] * f[1, b] + f[2, b] * f[2, b])
        rad = col_bradius[c] * math.sqrt(sc) * (1.0 + 1e-9)
        cw[c, 0] = px
        cw[c, 1] = py
        cw[c, 2] = pz
        cw[c, 3] = rad
        cw[c, 4] = rad * rad


@njit(cache=True, inline="always")
def _world_box(c, m, col_kind, col_index, sph_radius, use_obb, fq, cw):
    """(lo0, lo1, lo2, hi0, hi1, hi2): a world axis-aligned box holding every point collider c can
    report inside: its world sphere's box, cut to the box of its query-frame box (hull: the OBB
    widened by the maps' convexity tolerance; sphere: the cube around it) when use_obb; widened by
    1e-9 of its size and position against round-off between fq and tq."""
    r = cw[c, 3]
    e = 1e-9 * (r + abs(cw[c, 0]) + abs(cw[c, 1]) + abs(cw[c, 2]))
    lo0 = cw[c, 0] - r
    lo1 = cw[c, 1] - r
    lo2 = cw[c, 2] - r
    hi0 = cw[c, 0] + r
    hi1 = cw[c, 1] + r
    hi2 = cw[c, 2] + r
    if use_obb:
        b0, b1, b2 = _query_box(c, m, col_kind, col_index, sph_radius)
        x0 = abs(fq[c, 0]) * b0 + abs(fq[c, 1]) * b1 + abs(fq[c, 2]) * b2
        x1 = abs(fq[c, 4]) * b0 + abs(fq[c, 5]) * b1 + abs(fq[c, 6]) * b2
        x2 = abs(fq[c, 8]) * b0 + abs(fq[c, 9]) * b1 + abs(fq[c, 10]) * b2
        lo0 = max(lo0, fq[c, 3] - x0)
        lo1 = max(lo1, fq[c, 7] - x1)
        lo2 = max(lo2, fq[c, 11] - x2)
        hi0 = min(hi0, fq[c, 3] + x0)
        hi1 = min(hi1, fq[c, 7] + x1)
        hi2 = min(hi2, fq[c, 11] + x2)
    return lo0 - e, lo1 - e, lo2 - e, hi0 + e, hi1 + e, hi2 + e


@njit(cache=True, inline="always")
def _query_box(c, m, col_kind, col_index, sph_radius):
    """Half extents of a query-frame box around collider c: hull, its OBB widened by the maps'
    convexity tolerance (CONVEX_TOL = 1e-6 of the longest half extent: a face plane may pass that
    far outside a vertex); sphere, the cube around it."""
    idx = col_index[c]
    if col_kind[c] == KIND_SPHERE:
        r = sph_radius[idx] * (1.0 + 1e-9)
        return r, r, r
    e = 1e-6 * m.half[idx, 0]
    return m.half[idx, 0] + e, m.half[idx, 1] + e, m.half[idx, 2] + e


@njit(cache=True, inline="always")
def _k_range(q, s, inv_s, lim, ka, kb):
    """[ka, kb] narrowed to the reals k with |q + k s| <= lim (empty: ka > kb); inv_s = 1 / s."""
    if s > 0.0:
        return max(ka, (-lim - q) * inv_s), min(kb, (lim - q) * inv_s)
    if s < 0.0:
        return max(ka, (lim - q) * inv_s), min(kb, (-lim - q) * inv_s)
    if abs(q) > lim:
        return ka, ka - 1.0
    return ka, kb


@njit(cache=True, _nrt=False)
def _collider_runs(c, m, col_kind, col_index, sph_radius, use_obb, tq, fq, cw, grid_start, grid_runs, nr, grid_box,
                   grid_dims):
    """Append to grid_runs[nr:] the runs (c, first cell, cells) of consecutive cells (along axis 2)
    that collider c may reach, counting each cell into grid_start[cell]; returns the new run count.
    Per row (i, j) of the collider's world box, the k whose cell (widened against round-off) meets
    its world sphere and, when use_obb, its query-frame box: on each query axis the cell, a
    parallelepiped there, has half-width hc sum|tq row| around its centre, which moves linearly in k."""
    g0 = grid_box[0]
    g1 = grid_box[1]
    g2 = grid_box[2]
    inv = grid_box[3]
    cs = 1.0 / inv
    n1 = grid_dims[1]
    n2 = grid_dims[2]
    hc = 0.5 * cs + 1e-9 * (cs + abs(g0) + abs(g1) + abs(g2))   # cells widened against round-off
    lo0, lo1, lo2, hi0, hi1, hi2 = _world_box(c, m, col_kind, col_index, sph_radius, use_obb, fq, cw)
    b0, b1, b2 = _query_box(c, m, col_kind, col_index, sph_radius)
    l0 = b0 + hc * (abs(tq[c, 0]) + abs(tq[c, 1]) + abs(tq[c, 2]))
    l1 = b1 + hc * (abs(tq[c, 4]) + abs(tq[c, 5]) + abs(tq[c, 6]))
    l2 = b2 + hc * (abs(tq[c, 8]) + abs(tq[c, 9]) + abs(tq[c, 10]))
    s0 = cs * tq[c, 2]
    s1 = cs * tq[c, 6]
    s2 = cs * tq[c, 10]
    i0 = 1.0 / s0 if s0 != 0.0 else 0.0
    i1 = 1.0 / s1 if s1 != 0.0 else 0.0
    i2 = 1.0 / s2 if s2 != 0.0 else 0.0
    r2 = cw[c, 4]
    z0 = g2 + 0.5 * cs          # the centre of cell k = 0 along axis 2
    k0 = float(int((lo2 - g2) * inv))
    k1 = float(int((hi2 - g2) * inv))
    for i in range(int((lo0 - g0) * inv), int((hi0 - g0) * inv) + 1):
        x = g0 + (i + 0.5) * cs
        d0 = max(abs(x - cw[c, 0]) - hc, 0.0)
        for j in range(int((lo1 - g1) * inv), int((hi1 - g1) * inv) + 1):
            y = g1 + (j + 0.5) * cs
            d1 = max(abs(y - cw[c, 1]) - hc, 0.0)
            rem = r2 - d0 * d0 - d1 * d1
            if rem <= 0.0:
                continue
            ka, kb = _k_range((z0 - cw[c, 2]) * inv, 1.0, 1.0, (hc + math.sqrt(rem)) * inv, k0, k1)
            if use_obb:
                q0, q1, q2 = _apply12(tq, c, x, y, z0)
                ka, kb = _k_range(q0, s0, i0, l0, ka, kb)
                ka, kb = _k_range(q1, s1, i1, l1, ka, kb)
                ka, kb = _k_range(q2, s2, i2, l2, ka, kb)
            ka = math.ceil(ka)
            kb = math.floor(kb)
            if ka > kb:
                continue
            first = (i * n1 + j) * n2 + int(ka)
            count = int(kb) - int(ka) + 1
            grid_runs[nr, 0] = c
            grid_runs[nr, 1] = first
            grid_runs[nr, 2] = count
            nr += 1
            for cell in range(first, first + count):
                grid_start[cell] += 1
    return nr


@njit(cache=True, _nrt=False)
def build_grid(m, method, col_kind, col_index, sph_radius, tq, fq, cw, grid_start, grid_items, grid_runs, grid_box,
               grid_dims):
    """Broad phase: a uniform grid over the colliders' world boxes (_world_box), rebuilt per step.

    grid_box (4,): the grid's low corner and 1 / cell size; grid_dims (3,): cells per axis, at most
    grid_start.size - 1 cells in all; cell (i, j, k) = (i n1 + j) n2 + k holds the world points p
    with int((p - low) / size) = (i, j, k). grid_start (cells + 1,), grid_items (C cells,): CSR
    list per cell, ascending c, of every collider whose world sphere and query-frame box (not with
    METHOD_NEAREST_PLANE, which does not test the OBB) meet the cell: no other can hold a point of
    it. A point off the grid is outside every collider. Cells of about the smallest collider's
    world radius, larger when that would exceed the cell budget. grid_runs (C cells, 3): scratch.
    """
    nc = cw.shape[0]
    grid_dims[:] = 0
    grid_start[0] = 0
    if nc == 0:
        return
    use_obb = method != METHOD_NEAREST_PLANE
    g0 = g1 = g2 = np.inf
    t0 = t1 = t2 = -np.inf
    rmin = np.inf
    for c in range(nc):
        lo0, lo1, lo2, hi0, hi1, hi2 = _world_box(c, m, col_kind, col_index, sph_radius, use_obb, fq, cw)
        g0 = min(g0, lo0)
        g1 = min(g1, lo1)
        g2 = min(g2, lo2)
        t0 = max(t0, hi0)
        t1 = max(t1, hi1)
        t2 = max(t2, hi2)
        rmin = min(rmin, cw[c, 3])
    cap = grid_start.size - 1
    inv = 1.0 / max(rmin, ((t0 - g0) * (t1 - g1) * (t2 - g2) / cap) ** (1.0 / 3.0))
    while True:
        n0 = int((t0 - g0) * inv) + 1
        n1 = int((t1 - g1) * inv) + 1
        n2 = int((t2 - g2) * inv) + 1
        if n0 * n1 * n2 <= cap:
            break
        inv *= 0.9
    grid_box[0] = g0
    grid_box[1] = g1
    grid_box[2] = g2
    grid_box[3] = inv
    grid_dims[0] = n0
    grid_dims[1] = n1
    grid_dims[2] = n2
    nce = n0 * n1 * n2
    grid_start[:nce + 1] = 0
    nr = 0
    for c in range(nc):     # count each cell's colliders into grid_start[cell]
        nr = _collider_runs(c, m, col_kind, col_index, sph_radius, use_obb, tq, fq, cw, grid_start, grid_runs, nr,
                            grid_box, grid_dims)
    for b in range(1, nce):     # grid_start[b]: the end of cell b's list
        grid_start[b] += grid_start[b - 1]
    grid_start[nce] = grid_start[nce - 1]
    for r in range(nr - 1, -1, -1):     # descending c, each list filled from its end: ascending lists,
        c = grid_runs[r, 0]             # and grid_start[b] moves back to the start of cell b's list
        for cell in range(grid_runs[r, 1], grid_runs[r, 1] + grid_runs[r, 2]):
            grid_start[cell] -= 1
            grid_items[grid_start[cell]] = c


@njit(cache=True, inline="always")
def _grid_cell(grid_box, grid_dims, px, py, pz):
    """The grid cell of the world point (build_grid), -1 off the grid (non-finite points too)."""
    u0 = (px - grid_box[0]) * grid_box[3]
    u1 = (py - grid_box[1]) * grid_box[3]
    u2 = (pz - grid_box[2]) * grid_box[3]
    if not (0.0 <= u0 < grid_dims[0] and 0.0 <= u1 < grid_dims[1] and 0.0 <= u2 < grid_dims[2]):
        return -1
    return (int(u0) * grid_dims[1] + int(u1)) * grid_dims[2] + int(u2)


# -- collider queries -----------------------------------------------------------------------------
# Hulls: stages.maps.kernels.hull_query over the MapArrays fields as plain arrays (unpacked once per
# kernel with query_arrays: a named tuple reached inside the loop would cost reference counting per
# query); the sphere test and the OBB rejection are written out in collide's loop, and only points
# inside an OBB reach the hull query.
@njit(cache=True, inline="always")
def _sphere_hit(rad, q0, q1, q2):
    """(hit, r0, r1, r2, n0, n1, n2) of a sphere of radius rad at the origin of the query frame:
    paper eq. 5 (inside iff |q| < r) and eq. 6 (response r q / |q|), outward normal q / |q|."""
    d2 = q0 * q0 + q1 * q1 + q2 * q2
    if d2 >= rad * rad:
        return False, q0, q1, q2, 0.0, 0.0, 0.0
    d = math.sqrt(d2)
    if d < 1e-12:                     # at the centre: no direction, push up (deterministic)
        return True, 0.0, rad, 0.0, 0.0, 1.0, 0.0
    f = rad / d
    return True, f * q0, f * q1, f * q2, q0 / d, q1 / d, q2 / d


@njit(cache=True, _nrt=False)
def _collider_hit(c, col_kind, col_index, sph_radius, method,
                  half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes, cell_base,
                  cell_start, cell_tris, loc_base, loc_x, loc_start, loc_y, loc_face,
                  q0, q1, q2):
    """(hit, r0, r1, r2, n0, n1, n2): inside test, response point and outward unit contact normal
    of collider c, all in its query frame (the slow-path form of the test written out in collide)."""
    idx = col_index[c]
    if col_kind[c] == KIND_SPHERE:
        return _sphere_hit(sph_radius[idx], q0, q1, q2)
    if method != METHOD_NEAREST_PLANE and (abs(q0) > half[idx, 0] or abs(q1) > half[idx, 1] or abs(q2) > half[idx, 2]):
        return False, q0, q1, q2, 0.0, 0.0, 0.0
    hit, r0, r1, r2, face = hull_query(
        half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes, cell_base,
        cell_start, cell_tris, loc_base, loc_x, loc_start, loc_y, loc_face,
        idx, method, q0, q1, q2)
    if not hit:
        return False, q0, q1, q2, 0.0, 0.0, 0.0
    return True, r0, r1, r2, planes[face, 0], planes[face, 1], planes[face, 2]


@njit(cache=True, inline="always")
def _penetrates(c, col_kind, col_index, sph_radius, method, tq, cw,
                half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes, cell_base,
                cell_start, cell_tris, loc_base, loc_x, loc_start, loc_y, loc_face,
                px, py, pz):
    """True if the world point is inside collider c with a real push (world sphere test first)."""
    dx = px - cw[c, 0]
    dy = py - cw[c, 1]
    dz = pz - cw[c, 2]
    if dx * dx + dy * dy + dz * dz >= cw[c, 4]:
        return False
    q0, q1, q2 = _apply12(tq, c, px, py, pz)
    hit, r0, r1, r2, n0, n1, n2 = _collider_hit(
        c, col_kind, col_index, sph_radius, method,
        half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes, cell_base,
        cell_start, cell_tris, loc_base, loc_x, loc_start, loc_y, loc_face, q0, q1, q2)
    return hit and (r0 - q0) ** 2 + (r1 - q1) ** 2 + (r2 - q2) ** 2 >= TOUCH_EPS * TOUCH_EPS


@njit(cache=True, _nrt=False)
def _inside_any(col_kind, col_index, sph_radius, method, tq, cw, skip,
                half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes, cell_base,
                cell_start, cell_tris, loc_base, loc_x, loc_start, loc_y, loc_face,
                px, py, pz):
    """True if the world point is inside any collider except `skip` (with a real push)."""
    for c in range(cw.shape[0]):
        if c != skip and _penetrates(c, col_kind, col_index, sph_radius, method, tq, cw,
                                     half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes,
                                     cell_base, cell_start, cell_tris, loc_base, loc_x, loc_start, loc_y, loc_face,
                                     px, py, pz):
            return True
    return False


@njit(cache=True, _nrt=False, inline="always")
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
    o0, o1, o2 = _apply12(tq0, c, xp[i, 0], xp[i, 1], xp[i, 2])
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
    px, py, pz = _apply12(fq, c, r0, r1, r2)
    if vn > 0.0:
        # fully inelastic: the push-out must not become an outward Verlet velocity,
        # so move xp along the (world) normal by the outward relative travel
        w0, w1, w2 = _rotate12(fq, c, n0, n1, n2)
        xp[i, 0] += vn * w0
        xp[i, 1] += vn * w1
        xp[i, 2] += vn * w2
    return True, px, py, pz


EDGE_EPS = 1e-12     # m: slack of the exit-face containment test (rounding is ~1e-17 m here)


@njit(cache=True, inline="always")
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


# -- overlapping colliders: escape from their union when the pass budget is spent ------------------
@njit(cache=True, inline="always")
def _outward(c, col_kind, face_start, planes, idx, tq, px, py, pz):
    """World unit direction out of collider c at the world point p: sphere, radial from its centre;
    hull, the normal of the face whose plane p is farthest in front of (the nearest face from inside).
    Normals go to world by the transpose of tq's linear part (inverse transpose of query -> world)."""
    q0, q1, q2 = _apply12(tq, c, px, py, pz)
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


@njit(cache=True, inline="always")
def _ray_exit(c, col_kind, face_start, planes, idx, sph_radius, tq, px, py, pz, dx, dy, dz):
    """Parameter t >= 0 where the world ray p + t d leaves convex collider c (0 if p is not inside).
    The query frame is affine in world, so t is the same in both frames: q(p + t d) = q(p) + t e."""
    q0, q1, q2 = _apply12(tq, c, px, py, pz)
    e0, e1, e2 = _rotate12(tq, c, dx, dy, dz)
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


@njit(cache=True, inline="always")
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


@njit(cache=True, parallel=True, _nrt=False)
def collide(x, xp, inv_mass, m, method, col_kind, col_index, sph_radius, tq, tq0, fq, cw,
            grid_start, grid_items, grid_box, grid_dims, face_edges, src_range, friction, passes, corrected, inside,
            speed2, contact, h):
    """Collision detection and response of every free particle against every collider.

    Per particle: the colliders listed in its grid cell (build_grid) whose world bounding sphere
    holds it are tested in their query frame (spheres: paper eq. 5-6; hulls: OBB rejection, then
    stages.maps.kernels.hull_query with `method`). After a push by collider c the particle is outside c
    (by PUSH_EPS; friction slides it along the contact plane); the colliders of the cell of its new
    position are then visited cyclically after c (world sphere test first) until every one has been
    checked at the current position without a push, at most `passes` x (number of colliders) visits.
    A particle still inside one when the budget is spent is being pushed back and forth between
    overlapping colliders: `escape_union` moves it to a point outside all of them (no friction,
    inelastic along the escape). The response gets Coulomb friction relative to the collider: its
    tangential travel over the step loses up to `friction` times the push's normal depth.
    corrected[i] |= 1 if the particle was pushed; inside[i] = 1 if it is still inside a collider at
    the end; speed2[i] = |x - xp|^2 / h^2 at the end (divergence check).
    Temporal coherence (METHOD_PAPER): contact (N, C) int32 holds per particle and hull the face of
    its last verdict (the exit face of a push, or a separating face), -1 unknown; the next query of
    that hull first tries that face (_cached_face: the same answer when it gives one), which is right
    again for a particle resting on, sliding over or hovering near the hull. face_edges (F, 12),
    src_range (H, 2): see _cached_face and stages/sim/simulate.py.
    """
    (half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes, cell_base, cell_start, cell_tris,
     loc_base, loc_x, loc_start, loc_y, loc_face) = query_arrays(m)
    nc = cw.shape[0]
    ih2 = 1.0 / (h * h)
    for i in prange(x.shape[0]):   # particles are independent: any thread count, same result
        px = x[i, 0]
        py = x[i, 1]
        pz = x[i, 2]
        inside[i] = 0
        b = _grid_cell(grid_box, grid_dims, px, py, pz) if inv_mass[i] > 0.0 else -1
        if b >= 0:
            # one visiting loop (a single inlined query site keeps the loop small):
            # stage 0, the cell's colliders; stage 1, after a push, the others cyclically until all
            # were seen without a push; stage 2, the budget spent: only detect (no push).
            e = grid_start[b]
            e1 = grid_start[b + 1]
            stage = 0
            last = -1
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
                        bb = _grid_cell(grid_box, grid_dims, px, py, pz)
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
                if dx * dx + dy * dy + dz * dz < cw[c, 4]:
                    q0, q1, q2 = _apply12(tq, c, px, py, pz)
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
                        if not known:
                            hit, r0, r1, r2, face = hull_query(
                                half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes, cell_base,
                                cell_start, cell_tris, loc_base, loc_x, loc_start, loc_y, loc_face,
                                idx, method, q0, q1, q2)
                            if face >= 0:
                                contact[i, c] = face
                        if hit:
                            n0 = planes[face, 0]
                            n1 = planes[face, 1]
                            n2 = planes[face, 2]
                    if hit:
                        if stage == 2:
                            if (r0 - q0) ** 2 + (r1 - q1) ** 2 + (r2 - q2) ** 2 >= TOUCH_EPS * TOUCH_EPS:
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
                corrected[i] = 1
                x[i, 0] = px
                x[i, 1] = py
                x[i, 2] = pz
        vx = px - xp[i, 0]
        vy = py - xp[i, 1]
        vz = pz - xp[i, 2]
        speed2[i] = (vx * vx + vy * vy + vz * vz) * ih2


@njit(cache=True, _nrt=False)
def count_inside(x, inv_mass, m, method, col_kind, col_index, sph_radius, tq, cw, inside):
    """inside[i] = 1 if free particle i is inside any collider (no response)."""
    (half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes, cell_base, cell_start, cell_tris,
     loc_base, loc_x, loc_start, loc_y, loc_face) = query_arrays(m)
    for i in range(x.shape[0]):
        inside[i] = 0
        if inv_mass[i] > 0.0:
            inside[i] = _inside_any(
                col_kind, col_index, sph_radius, method, tq, cw, -1,
                half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes, cell_base,
                cell_start, cell_tris, loc_base, loc_x, loc_start, loc_y, loc_face, x[i, 0], x[i, 1], x[i, 2])


# -- steps and frames ------------------------------------------------------------------------------
@njit(cache=True, _nrt=False)
def run_steps(cloth, cols, m, prm, gravity, wind, fwd, inv, inv0, d_prev, d_next, k0, k1, flags, timers):
    """Steps k0..k1-1 in the paper's order: forces, Verlet (+ attachments), spring corrections,
    collisions. Per step k: fwd[k] / inv[k] (J, 4, 4) the pose at its end, inv0[k] at its start;
    d_prev[k] / d_next[k] (3,) the root translation over the previous / this step.
    timers (3,) int64 accumulate cycles of integrate / constraints / collisions."""
    (x, xp, inv_mass, attach_joint, attach_local, ij, sp, group_start, ti, ta, tl, tris, tri_mass,
     tri_force, vt_table, x4) = cloth
    (col_joint, col_kind, col_index, col_bcenter, col_bradius, sph_center, sph_radius,
     tq, tq0, fq, cw, grid_start, grid_items, grid_runs, grid_box, grid_dims, face_edges, src_range) = cols
    h, damping, s, k_drag, k_lift, friction, use_aero, iterations, passes, method = prm
    corrected, inside, speed2, contact = flags
    for k in range(k0, k1):
        t0 = cycles()
        if use_aero:
            aero_forces(x, xp, tri_mass, tris, h, s, d_prev[k], wind, k_drag, k_lift, tri_force)
        integrate(x, xp, inv_mass, attach_joint, attach_local, fwd[k], h, gravity, damping, s,
                  d_prev[k], d_next[k], use_aero, tri_force, vt_table)
        t1 = cycles()
        correct_springs(x, x4, ij, sp, group_start, ti, ta, tl, iterations)
        t2 = cycles()
        collider_frames(fwd[k], inv[k], inv0[k], m, col_joint, col_kind, col_index, col_bcenter, col_bradius,
                        sph_center, tq, tq0, fq, cw)
        build_grid(m, method, col_kind, col_index, sph_radius, tq, fq, cw, grid_start, grid_items, grid_runs, grid_box,
                   grid_dims)
        collide(x, xp, inv_mass, m, method, col_kind, col_index, sph_radius, tq, tq0, fq, cw,
                grid_start, grid_items, grid_box, grid_dims, face_edges, src_range, friction, passes, corrected, inside,
                speed2, contact, h)
        t3 = cycles()
        timers[T_INTEGRATE] += t1 - t0
        timers[T_CONSTRAINTS] += t2 - t1
        timers[T_COLLISIONS] += t3 - t2


@njit(cache=True, _nrt=False)
def record_frame(x, flags, max_speed2, goff, pos, pen, counts):
    """Store one frame: pos (N, 3) float32 <- x; pen (G,) particles inside a collider per garment
    (garment g = goff[g]..goff[g+1]); counts = (corrected particles, max speed^2).
    Returns False (storing nothing) if a particle is non-finite or faster than sqrt(max_speed2)."""
    corrected, inside, speed2, _ = flags
    vmax = 0.0
    for i in range(x.shape[0]):
        v = speed2[i]
        if not (v <= max_speed2) or not (np.isfinite(x[i, 0]) and np.isfinite(x[i, 1]) and np.isfinite(x[i, 2])):
            return False
        vmax = max(vmax, v)
    nc = 0
    for g in range(goff.size - 1):
        n_in = 0
        for i in range(goff[g], goff[g + 1]):
            pos[i, 0] = x[i, 0]
            pos[i, 1] = x[i, 1]
            pos[i, 2] = x[i, 2]
            n_in += inside[i]
            nc += corrected[i]
        pen[g] = n_in
    counts[0] = nc
    counts[1] = vmax
    return True


@njit(cache=True, _nrt=False)
def run_frames(cloth, cols, m, prm, gravity, wind, fwd, inv, inv0, d_prev, d_next, substeps, max_speed2,
               goff, pos, pen, counts, step_cycles, flags, timers):
    """Frames 0..F-1 of a chunk (F = pos.shape[0]), `substeps` steps each (pose arrays: F * substeps),
    each recorded with record_frame into pos[f], pen[f], counts[f]; step_cycles[f] the frame's
    stepping cycles (recording excluded). Returns the number of frames done: F, or the index of the
    first frame that diverged (not recorded; the state is left as it diverged)."""
    corrected = flags[0]
    for f in range(pos.shape[0]):
        corrected[:] = 0
        c0 = cycles()
        run_steps(cloth, cols, m, prm, gravity, wind, fwd, inv, inv0, d_prev, d_next,
                  f * substeps, (f + 1) * substeps, flags, timers)
        step_cycles[f] = cycles() - c0
        if not record_frame(cloth[0], flags, max_speed2, goff, pos[f], pen[f], counts[f]):
            return f
    return pos.shape[0]

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
                nx, ny, nz = triangle_cross(vertices, a, b, c)
                nx *= 0.5
                ny *= 0.5
                nz *= 0.5
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
