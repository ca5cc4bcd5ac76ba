"""The cloth audit (stages.sim.audit): edge crossings against an O(E T) brute force in exact
arithmetic, on random and degenerate configurations; strain figures against a direct computation."""
from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from stages.garments.simple import rectangle_cloth
from stages.garments.types import build_garment
from stages.geometry.mesh import mesh_edges
from stages.sim.audit import audit_cloth, crossing_flags, crosses_exact
from stages.sim.types import SimParams


def _orient(a, b, c, d):
    m = [[Fraction(float(a[k])) - Fraction(float(d[k])) for k in range(3)],
         [Fraction(float(b[k])) - Fraction(float(d[k])) for k in range(3)],
         [Fraction(float(c[k])) - Fraction(float(d[k])) for k in range(3)]]
    det = (m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
           + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]))
    return (det > 0) - (det < 0)


def _brute(x, edges, edge_group, tris, tri_group):
    """Every edge against every triangle; a crossing: endpoints strictly on both sides of the plane and
    the three edge-line orientations strictly of one sign (cofactor determinants, exact)."""
    own = np.zeros(len(edges), bool)
    other = np.zeros(len(edges), bool)
    for e, (p, q) in enumerate(edges):
        for t, (a, b, c) in enumerate(tris):
            if len({p, q} & {a, b, c}):
                continue
            sp, sq = _orient(x[a], x[b], x[c], x[p]), _orient(x[a], x[b], x[c], x[q])
            if sp * sq >= 0:
                continue
            s = {_orient(x[p], x[q], x[a], x[b]), _orient(x[p], x[q], x[b], x[c]), _orient(x[p], x[q], x[c], x[a])}
            if len(s) == 1 and 0 not in s:
                (own if tri_group[t] == edge_group[e] else other)[e] = True
    return own, other


def _random_meshes(draw_ints, n_points, n_tris, grid):
    """Triangles over n_points random points; grid: coordinates on a small integer lattice (many
    coplanar / collinear / touching cases) instead of floats."""
    rng = np.random.default_rng(draw_ints)
    if grid:
        x = rng.integers(-2, 3, size=(n_points, 3)).astype(np.float64)
    else:
        x = rng.normal(size=(n_points, 3)).astype(np.float32).astype(np.float64)
    tris = np.array([rng.choice(n_points, 3, replace=False) for _ in range(n_tris)], np.int32)
    tri_group = rng.integers(0, 2, size=n_tris).astype(np.int32)
    edges = mesh_edges(tris)
    # an edge's group: that of the first triangle holding it
    first = {}
    for t, tri in enumerate(tris):
        for k in range(3):
            first.setdefault(tuple(sorted((tri[k], tri[(k + 1) % 3]))), tri_group[t])
    edge_group = np.array([first[tuple(e)] for e in edges], np.int32)
    return x, edges, edge_group, tris, tri_group


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), n_points=st.integers(4, 14), n_tris=st.integers(1, 12), grid=st.booleans())
def test_crossings_equal_brute_force(seed, n_points, n_tris, grid):
    x, edges, eg, tris, tg = _random_meshes(seed, n_points, n_tris, grid)
    own, other, _ = crossing_flags(x, edges, eg, tris, tg)
    bown, bother = _brute(x, edges, eg, tris, tg)
    np.testing.assert_array_equal(own, bown)
    np.testing.assert_array_equal(other, bother)


def test_crossing_cases():
    a, b, c = np.array([0.0, 0, 0]), np.array([1.0, 0, 0]), np.array([0.0, 1, 0])
    through = (np.array([0.2, 0.2, -1]), np.array([0.2, 0.2, 1]))
    assert crosses_exact(*through, a, b, c)
    assert not crosses_exact(np.array([0.2, 0.2, 0.0]), np.array([0.2, 0.2, 1]), a, b, c)    # endpoint on it
    assert not crosses_exact(np.array([0.5, 0.5, -1]), np.array([0.5, 0.5, 1]), a, b, c)     # through its edge
    assert not crosses_exact(np.array([-0.5, 0.2, 0]), np.array([1.0, 0.2, 0]), a, b, c)     # coplanar
    assert not crosses_exact(np.array([0.8, 0.8, -1]), np.array([0.8, 0.8, 1]), a, b, c)     # misses
    # the kernel agrees, and a near-degenerate pair (1e-30 off the edge) is decided exactly
    x = np.array([a, b, c, through[0], through[1], [0.5, 0.5 + 1e-30, -1], [0.5, 0.5 + 1e-30, 1]])
    own, _, _ = crossing_flags(x, np.array([[3, 4], [5, 6]]), np.zeros(2), np.array([[0, 1, 2]]), np.zeros(1))
    assert own.tolist() == [True, False]


