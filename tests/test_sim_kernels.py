"""Simulation kernels against plain-Python references on small meshes."""
import math

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings, strategies as st

from stages.garments.simple import rectangle_cloth
from stages.garments.types import build_garment
from stages.sim import kernels as K
from stages.sim import winding_number
from stages.sim.scenes import sphere_set
from stages.sim.simulate import empty_map_arrays


def _small_cloth(seed=0):
    x, tri = rectangle_cloth(0.5, 0.4, 6, 5)
    g = build_garment("c", x, tri)
    rng = np.random.default_rng(seed)
    return g, g.positions + rng.normal(0, 0.01, g.positions.shape)


def test_springs_match_python_gauss_seidel():
    g, x0 = _small_cloth()
    order, part = K.partition_springs(x0, g.springs, n_parts=1)
    s = g.springs[order]
    rest = g.rest_lengths[order]
    w = g.inverse_mass
    k = np.where(g.kinds[order] == 1, 0.7, 1.0)
    wi = k * w[s[:, 0]] / (w[s[:, 0]] + w[s[:, 1]])
    wj = k * w[s[:, 1]] / (w[s[:, 0]] + w[s[:, 1]])
    x = x0.copy()
    K.correct_springs(x, s[:, 0].copy(), s[:, 1].copy(), rest, wi, wj, part, 3)
    ref = x0.copy()
    for _ in range(3):
        for q in range(len(s)):
            i, j = s[q]
            d = ref[j] - ref[i]
            c = 1 - rest[q] / np.linalg.norm(d)
            ref[i] += wi[q] * c * d
            ref[j] -= wj[q] * c * d
    np.testing.assert_allclose(x, ref, atol=1e-13)


def test_partition_blocks_touch_disjoint_particles():
    x, tri = rectangle_cloth(1, 1, 20, 20)
    g = build_garment("c", x, tri)
    order, part = K.partition_springs(g.positions, g.springs, n_parts=2)
    s = g.springs[order]
    a = set(s[part[0]:part[1]].ravel())
    b = set(s[part[1]:part[2]].ravel())
    assert not (a & b) and part[-1] == len(s) and part[2] - part[0] > 0.8 * len(s)
    colours = K.spring_colours(g.springs.astype(np.int64), g.n_particles)[order]
    assert np.all(np.diff(colours[part[0]:part[1]]) >= 0)  # ordered by colour inside a block
    for c in np.unique(colours):  # a colour never holds two springs on one particle
        ends = g.springs[order][colours == c].ravel()
        assert np.unique(ends).size == ends.size


def test_integrate_matches_reference():
    g, x0 = _small_cloth(1)
    xp0 = x0 - 0.01
    n = x0.shape[0]
    aj = np.full(n, -1, np.int32)
    aj[0] = 0
    w = g.inverse_mass.copy()
    w[0] = 0.0
    w[1] = 0.0
    al = np.zeros((n, 3))
    al[0] = [1.0, 2.0, 3.0]
    fwd = np.eye(4)[None].copy()
    fwd[0, :3, 3] = [0.5, 0, 0]
    h, damp, s = 1 / 30, 0.02, 0.6
    dp, dn = np.array([0.01, 0, 0.002]), np.array([0.02, 0.001, 0])
    gvec = np.array([0, -9.81, 0.0])
    x, xp = x0.copy(), xp0.copy()
    tf = np.zeros((g.triangles.shape[0], 3))
    K.integrate(x, xp, w, aj, al, fwd, h, gvec, damp, s, dp, dn, False, tf, np.zeros(n + 1, np.int64),
                np.zeros(0, np.int32))
    ref = x0 + (1 - damp) * (x0 - xp0 + s * dp) - s * dn + gvec * h * h
    ref[0] = al[0] + [0.5, 0, 0]
    ref[1] = x0[1]
    np.testing.assert_allclose(x, ref, atol=1e-14)
    np.testing.assert_array_equal(xp, x0)


def test_aero_matches_reference():
    g, x0 = _small_cloth(2)
    xp = x0 - np.array([0.0, -0.02, 0.01])
    wind = np.array([1.0, 0.5, -2.0])
    out = np.zeros((g.triangles.shape[0], 3))
    h, kd, kl = 1 / 30, 0.3, 0.06
    K.aero_forces(x0, xp, g.inverse_mass, g.triangles, h, 0.0, np.zeros(3), wind, kd, kl, out)
    for t, (a, b, c) in enumerate(g.triangles):
        v = ((x0[a] - xp[a]) + (x0[b] - xp[b]) + (x0[c] - xp[c])) / (3 * h)
        w = wind - v
        n = np.cross(x0[b] - x0[a], x0[c] - x0[a])
        area = np.linalg.norm(n) / 2
        n /= np.linalg.norm(n)
        u = w / np.linalg.norm(w)
        if n @ u < 0:
            n = -n
        cs = n @ u
        f = kd * area * cs * (w @ w) * u + kl * area * cs * (w @ w) * (n - cs * u)
        m = sum(1 / (3 * g.inverse_mass[v]) for v in (a, b, c))
        cap = m * np.linalg.norm(w) / h
        if np.linalg.norm(f) > cap:
            f *= cap / np.linalg.norm(f)
        np.testing.assert_allclose(out[t], f, rtol=1e-10, atol=1e-15)


