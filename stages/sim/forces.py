"""External forces of the cloth step: the aerodynamic drag and lift per triangle (paper A §3.3).
Gravity is added in the Verlet step (stages.sim.integrate), which gathers these triangle forces.
"""
from __future__ import annotations

import llvmlite.ir as ir
import numpy as np
from numba import njit, prange, types
from numba.core import cgutils
from numba.extending import intrinsic

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)
from stages.jit import serial_and_parallel
from stages.fastmath import V4, inv_sqrt_v4, v4_const
from stages.sim.simd import fmuladd, shuffle, splat, transpose

NUMBA_CACHE_DEPENDS = ("stages.fastmath", "stages.sim.simd")


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
        c = [splat(builder, a) for a in args[6:]]
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
        vel = transpose(builder, *vel)
        e1x, e1y, e1z = transpose(builder, *e1)
        e2x, e2y, e2z = transpose(builder, *e2)
        wx, wy, wz = (builder.fsub(wind[k], builder.fmul(builder.fadd(vel[k], c3[k]), ih)) for k in range(3))

        def cross_lane(a1, b2, a2, b1):      # a1 b2 - a2 b1
            return fmuladd(builder, a1, b2, builder.fneg(builder.fmul(a2, b1)))

        def dot(ax, ay, az, bx, by, bz):
            return fmuladd(builder, az, bz, fmuladd(builder, ay, by, builder.fmul(ax, bx)))

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
        f = [fmuladd(builder, fd, wk, builder.fmul(fl, fmuladd(builder, minus_g, wk, nk)))
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
        xy01 = shuffle(builder, fx, fy, [0, 4, 1, 5])
        xy23 = shuffle(builder, fx, fy, [2, 6, 3, 7])
        z01 = shuffle(builder, fz, zero, [0, 4, 1, 5])
        z23 = shuffle(builder, fz, zero, [2, 6, 3, 7])
        rows = (shuffle(builder, xy01, z01, [0, 1, 4, 5]), shuffle(builder, xy01, z01, [2, 3, 6, 7]),
                shuffle(builder, xy23, z23, [0, 1, 4, 5]), shuffle(builder, xy23, z23, [2, 3, 6, 7]))
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


@serial_and_parallel(cache=True, fastmath=True, _nrt=False)
def aero_forces(x, xp, tri_mass, tris, h, s, d_prev, wind, k_drag, k_lift, out, hold=1):
    """Per-triangle aerodynamic forces (N) into rows 0..T-1 of out (rows (x, y, z, 0), 4 columns), from
    the air velocity relative to each triangle. tri_mass (T,): the mass of the triangle's free vertices
    (a third of each free vertex's lumped mass), kg.

    Vertex velocity v = (x - xp + s d_prev) / h (Verlet estimate, world velocity scaled by the
    inertia scale s). w = wind - mean v; n' = unit normal oriented along w; c = n'.w/|w|.
    drag = k_drag A c |w|^2 w/|w|; lift = k_lift A c |w|^2 (n' - c w/|w|)   (k = 0.5 rho C).
    With N = (b - a) x (c - a) (|N| = 2A) these are drag = k_drag/2 |N.w| w and
    lift = k_lift/2 (N.w) |w|/|N| (N - (N.w)/|w|^2 w), from one r = 1/sqrt(|w|^2 |N|^2):
    |w|/|N| = |w|^2 r, 1/|w|^2 = |N|^2 r^2. Explicit drag
    is unstable once it would more than stop the triangle within a step: |F| is capped at m |w| / h,
    or m |w| / (hold h) for a force held over `hold` steps (SimParams.aero_interval).
    Computed 4 triangles at a time (`_aero_group`, its docstring: the exact operation order).
    """
    if out.shape[1] != 4 or out.shape[0] < tris.shape[0]:
        raise ValueError("aero_forces: out must have (T, 4) rows")
    ih = 1.0 / (3.0 * h)
    span = hold * h                  # the time the forces are held (one step: h, exactly)
    ihh = 1.0 / (span * span)
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
