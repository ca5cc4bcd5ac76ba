"""Spring position corrections (paper A §1: stretch, shear and bend springs, Gauss-Seidel) and tethers
(long-range attachments, Kim, Chentanez & Mueller 2012).
"""
from __future__ import annotations

import llvmlite.ir as ir
import numpy as np
from numba import njit, prange, types
from numba.extending import intrinsic

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)
from stages.jit import serial_and_parallel
from stages.fastmath import V4, inv_sqrt, inv_sqrt_v4, v4_const
from stages.sim.simd import fmuladd, shuffle

NUMBA_CACHE_DEPENDS = ("stages.fastmath", "stages.sim.simd")


# -- springs --------------------------------------------------------------------------------------
# Speed (the largest phase of a step): positions are corrected in a (N + 1, 4) float64 scratch,
# a particle one 256-bit row (x, y, z, 0), and springs 4 at a time, as groups of 4 springs on 8
# distinct particles (colour order makes nearly every run of 4 such a group): one vector load /
# store per particle, the 4 lengths and their inverse square roots as vectors (no gather: AVX-512
# gathers / scatters were slower on the benchmark CPU). Per spring it is the same arithmetic in the
# same order as the scalar loop, so the result is bit-identical to it (drape: 138 -> 79 us a step).




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
        xz01 = shuffle(builder, d[0], d[1], [0, 4, 2, 6])
        y_01 = shuffle(builder, d[0], d[1], [1, 5, 3, 7])
        xz23 = shuffle(builder, d[2], d[3], [0, 4, 2, 6])
        y_23 = shuffle(builder, d[2], d[3], [1, 5, 3, 7])
        dx = shuffle(builder, xz01, xz23, [0, 1, 4, 5])
        dy = shuffle(builder, y_01, y_23, [0, 1, 4, 5])
        dz = shuffle(builder, xz01, xz23, [2, 3, 6, 7])
        d2 = fmuladd(builder, dz, dz, fmuladd(builder, dy, dy, builder.fmul(dx, dx)))
        live = builder.fcmp_unordered(">", d2, v4_const(1e-24))       # not (d2 <= 1e-24)
        d2 = builder.select(live, d2, v4_const(1.0))                 # no inf / nan in dead lanes
        rest, wi, wj = (builder.load(builder.bitcast(builder.gep(sp_data, [builder.add(builder.mul(g, at(12)), at(4 * q))]),
                                                     V4.as_pointer()), align=8) for q in range(3))
        c = builder.fsub(v4_const(1.0), builder.fmul(rest, inv_sqrt_v4(builder, d2)))
        c = builder.select(live, c, ir.Constant(V4, None))
        a = builder.fmul(wi, c)
        b = builder.fneg(builder.fmul(wj, c))
        for k in range(4):
            builder.store(fmuladd(builder, shuffle(builder, a, a, [k] * 4), d[k], xi[k]), rows[k], align=8)
            builder.store(fmuladd(builder, shuffle(builder, b, b, [k] * 4), d[k], xj[k]), rows[4 + k], align=8)
        return context.get_dummy_value()

    arrays = ((xf, types.float64), (ij, types.uint32), (sp, types.float64))
    if not all(isinstance(a, types.Array) and a.ndim == 1 and a.layout == "C" and a.dtype == t for a, t in arrays):
        return None     # the codegen addresses flat contiguous arrays of these types
    return types.void(xf, ij, sp, g), codegen


@serial_and_parallel(cache=True, fastmath=True, _nrt=False)
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
