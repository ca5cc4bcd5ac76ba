"""Dressed garments start apart: a two-legged garment's legs on their own sides of the plane between
the thighs (stages.garments.separation), a garment worn over another outside it. Checked with the
audit's brute-force crossing count (cloth edges through cloth triangles)."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from stages.garments.separation import LEG_GAP, LEG_SQUEEZE, leg_plane, separate_legs
from stages.sim.cloth_contact.ccd import count_edge_triangle_crossings
from tests.test_garments_pants import rest_scene  # noqa: F401  (module fixture)


def _edges(tri):
    e = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
    return np.unique(e, axis=0).astype(np.int64)


def _crossings(x, edges, tris, edge_mask, tri_mask) -> int:
    return int(count_edge_triangle_crossings(np.ascontiguousarray(x, np.float64), edges,
                                             np.ascontiguousarray(tris, np.int64), edge_mask, tri_mask))


def self_crossings(g) -> int:
    e = _edges(g.triangles)
    return _crossings(g.positions, e, g.triangles, np.ones(len(e), bool), np.ones(len(g.triangles), bool))


def crossings_between(a, b) -> int:
    """Edges of either garment through the other's triangles."""
    n = a.n_particles
    x = np.concatenate([a.positions, b.positions])
    tri = np.concatenate([a.triangles, b.triangles + n])
    e = _edges(tri)
    in_a = e[:, 0] < n
    t_a = np.arange(len(tri)) < len(a.triangles)
    return _crossings(x, e, tri, in_a, ~t_a) + _crossings(x, e, tri, ~in_a, t_a)


coord = st.floats(-0.2, 0.2, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(coord, coord, coord), min_size=2, max_size=30),
       st.floats(0.0, 2 * np.pi), st.integers(0, 2 ** 16))
def test_separate_legs_puts_each_leg_on_its_side_keeping_order(points, angle, seed):
    p = np.array(points)
    rng = np.random.default_rng(seed)
    side = rng.integers(0, 3, len(p))        # 0 left, 1 right, 2 both (a welded crotch seam)
    left = np.flatnonzero(side != 1)
    right = np.flatnonzero(side != 0)
    n = np.array([np.cos(angle), 0.0, np.sin(angle)])
    m = np.array([0.01, 0.9, -0.02])
    q = separate_legs(p, left, right, (m, n))
    d0 = (p - m) @ n
    d1 = (q - m) @ n
    both = side == 2
    # only along the normal; the welded seam and everything beyond the squeeze band untouched
    np.testing.assert_allclose(q - np.outer(d1, n), p - np.outer(d0, n), atol=1e-12)
    np.testing.assert_array_equal(q[both], p[both])
    for sel, s in ((side == 0, 1.0), (side == 1, -1.0)):
        assert np.all(s * d1[sel] >= LEG_GAP - 1e-12)
        far = sel & (s * d0 >= LEG_SQUEEZE)
        np.testing.assert_array_equal(q[far], p[far])
        # the order along the normal kept (no fold through itself)
        a, b = s * d0[sel], s * d1[sel]
        i, j = np.triu_indices(len(a), 1)
        assert np.all((a[i] - a[j]) * (b[i] - b[j]) >= -1e-15)


def test_separate_legs_without_a_plane_changes_nothing():
    p = np.random.default_rng(0).normal(size=(5, 3))
    np.testing.assert_array_equal(separate_legs(p, np.arange(3), np.arange(3, 5), None), p)


def test_leg_plane_lies_between_the_thighs(rest_scene):
    from stages.garments.placement import bind_geometry
    from stages.rig.humanoid import humanoid_joints
    c, m = rest_scene[:2]
    _, origins, _ = bind_geometry(c, m)
    point, normal = leg_plane(c, origins)
    hj = humanoid_joints(c)
    left, right = origins[hj.leg_l[0]], origins[hj.leg_r[0]]
    assert normal[1] == 0.0 and np.linalg.norm(normal) == pytest.approx(1.0)
    assert (left - point) @ normal > 0.03 and (right - point) @ normal < -0.03   # the wearer's left is +X
    assert (left - point) @ normal == pytest.approx(-((right - point) @ normal))


@pytest.fixture(scope="module")
def dressed(rest_scene):
    """Shorts on the built-in character's bind pose and a T-shirt dressed over them; then shorts
    without the legs' separation (monkeypatched out) and a T-shirt dressed independently; all without
    the untangling after sewing (stages.garments.untangle), which would hide what the separation does.
    Last: shorts without the separation but with the untangling."""
    import stages.garments.separation as sep
    import stages.garments.untangle as unt
    from stages.garments.library import library_pattern, make_garment
    from stages.garments.measurements import garment_measurements
    c, m, cols, maps, _ = rest_scene
    meas = garment_measurements(c, cols, m)
    mp = pytest.MonkeyPatch()
    mp.setattr(unt, "untangle", lambda pos, tri, **k: (pos, 0, 0))
    try:
        shorts, _, _ = make_garment(library_pattern("shorts", meas), c, m, cols, maps)
        shirt, _, _ = make_garment(library_pattern("tshirt", meas), c, m, cols, maps, under=[shorts], under_gap=0.007)
        mp.setattr(sep, "separate_legs", lambda pos, *a, **k: pos)
        plain_shorts, _, _ = make_garment(library_pattern("shorts", meas), c, m, cols, maps)
        mp.undo()
        mp.setattr(sep, "separate_legs", lambda pos, *a, **k: pos)
        untangled, log, _ = make_garment(library_pattern("shorts", meas), c, m, cols, maps)
    finally:
        mp.undo()
    plain_shirt, _, _ = make_garment(library_pattern("tshirt", meas), c, m, cols, maps)
    return (shorts, shirt), (plain_shorts, plain_shirt), (untangled, log)


def test_shorts_legs_start_apart(dressed):
    (shorts, _), (plain, _), _ = dressed
    assert self_crossings(plain) > 0        # the legs' inner sides through each other (main: 38)
    assert self_crossings(shorts) == 0


def test_legs_through_each_other_are_untangled_after_sewing(dressed):
    # without the separation, the untangling alone moves the 38 edges of the legs' inner sides back out
    _, (plain, _), (untangled, log) = dressed
    assert self_crossings(plain) > 0
    assert self_crossings(untangled) == 0
    assert any(n.startswith("untangled") for n in log.notes)


def test_tshirt_over_shorts_starts_outside_them(dressed):
    (shorts, shirt), (plain_shorts, plain_shirt), _ = dressed
    assert crossings_between(plain_shorts, plain_shirt) > 0
    assert crossings_between(shorts, shirt) == 0
