"""Constrained hull simplification (stages/hulls/simplify.py, kernels.py): convexity, containment,
face counts, the LP against scipy's HiGHS, the exact Hausdorff kernel against brute force."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.optimize import linprog
from scipy.spatial import ConvexHull

from stages.hulls import kernels, lp
from stages.hulls.fit import distance_to_hull, hausdorff_to_hull
from stages.hulls.hull import convex_hull, inflate_hull, mesh_volume
from stages.hulls.simplify import simplify_hull
from stages.hulls.types import ConvexMesh
from tests.test_hulls_hull import cloud


def assert_convex(mesh: ConvexMesh, tol: float):
    """Every vertex behind every face plane; Qhull of the vertices finds the same hull."""
    pl = mesh.planes
    assert (mesh.vertices @ pl[:, :3].T - pl[:, 3]).max() <= tol
    assert mesh_volume(mesh) > 0
    h = ConvexHull(mesh.vertices)
    assert len(h.vertices) == mesh.vertices.shape[0]          # every vertex is extreme
    assert len(h.simplices) == mesh.faces.shape[0]
    # every face plane is a Qhull facet plane and vice versa
    q = h.equations  # outward n, offset: n.x + off <= 0
    dn = np.abs(pl[:, None, :3] - q[None, :, :3]).max(axis=2)
    do = np.abs(pl[:, None, 3] + q[None, :, 3])
    match = (dn < 1e-6) & (do < 1e-6 * max(1.0, np.abs(pl[:, 3]).max()))
    assert match.any(axis=1).all() and match.any(axis=0).all()


def assert_contains(mesh: ConvexMesh, points: np.ndarray, tol: float):
    pl = mesh.planes
    assert (points @ pl[:, :3].T - pl[:, 3]).max() <= tol


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.integers(8, 300), st.sampled_from(["gauss", "sphere", "uniform", "grid"]),
       st.sampled_from([0.0, 0.002, 0.01]), st.sampled_from([4, 20, 60]), st.sampled_from(["qem", "volume"]))
def test_simplified_hull_is_convex_contains_and_respects_counts(seed, n, kind, delta, min_tri, priority):
    pts = cloud(seed, n, kind)
    raw = convex_hull(pts)
    inflated = inflate_hull(raw, delta)
    out = simplify_hull(inflated, min_tri, priority=priority)
    diag = np.linalg.norm(np.ptp(inflated.vertices, axis=0))
    tol = 1e-9 * diag
    assert_convex(out, tol)
    assert_contains(out, pts, tol)
    assert_contains(out, inflated.vertices, tol)
    assert out.faces.shape[0] <= inflated.faces.shape[0]
    if inflated.faces.shape[0] >= min_tri:
        assert out.faces.shape[0] >= max(min_tri, 4)
    if out.faces.shape[0] - 4 >= min_tri:
        # it stopped early: then no legal collapse is left (a stricter re-run finds none either)
        assert simplify_hull(out, min_tri, priority=priority).faces.shape[0] == out.faces.shape[0]
    assert mesh_volume(out) >= mesh_volume(inflated) * (1 - 1e-12)
    # deterministic
    again = simplify_hull(inflated, min_tri, priority=priority)
    assert np.array_equal(again.vertices, out.vertices) and np.array_equal(again.faces, out.faces)


def test_euler_step_and_floor():
    mesh = inflate_hull(convex_hull(cloud(3, 400, "sphere")), 0.005)
    for m in (mesh.faces.shape[0] - 4, 100, 37):
        out = simplify_hull(mesh, m)
        assert (mesh.faces.shape[0] - out.faces.shape[0]) % 4 == 0   # one collapse = -4 faces
        assert out.faces.shape[0] >= m
        assert out.vertices.shape[0] == out.faces.shape[0] // 2 + 2  # closed genus-0
    assert simplify_hull(mesh, 10_000) is mesh


def test_keep_points_stay_inside():
    pts = cloud(5, 200, "gauss")
    raw = convex_hull(pts)
    out = simplify_hull(raw, 20, keep=pts)
    assert_contains(out, pts, 1e-9 * np.linalg.norm(np.ptp(pts, axis=0)))


# --- the LP kernel against scipy's HiGHS -------------------------------------------------------

def highs(a, b, c, box):
    return linprog(c, A_ub=a, b_ub=b, bounds=[(-box, box)] * 3, method="highs")


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 10_000), st.integers(1, 80))
def test_seidel_lp_matches_highs_on_random_lps(seed, m):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(m, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = rng.uniform(-0.5, 1.0, size=m)
    c = rng.normal(size=3)
    ok, x = lp.seidel_lp3(a, b, c, 8.0, rng.permutation(m))
    ref = highs(a, b, c, 8.0)
    assert ok == (ref.status == 0)
    if ok:
        assert (a @ x - b).max() <= 1e-8 and np.abs(x).max() <= 8.0 + 1e-9
        assert c @ x == pytest.approx(ref.fun, abs=1e-7 * (1 + abs(ref.fun)))


def test_collapse_lps_match_highs():
    """The LPs of real collapses (every triangle of an inflated hull) solve like HiGHS."""
    mesh = inflate_hull(convex_hull(cloud(7, 150, "gauss")), 0.005)
    v, f = mesh.vertices, mesh.faces.astype(np.int64)
    nf = f.shape[0]
    falive, valive = np.ones(nf, bool), np.ones(len(v), bool)
    planes = np.ascontiguousarray(mesh.planes)
    buf = [np.empty(nf, np.int64) for _ in range(4)]
    vmark = np.zeros(len(v), np.int64)
    d = np.linalg.norm(np.ptp(v, axis=0))
    solved = 0
    for t in range(nf):
        nr, k = kernels._region(t, f, falive, *buf)
        if nr < 0:
            continue
        vmark[buf[1][:k]] = t + 1
        a, b, c, origin, scale, _ = kernels.collapse_rows(t, v, valive, f, falive, planes, v, np.arange(len(v)), nr, k,
                                                          buf[0], buf[1], vmark, t + 1, 1e-7 * d, 1e-4 * d,
                                                          np.zeros((0, 4)))
        ok, x = lp.seidel_lp3(a, b, c, kernels.BOX, np.random.default_rng(t).permutation(len(b)))
        ref = highs(a, b, c, kernels.BOX)
        assert ok == (ref.status == 0), t
        if ok:
            solved += 1
            assert c @ x == pytest.approx(ref.fun, abs=1e-7 * (1 + abs(ref.fun)))
    assert solved > nf // 4


# --- exact Hausdorff distance ------------------------------------------------------------------

def brute_point_triangle(p, a, b, c, n_sub=60):
    """Reference: distance to a dense barycentric sampling of each triangle (upper bound, fine)."""
    u, w = np.meshgrid(np.linspace(0, 1, n_sub + 1), np.linspace(0, 1, n_sub + 1))
    keep = u + w <= 1
    u, w = u[keep], w[keep]
    s = a[:, None] + u[None, :, None] * (b - a)[:, None] + w[None, :, None] * (c - a)[:, None]  # (T, S, 3)
    s = s.reshape(-1, 3)
    return np.linalg.norm(p[:, None] - s[None], axis=2).min(axis=1)


def test_distance_kernel_matches_sampling():
    hull = convex_hull(cloud(11, 40, "gauss"))
    rng = np.random.default_rng(0)
    p = rng.normal(size=(30, 3)) * 0.3
    got = distance_to_hull(p, hull)
    a, b, c = (hull.vertices[hull.faces[:, i]] for i in range(3))
    ref = brute_point_triangle(p, a, b, c)
    inside = (p @ hull.planes[:, :3].T - hull.planes[:, 3]).max(axis=1) <= 0
    assert np.all(got[inside] == 0)
    step = np.linalg.norm(np.ptp(hull.vertices, axis=0)) / 60
    assert np.all(got[~inside] <= ref[~inside] + 1e-12)
    assert np.all(ref[~inside] - got[~inside] <= step)


def test_hausdorff_is_the_max_over_a_dense_surface_sampling():
    raw = convex_hull(cloud(12, 80, "gauss"))
    out = simplify_hull(inflate_hull(raw, 0.01), 12)
    h = hausdorff_to_hull(out, raw)
    rng = np.random.default_rng(1)
    a, b, c = (out.vertices[out.faces[:, i]] for i in range(3))
    r1, r2 = rng.uniform(size=(2, 4000, 1))
    s = np.sqrt(r1)
    t = rng.integers(0, out.faces.shape[0], 4000)
    samples = (1 - s) * a[t] + s * (1 - r2) * b[t] + s * r2 * c[t]
    sampled = distance_to_hull(np.concatenate([samples, out.vertices]), raw).max()
    assert sampled == pytest.approx(h, rel=1e-12)
    assert h >= 0.01 * (1 - 1e-9)  # at least the inflation


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000), st.sampled_from(["gauss", "sphere"]), st.sampled_from([0.001, 0.01]))
def test_max_offset_bounds_the_growth(seed, kind, bound):
    inflated = inflate_hull(convex_hull(cloud(seed, 200, kind)), 0.003)
    out = simplify_hull(inflated, 4, max_offset=bound)
    pl = inflated.planes
    assert (out.vertices @ pl[:, :3].T - pl[:, 3]).max() <= bound + 1e-9
    assert_convex(out, 1e-9)
    assert_contains(out, inflated.vertices, 1e-9)
    free = simplify_hull(inflated, 4)
    assert out.faces.shape[0] >= free.faces.shape[0] or mesh_volume(out) <= mesh_volume(free)