def test_sphere_collision_matches_paper_equations():
    rng = np.random.default_rng(3)
    x = rng.uniform(-0.6, 0.6, (400, 3))
    xp = x.copy()
    cs = sphere_set(center=(0.1, 0.0, -0.05), radius=0.4)
    c = cs.spheres[0].center
    fwd = np.eye(4)[None].copy()
    cw = np.zeros((1, 4))
    bs, bi, br = np.zeros(K.N_BINS + 1, np.int64), np.zeros(K.N_BINS, np.int32), np.zeros(2)
    one = lambda a: np.array(a, np.int32)
    K.build_bins(fwd, one([0]), c[None], np.array([0.4 * (1 + 1e-9)]), cw, bs, bi, br)
    out = x.copy()
    corr, ins, sp = np.zeros(400, np.uint8), np.zeros(400, np.uint8), np.zeros(400)
    K.collide(out, xp, np.ones(400), fwd, fwd, fwd, empty_map_arrays(), 0, one([0]), one([K.KIND_SPHERE]), one([0]),
              c[None], np.array([0.4]), cw, bs, bi, br, 0.0, 4, corr, ins, sp, 1 / 30)
    d = np.linalg.norm(x - c, axis=1)
    inside = d < 0.4
    ref = np.where(inside[:, None], c + 0.4 * (x - c) / d[:, None], x)
    np.testing.assert_allclose(out, ref, atol=2e-7)
    assert (corr == inside).all() and not ins.any()
    assert (np.linalg.norm(out - c, axis=1) >= 0.4).all()


def _solid_angle_ref(a, b, c):
    la, lb, lc = np.linalg.norm(a), np.linalg.norm(b), np.linalg.norm(c)
    det = np.dot(a, np.cross(b, c))
    den = la * lb * lc + a @ b * lc + b @ c * la + c @ a * lb
    return 2 * math.atan2(det, den)


def test_winding_number_brute_matches_python_and_trimesh():
    mesh = trimesh.creation.torus(major_radius=0.5, minor_radius=0.2, major_sections=24, minor_sections=12)
    rng = np.random.default_rng(4)
    pts = rng.uniform(-0.8, 0.8, (300, 3))
    exact = winding_number(mesh.vertices, mesh.faces, pts, exact=True)
    ref = np.array([sum(_solid_angle_ref(*(mesh.vertices[f] - p)) for f in mesh.faces) / (4 * math.pi)
                    for p in pts[:20]])
    np.testing.assert_allclose(exact[:20], ref, atol=1e-10)
    np.testing.assert_array_equal(exact >= 0.5, _ray_parity_inside(mesh.vertices, mesh.faces, pts))


def _ray_parity_inside(v, f, pts):
    """Brute force: odd number of crossings of a ray in a generic direction (Moller-Trumbore)."""
    d = np.array([0.5773, 0.5774, 0.5775])
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    e1, e2 = b - a, c - a
    pv = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, pv)
    out = []
    for p in pts:
        tv = p - a
        u = np.einsum("ij,ij->i", tv, pv) / det
        qv = np.cross(tv, e1)
        w = (qv @ d) / det
        t = np.einsum("ij,ij->i", e2, qv) / det
        out.append(int(((u >= 0) & (w >= 0) & (u + w <= 1) & (t > 0)).sum()) % 2 == 1)
    return np.array(out)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_fast_winding_number_agrees_with_exact(seed):
    rng = np.random.default_rng(seed)
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    mesh.vertices *= rng.uniform(0.5, 1.5, 3)
    pts = rng.uniform(-0.6, 0.6, (200, 3))
    fast = winding_number(mesh.vertices, mesh.faces, pts)
    exact = winding_number(mesh.vertices, mesh.faces, pts, exact=True)
    assert np.abs(fast - exact).max() < 0.05
    far = np.abs(exact - 0.5) > 0.1
    np.testing.assert_array_equal((fast >= 0.5)[far], (exact >= 0.5)[far])
