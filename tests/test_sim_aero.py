"""The aerodynamic force on 4 triangles at a time (stages.sim.forces.aero_forces) against a
plain-Python evaluation of its formula, per triangle, on random triangles of every kind: partial
last groups, degenerate triangles, still air, capped forces, massless (pinned) triangles."""
import numba
import numpy as np
from hypothesis import given, settings, strategies as st

from stages.fastmath import INV_SQRT_REL_ERROR
from stages.jit import parallel
from stages.sim.forces import aero_forces


def _reference(x, xp, tri_mass, tris, h, s, d_prev, wind, k_drag, k_lift, hold=1):
    out = np.zeros((tris.shape[0], 3))
    for t, (a, b, c) in enumerate(tris):
        v = ((x[a] - xp[a]) + (x[b] - xp[b]) + (x[c] - xp[c]) + 3 * s * d_prev) / (3 * h)
        w = wind - v
        n = np.cross(x[b] - x[a], x[c] - x[a])
        if n @ n <= 1e-40 or w @ w <= 1e-20:
            continue
        nw = n @ w
        f = 0.5 * k_drag * abs(nw) * w + 0.5 * k_lift * nw * np.linalg.norm(w) / np.linalg.norm(n) * (n - nw / (w @ w) * w)
        cap = tri_mass[t] * np.linalg.norm(w) / (hold * h)      # held over `hold` steps: their span
        if tri_mass[t] > 0 and np.linalg.norm(f) > cap:
            f *= cap / np.linalg.norm(f)
        out[t] = f
    return out


def _scene(seed, n, t):
    rng = np.random.default_rng(seed)
    x = rng.normal(0.0, 0.3, (n, 3))
    xp = x - rng.normal(0.0, 0.02, (n, 3)) * rng.integers(0, 2, (n, 1))     # some particles at rest
    tris = rng.integers(0, n, (t, 3)).astype(np.int32)
    repeat = rng.random(t) < 0.2
    tris[repeat, 1] = tris[repeat, 0]                                         # degenerate: a repeated vertex
    tri_mass = rng.uniform(0.0, 0.02, t) * 10.0 ** rng.uniform(-3, 0, t) * (rng.random(t) < 0.8)   # capped or not; massless
    wind = rng.normal(0.0, 3.0, 3) * rng.integers(0, 2)                      # still air or a wind
    return x, xp, tri_mass, tris, wind, rng


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 100_000), n=st.integers(3, 30), t=st.integers(1, 23), hold=st.sampled_from([1, 1, 4]))
def test_aero_forces_match_the_formula(seed, n, t, hold):
    x, xp, tri_mass, tris, wind, rng = _scene(seed, n, t)
    h, s, d_prev = 1 / 90, rng.uniform(0, 1), rng.normal(0, 0.01, 3)
    k_drag, k_lift = rng.uniform(0, 2), rng.uniform(0, 1)
    out = np.full((t, 4), np.nan)
    if hold == 1:
        aero_forces(x, xp, tri_mass, tris, h, s, d_prev, wind, k_drag, k_lift, out)
    else:
        aero_forces(x, xp, tri_mass, tris, h, s, d_prev, wind, k_drag, k_lift, out, hold)
    assert np.all(out[:, 3] == 0.0)
    ref = _reference(x, xp, tri_mass, tris, h, s, d_prev, wind, k_drag, k_lift, hold)
    err = np.linalg.norm(out[:, :3] - ref, axis=1)
    # one 1/sqrt estimate enters the lift term up to squared; the cap's sqrt is exact; a degenerate
    # triangle's fused cross product is a rounding error, not 0 (its force: < 1e-12 N)
    assert np.all(err <= (4 * INV_SQRT_REL_ERROR + 1e-12) * np.linalg.norm(ref, axis=1) + 1e-12)


def test_each_triangle_is_computed_alone():
    """A triangle's force does not depend on its group's other lanes, the array's length (partial
    last group) or the thread count: bit-identical."""
    x, xp, tri_mass, tris, _, rng = _scene(7, 40, 61)
    args = (1 / 90, 0.7, rng.normal(0, 0.01, 3), np.array([2.0, -1.0, 0.5]), 1.2, 0.4)
    full = np.zeros((61, 4))
    aero_forces(x, xp, tri_mass, tris, *args, full)
    assert np.any(full != 0)
    for t in range(61):
        one = np.zeros((1, 4))
        aero_forces(x, xp, tri_mass[t:t + 1], tris[t:t + 1], *args, one)
        assert np.array_equal(one[0], full[t])
    old = numba.get_num_threads()
    try:
        numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
        two = np.zeros((61, 4))
        parallel(aero_forces)(x, xp, tri_mass, tris, *args, two)   # the parallel variant on 2 threads
    finally:
        numba.set_num_threads(old)
    assert np.array_equal(two, full)
