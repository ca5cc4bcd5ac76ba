"""k-DOP trees and traversal against brute force (paper B §2-3)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from stages.checks import ContractError
from stages.geometry.kdop import (build_particle_tree, build_triangle_tree, kdop_directions, kdop_nodes_at_depth,
                                  kdop_wireframe, refit_particle_tree, segment_bounds, triangle_bounds)
from stages.obstacles import ObstacleCollider, build_obstacle_set, make_obstacle
from stages.obstacles.kernels import candidate_pairs, motion_axis_order


@pytest.mark.parametrize("k", [6, 14, 18, 26])
def test_directions_are_standard_sets(k):
    d = kdop_directions(k)
    assert d.shape == (k // 2, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
    # no two directions parallel
    g = np.abs(d @ d.T) - np.eye(k // 2)
    assert g.max() < 0.99
    np.testing.assert_array_equal(d[:3], np.eye(3))


def test_directions_reject_unknown_k():
    with pytest.raises(ContractError):
        kdop_directions(10)


def random_soup(rng, n_tris, spread=1.0):
    centres = rng.uniform(-spread, spread, (n_tris, 3))
    v = (centres[:, None, :] + rng.normal(0, 0.15, (n_tris, 3, 3))).reshape(-1, 3)
    f = np.arange(3 * n_tris, dtype=np.int32).reshape(-1, 3)
    return v, f


def leaf_bounds_reference(directions, points):
    """k-DOP of a point set, plain numpy."""
    proj = points @ directions.T
    return proj.min(axis=0), proj.max(axis=0)


@pytest.mark.parametrize("k", [6, 18])
def test_tree_nodes_bound_their_primitives_and_split_at_median(k):
    rng = np.random.default_rng(1)
    v, f = random_soup(rng, 57)
    tree = build_triangle_tree(v, f, k=k, margin=0.01)
    d = tree.directions
    n = tree.node_min.shape[0]
    assert n == 2 * f.shape[0] - 1
    leaves = tree.leaf_prim[tree.leaf_prim >= 0]
    assert sorted(leaves.tolist()) == list(range(f.shape[0]))

    def prims(node):
        if tree.leaf_prim[node] >= 0:
            return [int(tree.leaf_prim[node])]
        a, b = tree.children[node]
        return prims(a) + prims(b)

    for node in range(n):
        ps = prims(node)
        lo, hi = leaf_bounds_reference(d, v[f[ps]].reshape(-1, 3))
        np.testing.assert_allclose(tree.node_min[node], lo - 0.01, atol=1e-12)
        np.testing.assert_allclose(tree.node_max[node], hi + 0.01, atol=1e-12)
        if tree.leaf_prim[node] < 0:
            a, b = tree.children[node]
            na, nb = len(prims(a)), len(prims(b))
            assert abs(na - nb) <= 1 and na + nb == len(ps)
            # split along the longest direction, at the median of the centre projections
            axis = int(np.argmax(tree.node_max[node] - tree.node_min[node]))
            ca = v[f[prims(a)]].mean(axis=1) @ d[axis]
            cb = v[f[prims(b)]].mean(axis=1) @ d[axis]
            assert ca.max() <= cb.min() + 1e-12


def brute_force_pairs(directions, x0, x1, v, f, margin):
    pmin = np.minimum(x0 @ directions.T, x1 @ directions.T)
    pmax = np.maximum(x0 @ directions.T, x1 @ directions.T)
    proj = v[f] @ directions.T  # (T, 3, h)
    tmin = proj.min(axis=1) - margin
    tmax = proj.max(axis=1) + margin
    ok = (pmax[:, None, :] >= tmin[None, :, :]) & (tmax[None, :, :] >= pmin[:, None, :])
    return {(int(i), int(j)) for i, j in zip(*np.nonzero(ok.all(axis=2)))}


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), k=st.sampled_from([6, 14, 18, 26]),
       n_part=st.integers(1, 80), n_tri=st.integers(1, 40))
def test_traversal_finds_exactly_the_brute_force_candidates(seed, k, n_part, n_tri):
    rng = np.random.default_rng(seed)
    v, f = random_soup(rng, n_tri)
    margin = 0.02
    x0 = rng.uniform(-1.2, 1.2, (n_part, 3))
    x1 = x0 + rng.normal(0, 0.2, (n_part, 3))
    otree = build_triangle_tree(v, f, k=k, margin=margin)
    # cloth tree topology from other positions, then refit: the refit must keep it exact
    ctree = build_particle_tree(x0 + rng.normal(0, 0.5, x0.shape), k=k)
    cmin, cmax = ctree.node_min.copy(), ctree.node_max.copy()
    refit_particle_tree(cmin, cmax, ctree.children, ctree.leaf_prim, ctree.directions, x0, x1)
    stats = np.zeros(4, np.int64)
    order = motion_axis_order(ctree.directions, x0, x1)
    pairs, m = candidate_pairs(cmin, cmax, ctree.children, ctree.leaf_prim, otree.node_min, otree.node_max,
                               otree.children, otree.leaf_prim, otree.tree_offsets, order, stats)
    got = [tuple(map(int, p)) for p in pairs[:m]]
    assert len(got) == len(set(got)), "a pair was reported twice"
    assert set(got) == brute_force_pairs(otree.directions, x0, x1, v, f, margin)


def test_forest_leaves_hold_global_triangle_ids():
    rng = np.random.default_rng(3)
    obs = [make_obstacle(f"soup{i}", random_soup(rng, 5 + i)) for i in range(3)]
    oset = build_obstacle_set(obs, k=14)
    t = oset.tree
    assert t.n_trees == 3
    for i in range(3):
        sl = slice(t.tree_offsets[i], t.tree_offsets[i + 1])
        leaves = np.sort(t.leaf_prim[sl][t.leaf_prim[sl] >= 0])
        np.testing.assert_array_equal(leaves, np.arange(oset.triangle_offsets[i], oset.triangle_offsets[i + 1]))
        assert np.all(oset.tri_obstacle[leaves] == i)


def test_nodes_at_depth_cover_every_primitive():
    rng = np.random.default_rng(4)
    v, f = random_soup(rng, 37)
    tree = build_triangle_tree(v, f, k=18)
    for depth in range(tree.max_depth + 1):
        mins, maxs = kdop_nodes_at_depth(tree, depth)
        centres = v[f].mean(axis=1) @ tree.directions.T
        inside = np.all((centres[:, None, :] >= mins[None] - 1e-12) & (centres[:, None, :] <= maxs[None] + 1e-12), axis=2)
        assert inside.any(axis=1).all()
    mins, maxs = kdop_nodes_at_depth(tree, 0)
    assert mins.shape == (1, 9)


def test_wireframe_of_an_aabb_is_its_12_edges():
    d = kdop_directions(6)
    segs = kdop_wireframe(np.array([0.0, 0.0, 0.0]), np.array([1.0, 2.0, 3.0]), d)
    assert segs.shape == (12, 2, 3)
    lengths = np.sort(np.linalg.norm(segs[:, 1] - segs[:, 0], axis=1))
    np.testing.assert_allclose(lengths, [1] * 4 + [2] * 4 + [3] * 4, atol=1e-5)


def test_wireframe_of_an_18dop_lies_on_its_boundary():
    rng = np.random.default_rng(5)
    pts = rng.normal(size=(30, 3))
    d = kdop_directions(18)
    lo, hi = leaf_bounds_reference(d, pts)
    segs = kdop_wireframe(lo, hi, d)
    ends = segs.reshape(-1, 3) @ d.T
    assert np.all(ends >= lo - 1e-5) and np.all(ends <= hi + 1e-5)
    # every endpoint is a polytope vertex: at least 3 active half-spaces
    active = (np.abs(ends - lo) < 1e-5).sum(axis=1) + (np.abs(ends - hi) < 1e-5).sum(axis=1)
    assert np.all(active >= 3)
    assert len(segs) > 12
