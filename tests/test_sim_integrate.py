"""The Verlet step with the aerodynamic force gather (stages.sim.integrate.integrate, vertex_triangles)
against a plain-Python loop doing the same float operations in the same order (ascending triangle
index per vertex): bit-identical, on random meshes (vertex degrees 0 to > 8, N not a multiple of 4),
with free, pinned and attached particles, for 1 and 2 threads."""
import numba
import numpy as np
from hypothesis import given, settings, strategies as st

from stages.sim.forces import vertex_triangles
from stages.jit import for_threads
from stages.sim.integrate import gather_forces, identity_table, integrate


def _reference(x0, xp0, w, aj, al, fwd, h, g, damping, s, dp, dn, use_aero, tf, tris):
    hh = h * h
    keep = 1.0 - damping
    x, xp = x0.copy(), x0.copy()
    for i in range(len(x0)):
        if aj[i] >= 0:
            m = fwd[aj[i]]
            x[i] = [m[r, 0] * al[i, 0] + m[r, 1] * al[i, 1] + m[r, 2] * al[i, 2] + m[r, 3] for r in range(3)]
            continue
        if w[i] == 0.0:
            continue
        f = [0.0, 0.0, 0.0]
        for t in range(len(tris)):          # ascending triangle index, once per corner at vertex i
            for q in range(3):
                if tris[t, q] == i:
                    f = [f[k] + tf[t, k] for k in range(3)]
        for k in range(3):
            a = g[k] * hh
            if use_aero:
                a += f[k] * (w[i] * hh / 3.0)
            r = keep * s * dp[k] - s * dn[k]
            x[i, k] = x0[i, k] + keep * (x0[i, k] - xp0[i, k]) + r + a
    return x, xp


def test_vertex_triangles_lists_each_vertex_triangles_in_order():
    tris = np.array([[0, 1, 2], [2, 1, 3], [0, 2, 4], [4, 2, 3], [2, 5, 0]], np.int32)
    table = vertex_triangles(tris, 7)
    t = len(tris)
    assert table.dtype == np.int32 and table.shape == (7, 5)
    assert table[2].tolist() == [0, 1, 2, 3, 4]
    assert table[0].tolist() == [0, 2, 4, t, t]
    assert table[6].tolist() == [t] * 5                   # a vertex of no triangle: padding only
    assert vertex_triangles(np.zeros((0, 3), np.int32), 3).shape == (3, 1)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 100_000), n=st.integers(1, 23), t=st.integers(0, 40), use_aero=st.booleans(),
       all_free=st.booleans())
def test_integrate_is_the_reference_bit_for_bit(seed, n, t, use_aero, all_free):
    """all_free: every run of 4 particles takes the vector path (_verlet4); else a mix."""
    rng = np.random.default_rng(seed)
    x0 = rng.normal(0, 0.5, (n, 3))
    xp0 = x0 - rng.normal(0, 0.01, (n, 3))
    tris = rng.integers(0, n, (t, 3)).astype(np.int32)
    if t and n > 2:
        tris[: t // 2, 0] = 0                               # vertex 0: a high degree (table wider than 8)
    w = rng.uniform(0.5, 50.0, n) * (rng.random(n) < 0.8)   # some pinned
    aj = np.where(rng.random(n) < 0.15, rng.integers(0, 2, n), -1).astype(np.int32)
    if all_free:
        w = rng.uniform(0.5, 50.0, n)
        aj[:] = -1
    al = rng.normal(0, 0.2, (n, 3))
    fwd = np.tile(np.eye(4), (2, 1, 1))
    fwd[:, :3, :] += rng.normal(0, 0.1, (2, 3, 4))
    tf = rng.normal(0, 1e-3, (t, 3))
    rows = np.zeros((t + 1, 4))
    rows[:t, :3] = tf
    args = (w, aj, al, fwd, 1 / 90, np.array([0.0, -9.81, 0.0]), 0.02, rng.uniform(0, 1),
            rng.normal(0, 0.01, 3), rng.normal(0, 0.01, 3))
    ref = _reference(x0, xp0, *args, use_aero, tf, tris)
    table = vertex_triangles(tris, n)
    old = numba.get_num_threads()
    try:
        for threads in sorted({1, min(2, numba.config.NUMBA_NUM_THREADS)}):
            numba.set_num_threads(threads)
            x, xp = x0.copy(), xp0.copy()
            for_threads(integrate, threads)(x, xp, *args, use_aero, rows, table)   # 2: the parallel variant
            np.testing.assert_array_equal(x, ref[0])
            np.testing.assert_array_equal(xp, ref[1])
            # held forces (SimParams.aero_interval): the per-vertex sums gathered once, then read
            # through the identity table: the same step, bit for bit
            vf = np.full((n + 1, 4), np.nan)
            for_threads(gather_forces, threads)(rows, table, vf)
            assert np.isnan(vf[n]).all() and np.isnan(vf[:, 3]).all()      # row N and column 3 left alone
            vf[n] = 0.0
            x, xp = x0.copy(), xp0.copy()
            for_threads(integrate, threads)(x, xp, *args, use_aero, vf, identity_table(n))
            np.testing.assert_array_equal(x, ref[0])
            np.testing.assert_array_equal(xp, ref[1])
    finally:
        numba.set_num_threads(old)


def _limit_speed_reference(x, xp, inv_mass, vh, h):
    """Plain-Python limit_speed: (xp, limited, speed2)."""
    xp = xp.copy()
    limited = np.zeros(len(x), bool)
    speed2 = np.zeros(len(x))
    for i in range(len(x)):
        if inv_mass[i] == 0.0:
            continue
        v = x[i] - xp[i]
        if np.linalg.norm(v) > vh:
            xp[i] = x[i] - v * (vh / np.linalg.norm(v))
            limited[i] = True
        speed2[i] = np.sum((x[i] - xp[i]) ** 2) / h ** 2
    return xp, limited, speed2


def test_limit_speed_caps_free_particles_as_the_reference_does():
    from stages.sim.integrate import LIMITED, limit_speed
    rng = np.random.default_rng(3)
    n, h, vh = 200, 1.0 / 600.0, 0.01
    x = rng.normal(size=(n, 3))
    xp = x - rng.normal(scale=0.01, size=(n, 3))
    inv_mass = np.where(rng.random(n) < 0.2, 0.0, 1.0)
    want_xp, want_lim, want_s2 = _limit_speed_reference(x, xp, inv_mass, vh, h)
    corrected = np.zeros(n, np.int32)
    corrected[::3] = 1                       # a collider's mark is kept
    speed2 = np.full(n, -1.0)
    got = xp.copy()
    limit_speed(x, got, inv_mass, vh, speed2, h, corrected)
    np.testing.assert_allclose(got, want_xp, rtol=0, atol=1e-15)
    assert want_lim.any() and (~want_lim & (inv_mass > 0)).any()
    np.testing.assert_array_equal((corrected & LIMITED) != 0, want_lim)
    np.testing.assert_array_equal(corrected & 1, (np.arange(n) % 3 == 0).astype(np.int32))
    free = inv_mass > 0
    np.testing.assert_allclose(speed2[free], want_s2[free], rtol=1e-12)
    assert np.all(np.linalg.norm(x - got, axis=1)[free] <= vh * (1 + 1e-12))
    np.testing.assert_array_equal(got[~free], xp[~free])      # pinned particles untouched
