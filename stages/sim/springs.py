"""Spring position corrections (paper A §1: stretch, shear and bend springs, Gauss-Seidel) and tethers
(long-range attachments, Kim, Chentanez & Mueller 2012).
"""
from __future__ import annotations

import llvmlite.ir as ir
import numpy as np
from numba import njit, prange, types
from numba.core import cgutils
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
# The groups of a block are software-pipelined over PIPELINE stages (_correct_run): one group's
# corrections are stored while the next three are read and computed, as the out-of-order core
# alone did not overlap them (its window held ~2 groups of the ~60-cycle chain: load, transpose,
# lengths, inverse square root, store). pack_springs keeps each group on other particles than the
# PIPELINE - 1 before it, so the reads ahead see what the plain order sees: the same bits. Drape,
# 2 rounds, one thread, alternating in one process (2026-11-24, load 0.7-1.2): 7.8 -> 5.7 ns a group.
PIPELINE = 4


@njit(cache=True, forceinline=True)
def _touches(si, sj, k, lane_spring, q0, q1):
    """True if spring k shares a particle with a spring in lane_spring[q0:q1] (-1: padding)."""
    for q in range(q0, q1):
        kq = lane_spring[q]
        if kq >= 0 and (si[k] == si[kq] or si[k] == sj[kq] or sj[k] == si[kq] or sj[k] == sj[kq]):
            return True
    return False


@njit(cache=True)
def _group_springs(si, sj, part_start, window, lane_spring, group_start):
    """The springs of each block (part_start), in order, into groups of 4 lanes: lane_spring[4 g + l]
    = the spring in lane l of group g (left -1: padding). A group is closed early before a spring
    that shares a particle with one in it or in the `window` groups before it (of its block); a
    group of padding only goes in where no open group could take the spring. group_start[b] =
    block b's first group; returns the number of groups."""
    g = 0
    for b in range(part_start.size - 1):
        group_start[b] = g
        lane = 0
        for k in range(part_start[b], part_start[b + 1]):
            while lane == 4 or _touches(si, sj, k, lane_spring, 4 * max(g - window, group_start[b]), 4 * g + lane):
                g += 1          # close the group (or leave it empty: padding)
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
    distinct particles that no spring of the PIPELINE - 1 groups before it (in its block) touches
    (a group is closed early, padded with dummy springs, before a spring that shares a particle with
    it or them, with groups of dummies between where needed; in colour order that happens only
    where the colour changes).
    ij (8 G,) uint32: per group 4 si then 4 sj, as offsets 4 i into the flat scratch (unsigned: no
    negative-index wraparound); sp (12 G,) float64: per group 4 rest, 4 wi, 4 wj; dummy springs join
    the scratch's row N to itself with rest = wi = wj = 0 (they move nothing); group_start (B + 1,):
    block b is groups group_start[b]..group_start[b + 1] - 1.
    """
    si = np.ascontiguousarray(si, np.int64)
    sj = np.ascontiguousarray(sj, np.int64)
    if 4 * n_particles + 3 >= 2 ** 32:
        raise ValueError("pack_springs: too many particles for uint32 offsets")
    lane_spring = np.full(4 * PIPELINE * si.size, -1, np.int64)     # at most PIPELINE groups per spring
    group_start = np.zeros(part_start.size, np.int64)
    n_groups = _group_springs(si, sj, np.ascontiguousarray(part_start, np.int64), PIPELINE - 1, lane_spring,
                             group_start)
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


def _group_rows(builder, x_data, ij_data, g):
    """The 8 row pointers (4 particles i, then 4 particles j) of group g into the flat scratch."""
    rows = []
    for lane in range(8):
        k = builder.add(builder.mul(g, ir.Constant(g.type, 8)), ir.Constant(g.type, lane))
        offset = builder.zext(builder.load(builder.gep(ij_data, [k])), ir.IntType(64))
        rows.append(builder.bitcast(builder.gep(x_data, [offset]), V4.as_pointer()))
    return rows


def _sp_row(builder, sp_data, g, q):
    """Row q (0 rest, 1 wi, 2 wj) of group g's parameters, one <4 x double>."""
    k = builder.add(builder.mul(g, ir.Constant(g.type, 12)), ir.Constant(g.type, 4 * q))
    return builder.load(builder.bitcast(builder.gep(sp_data, [k]), V4.as_pointer()), align=8)


def _stage_read(builder, x_data, ij_data, sp_data, g, state):
    """Stage 0 of group g: its rows read, d = x_j - x_i (4 rows (dx, dy, dz, 0))."""
    rows = _group_rows(builder, x_data, ij_data, g)
    return [builder.fsub(builder.load(rows[4 + k], align=8), builder.load(rows[k], align=8)) for k in range(4)]


