"""The cloth narrow phase's conservative filters (stages.sim.cloth_contact.narrow, the Bernstein and
end-distance test of stages.sim.cloth_contact.ccd): each may only drop pairs the exact tests would
not report, checked against the exact tests and plain numpy. (That the accelerated detection finds
exactly what brute force finds is tests/test_sim_cloth_candidates.py and test_sim_cloth_contact.py.)"""
from __future__ import annotations

import numpy as np
import pytest

from stages.sim.cloth_contact import ccd as CC
from stages.sim.cloth_contact import narrow as CN
from stages.sim.cloth_contact.setup import build_cloth_contact
from stages.sim.cloth_contact.bench import grid_sheet


def _cubics(rng, n):
    """Cubics with roots placed in and around [0, 1] (some double, some none), at mixed scales."""
    out = []
    for k in range(n):
        scale = 10.0 ** rng.uniform(-12, 2)
        kind = k % 4
        if kind == 0:     # three real roots anywhere near [0, 1]
            r = rng.uniform(-0.5, 1.5, 3)
        elif kind == 1:   # a double root in [0, 1] (a touch) and one elsewhere
            t = rng.uniform(0, 1)
            r = np.array([t, t + rng.choice([0.0, 1e-9]), rng.uniform(-2, 3)])
        elif kind == 2:   # roots outside [0, 1]
            r = np.concatenate([rng.uniform(-3, -0.01, 2), rng.uniform(1.01, 4, 1)])
        else:             # one real root outside, a complex pair
            c = np.poly(rng.uniform(-2, -0.1, 1))
            q = np.array([1.0, -2 * rng.uniform(-1, 2), rng.uniform(-1, 2) ** 2 + rng.uniform(0.01, 1)])
            out.append(scale * rng.choice([-1, 1]) * np.polymul(c, q)[::-1])
            continue
        out.append(scale * rng.choice([-1, 1]) * np.poly(r)[::-1])   # ascending c0..c3
    return out


def test_a_clear_cubic_has_no_root_in_the_step():
    rng = np.random.default_rng(7)
    t = np.linspace(0.0, 1.0, 4001)
    clear = 0
    crossing = 0
    for c in _cubics(rng, 4000):
        c0, c1, c2, c3 = (float(v) for v in c)
        f1 = c0 + c1 + c2 + c3
        vals = ((c3 * t + c2) * t + c1) * t + c0
        changes = bool(np.any(np.sign(vals) != np.sign(vals[0])))
        crossing += changes
        if CC.cubic_clear01(c0, c1, c2, c3, f1):
            clear += 1
            assert not changes
            assert CC.cubic_roots01(c0, c1, c2, c3, c0, f1)[3] == 0
    # the filter must matter: most of the root-free cubics are cleared, none with a sign change
    assert clear > 1000 and crossing > 500


def _edge_pairs(rng, n):
    """Edges ab, cd (particles 0-3) moving over a step, a few millimetres apart at most."""
    for _ in range(n):
        xs = rng.uniform(-0.01, 0.01, (4, 3))
        xs[1] = xs[0] + rng.normal(size=3) * 0.01
        xs[3] = xs[2] + rng.normal(size=3) * 0.01
        xe = xs + rng.normal(size=(4, 3)) * rng.choice([0.0005, 0.003])
        yield np.ascontiguousarray(xs), np.ascontiguousarray(xe)


def test_a_clear_edge_pair_is_no_contact_on_any_side():
    rng = np.random.default_rng(11)
    h = 0.003
    cleared = 0
    contacts = 0
    for xs, xe in _edge_pairs(rng, 3000):
        depth = h * rng.choice([1.0, 3.0])
        reach = max(h, depth)
        clear = CC.ee_clear(xs, xe, 0, 1, 2, 3, reach)
        cleared += clear
        for forced in (-1, 0, 1):
            o = rng.normal(size=3)
            kind = CC.test_edge_edge(xs, xe, 0, 1, 2, 3, forced, *o, h, depth)[0]
            contacts += kind >= 0
            if clear:
                assert kind < 0
    assert cleared > 300 and contacts > 300


@pytest.mark.parametrize("offset", [0.0, 900.0])
def test_float32_boxes_hold_the_float64_bounds(offset):
    """The float32 boxes contain each particle's, edge's and triangle's float64 bounds (rounded
    outwards, also far from the origin), and each particle's float32 diagonal bounds (pdiag) its
    18-DOP's other projections, by the direction dot products (the unused lanes 0)."""
    rng = np.random.default_rng(3)
    xa, ta = grid_sheet(12, 12, 0.5, 0.5, (offset, 0.3, -offset))
    xb, tb = grid_sheet(12, 12, 0.5, 0.5, (offset, 0.31, -offset))
    x = np.concatenate([xa, xb])
    tris = np.concatenate([ta, tb + xa.shape[0]])
    cc = build_cloth_contact(x, tris, [0, xa.shape[0], x.shape[0]], layers=[0, 1], motion_margin=0.005)
    topo, tree, work, prm = cc.kernel_args()
    xs = x + rng.normal(size=x.shape) * 1e-3
    xe = xs + rng.normal(size=x.shape) * 2e-3
    work[0][:] = 0
    work[0][::3] = 1
    margin = 0.0015
    CN.feature_bounds(xs, xe, topo, tree, work[0], margin, True)
    d = tree[0]
    pa, pb = xs @ d.T, xe @ d.T
    lo_d = np.minimum(pa, pb)[:, 3:] - margin
    hi_d = np.maximum(pa, pb)[:, 3:] + margin
    nd = d.shape[0] - 3
    hp = cc.pdiag.shape[1] // 2
    assert nd == 6 and hp >= nd
    # rounded outwards: below / above by at most float32's rounding of the value plus the widening
    tol = 4e-6 * (1.0 + np.abs(lo_d))
    assert np.all(cc.pdiag[:, :nd].astype(np.float64) <= lo_d)
    assert np.all(cc.pdiag[:, :nd].astype(np.float64) >= lo_d - tol)
    assert np.all(cc.pdiag[:, hp:hp + nd].astype(np.float64) >= hi_d)
    assert np.all(cc.pdiag[:, hp:hp + nd].astype(np.float64) <= hi_d + 4e-6 * (1.0 + np.abs(hi_d)))
    assert not cc.pdiag[:, nd:hp].any() and not cc.pdiag[:, hp + nd:].any()
    lo64 = np.minimum(xs, xe) - margin
    hi64 = np.maximum(xs, xe) + margin
    assert np.all(cc.pbox[:, :3].astype(np.float64) <= lo64) and np.all(cc.pbox[:, 4:7].astype(np.float64) >= hi64)
    e = cc.edges
    assert np.all(cc.ebox[:, :3].astype(np.float64) <= np.minimum(lo64[e[:, 0]], lo64[e[:, 1]]))
    assert np.all(cc.ebox[:, 4:7].astype(np.float64) >= np.maximum(hi64[e[:, 0]], hi64[e[:, 1]]))
    assert np.all(cc.tbox[:, :3].astype(np.float64) <= lo64[tris].min(axis=1))
    assert np.all(cc.tbox[:, 4:7].astype(np.float64) >= hi64[tris].max(axis=1))
    # moved flags: particles as given, edges / triangles with a moved particle
    m = work[0].astype(bool)
    ne = e.shape[0]
    assert np.array_equal(cc.feat_moved[:ne] != 0, m[e].any(axis=1))
    assert np.array_equal(cc.feat_moved[ne:] != 0, m[tris].any(axis=1))
    assert np.allclose(cc.p_move, np.linalg.norm(xe - xs, axis=1), rtol=1e-15, atol=0)
