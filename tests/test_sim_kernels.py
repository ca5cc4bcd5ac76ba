"""Simulation kernels against plain-Python references on small meshes."""
import math

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings, strategies as st
from numba import njit

from stages.garments.simple import rectangle_cloth
from stages.garments.types import build_garment
from stages.sim.body_collide import _cached_face, collide, TOUCH_EPS
from stages.sim.collider_grid import build_grid, collider_frames
from stages.sim.forces import aero_forces, vertex_triangles
from stages.sim.integrate import integrate
from stages.sim.simd import padded_rows
from stages.jit import for_threads
from stages.sim.springs import PIPELINE, correct_springs, pack_springs, partition_springs, spring_colours
from stages.geometry.winding import winding_number
from scipy.spatial.transform import Rotation

from stages.hulls.types import ColliderSet, SphereCollider
from stages.maps.build import build_maps
from stages.maps.kernels import (METHOD_BRUTE, METHOD_NEAREST_PLANE, METHOD_PAPER, collide_points, hull_query,
                                query_arrays)
from stages.sim.scenes import convex_mesh, fibonacci_points, hull_set, sphere_set
from stages.sim.simulate import _Colliders
from stages.fastmath import INV_SQRT_REL_ERROR


def _small_cloth(seed=0):
    x, tri = rectangle_cloth(0.5, 0.4, 6, 5)
    g = build_garment("c", x, tri)
    rng = np.random.default_rng(seed)
    return g, g.positions + rng.normal(0, 0.01, g.positions.shape)


def test_springs_match_python_gauss_seidel():
    g, x0 = _small_cloth()
    order, part = partition_springs(x0, g.springs, n_parts=1)
    s = g.springs[order]
    rest = g.rest_lengths[order]
    w = g.inverse_mass
    k = np.where(g.kinds[order] == 1, 0.7, 1.0)
    wi = k * w[s[:, 0]] / (w[s[:, 0]] + w[s[:, 1]])
    wj = k * w[s[:, 1]] / (w[s[:, 0]] + w[s[:, 1]])
    x = x0.copy()
    # tethers: particle 7 may be at most 0.05 from particle 0, particle 9 at most 1.0 from 3
    ti, ta, tl = np.array([7, 9], np.int32), np.array([0, 3], np.int32), np.array([0.05, 1.0])
    correct_springs(x, padded_rows(len(x)), *pack_springs(s[:, 0], s[:, 1], rest, wi, wj, part, len(x)),
                      ti, ta, tl, 3)
    ref = x0.copy()
    for _ in range(3):
        for q in range(len(s)):
            i, j = s[q]
            d = ref[j] - ref[i]
            c = 1 - rest[q] / np.linalg.norm(d)
            ref[i] += wi[q] * c * d
            ref[j] -= wj[q] * c * d
        for i, a, length in zip(ti, ta, tl):
            d = ref[i] - ref[a]
            if np.linalg.norm(d) > length:
                ref[i] = ref[a] + d * length / np.linalg.norm(d)
    # the kernel's 1/|d| is the CPU estimate refined once (stages.fastmath): a few of its relative
    # errors times the cloth's size (0.5 m)
    np.testing.assert_allclose(x, ref, atol=1e-13 + 3 * INV_SQRT_REL_ERROR * 0.5)
    assert np.linalg.norm(x[7] - x[0]) <= 0.05 + 1e-12


def test_partition_blocks_touch_disjoint_particles():
    x, tri = rectangle_cloth(1, 1, 20, 20)
    g = build_garment("c", x, tri)
    order, part = partition_springs(g.positions, g.springs, n_parts=2)
    assert np.array_equal(np.sort(order), np.arange(len(g.springs)))
    s = g.springs[order]
    a = set(s[part[0]:part[1]].ravel())
    b = set(s[part[1]:part[2]].ravel())
    assert not (a & b) and part[-1] == len(s) and part[2] - part[0] > 0.8 * len(s)
    colours = spring_colours(g.springs.astype(np.int64), g.n_particles)[order]
    for k in range(3):
        assert np.all(np.diff(colours[part[k]:part[k + 1]]) >= 0)  # ordered by colour inside a block
    for c in np.unique(colours):  # a colour never holds two springs on one particle
        ends = g.springs[order][colours == c].ravel()
        assert np.unique(ends).size == ends.size