def _stage_factor(builder, x_data, ij_data, sp_data, g, d):
    """Stage 1: d2 = fma(dz, dz, fma(dy, dy, dx dx)) per spring and c = 1 - rest inv_sqrt(d2), 0 where
    d2 <= 1e-24 (coincident ends: nothing moves). Returns d + [c]."""
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
    c = builder.fsub(v4_const(1.0), builder.fmul(_sp_row(builder, sp_data, g, 0), inv_sqrt_v4(builder, d2)))
    return list(d) + [builder.select(live, c, ir.Constant(V4, None))]


def _stage_weights(builder, x_data, ij_data, sp_data, g, state):
    """Stage 2: the shares a = wi c and b = -(wj c). Returns d + [a, b]."""
    c = state[4]
    a = builder.fmul(_sp_row(builder, sp_data, g, 1), c)
    b = builder.fneg(builder.fmul(_sp_row(builder, sp_data, g, 2), c))
    return state[:4] + [a, b]


def _stage_write(builder, x_data, ij_data, sp_data, g, state):
    """Stage 3: x_i += a d, x_j += b d (rows read again: unchanged since stage 0)."""
    rows = _group_rows(builder, x_data, ij_data, g)
    d, a, b = state[:4], state[4], state[5]
    for k in range(4):
        builder.store(fmuladd(builder, shuffle(builder, a, a, [k] * 4), d[k], builder.load(rows[k], align=8)),
                      rows[k], align=8)
        builder.store(fmuladd(builder, shuffle(builder, b, b, [k] * 4), d[k], builder.load(rows[4 + k], align=8)),
                      rows[4 + k], align=8)
    return []


_STAGES = (_stage_read, _stage_factor, _stage_weights, _stage_write)
assert len(_STAGES) == PIPELINE


def _stages(builder, data, g, state, first, last):
    """Stages first..last - 1 of group g."""
    for stage in _STAGES[first:last]:
        state = stage(builder, *data, g, state)
    return state


def _flat_arrays_ok(xf, ij, sp):
    arrays = ((xf, types.float64), (ij, types.uint32), (sp, types.float64))
    return all(isinstance(a, types.Array) and a.ndim == 1 and a.layout == "C" and a.dtype == t for a, t in arrays)


@intrinsic
def _correct_run(typingctx, xf, ij, sp, g0, g1):
    """Gauss-Seidel correction of the springs of groups g0..g1-1 (`pack_springs`) in the flat scratch
    xf, per spring as the scalar loop: d = x_j - x_i, d2 = fma(dz, dz, fma(dy, dy, dx dx)); if
    d2 > 1e-24: c = 1 - rest inv_sqrt(d2), x_i += wi c d, x_j -= wj c d. Software-pipelined: each
    pass of the loop runs stage 0 of group g + 3, stage 1 of g + 2, stage 2 of g + 1 and stage 3
    (the stores) of g; runs shorter than the pipeline go group by group."""
    def codegen(context, builder, signature, args):
        data = tuple(context.make_array(ty)(context, builder, a).data for ty, a in zip(signature.args[:3], args[:3]))
        i64 = ir.IntType(64)

        def at(k):
            return ir.Constant(i64, k)

        g0, g1 = (context.cast(builder, a, t, types.int64) for a, t in zip(args[3:5], signature.args[3:5]))
        depth = PIPELINE - 1
        # slots[j]: the state of group g + j (stages 0..depth-1-j done), at most 6 vectors
        slots = [[cgutils.alloca_once(builder, V4) for _ in range(6)] for _ in range(depth)]

        def put(j, state):
            for slot, v in zip(slots[j], state):
                builder.store(v, slot)

        def get(j, n):
            return [builder.load(slot) for slot in slots[j][:n]]

        sizes = [4, 5, 6]       # vectors after stages 0, 1, 2
        with builder.if_else(builder.icmp_signed(">=", builder.sub(g1, g0), at(PIPELINE))) as (long_run, short_run):
            with long_run:
                for j in range(depth):
                    put(j, _stages(builder, data, builder.add(g0, at(j)), [], 0, depth - j))
                with cgutils.for_range(builder, builder.sub(g1, at(depth)), start=g0) as loop:
                    g = loop.index
                    states = [get(j, sizes[depth - 1 - j]) for j in range(depth)]
                    new = _stages(builder, data, builder.add(g, at(depth)), [], 0, 1)
                    done = [_stages(builder, data, builder.add(g, at(j)), states[j], depth - j, depth - j + 1)
                            for j in range(depth - 1, -1, -1)]      # stage 1 of g + 2, ..., stage 3 of g
                    for j, state in zip(range(depth - 1, 0, -1), done):
                        put(j - 1, state)
                    put(depth - 1, new)
                tail = builder.sub(g1, at(depth))
                for j in range(depth):
                    _stages(builder, data, builder.add(tail, at(j)), get(j, sizes[depth - 1 - j]), depth - j, PIPELINE)
            with short_run:
                with cgutils.for_range(builder, g1, start=g0) as loop:
                    _stages(builder, data, loop.index, [], 0, PIPELINE)
        return context.get_dummy_value()

    if not (_flat_arrays_ok(xf, ij, sp) and isinstance(g0, types.Integer) and isinstance(g1, types.Integer)):
        return None     # the codegen addresses flat contiguous arrays of these types
    return types.void(xf, ij, sp, g0, g1), codegen


