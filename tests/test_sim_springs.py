"""The 4-spring groups of the spring correction (stages.sim.springs.pack_springs / correct_springs)
against a scalar Gauss-Seidel loop over the springs in their given order."""
import numpy as np
from hypothesis import given, settings, strategies as st
from numba import njit

from stages.fastmath import inv_sqrt
from stages.sim.simd import padded_rows
from stages.sim.springs import PIPELINE, correct_springs, pack_springs


@njit(fastmath=True)   # not cached: it inlines inv_sqrt
def _scalar_gauss_seidel(x, si, sj, rest, wi, wj, iterations):
    for _ in range(iterations):
        for k in range(si.size):
            i, j = si[k], sj[k]
            dx = x[j, 0] - x[i, 0]
            dy = x[j, 1] - x[i, 1]
            dz = x[j, 2] - x[i, 2]
            d2 = dx * dx + dy * dy + dz * dz
            if d2 <= 1e-24:
                continue
            c = 1.0 - rest[k] * inv_sqrt(d2)
            a = wi[k] * c
            b = wj[k] * c
            x[i, 0] += a * dx
            x[i, 1] += a * dy
            x[i, 2] += a * dz
            x[j, 0] -= b * dx
            x[j, 1] -= b * dy
            x[j, 2] -= b * dz


def _random_springs(rng, n, s):
    si = rng.integers(0, n, s)
    sj = (si + rng.integers(1, n, s)) % n          # never i == j
    rest = rng.uniform(0.0, 0.3, s)
    wi = rng.uniform(0.0, 1.0, s)
    return si, sj, rest, wi, rng.uniform(0.0, 1.0, s) * (wi > 0.1)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(2, 40), s=st.integers(0, 120), n_blocks=st.integers(1, 3))
def test_groups_hold_each_spring_once_in_order_on_distinct_particles(seed, n, s, n_blocks):
    rng = np.random.default_rng(seed)
    si, sj, rest, wi, wj = _random_springs(rng, n, s)
    part = np.sort(np.concatenate([[0, s], rng.integers(0, s + 1, n_blocks - 1)])).astype(np.int64)
    ij, sp, group_start = pack_springs(si, sj, rest, wi, wj, part, n)
    assert ij.dtype == np.uint32 and ij.size == 8 * group_start[-1] and sp.size == 12 * group_start[-1]
    groups_i = ij.reshape(-1, 2, 4)[:, 0] // 4
    groups_j = ij.reshape(-1, 2, 4)[:, 1] // 4
    prm = sp.reshape(-1, 3, 4)
    for b in range(part.size - 1):
        gi = groups_i[group_start[b]:group_start[b + 1]]
        gj = groups_j[group_start[b]:group_start[b + 1]]
        real = gi < n
        # the block's springs, in order, with their parameters; dummies join row n to itself
        assert np.array_equal(gi[real], si[part[b]:part[b + 1]]) and np.array_equal(gj[real], sj[part[b]:part[b + 1]])
        assert np.all(gj[~real] == n)
        p = prm[group_start[b]:group_start[b + 1]]
        for q, values in enumerate((rest, wi, wj)):
            assert np.array_equal(p[:, q][real], values[part[b]:part[b + 1]]) and np.all(p[:, q][~real] == 0)
        for g in range(gi.shape[0]):
            ends = np.concatenate([gi[g][real[g]], gj[g][real[g]]])
            assert np.unique(ends).size == ends.size
            # no particle of the PIPELINE - 1 groups before it (correct_springs reads that far ahead)
            before = slice(max(g - PIPELINE + 1, 0), g)
            near = np.concatenate([gi[before][real[before]], gj[before][real[before]]])
            assert not np.intersect1d(ends, near).size


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(2, 60), s=st.integers(0, 200))
def test_grouped_correction_equals_the_scalar_loop_bit_for_bit(seed, n, s):
    """Springs in random (uncoloured) order: many groups close early. Same arithmetic per spring in
    the same order: the same bits, coincident ends (skipped) included."""
    rng = np.random.default_rng(seed)
    si, sj, rest, wi, wj = _random_springs(rng, n, s)
    x0 = rng.uniform(-0.5, 0.5, (n, 3))
    x0[rng.integers(0, n, 3)] = x0[0]               # coincident particles
    ref = x0.copy()
    _scalar_gauss_seidel(ref, si, sj, rest, wi, wj, 3)
    x = x0.copy()
    packed = pack_springs(si, sj, rest, wi, wj, np.array([0, s, s], np.int64), n)
    no = np.zeros(0, np.int32)
    correct_springs(x, padded_rows(n), *packed, no, no, np.zeros(0), 3)
    np.testing.assert_array_equal(x, ref)


def test_scratch_rows_are_aligned_and_its_contents_do_not_matter():
    x4 = padded_rows(10)
    assert x4.shape == (11, 4) and x4.ctypes.data % 32 == 0 and x4.flags.c_contiguous
    rng = np.random.default_rng(3)
    si, sj, rest, wi, wj = _random_springs(rng, 10, 30)
    x0 = rng.uniform(-0.5, 0.5, (10, 3))
    packed = pack_springs(si, sj, rest, wi, wj, np.array([0, 30, 30], np.int64), 10)
    no = np.zeros(0, np.int32)
    out = []
    for fill in (0.0, np.nan):
        x4[:] = fill
        x = x0.copy()
        correct_springs(x, x4, *packed, no, no, np.zeros(0), 2)
        out.append(x)
    np.testing.assert_array_equal(out[0], out[1])