def test_parallel_springs_match_sequential_block_order():
    """The blocks run in parallel; as they touch disjoint particles the result equals running them
    one after the other, whatever the thread count."""
    import numba
    x, tri = rectangle_cloth(1, 1, 24, 24)
    g = build_garment("c", x, tri)
    x0 = g.positions + np.random.default_rng(8).normal(0, 0.01, g.positions.shape)
    order, part = partition_springs(x0, g.springs, n_parts=2)
    s = g.springs[order].astype(np.int32)
    w = g.inverse_mass
    wi = w[s[:, 0]] / (w[s[:, 0]] + w[s[:, 1]])
    wj = 1 - wi
    rest = g.rest_lengths[order]
    no = np.zeros(0, np.int32)
    seq = x0.copy()
    one = np.array([0, len(s), len(s)], np.int64)  # everything as one sequential block
    scratch = padded_rows(len(x0))
    correct_springs(seq, scratch, *pack_springs(s[:, 0], s[:, 1], rest, wi, wj, one, len(x0)), no, no,
                      np.zeros(0), 3)
    packed = pack_springs(s[:, 0], s[:, 1], rest, wi, wj, part, len(x0))
    out = []
    for t in sorted({1, min(2, numba.config.NUMBA_NUM_THREADS)}):
        old = numba.get_num_threads()
        numba.set_num_threads(t)
        try:
            y = x0.copy()
            for_threads(correct_springs, t)(y, scratch, *packed, no, no, np.zeros(0), 3)   # 2: the parallel variant
        finally:
            numba.set_num_threads(old)
        out.append(y)
    np.testing.assert_array_equal(out[0], out[-1])
    np.testing.assert_array_equal(out[0], seq)


@pytest.mark.parametrize("use_aero", [False, True])
def test_integrate_matches_reference(use_aero):
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
    tri = g.triangles
    tf = np.random.default_rng(5).normal(0, 1e-3, (tri.shape[0], 3))
    rows = np.zeros((tri.shape[0] + 1, 4))
    rows[:-1, :3] = tf
    x, xp = x0.copy(), xp0.copy()
    integrate(x, xp, w, aj, al, fwd, h, gvec, damp, s, dp, dn, use_aero, rows, vertex_triangles(tri, n))
    force = np.zeros((n, 3))
    for q in range(3):
        np.add.at(force, tri[:, q], tf / 3)
    acc = gvec + (w[:, None] * force if use_aero else 0.0)
    ref = x0 + (1 - damp) * (x0 - xp0 + s * dp) - s * dn + acc * h * h
    ref[0] = al[0] + [0.5, 0, 0]
    ref[1] = x0[1]
    np.testing.assert_allclose(x, ref, atol=1e-14)
    np.testing.assert_array_equal(xp, x0)


def test_aero_matches_reference():
    g, x0 = _small_cloth(2)
    xp = x0 - np.array([0.0, -0.02, 0.01])
    wind = np.array([1.0, 0.5, -2.0])
    tri = g.triangles
    out = np.zeros((tri.shape[0], 4))
    h, kd, kl, s, dprev = 1 / 30, 0.3, 0.06, 0.5, np.array([0.01, 0.0, -0.02])
    tri_mass = (1 / (3 * g.inverse_mass))[tri].sum(axis=1)
    aero_forces(x0, xp, tri_mass, tri, h, s, dprev, wind, kd, kl, out)
    for t, (a, b, c) in enumerate(tri):
        v = ((x0[a] - xp[a]) + (x0[b] - xp[b]) + (x0[c] - xp[c])) / (3 * h) + s * dprev / h
        w = wind - v
        n = np.cross(x0[b] - x0[a], x0[c] - x0[a])
        area = np.linalg.norm(n) / 2
        n /= np.linalg.norm(n)
        u = w / np.linalg.norm(w)
        if n @ u < 0:
            n = -n
        cs = n @ u
        f = kd * area * cs * (w @ w) * u + kl * area * cs * (w @ w) * (n - cs * u)
        cap = tri_mass[t] * np.linalg.norm(w) / h
        if np.linalg.norm(f) > cap:
            f *= cap / np.linalg.norm(f)
        # one 1/sqrt estimate (stages.fastmath) enters the lift term up to squared
        assert np.linalg.norm(out[t, :3] - f) <= (4 * INV_SQRT_REL_ERROR + 1e-12) * np.linalg.norm(f) + 1e-15


