"""The offset cloth x cloth phase (stages.sim.cloth_contact.offset): its proximity query against a
brute-force reference, the bounds never let a feature pass another along the path they prove
(property test), and stacked sheets / a cloth folded on itself end with no crossing."""
from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings, strategies as st

from stages.sim.cloth_contact import offset as OF
from stages.sim.cloth_contact import proximity as PX
from stages.sim.cloth_contact.bench import _obstacles, _springs, _verlet, cloth_springs, grid_sheet
from stages.sim.cloth_contact.ccd import count_edge_triangle_crossings
from stages.sim.cloth_contact.setup import feature_owners, mesh_edges
from tests.test_sim_cloth_contact import folded_sheet

H = 0.004


def _canon(kind, idx):
    """A pair as (kind, vertex tuple) with each edge's ends and the two edges in a fixed order."""
    if kind == PX.KIND_EE:
        e1, e2 = tuple(sorted(idx[:2])), tuple(sorted(idx[2:]))
        idx = min(e1, e2) + max(e1, e2)
    return int(kind), tuple(int(v) for v in idx)


def _query(x, t, radius, x_tree):
    """query_pairs at x with the tree's topology built at x_tree (the cloth at the phase's start)."""
    edges, te, _ = mesh_edges(t)
    owns = feature_owners(t, te, x.shape[0], edges.shape[0])
    children, leaf_prim = PX.triangle_tree(x_tree, t)
    nodes = children.shape[0]
    cap = 20000
    kind, idx, dist, dmin = np.zeros(cap, np.int8), np.zeros((cap, 4), np.int32), np.zeros(cap), np.zeros(x.shape[0])
    n = PX.query_pairs(x, t, edges, te, owns, radius, np.zeros((t.shape[0], 6)), children, leaf_prim,
                       np.zeros((nodes, 6)), np.zeros((2 * nodes + 8, 2), np.int32), kind, idx, dist, dmin)
    assert n <= cap
    return edges, {_canon(kind[p], idx[p]): dist[p] for p in range(n)}, n, dmin


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), jitter=st.sampled_from([0.0005, 0.003, 0.01]),
       radius=st.sampled_from([0.004, 0.012, 0.03]), stale=st.booleans())
def test_query_equals_brute_force(seed, jitter, radius, stale):
    """The tree's topology built at the positions queried, or at the sheets before they moved
    (stale: refitted, as the phase uses it)."""
    rng = np.random.default_rng(seed)
    xa, ta = grid_sheet(5, 5, 0.08, 0.08)
    xb, tb = grid_sheet(5, 5, 0.08, 0.08, (0.005, 0.006, 0.003))
    x = np.concatenate([xa, xb]) + rng.normal(0.0, jitter, (50, 3))
    t = np.concatenate([ta, tb + 25]).astype(np.int32)
    x_tree = np.concatenate([xa, xb + (0.0, 0.1, 0.0)]) if stale else x
    edges, got, n, dmin = _query(x, t, radius, x_tree)
    assert len(got) == n    # each pair once
    ref = {_canon(k, i): d for (k, i), d in PX.brute_force_pairs(x, t, edges, radius).items()}
    assert set(got) == set(ref)
    for key, d in ref.items():
        assert abs(got[key] - d) < 1e-12
    want = np.full(x.shape[0], radius)
    for (_, ids), d in ref.items():
        for v in ids:
            want[v] = min(want[v], d)
    np.testing.assert_allclose(dmin, want, atol=1e-12)


def _min_distance(x, t, edges):
    """The smallest distance over every non-incident VF and EE pair (brute force)."""
    return min(PX.brute_force_pairs(x, t, edges, np.inf).values())


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), move=st.sampled_from([0.002, 0.006, 0.02, 0.08]),
       pinned=st.booleans())
def test_bounds_never_let_a_feature_pass_another(seed, move, pinned):
    """Two small sheets 3 mm apart, a random displacement of every particle (the pinned ones, if any,
    one displacement together): after keep_apart (as a call runs it), no pair of features that share no vertex touches anywhere on the straight
    path from the query positions, sampled finely, and none crosses at its end."""
    rng = np.random.default_rng(seed)
    xa, ta = grid_sheet(4, 4, 0.03, 0.03)
    xb, tb = grid_sheet(4, 4, 0.03, 0.03, (0.002, 0.003, 0.001))
    x0 = np.concatenate([xa, xb]) + rng.normal(0.0, 0.0005, (32, 3))
    t = np.concatenate([ta, tb + 16]).astype(np.int32)
    cinv = np.ones(32)
    if pinned:
        cinv[[0, 3, 16]] = 0.0
    og = OF.offset_state(x0, t, cinv, thickness=0.002, every=1, radius=0.006)
    xq, topo, work, prm, counters = og
    x = x0 + rng.normal(0.0, move, x0.shape)
    x[cinv == 0.0] = x0[cinv == 0.0] + rng.normal(0.0, move, 3)   # the pinned ones move together (one bone)
    kind, idx, dist, dmin, vstart, vpair, m, flag = work[4:12]
    OF.keep_apart(x, xq, topo[4], kind, idx, dist, dmin, vstart, vpair, m, flag, 0.5 * work[14][0], prm[2], counters)
    assert counters[OF.O_UNPROVEN] == 0
    edges = topo[1]
    # what the proof leaves: a listed pair d apart keeps 2 % of d + MIN_GAP, an unlisted one 2 % of r
    floor = 0.9 * min(OF.MIN_GAP, (1.0 - OF.SAFE) * prm[0])
    assert _min_distance(xq, t, edges) > floor
    for s in np.linspace(0.0, 1.0, 21):
        assert _min_distance(xq + s * (x - xq), t, edges) > floor
    assert count_edge_triangle_crossings(x, edges, t, np.ones(edges.shape[0], bool), np.ones(t.shape[0], bool)) == 0


