"""Trouser legs kept apart once sewn (stages.garments.garmentcode_legs): two tubes wider than the space
between their axes overlap in the middle; kept to their sides of the plane between the legs, no edge of
one passes through a triangle of the other (counted by the cloth audit's exact crossing test)."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from types import SimpleNamespace

from stages.garments.garmentcode_legs import LEG_GAP, below_sides, crotch_height, keep_side, legs_apart, vertex_sides
from stages.geometry.mesh import mesh_edges
from stages.sim.audit import crossing_flags


def tube(center_x: float, radius: float, rings: int = 12, around: int = 16, top: float = 0.8):
    """(N, 3) points, (T, 3) triangles of an open vertical tube round x = center_x, y 0..top."""
    a = np.linspace(0.0, 2 * np.pi, around, endpoint=False)
    y = np.linspace(0.0, top, rings)
    pts = np.array([[center_x + radius * np.cos(t), h, radius * np.sin(t)] for h in y for t in a])
    tris = []
    for r in range(rings - 1):
        for k in range(around):
            i, j = r * around + k, r * around + (k + 1) % around
            tris += [[i, j, j + around], [i, j + around, i + around]]
    return pts, np.array(tris, np.int32)


def between_tubes(x, tris, n_first):
    """Edges of one tube through a triangle of the other."""
    edges = mesh_edges(tris)
    group = (np.arange(len(x)) >= n_first).astype(np.int32)
    _, other, _ = crossing_flags(x, edges, group[edges[:, 0]], tris, group[tris[:, 0]])
    return int(other.sum())


AXES = {1.0: np.array([[0.09, 0.9, 0.0], [0.1, 0.05, 0.0]]), -1.0: np.array([[-0.09, 0.9, 0.0], [-0.1, 0.05, 0.0]])}


def two_legs(radius):
    a, ta = tube(0.095, radius)
    b, tb = tube(-0.095, radius)
    x = np.concatenate([a, b])
    tris = np.concatenate([ta, tb + len(a)])
    side = np.r_[np.ones(len(a)), -np.ones(len(b))]
    return x, tris, side, len(a)


def test_wide_legs_overlapping_in_the_middle_part():
    x, tris, side, n = two_legs(0.14)      # 14 cm round 9.5 cm from the middle: they overlap
    assert between_tubes(x, tris, n) > 0
    out = legs_apart(x, np.arange(len(x)), side, AXES, crotch=1.0)
    assert between_tubes(out, tris, n) == 0
    # only the inner sides move, horizontally, and by no more than they overlapped
    moved = np.linalg.norm(out - x, axis=1) > 0
    assert np.all(side[moved] * x[moved, 0] < LEG_GAP + 1e-9)
    assert np.allclose(out[:, 1], x[:, 1])
    assert np.all(side * out[:, 0] >= LEG_GAP - 1e-9)


def test_narrow_legs_and_cloth_above_the_crotch_are_left_as_they_are():
    x, tris, side, n = two_legs(0.06)
    assert np.array_equal(legs_apart(x, np.arange(len(x)), side, AXES, crotch=1.0), x)
    x, tris, side, n = two_legs(0.14)
    out = legs_apart(x, np.arange(len(x)), side, AXES, crotch=0.3)
    assert np.array_equal(out[x[:, 1] >= 0.3], x[x[:, 1] >= 0.3])


def test_a_merged_vertex_of_both_legs_stays_and_no_legs_no_change():
    x = np.array([[0.0, 0.5, 0.0], [-0.01, 0.5, 0.0]])
    remap = np.array([0, 0, 1])      # unsewn 0 (left) and 1 (right) merged into 0 (the crotch seam)
    side = np.array([1.0, -1.0, 1.0])
    out = legs_apart(x, remap, side, AXES, crotch=1.0)
    assert np.array_equal(out[0], x[0]) and out[1, 0] == pytest.approx(LEG_GAP)
    assert np.array_equal(legs_apart(x, remap, side, {}, crotch=1.0), x)


def test_crotch_is_the_lowest_seam_joining_the_two_legs():
    placed = np.array([[0.05, 0.8, 0.1], [-0.05, 0.8, 0.1], [0.05, 0.7, 0.1], [-0.05, 0.72, 0.1], [0.1, 0.1, 0.0]])
    side = np.array([1.0, -1.0, 1.0, -1.0, 1.0])
    assert crotch_height(placed, np.array([[0, 1], [2, 3], [4, 2]]), side) == pytest.approx(0.7)
    assert crotch_height(placed, np.array([[4, 2]]), side) is None


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(-0.3, 0.3), st.floats(0.0, 1.0), st.floats(-0.3, 0.3)), min_size=1, max_size=30),
       st.floats(0.02, 0.2), st.floats(-0.1, 0.1))
def test_keep_side_puts_every_point_on_its_side_and_moves_only_those_that_were_not(points, half, slant):
    x = np.array(points)
    own = np.c_[np.full(len(x), half), x[:, 1], np.full(len(x), slant)]
    other = np.c_[np.full(len(x), -half), x[:, 1], np.full(len(x), -slant)]
    out = keep_side(x, own, other)
    n = own - other
    n[:, 1] = 0.0
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    d0 = np.einsum("ij,ij->i", x - 0.5 * (own + other), n)
    d1 = np.einsum("ij,ij->i", out - 0.5 * (own + other), n)
    assert np.all(d1 >= LEG_GAP - 1e-9)
    assert np.array_equal(out[d0 >= LEG_GAP], x[d0 >= LEG_GAP])
    assert np.allclose(out[:, 1], x[:, 1])


def test_a_cuff_sewn_under_a_leg_takes_its_side_and_a_panel_sewn_to_both_legs_none():
    # panels (one vertex each is enough): 0 left leg, 1 right leg, 2 a ruffle under the left cuff 3,
    # 4 a skirt front sewn to both legs, 5 a panel above the crotch sewn to the left leg
    pv = np.array([0, 1, 2, 3, 4, 5])
    placed = np.array([[0.1, 0.5, 0], [-0.1, 0.5, 0], [0.0, 0.05, 0], [0.05, 0.1, 0], [0.0, 0.3, 0], [0.0, 0.9, 0]])
    side = np.array([1.0, -1.0, 0.0, 0.0, 0.0, 0.0])
    pairs = np.array([[2, 3], [3, 0], [4, 0], [4, 1], [5, 0]])
    out = below_sides(side, placed, pv, pairs, crotch=0.7)
    assert out.tolist() == [1.0, -1.0, 1.0, 1.0, 0.0, 0.0]


def test_a_leg_panel_over_the_middle_keeps_its_side_and_a_centred_panel_has_none():
    # a wide trouser leg placed 3 cm over the middle (a sampled pair of pants), a cuff on one side, a
    # waistband round the middle and a sleeve
    # waistband round the middle, a sleeve, and a skirt's front (GarmentCode labels it `leg` too)
    panels = [SimpleNamespace(name="pant_f_l", label="leg"), SimpleNamespace(name="cuff_l", label="body"),
              SimpleNamespace(name="wb_front", label="body"), SimpleNamespace(name="sleeve", label="arm"),
              SimpleNamespace(name="skirt_front", label="leg")]
    leg = np.c_[np.linspace(-0.03, 0.2, 10), np.full(10, 0.5), np.zeros(10)]
    skirt = np.c_[np.linspace(-0.2, 0.21, 10), np.full(10, 0.5), np.zeros(10)]
    placed = np.concatenate([leg, [[0.05, 0.1, 0], [0.1, 0.1, 0], [-0.15, 1.0, 0], [0.15, 1.0, 0],
                                   [0.3, 1.3, 0], [0.4, 1.2, 0]], skirt])
    pv = np.repeat([0, 1, 2, 3, 4], [10, 2, 2, 2, 10])
    sides = vertex_sides(SimpleNamespace(panels=panels), placed, pv, 0.0)
    assert sides.tolist() == [1] * 12 + [0] * 14