def _collider_arrays(cs, maps, fwd, inv0=None):
    """Flat collider arrays as simulate builds them, posed by fwd (J, 4, 4) at the end of a step."""
    col = _Colliders(cs, maps)
    inv = np.linalg.inv(fwd)
    collider_frames(fwd, inv, inv if inv0 is None else inv0, col.m, col.joint, col.kind, col.index, col.bcenter,
                      col.bradius, col.sph_center, col.tq, col.tq0, col.fq, col.cw)
    return col


def _collide(col, x, xp, friction=0.0, method=0, passes=4, contact=None, pinch=False, entry=False, family=None):
    """collide on the points; pinch: a body_collide.PINCH_* code (False: escape, True: midpoint)."""
    n = x.shape[0]
    out, xp = x.copy(), xp.copy()
    corr, ins, sp = np.zeros(n, np.uint8), np.zeros(n, np.uint8), np.zeros(n)
    contact = np.full((n, col.joint.size), -1, np.int32) if contact is None else contact
    build_grid(col.m, method, col.kind, col.index, col.sph_radius, col.tq, col.fq, col.cw, col.grid_start,
                 col.grid_items, col.grid_runs, col.grid_box, col.grid_dims)
    collide(out, xp, np.ones(n), col.m, method, col.kind, col.index, col.sph_radius, col.tq, col.tq0, col.fq,
              col.cw, col.grid_start, col.grid_items, col.grid_box, col.grid_dims, col.face_edges, col.src_range,
              friction, passes, corr, ins, sp, contact, 1 / 30, col.joint, int(pinch), entry,
              col.family if family is None else family)
    return out, xp, corr, ins


def test_sphere_collision_matches_paper_equations():
    rng = np.random.default_rng(3)
    x = rng.uniform(-0.6, 0.6, (400, 3))
    cs = sphere_set(center=(0.1, 0.0, -0.05), radius=0.4)
    c = cs.spheres[0].center
    # the bone is moved: the test happens in its local frame
    fwd = np.eye(4)[None].copy()
    fwd[0, :3, :3] = Rotation.from_euler("xyz", [0.3, -0.5, 1.1]).as_matrix()
    fwd[0, :3, 3] = [0.2, -0.1, 0.3]
    col = _collider_arrays(cs, None, fwd)
    xw = x @ fwd[0, :3, :3].T + fwd[0, :3, 3]
    out, _, corr, ins = _collide(col, xw, xw)
    out = (out - fwd[0, :3, 3]) @ fwd[0, :3, :3]
    d = np.linalg.norm(x - c, axis=1)
    inside = d < 0.4
    ref = np.where(inside[:, None], c + 0.4 * (x - c) / d[:, None], x)
    np.testing.assert_allclose(out, ref, atol=2e-7)
    assert (corr == inside).all() and not ins.any()
    assert (np.linalg.norm(out - c, axis=1) >= 0.4).all()


def _one_hull_maps(seed=0):
    rng = np.random.default_rng(seed)
    mesh = convex_mesh(fibonacci_points(30, rng.uniform(0.15, 0.4, 3)) + rng.normal(0, 0.01, (30, 3)))
    cs = hull_set(mesh)
    return cs, build_maps(cs)


@pytest.mark.parametrize("method", [METHOD_PAPER, METHOD_BRUTE, METHOD_NEAREST_PLANE])
def test_hull_response_matches_maps_kernel_and_reports_the_contact_face(method):
    cs, maps = _one_hull_maps(1)
    rng = np.random.default_rng(7)
    pts = rng.uniform(-0.45, 0.45, (600, 3))
    hit_ref, resp_ref = collide_points(maps, pts, 0, method)
    col = _collider_arrays(cs, maps, np.eye(4)[None].copy())
    out, _, corr, ins = _collide(col, pts, pts, method=method)
    moved = np.linalg.norm(resp_ref - pts, axis=1) >= TOUCH_EPS
    assert np.array_equal(corr.astype(bool), hit_ref & moved)
    np.testing.assert_allclose(out, np.where((hit_ref & moved)[:, None], resp_ref, pts), atol=2e-7)
    # the reported face: the response point lies on its plane (plane of the exit / pushed face)
    m = maps.arrays
    for p in pts[hit_ref & moved][:100]:
        q = m.axes[0] @ (p - m.center[0])
        hit, r0, r1, r2, face = hull_query(*query_arrays(m), 0, method, *q)
        pl = m.planes[face]
        assert hit and abs(pl[:3] @ [r0, r1, r2] - pl[3]) < 1e-9
        assert (m.planes[:, :3] @ [r0, r1, r2] - m.planes[:, 3]).max() < 1e-9     # on the hull surface