@intrinsic
def _copy_rows4(typingctx, src, dst, i, to_scratch):
    """Rows i..i+3 of the (N, 3) positions to / from the (N + 1, 4) scratch (to_scratch: a literal
    bool): 3 vector loads and 4 stores, or 4 loads and 3 stores, through shuffles (the plain loop
    was 7 scalar memory operations a particle, ~4 us a step on the drape). Lane 3 of a scratch row
    becomes 0."""
    def codegen(context, builder, signature, args):
        s_data, d_data = (context.make_array(ty)(context, builder, a).data for ty, a in zip(signature.args[:2], args[:2]))
        i = context.cast(builder, args[2], signature.args[2], types.int64)
        i64 = ir.IntType(64)
        zero = ir.Constant(V4, None)

        def vec(data, offset):
            return builder.bitcast(builder.gep(data, [offset]), V4.as_pointer())

        if to_scratch.literal_value:
            a, b, c = (builder.load(vec(s_data, builder.add(builder.mul(i, ir.Constant(i64, 3)), ir.Constant(i64, 4 * k))),
                                    align=8) for k in range(3))
            rows = (shuffle(builder, a, zero, [0, 1, 2, 4]), shuffle(builder, shuffle(builder, a, b, [3, 4, 5, 5]), zero,
                                                                       [0, 1, 2, 4]),
                    shuffle(builder, shuffle(builder, b, c, [2, 3, 4, 4]), zero, [0, 1, 2, 4]),
                    shuffle(builder, c, zero, [1, 2, 3, 4]))
            for k, row in enumerate(rows):
                builder.store(row, vec(d_data, builder.mul(builder.add(i, ir.Constant(i64, k)), ir.Constant(i64, 4))),
                              align=8)
        else:
            r = [builder.load(vec(s_data, builder.mul(builder.add(i, ir.Constant(i64, k)), ir.Constant(i64, 4))), align=8)
                 for k in range(4)]
            out = (shuffle(builder, r[0], r[1], [0, 1, 2, 4]), shuffle(builder, r[1], r[2], [1, 2, 4, 5]),
                   shuffle(builder, r[2], r[3], [2, 4, 5, 6]))
            for k, v in enumerate(out):
                builder.store(v, vec(d_data, builder.add(builder.mul(i, ir.Constant(i64, 3)), ir.Constant(i64, 4 * k))),
                              align=8)
        return context.get_dummy_value()

    if not (all(isinstance(a, types.Array) and a.ndim == 1 and a.layout == "C" and a.dtype == types.float64
                for a in (src, dst)) and isinstance(i, types.Integer) and isinstance(to_scratch, types.BooleanLiteral)):
        return None
    return types.void(src, dst, i, to_scratch), codegen


@njit(cache=True, _nrt=False)
def to_scratch(x, x4):
    """x4[:N, :3] = x, x4[:, 3] = 0 and x4[N] = 0 (x (N, 3) C-contiguous, x4 = padded_rows(N))."""
    n = x.shape[0]
    xf = x.reshape(x.size)
    x4f = x4.reshape(x4.size)
    for g in range(n // 4):
        _copy_rows4(xf, x4f, 4 * g, True)
    for i in range(n - n % 4, n):
        x4[i, 0] = x[i, 0]
        x4[i, 1] = x[i, 1]
        x4[i, 2] = x[i, 2]
        x4[i, 3] = 0.0
    x4[n, :] = 0.0


@njit(cache=True, _nrt=False)
def from_scratch(x4, x):
    """x = x4[:N, :3]."""
    n = x.shape[0]
    xf = x.reshape(x.size)
    x4f = x4.reshape(x4.size)
    for g in range(n // 4):
        _copy_rows4(x4f, xf, 4 * g, False)
    for i in range(n - n % 4, n):
        x[i, 0] = x4[i, 0]
        x[i, 1] = x4[i, 1]
        x[i, 2] = x4[i, 2]


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
    to_scratch(x, x4)
    xf = x4.reshape(x4.size)
    n_parts = group_start.size - 2
    for _ in range(iterations):
        for p in prange(n_parts):
            _correct_run(xf, ij, sp, group_start[p], group_start[p + 1])
        _correct_run(xf, ij, sp, group_start[n_parts], group_start[n_parts + 1])
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
    from_scratch(x4, x)


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