class _Sheets:
    """Verlet mass-spring cloth (unit masses, particles with inv_mass 0 pinned) with a ground plane and
    the offset phase last in every step (a call every `every` steps)."""

    def __init__(self, x, t, inv_mass, thickness=H, every=1, dt=1 / 240):
        self.x = np.ascontiguousarray(x, np.float64).copy()
        self.xp = self.x.copy()
        self.t = np.ascontiguousarray(t, np.int32)
        self.inv_mass = np.ascontiguousarray(inv_mass, np.float64)
        self.springs, self.rest = cloth_springs(self.x, self.t)
        self.dt = dt
        self.every = every
        self.k = 0
        self.og = OF.offset_state(self.x, self.t, self.inv_mass, thickness, every)
        self.edges = self.og[1][1]

    def step(self):
        _verlet(self.x, self.xp, self.inv_mass, self.dt, -9.81, 0.99)
        _springs(self.x, self.inv_mass, self.springs, self.rest, 8)
        _obstacles(self.x, self.xp, np.zeros(3), -1.0, 0.0, 0.5)
        self.k += 1
        if self.k % self.every == 0:
            OF.offset_call(self.x, self.xp, self.og)

    def crossings(self):
        return count_edge_triangle_crossings(self.x, self.edges, self.t, np.ones(self.edges.shape[0], bool),
                                             np.ones(self.t.shape[0], bool))


def test_stacked_sheets_dropped_on_each_other_do_not_cross():
    """Three 16 x 16 sheets 2 cm apart above a pinned one (its edge rows held), a call every second
    step: they fall onto it and each other; no crossing after any call, and they end stacked (each
    above the one below)."""
    n, size = 16, 0.3
    parts, tris, off = [], [], 0
    for k in range(4):
        xs, ts = grid_sheet(n, n, size - 0.002 * k, size - 0.002 * k, (0.001 * k, 0.1 + 0.02 * k, 0.001 * k))
        parts.append(xs)
        tris.append(ts + off)
        off += xs.shape[0]
    x = np.concatenate(parts)
    t = np.concatenate(tris)
    inv = np.ones(x.shape[0])
    grid = np.arange(n * n).reshape(n, n)
    inv[np.concatenate([grid[0], grid[-1], grid[:, 0], grid[:, -1]])] = 0.0   # the bottom sheet's border
    sim = _Sheets(x, t, inv, every=2)
    for _ in range(120):    # the state a call left (as the step loop records it, at a call)
        sim.step()
        sim.step()
        assert sim.crossings() == 0
    mid = [sim.x[k * n * n:(k + 1) * n * n].reshape(n, n, 3)[n // 2, n // 2, 1] for k in range(4)]
    assert mid[0] < 0.1 - 0.01                       # the stack sagged the bottom sheet
    assert all(b > a for a, b in zip(mid, mid[1:]))  # in their order, apart
    assert sim.og[4][OF.O_UNPROVEN] == 0


def test_folded_cloth_does_not_pass_through_itself():
    """A sheet bent into a hairpin falling onto the ground with a random initial velocity: its halves
    land on each other, never through."""
    x, t = folded_sheet()
    sim = _Sheets(x, t, np.ones(x.shape[0]), every=1)
    sim.xp -= np.random.default_rng(0).normal(0, 0.002, x.shape)
    for _ in range(160):
        sim.step()
        assert sim.crossings() == 0
    assert sim.og[4][OF.O_QUERIES] > 1
    assert sim.x[:, 1].max() < 0.1    # it fell and lies folded on the ground


def test_simulation_with_the_offset_phase_is_the_same_for_any_thread_count():
    """The drape (a 2,500-particle sheet onto a hull) with the offset phase: bit-identical frames on one
    and two threads, its queries counted, and no cloth edge through the cloth."""
    from dataclasses import replace

    from stages.sim.audit import audit_cloth
    from pipeline.benches.sim import drape_scene
    from stages.sim.simulate import simulate
    from stages.sim.types import SimParams

    scene = drape_scene(14)
    params = replace(SimParams.preset("default", body_audit=False), cloth_contact="offset")
    one = simulate(*scene[:4], scene[4], params, threads=1)
    two = simulate(*scene[:4], scene[4], params, threads=2)
    np.testing.assert_array_equal(one.garments[0].positions, two.garments[0].positions)
    assert one.cloth_contact["method"] == "offset" and one.cloth_contact["offset"]["queries"] >= 1
    assert audit_cloth(one, scene[4]).garments[0].crossings_self.max() == 0