@njit   # not cached: it inlines the kernel under test
def _cached_face_many(m, face_edges, src_range, pts, face, out):
    for i in range(pts.shape[0]):
        known, hit, r0, r1, r2 = _cached_face(m.kind, m.half, m.planes, face_edges, src_range, 0, face[i],
                                                pts[i, 0], pts[i, 1], pts[i, 2])
        out[i, 0] = known
        out[i, 1] = hit
        out[i, 2] = r0
        out[i, 3] = r1
        out[i, 4] = r2


@pytest.mark.parametrize("kind", ["sphere", "cylinder"])
def test_exit_face_cache_gives_the_paper_answer(kind):
    """The collision kernel's remembered-face shortcut: whenever it answers, it answers as the paper's
    query (inside test and response); with the true exit face it always answers for inside points,
    and with the separating face the paper's query reports it always answers for outside points."""
    rng = np.random.default_rng(11)
    mesh = convex_mesh(fibonacci_points(40, (0.12, 0.35, 0.15)) + rng.normal(0, 0.005, (40, 3)))
    cs = hull_set(mesh)
    maps = build_maps(cs, kind=kind)
    col = _collider_arrays(cs, maps, np.eye(4)[None].copy())
    m = maps.arrays
    assert (m.kind[0] == 1) == (kind == "cylinder")
    q = rng.uniform(-1.2, 1.2, (3000, 3)) * m.half[0]                    # OBB-local, in and around
    ref = np.array([hull_query(*query_arrays(m), 0, METHOD_PAPER, *p) for p in q], dtype=object)
    hit_ref = ref[:, 0].astype(bool)
    resp_ref = np.array([r[1:4] for r in ref], float)
    exit_face = np.array([r[4] for r in ref], np.int32)
    # any face: answers only when right
    out = np.zeros((q.shape[0], 5))
    _cached_face_many(m, col.face_edges, col.src_range, q, rng.integers(0, m.planes.shape[0], q.shape[0]).astype(np.int32), out)
    known = out[:, 0].astype(bool)
    assert known.any()
    assert np.array_equal(out[known, 1].astype(bool), hit_ref[known])
    both = known & hit_ref
    np.testing.assert_allclose(out[both, 2:], resp_ref[both], atol=1e-12)
    # the true exit face: always answers for inside points whose ray source is inside the hull
    _cached_face_many(m, col.face_edges, col.src_range, q[hit_ref], exit_face[hit_ref], out[:hit_ref.sum()])
    src = q[hit_ref, 0] if kind == "cylinder" else np.zeros(hit_ref.sum())
    ok = (col.src_range[0, 0] < src) & (src < col.src_range[0, 1])
    assert ok.mean() > 0.9 and out[:hit_ref.sum()][ok, 0].all() and out[:hit_ref.sum()][ok, 1].all()
    np.testing.assert_allclose(out[:hit_ref.sum()][ok, 2:], resp_ref[hit_ref][ok], atol=1e-12)
    # inside the collision kernel: a remembered contact changes nothing but the speed
    pts = q @ m.axes[0] + m.center[0]                                      # bone = world here
    sep = ~hit_ref & (exit_face >= 0)
    assert sep.sum() > 100
    _cached_face_many(m, col.face_edges, col.src_range, q[sep], exit_face[sep], out[:sep.sum()])
    assert out[:sep.sum(), 0].all() and not out[:sep.sum(), 1].any()
    contact = np.full((q.shape[0], 1), -1, np.int32)
    a = _collide(col, pts, pts, contact=contact)
    assert (contact[a[2].astype(bool), 0] >= 0).all()
    b = _collide(col, pts, pts, contact=contact)
    np.testing.assert_allclose(b[0], a[0], atol=1e-12)
    assert np.array_equal(a[2], b[2]) and np.array_equal(a[3], b[3])


