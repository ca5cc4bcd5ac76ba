"""Cloth x cloth candidate lists (stages.sim.cloth_contact.kernels.find_contacts with motion_margin > 0):
built once, kept over later steps while every particle stays within its motion radius of where it
was, they must find every contact the brute force finds at each of those steps; moving farther must
rebuild them (else contacts are missed: the control). Also the neighbouring-node culling on a curved
sheet, and the small simulations with the lists on."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from stages.sim.cloth_contact import kernels as CK
from stages.sim.cloth_contact.setup import DEFAULT_MOTION, build_cloth_contact
from stages.sim.cloth_contact.bench import SheetSim, grid_sheet
from tests.test_sim_cloth_contact import H, brute_force_reference, folded_sheet, two_sheets

MOTION = 0.01


def _within(rng, x, radius):
    """x moved by a random offset of length < radius per particle."""
    d = rng.normal(0.0, 1.0, x.shape)
    d *= (radius * rng.uniform(0.0, 0.95, (x.shape[0], 1))) / np.linalg.norm(d, axis=1, keepdims=True)
    return x + d


def _same(cc, xs, xe, counters):
    kind, feat = cc.contacts(xs, xe, counters=counters)
    ref_kind, ref_feat = brute_force_reference(cc, xs, xe)
    np.testing.assert_array_equal(kind, ref_kind)
    np.testing.assert_array_equal(feat, ref_feat)
    return len(ref_kind)


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), layered=st.booleans(), cull=st.booleans())
def test_kept_candidate_lists_find_what_brute_force_finds(seed, layered, cull):
    rng = np.random.default_rng(seed)
    x, t, off, layers = two_sheets(layers=(0, 1) if layered else (0, 0))
    # rotation near its limit: the normals of this jittered pair of sheets turn freely, and the test
    # is about the kept lists, not how often they are rebuilt
    cc = build_cloth_contact(x, t, off, layers, thickness=H, layer_depth=3 * H, cull=cull, motion_margin=MOTION, candidate_capacity=100_000,
                             rotation=1.2)
    counters = np.zeros(CK.N_COUNTERS, np.int64)
    xs0 = x + rng.normal(0.0, 0.001, x.shape)
    xe0 = xs0 + rng.normal(0.0, 0.001, x.shape)
    found = _same(cc, xs0, xe0, counters)     # builds the lists at (xs0, xe0)
    assert counters[CK.N_BUILDS] == 1
    # later steps, every particle within MOTION of where the lists were built (its end point)
    for _ in range(4):
        xs = _within(rng, xe0, MOTION / 2)
        xe = _within(rng, xe0, MOTION / 2)
        found += _same(cc, xs, xe, counters)
    assert counters[CK.N_BUILDS] == 1          # the lists were kept, so the steps above used them
    assert found > 0


def test_moving_beyond_the_margin_rebuilds_the_lists():
    # built with the sheets 5 cm apart (no pair between them); then the upper sheet moves down 4.7 cm
    # onto the lower one: the kept lists do not hold those pairs, only a rebuild finds them
    x, t, off, layers = two_sheets(gap=0.05)
    cc = build_cloth_contact(x, t, off, layers, thickness=H, layer_depth=3 * H, cull=False, motion_margin=MOTION,
                             candidate_capacity=100_000)
    counters = np.zeros(CK.N_COUNTERS, np.int64)
    assert _same(cc, x, x, counters) == 0
    xe = x.copy()
    xe[off[1]:, 1] -= 0.047
    # the control: the kept lists, used without their check, miss the contacts
    topo, tree, work, prm = cc.kernel_args()
    cc.moved[:] = 1
    margin = 0.5 * 3 * H
    assert not CK.candidates_valid(x, xe, topo, tree, work, margin, MOTION, prm[6], counters)
    assert CK.narrow(x, xe, topo, tree, work, margin, H, 3 * H, False, counters, True) == 0
    # as collide_cloth does it: the check fails, the lists are rebuilt (or, 25 particles out of
    # their boxes, updated in place: stages.sim.cloth_contact.local), every contact is found
    assert _same(cc, x, xe, counters) > 0
    assert counters[CK.N_BUILDS] + counters[CK.N_LOCAL] == 2


def test_turning_beyond_the_rotation_rebuilds_the_lists():
    x, t = grid_sheet(6, 6, 0.1, 0.1)
    cc = build_cloth_contact(x, t, [0, x.shape[0]], thickness=H, motion_margin=0.2, rotation=0.3)
    counters = np.zeros(CK.N_COUNTERS, np.int64)
    cc.contacts(x, x, counters=counters)
    c, s = np.cos(0.2), np.sin(0.2)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    cc.contacts(x, x @ rot.T, counters=counters)   # 0.2 rad: kept
    assert counters[CK.N_BUILDS] == 1
    c, s = np.cos(0.4), np.sin(0.4)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    cc.contacts(x, x @ rot.T, counters=counters)   # 0.4 rad: rebuilt
    assert counters[CK.N_BUILDS] == 2


def _turned(x, angle):
    c, s = np.cos(angle), np.sin(angle)
    return x @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T


@pytest.mark.parametrize("kept_for", [1, CK.YOUNG_LIST])
def test_a_culled_list_a_turn_undoes_young_is_followed_by_plain_lists(kept_for):
    # a flat sheet's lists cull it whole; turned past the rotation limit after `kept_for` more
    # detections they are rebuilt. Undone that young (fewer than YOUNG_LIST detections), the next
    # PLAIN_BUILDS builds cull nothing: such lists hold more pairs and no turn undoes them (bvh_walk
    # rebuilt culled lists twice a sub-step); a list that lived longer is followed by culled ones
    x, t = grid_sheet(6, 6, 0.1, 0.1)
    cc = build_cloth_contact(x, t, [0, x.shape[0]], thickness=H, motion_margin=0.2, rotation=0.3,
                             candidate_capacity=100_000)
    counters = np.zeros(CK.N_COUNTERS, np.int64)
    _same(cc, x, x, counters)
    culled = int(cc.cand_n[0] + cc.cand_n[1])
    for _ in range(kept_for - 1):
        _same(cc, x, x, counters)
    assert counters[CK.N_BUILDS] == 1 and cc.cand_n[5] == 0
    _same(cc, x, _turned(x, 0.4), counters)      # past the limit: rebuilt
    assert counters[CK.N_BUILDS] == 2 and counters[CK.N_INVALID_TURN] == 1
    if kept_for < CK.YOUNG_LIST:
        assert cc.cand_n[5] == CK.PLAIN_BUILDS - 1       # this build was the first plain one
        assert cc.cand_n[0] + cc.cand_n[1] > culled
        _same(cc, x, _turned(x, 0.8), counters)  # a plain list: no turn undoes it
        assert counters[CK.N_BUILDS] == 2
    else:
        assert cc.cand_n[5] == 0 and cc.cand_n[0] + cc.cand_n[1] == culled


def test_culling_on_a_folded_sheet_keeps_the_contacts_across_the_fold():
    # a sheet folded over a gap under the thickness: without culling the tree search and the kept
    # lists equal the brute force; with it both find a subset (normal-cone culling has no contour
    # test: a fold over two triangle strips of 90 degrees each, narrower than the thickness, hides a
    # few neighbours' contacts), the lists at least what the tree search finds (they cull less, with
    # room to turn), and every contact between the two layers away from the fold
    x, t = folded_sheet(n=6, gap=0.75 * H, length=0.1, width=0.08)
    rng = np.random.default_rng(3)
    xs = x + rng.normal(0.0, 0.0005, x.shape)
    xe = xs + rng.normal(0.0, 0.0005, x.shape)
    counters = np.zeros(CK.N_COUNTERS, np.int64)
    ref = set(map(tuple, np.c_[brute_force_reference(build_cloth_contact(x, t, [0, x.shape[0]], thickness=H,
                                                                        cull=False), xs, xe)].tolist()))
    assert len(ref) > 100
    found = {}
    for cull in (False, True):
        for motion in (0.0, MOTION):
            cc = build_cloth_contact(x, t, [0, x.shape[0]], thickness=H, cull=cull, motion_margin=motion,
                                     candidate_capacity=100_000)
            found[cull, motion] = set(map(tuple, np.c_[cc.contacts(xs, xe, counters=counters)].tolist()))
    assert found[False, 0.0] == ref and found[False, MOTION] == ref
    assert found[True, 0.0] <= found[True, MOTION] <= ref
    # away from the fold (x < 8 cm: the fold's strips are at about 10 cm) nothing is missed
    far = {c for c in ref if c[0] < 2 and x[c[1], 0] < 0.08 and x[t[c[2]], 0].max() < 0.08}
    assert far and far <= found[True, 0.0]


@pytest.mark.parametrize("motion", [0.0, DEFAULT_MOTION])
def test_folded_cloth_with_candidate_lists_does_not_pass_through_itself(motion):
    x, t = folded_sheet()
    v0 = np.random.default_rng(0).normal(0, 0.002, x.shape)
    sim = SheetSim(x, t, [0, x.shape[0]], dt=1 / 240, thickness=H, ground_y=0.0, motion_margin=motion)
    sim.xp -= v0
    cc = sim.cc
    every_e = np.ones(cc.edges.shape[0], bool)
    every_t = np.ones(t.shape[0], bool)
    for _ in range(120):
        sim.step()
        assert CK.count_edge_triangle_crossings(sim.x, cc.edges, cc.triangles, every_e, every_t) == 0
    assert sim.counters[CK.N_CONTACTS] > 0 and sim.counters[CK.N_LEFT] == 0
    if motion > 0:   # the lists were kept over several steps
        assert 0 < sim.counters[CK.N_BUILDS] < 120


def test_step_normal_cone_holds_every_normal_of_the_step():
    """The culling's normal cone over a step is the cone of n(xs), the middle normal and n(xe)
    (_step_normal): n(u) of the linearly moving triangle is their Bernstein combination, checked
    against the cross product at sampled u; and a triangle that turns over and back within the step
    (n(xs) and n(xe) alike) has a middle normal pointing the other way."""
    rng = np.random.default_rng(7)
    tri = np.array([[0, 1, 2]], np.int32)
    for _ in range(50):
        xs = rng.normal(size=(3, 3))
        xe = xs + rng.normal(size=(3, 3))
        n0, nm, n1 = (np.array(CK._step_normal(xs, xe, tri, 0, j)) for j in range(3))
        for u in np.linspace(0.0, 1.0, 7):
            x = (1 - u) * xs + u * xe
            want = np.cross(x[1] - x[0], x[2] - x[0])
            got = (1 - u) ** 2 * n0 + 2 * u * (1 - u) * nm + u ** 2 * n1
            np.testing.assert_allclose(got, want, atol=1e-12)
    # a triangle that inverts in its plane and back within the step: +z at both ends, -z at u = 0.4
    # (its edges along x and y shrink through 0 at u = 1/3 and 1/2); only the middle normal sees it
    xs = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    xe = np.array([[0.0, 0.0, 0.0], [-2.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    n0, nm, n1 = (np.array(CK._step_normal(xs, xe, tri, 0, j)) for j in range(3))
    x = 0.6 * xs + 0.4 * xe
    n_mid = np.cross(x[1] - x[0], x[2] - x[0])
    assert n0 @ n1 > 0.0 and n_mid @ n0 < 0.0 and n_mid @ n1 < 0.0 and n_mid @ nm > 0.0
