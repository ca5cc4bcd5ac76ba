"""The Verlet step of the cloth (paper A §3.3): gravity, the gathered aerodynamic forces, damping,
the root translation terms (see stages/sim/simulate.py), attached particles put on their bones.
"""
from __future__ import annotations

import llvmlite.ir as ir
import numpy as np
from numba import njit, prange, types
from numba.core import cgutils
from numba.extending import intrinsic

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)
from stages.jit import serial_and_parallel
from stages.affine import apply_affine
from stages.fastmath import V4

NUMBA_CACHE_DEPENDS = ("stages.affine", "stages.fastmath")



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


@njit(cache=True, _nrt=False, forceinline=True)
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


@intrinsic
def _verlet4(typingctx, xf, xpf, inv_mass, i, keep, rx, ry, rz, gx, gy, gz, hh, forces, with_force):
    """_verlet for 4 free particles i..i+3 (not attached, inverse mass > 0; i + 3 < N) on the flat
    (3 N,) x and xp: their 12 coordinates as 3 <4 x double> (x0 y0 z0 x1 | y1 z1 x2 y2 | z2 x3 y3 z3),
    per lane the scalar code's operations in its order (no fma):
    new = ((x + keep (x - xp)) + r) + (g + f ((w hh) / 3)), the force term only when with_force (a
    literal bool); forces: the 12 force sums (x, y, z per particle)."""
    def codegen(context, builder, signature, args):
        x_data, xp_data, w_data = (context.make_array(ty)(context, builder, a).data
                                   for ty, a in zip(signature.args[:3], args[:3]))
        i64 = ir.IntType(64)
        i = context.cast(builder, args[3], signature.args[3], types.int64)

        def vec(data, offset):
            return builder.bitcast(builder.gep(data, [offset]), V4.as_pointer())

        def splat(value):
            v = builder.insert_element(ir.Constant(V4, None), value, ir.Constant(ir.IntType(32), 0))
            return builder.shuffle_vector(v, v, ir.Constant(ir.VectorType(ir.IntType(32), 4), [0] * 4))

        def pattern(values, lanes):
            """<4 x double> of values[lane] for the lanes given."""
            out = ir.Constant(V4, None)
            for k, lane in enumerate(lanes):
                out = builder.insert_element(out, values[lane], ir.Constant(ir.IntType(32), k))
            return out

        def lanes3(values):
            """The 3 vectors of a per-particle scalar repeated over its 3 coordinates."""
            return [pattern(values, ls) for ls in ((0, 0, 0, 1), (1, 1, 2, 2), (2, 3, 3, 3))]

        base = builder.mul(i, ir.Constant(i64, 3))
        ptrs = [(vec(x_data, builder.add(base, ir.Constant(i64, 4 * k))),
                 vec(xp_data, builder.add(base, ir.Constant(i64, 4 * k)))) for k in range(3)]
        keep = splat(args[4])
        r = [pattern(args[5:8], ls) for ls in ((0, 1, 2, 0), (1, 2, 0, 1), (2, 0, 1, 2))]
        g = [pattern(args[8:11], ls) for ls in ((0, 1, 2, 0), (1, 2, 0, 1), (2, 0, 1, 2))]
        if with_force.literal_value:
            w = builder.load(vec(w_data, i), align=8)
            scale = builder.fdiv(builder.fmul(w, splat(args[11])), splat(ir.Constant(ir.DoubleType(), 3.0)))
            scale = [builder.extract_element(scale, ir.Constant(ir.IntType(32), k)) for k in range(4)]
            forces = [builder.extract_value(args[12], k) for k in range(12)]
            f = [pattern(forces, range(4 * k, 4 * k + 4)) for k in range(3)]
            g = [builder.fadd(gk, builder.fmul(fk, sk)) for gk, fk, sk in zip(g, f, lanes3(scale))]
        for (px, pxp), rk, ak in zip(ptrs, r, g):
            o = builder.load(px, align=8)
            v = builder.fsub(o, builder.load(pxp, align=8))
            n = builder.fadd(builder.fadd(builder.fadd(o, builder.fmul(keep, v)), rk), ak)
            builder.store(o, pxp, align=8)
            builder.store(n, px, align=8)
        return context.get_dummy_value()

    flat = all(isinstance(a, types.Array) and a.ndim == 1 and a.layout == "C" and a.dtype == types.float64
               for a in (xf, xpf, inv_mass))
    if not (flat and isinstance(i, types.Integer) and isinstance(with_force, types.BooleanLiteral)
            and isinstance(forces, types.UniTuple) and forces.count == 12):
        return None
    scalars = (keep, rx, ry, rz, gx, gy, gz, hh)
    return types.void(xf, xpf, inv_mass, i, *scalars, forces, with_force), codegen