def test_overlapping_colliders_leave_no_particle_inside():
    """Two overlapping spheres and a hull through them: every particle ends outside all three."""
    cs_h, maps = _one_hull_maps(2)
    s1 = SphereCollider(0, "a", np.array([0.1, 0.0, 0.0]), 0.25, np.zeros((0, 3)))
    s2 = SphereCollider(1, "b", np.array([-0.1, 0.05, 0.0]), 0.22, np.zeros((0, 3)))
    cs = ColliderSet(hulls=cs_h.hulls, spheres=(s1, s2), delta=0.0, min_triangles=4)
    col = _collider_arrays(cs, maps, np.tile(np.eye(4), (2, 1, 1)))
    rng = np.random.default_rng(11)
    pts = rng.uniform(-0.45, 0.45, (2000, 3))
    out, _, corr, ins = _collide(col, pts, pts, passes=8)
    in_s = [np.linalg.norm(out - s.center, axis=1) < s.radius for s in (s1, s2)]
    in_h, _ = collide_points(maps, out, 0, METHOD_BRUTE)
    still = in_s[0] | in_s[1] | in_h
    assert corr.sum() > 200
    assert np.array_equal(still, ins.astype(bool))
    assert still.sum() == 0


@pytest.mark.parametrize("mu", [0.0, 0.3, 1.0])
def test_coulomb_friction_on_a_sphere_top(mu):
    """A particle that was on top of a sphere moves sideways by t and down by d: it is pushed back to
    the surface and its tangential travel loses min(t, mu d)."""
    cs = sphere_set(radius=0.3)
    col = _collider_arrays(cs, None, np.eye(4)[None].copy())
    t, d = 0.004, 0.005
    xp = np.array([[0.0, 0.3 + 1e-7, 0.0]])
    x = np.array([[t, 0.3 - d, 0.0]])
    out, xp_new, corr, ins = _collide(col, x, xp, friction=mu)
    assert corr[0] == 1 and not ins[0]
    r = np.linalg.norm(out[0])
    assert r >= 0.3          # outside (sliding back along the tangent plane lifts it slightly)
    # tangential (here ~ x) travel: the radial push moves x slightly; compare against the reference
    q = 0.3 * x[0] / np.linalg.norm(x[0])
    n = q / 0.3
    depth = (q - x[0]) @ n
    v = q - xp[0]
    tang = v - (v @ n) * n
    keep = 1 - min(1.0, mu * depth / np.linalg.norm(tang))
    ref = q - (1 - keep) * tang
    np.testing.assert_allclose(out[0], ref, atol=2e-7)
    assert (out[0] - xp_new[0]) @ n <= 1e-12        # no outward velocity (inelastic)


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


def test_springs_skip_coincident_ends_and_leave_pinned_particles():
    """A spring with (near) coincident ends has no direction: nothing moves. With w_i = 0 (pinned
    i) a stiffness-1 spring puts j exactly at rest length from i, along the spring."""
    x = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.3, 0.4, 0.0]])
    si, sj = np.array([0, 1]), np.array([1, 2])
    rest, wi, wj = np.array([0.1, 0.25]), np.array([0.5, 0.0]), np.array([0.5, 1.0])
    ij, sp, group_start = pack_springs(si, sj, rest, wi, wj, np.array([0, 2, 2], np.int64), 3)
    # spring 1 shares particle 1 with spring 0: two groups, each padded with dummies on row 3, with
    # PIPELINE - 1 groups of dummies between (a group is read that far ahead of the stores before it)
    gap = PIPELINE - 1
    assert ij.dtype == np.uint32 and list(group_start) == [0, 2 + gap, 2 + gap]
    assert list(ij) == [0, 12, 12, 12, 4, 12, 12, 12] + [12] * 8 * gap + [4, 12, 12, 12, 8, 12, 12, 12]
    assert list(sp[:12]) == [0.1, 0, 0, 0, 0.5, 0, 0, 0, 0.5, 0, 0, 0]
    assert not sp[12:12 * (1 + gap)].any()
    assert list(sp[12 * (1 + gap):]) == [0.25, 0, 0, 0, 0.0, 0, 0, 0, 1.0, 0, 0, 0]
    no = np.zeros(0, np.int32)
    correct_springs(x, padded_rows(3), ij, sp, group_start, no, no, np.zeros(0), 1)
    np.testing.assert_array_equal(x[:2], 0.0)
    np.testing.assert_allclose(x[2], [0.15, 0.2, 0.0], atol=1e-15)
