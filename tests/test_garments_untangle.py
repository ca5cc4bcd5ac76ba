"""Untangling sewn garments (stages.garments.untangle): edges through the garment's own triangles are
moved back out by intersection contour minimisation, against the exact crossing audit."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from stages.garments.untangle import contour_gradient, crossing_pairs, edge_faces, untangle
from stages.geometry.mesh import mesh_edges
from stages.sim.audit import crossing_flags


def grid(n: int, size: float, y: float, offset=(0.0, 0.0)):
    """An n x n vertex sheet in the plane y, (positions, triangles)."""
    u = np.linspace(-size / 2, size / 2, n)
    xx, zz = np.meshgrid(u + offset[0], u + offset[1], indexing="ij")
    pos = np.c_[xx.ravel(), np.full(n * n, y), zz.ravel()]
    tris = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1
            tris += [[a, b, c], [a, c, d]]
    return pos, np.array(tris, np.int32)


def two_sheets(depth: float, at=(0.0, 0.0), n: int = 7, gap: float = 0.02):
    """Two sheets `gap` apart, one vertex of the upper one pushed `depth` below the lower one; the
    upper sheet shifted by (0.013, 0.007) + `at` so that no edge meets an edge or vertex exactly."""
    lo, tl = grid(n, 0.3, 0.0)
    hi, th = grid(n, 0.3, gap, offset=(0.013 + at[0], 0.007 + at[1]))
    k = (n // 2) * n + n // 2
    hi[k, 1] = -depth
    return np.vstack([lo, hi]), np.vstack([tl, th + len(lo)])


def crossing_count(x, tris):
    edges = mesh_edges(tris)
    own, _, _ = crossing_flags(x, edges, np.zeros(len(edges), np.int32), tris, np.zeros(len(tris), np.int32))
    return int(own.sum())


def test_crossing_pairs_match_the_exact_audit():
    x, tris = two_sheets(0.01)
    edges = mesh_edges(tris)
    own, _, _ = crossing_flags(x, edges, np.zeros(len(edges), np.int32), tris, np.zeros(len(tris), np.int32))
    pairs = crossing_pairs(x, edges, tris, np.arange(len(edges)))
    assert own.sum() > 0
    assert sorted({e for e, _ in pairs}) == sorted(np.flatnonzero(own).tolist())


def test_edge_faces_lists_the_triangles_beside_each_edge():
    _, tris = grid(4, 1.0, 0.0)
    edges = mesh_edges(tris)
    beside = edge_faces(tris, edges)
    for e, (i, j) in enumerate(edges):
        want = sorted(t for t in range(len(tris)) if i in tris[t] and j in tris[t])
        assert sorted(t for t in beside[e] if t >= 0) == want


def test_the_contour_gradient_pulls_a_poked_vertex_back():
    # one vertex of the upper sheet poked through the lower one: the poked fan's edges through the
    # lower sheet get a G pointing up (out of it; the lower triangle moves down); a flat lower-sheet
    # edge through the fan gets none (its two triangles' terms cancel: moving a plane in itself does
    # not shorten the contour)
    x, tris = two_sheets(0.01)
    edges = mesh_edges(tris)
    beside = edge_faces(tris, edges)
    upper = len(x) // 2
    g = {(e, t): contour_gradient(x, tris, edges[e], beside[e], t)
         for e, t in crossing_pairs(x, edges, tris, np.arange(len(edges)))}
    poked = [v for (e, t), v in g.items() if edges[e][0] >= upper]
    flat = [v for (e, t), v in g.items() if edges[e][1] < upper]
    assert poked and flat
    assert all(v[1] > 0 for v in poked)
    assert all(np.allclose(v, 0.0) for v in flat)


def test_a_clean_mesh_is_returned_as_it_is():
    x, tris = grid(6, 0.3, 0.0)
    y, left, before = untangle(x, tris)
    assert before == 0 and left == 0 and np.array_equal(y, x)


@settings(max_examples=15, deadline=None)
@given(depth=st.floats(0.002, 0.03), ax=st.floats(-0.005, 0.005), az=st.floats(-0.005, 0.005))
def test_a_vertex_poked_through_a_sheet_is_moved_back_out(depth, ax, az):
    x, tris = two_sheets(depth, at=(ax, az))
    before = crossing_count(x, tris)
    y, left, counted = untangle(x, tris)
    assert counted == before > 0
    assert left == crossing_count(y, tris) == 0
    edge = np.median(np.linalg.norm(x[mesh_edges(tris)[:, 1]] - x[mesh_edges(tris)[:, 0]], axis=1))
    assert np.linalg.norm(y - x, axis=1).max() <= edge + 1e-12      # a local repair, never a tear