def test_two_sheets_one_through_the_other_and_strain():
    """A vertical sheet through a horizontal one: the between count is exactly the vertical sheet's
    edges that pierce the horizontal sheet; no self-crossings; strain 0 at rest, then measured."""
    xa, ta = rectangle_cloth(1.0, 1.0, 11, 11, center=(0.0, 0.5, 0.0))
    # vertical sheet in the plane x = 0.013 (not through vertices), spanning y in [0.3, 0.7]
    xb, tb = rectangle_cloth(0.4, 0.5, 5, 6, center=(0.013, 0.5, 0.02),
                             rotation=np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]))
    ga, gb = build_garment("a", xa, ta), build_garment("b", xb, tb)
    from stages.sim.types import GarmentTrack, SimResult
    pa = np.stack([xa, xa * [1.0, 1.0, 1.05]]).astype(np.float32)     # frame 1: a stretched by 5 % along z
    pb = np.stack([xb, xb]).astype(np.float32)
    tracks = tuple(GarmentTrack(g.name, g.triangles, p, np.zeros(2, np.int32), np.zeros(2, np.int32))
                   for g, p in ((ga, pa), (gb, pb)))
    z = np.zeros(2, np.int32)
    res = SimResult(tracks, np.array([0.0, 1 / 30]), z, z, z, np.zeros(2), np.zeros(2), {}, 0, SimParams())
    audit = audit_cloth(res, [ga, gb], vertex_strain=True)
    # edges of b crossing the plane y = 0.5 (all inside sheet a)
    e = mesh_edges(gb.triangles)
    y = xb[e][:, :, 1]
    b_through_a = int(np.sum((np.minimum(y[:, 0], y[:, 1]) < 0.5) & (np.maximum(y[:, 0], y[:, 1]) > 0.5)))
    # edges of a crossing the plane x = 0.013 inside sheet b (z strictly within its span)
    ea = mesh_edges(ga.triangles)
    a_through_b = []
    for f in range(2):
        p, q = pa[f][ea[:, 0]].astype(np.float64), pa[f][ea[:, 1]].astype(np.float64)
        cut = (np.minimum(p[:, 0], q[:, 0]) < 0.013) & (np.maximum(p[:, 0], q[:, 0]) > 0.013)
        z = p[:, 2] + (0.013 - p[:, 0]) / np.where(cut, q[:, 0] - p[:, 0], 1.0) * (q[:, 2] - p[:, 2])
        a_through_b.append(int(np.sum(cut & (z > -0.18) & (z < 0.22))))
    assert b_through_a > 0 and min(a_through_b) > 0
    assert audit.garment("b").crossings_other.tolist() == [b_through_a] * 2
    assert audit.garment("a").crossings_other.tolist() == a_through_b
    assert audit.crossings_between.tolist() == [b_through_a + n for n in a_through_b]
    assert audit.garment("a").crossings_self.tolist() == [0, 0]
    assert audit.garment("b").crossings_self.tolist() == [0, 0]
    sa = audit.garment("a")
    assert sa.strain_max[0] < 1e-6
    # z edges stretch by 5 %, x edges not, diagonals in between
    assert sa.strain_max[1] == pytest.approx(0.05, rel=1e-4)
    assert 0.02 < sa.strain_mean[1] < 0.05
    assert sa.vertex_strain.shape == (2, ga.n_particles)
    assert sa.vertex_strain[1].max() == pytest.approx(0.05, rel=1e-4)
    assert any("strain" in w for w in audit.warnings) and any("cross another" in w for w in audit.warnings)
    assert audit.exact_pairs == 0       # the flat sheets' coplanar pairs are decided in float64 expansions


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), scale=st.sampled_from([1e-3, 1.0, 30.0]))
def test_orient3d_sign_is_exact_near_coplanar(seed, scale):
    """Points rounded to float32 off the plane of abc by at most an ulp: the float64 filter cannot
    decide them, the expansion must give the exact (rational) sign."""
    from stages.sim.audit_kernels import orient3d_sign
    rng = np.random.default_rng(seed)
    a, b, c = (rng.normal(size=(3, 3)) * scale).astype(np.float32).astype(np.float64)
    s, t = rng.random(2)
    d = (a + s * (b - a) + t * (c - a)).astype(np.float32).astype(np.float64)
    assert orient3d_sign(*a, *b, *c, *d) == _orient(a, b, c, d)
    assert orient3d_sign(*a, *b, *c, *a) == 0
