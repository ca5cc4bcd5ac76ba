"""Gathered edges' rest lengths (stages.garments.gather): each triangle near a gathered edge is
compressed along it, never stretched; two gathered edges in line are one gather, not two."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from stages.garments.gather import gathered_lengths, gathered_rest
from stages.garments.patterns import Edge, Panel, Pattern, Placement, Seam, SeamSide
from stages.garments.triangulate import triangulate_pattern
from tests.test_gathered_seam import rect


def _cut(uv, tri):
    return np.linalg.norm(uv[tri[:, [1, 2, 0]]] - uv[tri], axis=2)


def split_top(name, w, h):
    """A w x h rectangle whose top edge is cut in two halves (a waistband's front: two stitches)."""
    return Panel(name, (Edge("bottom", "line", ((w, 0.0),)), Edge("right", "line", ((w, h),)),
                        Edge("top_r", "line", ((w / 2, h),)), Edge("top_l", "line", ((0.0, h),)),
                        Edge("left", "line", ((0.0, 0.0),))), Placement("plane"))


@settings(max_examples=25, deadline=None)
@given(w=st.floats(0.2, 0.6), h=st.floats(0.06, 0.3), ratio=st.floats(1.02, 2.0))
def test_gathering_compresses_and_never_stretches_and_each_triangle_stays_a_triangle(w, h, ratio):
    short = w / ratio
    pat = Pattern("g", (rect("long", w, h), rect("short", short, 0.1)),
                  (Seam(SeamSide("long", "top"), SeamSide("short", "bottom"), reverse=True),), 0.025)
    flat = triangulate_pattern(pat)
    uv, tri = flat.uv, flat.triangles
    rest, ratios = gathered_rest(tri, uv, flat.seam_pairs, flat.seam_index, flat.panel_of_vertex)
    cut = _cut(uv, tri)
    assert np.all(rest <= cut * (1 + 1e-9))
    l0, l1, l2 = rest.T
    assert np.all(l0 + l1 > l2) and np.all(l1 + l2 > l0) and np.all(l2 + l0 > l1)
    # the gathered edge is as long as the other side; the short panel is as cut
    p = flat.seam_pairs
    e = {tuple(sorted(k)): r for t, rr in zip(tri, rest) for k, r in zip(((t[0], t[1]), (t[1], t[2]), (t[2], t[0])), rr)}
    gathered = sum(e[tuple(sorted((int(a), int(b))))] for a, b in zip(p[:-1, 0], p[1:, 0]))
    assert gathered == pytest.approx(np.linalg.norm(np.diff(uv[p[:, 1]], axis=0), axis=1).sum(), rel=0.01)
    assert np.allclose(rest[flat.panel_of_triangle == 1], cut[flat.panel_of_triangle == 1])
    # across the gathered edge (the panel's sides) the cloth keeps its cut length
    side = np.isclose(uv[tri][:, :, 0], 0.0).sum(axis=1) == 2
    for t, r, c in zip(tri[side], rest[side], cut[side]):
        k = [i for i in range(3) if np.isclose(uv[t[i], 0], 0.0) and np.isclose(uv[t[(i + 1) % 3], 0], 0.0)][0]
        assert r[k] == pytest.approx(c[k], rel=1e-9)


def test_two_gathered_halves_in_line_are_compressed_once_at_their_shared_corner():
    # the sampled jumpsuit's waistband front: its lower edge is two stitches (1.45x each) to the two
    # pant fronts. Its shared corner was pulled towards each half's middle, and the front centre
    # stayed 13 mm open on the CMU walk
    pat = Pattern("g", (split_top("band", 0.60, 0.20), rect("a", 0.20, 0.1), rect("b", 0.20, 0.1)),
                  (Seam(SeamSide("band", "top_r"), SeamSide("a", "bottom"), reverse=True),
                   Seam(SeamSide("band", "top_l"), SeamSide("b", "bottom"), reverse=True)), 0.025)
    flat = triangulate_pattern(pat)
    uv, tri = flat.uv, flat.triangles
    rest, ratios = gathered_rest(tri, uv, flat.seam_pairs, flat.seam_index, flat.panel_of_vertex)
    assert sorted(ratios.values()) == pytest.approx([1.5, 1.5])
    corner = np.flatnonzero(np.isclose(uv[:, 0], 0.30) & np.isclose(uv[:, 1], 0.20) & (flat.panel_of_vertex == 0))
    assert corner.size == 1
    at = (tri == corner[0]).any(axis=1)
    cut = _cut(uv, tri)
    top = np.isclose(uv[tri][:, :, 1], 0.20)
    along = top & np.roll(top, -1, axis=1)                    # edge k on the top line
    assert np.allclose(rest[at & along.any(axis=1)][along[at & along.any(axis=1)]] / cut[at & along.any(axis=1)][along[at & along.any(axis=1)]], 1 / 1.5)


def test_runs_reach_only_their_own_panel_and_scale_one_changes_nothing():
    pat = Pattern("g", (rect("a", 0.3, 0.2), rect("b", 0.3, 0.2)),
                  (Seam(SeamSide("a", "top"), SeamSide("b", "bottom"), reverse=True),), 0.025)
    flat = triangulate_pattern(pat)
    uv, tri = flat.uv, flat.triangles
    run = flat.seam_pairs[:, 0]
    cut = _cut(uv, tri)
    assert np.allclose(gathered_lengths(tri, uv, flat.panel_of_vertex, [(run, 1.0)]), cut)
    r = gathered_lengths(tri, uv, flat.panel_of_vertex, [(run, 0.5)])
    other = flat.panel_of_triangle != flat.panel_of_vertex[run[0]]
    assert np.allclose(r[other], cut[other]) and np.any(r[~other] < cut[~other] - 1e-6)