# Speed: the gather of the triangle forces of a vertex reads whole (x, y, z, 0) rows as one vector,
# 4 vertices interleaved (each sum is a chain of dependent additions) over a fixed-width table; the
# same additions in the same order, so bit-identical to the CSR loop it replaced. Integrate phase
# (forces + Verlet), one thread: drape 51 -> 43 us a step, walk 66 -> 57 us.
@serial_and_parallel(cache=True, _nrt=False)
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
    xf = x.reshape(x.size)
    xpf = xp.reshape(xp.size)
    for g in prange((n + 3) // 4):
        i = 4 * g
        f = _force_sums(tri_force, vt_table, i) if use_aero else (0.0,) * 12
        if (i + 3 < n and attach_joint[i] < 0 and attach_joint[i + 1] < 0 and attach_joint[i + 2] < 0
                and attach_joint[i + 3] < 0 and inv_mass[i] != 0.0 and inv_mass[i + 1] != 0.0
                and inv_mass[i + 2] != 0.0 and inv_mass[i + 3] != 0.0):
            # 4 free particles: the same arithmetic on vectors (drape, Verlet alone: 9.5 -> 5.4 us a step)
            if use_aero:
                _verlet4(xf, xpf, inv_mass, i, keep, rx, ry, rz, gx, gy, gz, hh, f, True)
            else:
                _verlet4(xf, xpf, inv_mass, i, keep, rx, ry, rz, gx, gy, gz, hh, f, False)
            continue
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


@serial_and_parallel(cache=True, _nrt=False)
def gather_forces(tri_force, vt_table, vertex_force):
    """vertex_force[i, :3] = the sum of the tri_force rows of vertex i (vt_table, in its order: the
    sums `integrate` forms), row N and column 3 left alone. For forces held over several steps
    (SimParams.aero_interval): `integrate` then reads one row per vertex (vertex_force with the
    table `identity_table(N)`), the same sums, bit for bit (0 + f = f)."""
    n = vt_table.shape[0]
    for g in prange((n + 3) // 4):
        i = 4 * g
        f = _force_sums(tri_force, vt_table, i)
        for lane in range(4):
            if i + lane < n:
                vertex_force[i + lane, 0] = f[3 * lane]
                vertex_force[i + lane, 1] = f[3 * lane + 1]
                vertex_force[i + lane, 2] = f[3 * lane + 2]


LIMITED = 2    # limit_speed's mark in corrected[i] (bit 1; bit 0: pushed by a collider)


@serial_and_parallel(cache=True, _nrt=False)
def limit_speed(x, xp, inv_mass, vh, speed2, h, corrected):
    """Cap the Verlet velocity (x - xp) / h of every free particle at vh / h (m/s, relative frame):
    xp moves towards x, x stays. A particle a collider response or a pinch has thrown far in one
    step (a chibi's arm box pressing the skirt onto its leg: 117 m/s, diverged) then carries no more
    than the limit into the next step, and the springs pull it back. Marks corrected[i] |= LIMITED;
    speed2[i] becomes |x - xp|^2 / h^2 after the cap (the step's final speed: collide's was taken
    before the cloth phase)."""
    vh2 = vh * vh
    ih2 = 1.0 / (h * h)
    for i in prange(x.shape[0]):
        if inv_mass[i] == 0.0:
            continue
        v0 = x[i, 0] - xp[i, 0]
        v1 = x[i, 1] - xp[i, 1]
        v2 = x[i, 2] - xp[i, 2]
        d2 = v0 * v0 + v1 * v1 + v2 * v2
        if d2 > vh2:
            k = vh / np.sqrt(d2)
            xp[i, 0] = x[i, 0] - k * v0
            xp[i, 1] = x[i, 1] - k * v1
            xp[i, 2] = x[i, 2] - k * v2
            corrected[i] |= LIMITED
            d2 = vh2
        speed2[i] = d2 * ih2


def identity_table(n: int):
    """(N, 1) int32: vertex i lists row i (a `vt_table` over per-vertex force rows)."""
    return np.arange(n, dtype=np.int32).reshape(n, 1)
