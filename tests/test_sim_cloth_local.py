"""Cloth x cloth candidate lists updated in place (stages.sim.cloth_contact.local.update_candidates):
when a few particles leave their motion boxes, their pairs are dropped and searched again instead
of a full build. The lists must then hold exactly the pairs a plain-Python enumeration over the
lists' bounds finds (no culling: none missing, none twice), and detection over them must find
what the brute force finds."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from stages.sim.cloth_contact import kernels as CK
from stages.sim.cloth_contact.setup import build_cloth_contact
from tests.test_sim_cloth_contact import H, brute_force_reference, two_sheets

MOTION = 0.01


def _listed(cc):
    """The candidate lists as sorted lists of pairs (duplicates kept)."""
    nv, ne = int(cc.cand_n[0]), int(cc.cand_n[1])
    return sorted(map(tuple, cc.cand_vf[:nv].tolist())), sorted(map(tuple, cc.cand_ee[:ne].tolist()))


def _reference_pairs(cc):
    """Every vertex-face and edge-edge pair sharing no vertex whose bounds (the particles' bounds
    the lists keep, bld_min / bld_max; a triangle's and an edge's the union of their corners') overlap
    in every direction, enumerated in Python."""
    lo, hi = cc.bld_min, cc.bld_max
    tris, edges = cc.triangles, cc.edges
    tlo, thi = lo[tris].min(axis=1), hi[tris].max(axis=1)
    elo, ehi = lo[edges].min(axis=1), hi[edges].max(axis=1)
    vf = []
    for p in sorted(set(tris.ravel().tolist())):
        for t in range(tris.shape[0]):
            if p in tris[t]:
                continue
            if np.all(hi[p] >= tlo[t]) and np.all(thi[t] >= lo[p]):
                vf.append((p, t))
    ee = []
    for e in range(edges.shape[0]):
        for f in range(e + 1, edges.shape[0]):
            if set(edges[e].tolist()) & set(edges[f].tolist()):
                continue
            if np.all(ehi[e] >= elo[f]) and np.all(ehi[f] >= elo[e]):
                ee.append((e, f))
    return sorted(vf), sorted(ee)


def _drop_some(rng, x, off, count, depth):
    """x with `count` random inner particles of the upper sheet (n x n, over the lower one) moved
    down by `depth`."""
    xe = x.copy()
    n = int(round(np.sqrt(off[2] - off[1])))
    i, j = np.meshgrid(np.arange(1, n - 1), np.arange(1, n - 1), indexing="ij")
    idx = rng.choice(off[1] + (i * n + j).ravel(), size=count, replace=False)
    xe[idx, 1] -= depth
    return xe, idx


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), count=st.integers(1, 12))
def test_updated_lists_hold_exactly_the_overlapping_pairs(seed, count):
    # no culling: the build lists exactly the overlapping pairs; after particles left their boxes
    # the updated lists must too, over the new boxes (a missed pair or one listed twice fails)
    rng = np.random.default_rng(seed)
    x, t, off, layers = two_sheets(n=6, gap=0.06)
    cc = build_cloth_contact(x, t, off, layers, thickness=H, cull=False, motion_margin=MOTION,
                             candidate_capacity=100_000)
    counters = np.zeros(CK.N_COUNTERS, np.int64)
    cc.contacts(x, x, counters=counters)
    assert _listed(cc) == _reference_pairs(cc)
    xe, _ = _drop_some(rng, x, off, count, 0.05)
    cc.contacts(x, xe, counters=counters)
    assert counters[CK.N_BUILDS] == 1 and counters[CK.N_LOCAL] == 1
    assert _listed(cc) == _reference_pairs(cc)


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), count=st.integers(1, 12), cull=st.booleans(), layered=st.booleans())
def test_updated_lists_find_what_brute_force_finds(seed, count, cull, layered):
    # sheets 6 cm apart: no pair between them in the built lists. A few particles of the upper
    # sheet drop 5.9 cm onto the lower one: only the updated lists hold their new pairs
    rng = np.random.default_rng(seed)
    x, t, off, layers = two_sheets(n=6, gap=0.06, layers=(0, 1) if layered else (0, 0))
    cc = build_cloth_contact(x, t, off, layers, thickness=H, layer_depth=3 * H, cull=cull, motion_margin=MOTION,
                             candidate_capacity=100_000, rotation=1.2)
    counters = np.zeros(CK.N_COUNTERS, np.int64)
    cc.contacts(x, x, counters=counters)
    xe, _ = _drop_some(rng, x, off, count, 0.059)
    found = 0
    for xs_, xe_ in ((x, xe), (xe, xe), (x, 0.5 * (x + xe))):   # kept after the update
        kind, feat = cc.contacts(xs_, xe_, counters=counters)
        ref_kind, ref_feat = brute_force_reference(cc, xs_, xe_)
        np.testing.assert_array_equal(kind, ref_kind)
        np.testing.assert_array_equal(feat, ref_feat)
        found += len(ref_kind)
    if not cull:   # culled, the dropped particles' triangles may turn past the culled patch's limit: a build
        assert counters[CK.N_BUILDS] == 1 and counters[CK.N_LOCAL] >= 1
    assert found > 0


def test_many_particles_out_of_their_boxes_build_afresh():
    x, t, off, layers = two_sheets(n=12, gap=0.06)
    cc = build_cloth_contact(x, t, off, layers, thickness=H, motion_margin=MOTION, candidate_capacity=100_000)
    counters = np.zeros(CK.N_COUNTERS, np.int64)
    cc.contacts(x, x, counters=counters)
    xe, _ = _drop_some(np.random.default_rng(0), x, off, CK.LOCAL_MAX + 1, 0.05)
    cc.contacts(x, xe, counters=counters)
    assert counters[CK.N_BUILDS] == 2 and counters[CK.N_LOCAL] == 0


@pytest.mark.parametrize("layered", [False, True])
def test_the_control_without_the_update_misses_the_dropped_particles_contacts(layered):
    # the kept lists used without their check (no update) miss what the update finds
    x, t, off, layers = two_sheets(n=6, gap=0.06, layers=(0, 1) if layered else (0, 0))
    # no culling: the dropped particles' triangles turn ~70 degrees, past a culled sheet's limit
    cc = build_cloth_contact(x, t, off, layers, thickness=H, layer_depth=3 * H, motion_margin=MOTION,
                             candidate_capacity=100_000, cull=False)
    counters = np.zeros(CK.N_COUNTERS, np.int64)
    cc.contacts(x, x, counters=counters)
    xe, _ = _drop_some(np.random.default_rng(1), x, off, 6, 0.059)
    topo, tree, work, prm = cc.kernel_args()
    cc.moved[:] = 1
    margin = 0.5 * 3 * H
    kept = CK.narrow(x, xe, topo, tree, work, margin, H, 3 * H, False, counters, True)
    ref_kind, ref_feat = brute_force_reference(cc, x, xe)
    assert kept < len(ref_kind)
    kind, feat = cc.contacts(x, xe, counters=counters)
    np.testing.assert_array_equal(feat, ref_feat)
    assert counters[CK.N_LOCAL] == 1
