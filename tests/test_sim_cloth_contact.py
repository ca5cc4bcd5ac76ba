"""Cloth x cloth collision (stages.sim.cloth_contact): the tree search + exact tests against plain-Python
brute force, the continuous tests against an independent numpy reference, and small simulations:
a folded cloth, stacked sheets on a sphere, layered sheets that start interpenetrating."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from stages.checks import ContractError
from stages.sim.cloth_contact import kernels as CK
from stages.sim.cloth_contact.setup import build_cloth_contact, mesh_edges
from stages.sim.cloth_contact.bench import SheetSim, grid_sheet

H = 0.004


# ---------------------------------------------------------------------------------------------
# plain-Python references

def brute_force_reference(cc, xs, xe, only_cross=False):
    """Every vertex-face and edge-edge pair that shares no vertex, enumerated in Python; the layer
    rule written out again here. Returns sorted (kind, feature pair) like ClothContact.contacts."""
    tris = cc.triangles
    h, depth = cc.thickness, cc.layer_depth
    sets = [set(tris[t].tolist()) for t in range(tris.shape[0])]
    layer = cc.garment_layer
    out = cc.garment_outward
    found = []
    for p in sorted(set(tris.ravel().tolist())):
        for t in range(tris.shape[0]):
            if p in sets[t]:
                continue
            gp, gt = cc.particle_garment[p], cc.tri_garment[t]
            forced = 0 if layer[gp] == layer[gt] else (int(out[gt]) if layer[gp] > layer[gt] else -int(out[gt]))
            kind = CK.test_vertex_face(xs, xe, p, *tris[t], forced, h, depth)[0]
            if kind >= 0 and (not only_cross or kind == CK.VF_CROSS):
                found.append((kind, p, t))
    ne = cc.edges.shape[0]
    for e in range(ne):
        for f in range(e + 1, ne):
            if set(cc.edges[e].tolist()) & set(cc.edges[f].tolist()):
                continue
            le, lf = layer[cc.edge_garment[e]], layer[cc.edge_garment[f]]
            forced, o = 0, (0.0, 0.0, 0.0)
            if le != lf:
                inner = e if le < lf else f
                forced = 1 if le < lf else -1
                o = np.zeros(3)
                for t in cc.edge_tris[inner]:
                    if t >= 0:
                        a, b, c = xe[tris[t]]
                        nrm = np.cross(b - a, c - a)
                        o += out[cc.tri_garment[t]] * nrm / np.linalg.norm(nrm)
            kind = CK.test_edge_edge(xs, xe, *cc.edges[e], *cc.edges[f], forced, *o, h, depth)[0]
            if kind >= 0 and (not only_cross or kind == CK.EE_CROSS):
                found.append((kind, e, f))
    found.sort()
    return (np.array([f[0] for f in found], np.int8), np.array([f[1:] for f in found], np.int32).reshape(-1, 2))


def crossing_reference(p0, p1, tri0, tri1):
    """Independent numpy CCD of a point against a moving triangle: the coplanarity polynomial fitted
    from 4 samples, its real roots in [0, 1], the barycentric coordinates there. Returns the minimum
    barycentric coordinate over the roots (>= 0: the point passes through), or None without roots."""
    ts = np.array([0.0, 1 / 3, 2 / 3, 1.0])

    def at(t):
        p = p0 + t * (p1 - p0)
        a, b, c = tri0 + t * (tri1 - tri0)
        return p, a, b, c

    vals = [np.dot(np.cross(b - a, c - a), p - a) for p, a, b, c in map(at, ts)]
    roots = np.roots(np.polyfit(ts, vals, 3))
    best = None
    for r in roots:
        if abs(r.imag) > 1e-9 or not (0.0 <= r.real <= 1.0):
            continue
        p, a, b, c = at(r.real)
        m = np.array([b - a, c - a]).T
        vw = np.linalg.lstsq(m, p - a, rcond=None)[0]
        bary = min(1 - vw.sum(), vw[0], vw[1])
        best = bary if best is None else max(best, bary)
    return best


def two_sheets(n=5, gap=0.006, layers=(0, 1)):
    xa, ta = grid_sheet(n, n, 0.1, 0.1)
    xb, tb = grid_sheet(n, n, 0.1, 0.1, (0.003, gap, 0.004))
    x = np.concatenate([xa, xb])
    t = np.concatenate([ta, tb + xa.shape[0]])
    return x, t, [0, xa.shape[0], x.shape[0]], list(layers)


# ---------------------------------------------------------------------------------------------
# (a) accelerated search + CCD equals brute force

@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), jitter=st.sampled_from([0.001, 0.004, 0.01]),
       move=st.sampled_from([0.002, 0.01, 0.03]), layered=st.booleans())
def test_tree_search_equals_brute_force_on_random_motions(seed, jitter, move, layered):
    rng = np.random.default_rng(seed)
    x, t, off, layers = two_sheets(layers=(0, 1) if layered else (0, 0))
    cc = build_cloth_contact(x, t, off, layers, thickness=H, layer_depth=3 * H, cull=False)
    xs = x + rng.normal(0.0, jitter, x.shape)
    xe = xs + rng.normal(0.0, move, x.shape)
    kind, feat = cc.contacts(xs, xe)
    ref_kind, ref_feat = brute_force_reference(cc, xs, xe)
    np.testing.assert_array_equal(kind, ref_kind)
    np.testing.assert_array_equal(feat, ref_feat)
    nb_kind, nb_feat = cc.contacts(xs, xe, brute_force=True)  # the numba brute force used elsewhere
    np.testing.assert_array_equal(nb_kind, ref_kind)
    np.testing.assert_array_equal(nb_feat, ref_feat)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1))
def test_tree_search_equals_brute_force_on_triangle_soup(seed):
    # disconnected triangles in a small box: every feature pair is a candidate somewhere
    rng = np.random.default_rng(seed)
    nt = 30
    x = (rng.uniform(-0.05, 0.05, (nt, 1, 3)) + rng.normal(0, 0.02, (nt, 3, 3))).reshape(-1, 3)
    t = np.arange(3 * nt, dtype=np.int32).reshape(-1, 3)
    off = [0, 45, 3 * nt]  # two garments
    cc = build_cloth_contact(x, t, off, [1, 0], outward=[1.0, -1.0], thickness=H, layer_depth=3 * H, cull=False)
    xe = x + rng.normal(0.0, 0.02, x.shape)
    for only_cross in (False, True):
        kind, feat = cc.contacts(x, xe, only_cross=only_cross)
        ref_kind, ref_feat = brute_force_reference(cc, x, xe, only_cross)
        assert len(ref_kind) > 0 or only_cross
        np.testing.assert_array_equal(kind, ref_kind)
        np.testing.assert_array_equal(feat, ref_feat)


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_point_triangle_crossing_matches_numpy_reference(seed):
    rng = np.random.default_rng(seed)
    tri0 = rng.normal(0, 1, (3, 3))
    tri1 = tri0 + rng.normal(0, 0.5, (3, 3))
    p0 = tri0.mean(0) + rng.normal(0, 1, 3)
    p1 = tri1.mean(0) - (p0 - tri0.mean(0)) + rng.normal(0, 0.5, 3)
    xs = np.vstack([p0, tri0])
    xe = np.vstack([p1, tri1])
    ref = crossing_reference(p0, p1, tri0, tri1)
    kind = CK.test_vertex_face(xs, xe, 0, 1, 2, 3, 0, 1e-9, 1e-9)[0]
    # the crossing's direction matters to the kernel (start side -> other side), so compare only
    # paths that start and end on different sides, away from the tolerance boundary
    f = [np.dot(np.cross(x[2] - x[1], x[3] - x[1]), x[0] - x[1]) for x in (xs, xe)]
    if f[0] * f[1] >= 0 or ref is None or abs(ref) < 1e-6:
        return
    assert (kind == CK.VF_CROSS) == (ref > 0), (kind, ref)


def test_exact_tests_on_hand_made_cases():
    tri = np.array([[0.0, 0, 0], [1, 0, 0], [0, 0, 1]])  # normal (b-a) x (c-a) = -y
    st_ = np.vstack([[0.2, 0.1, 0.2], tri])
    # falls straight through: CROSS, pushed back up (dir = +y, the side it came from)
    k, *_, dx, dy, dz = CK.test_vertex_face(st_, np.vstack([[0.2, -0.1, 0.2], tri]), 0, 1, 2, 3, 0, H, H)
    assert k == CK.VF_CROSS and dy == pytest.approx(1.0)
    # falls beside the triangle: nothing
    assert CK.test_vertex_face(st_ + [[1.0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0]],
                               np.vstack([[1.2, -0.1, 0.2], tri]), 0, 1, 2, 3, 0, H, H)[0] < 0
    # stops within the thickness: NEAR
    assert CK.test_vertex_face(st_, np.vstack([[0.2, 0.002, 0.2], tri]), 0, 1, 2, 3, 0, H, H)[0] == CK.VF_NEAR
    # a static point that the moving triangle sweeps through: CROSS
    p = np.array([[0.3, 0.0, 0.3]])
    t0 = tri + [0, -0.2, 0]
    t1 = tri.copy()
    t1[:, 1] = [0.3, 0.3, 0.3]
    assert CK.test_vertex_face(np.vstack([p, t0]), np.vstack([p, t1]), 0, 1, 2, 3, 0, H, H)[0] == CK.VF_CROSS
    # edge through edge: CROSS; parallel edges: nothing
    e0 = np.array([[0.5, 0.1, -1], [0.5, 0.1, 1], [-1, 0, 0], [1, 0, 0]])
    e1 = e0.copy()
    e1[:2, 1] = -0.1
    assert CK.test_edge_edge(e0, e1, 0, 1, 2, 3, 0, 0.0, 0.0, 0.0, H, H)[0] == CK.EE_CROSS
    par = e0.copy()
    par[:2] = [[-1, 0.1, 0], [1, 0.1, 0]]
    par1 = par.copy()
    par1[:2, 1] = -0.1
    assert CK.test_edge_edge(par, par1, 0, 1, 2, 3, 0, 0.0, 0.0, 0.0, H, H)[0] < 0
    # layers: a point 2 mm below a triangle whose outward normal is -y, i.e. outward of it, keeps;
    # forced +1 (outer, along the normal) and starting 2 mm on the wrong side (+y): pushed through to -y
    xs = np.vstack([[0.2, 0.002, 0.2], tri])
    k, *_, dy, _ = CK.test_vertex_face(xs, xs, 0, 1, 2, 3, 1, H, 3 * H)
    assert k == CK.VF_NEAR and dy == pytest.approx(-1.0)
    # ... but not from deeper than layer_depth (the far side of the body): side kept, no contact
    xs = np.vstack([[0.2, 0.05, 0.2], tri])
    assert CK.test_vertex_face(xs, xs, 0, 1, 2, 3, 1, H, 3 * H)[0] < 0


def test_static_crossing_count_matches_python():
    rng = np.random.default_rng(3)
    nt = 25
    x = (rng.uniform(-0.1, 0.1, (nt, 1, 3)) + rng.normal(0, 0.06, (nt, 3, 3))).reshape(-1, 3)
    t = np.arange(3 * nt, dtype=np.int32).reshape(-1, 3)
    edges, _, _ = mesh_edges(t)

    def crosses(p, q, a, b, c):
        # plane crossing, then the crossing point inside by barycentric coordinates
        n = np.cross(b - a, c - a)
        dp, dq = np.dot(n, p - a), np.dot(n, q - a)
        if dp * dq >= 0:
            return False
        y = p + dp / (dp - dq) * (q - p)
        m = np.array([b - a, c - a]).T
        v, w = np.linalg.lstsq(m, y - a, rcond=None)[0]
        return v > 0 and w > 0 and v + w < 1

    ref = sum(crosses(x[i], x[j], *x[tri]) for i, j in edges for tri in t if not ({i, j} & set(tri)))
    got = CK.count_edge_triangle_crossings(x, edges, t, np.ones(len(edges), bool), np.ones(len(t), bool))
    assert ref > 0 and got == ref


# ---------------------------------------------------------------------------------------------
# response: pinned particles, layers

def test_response_shares_by_inverse_mass_and_never_moves_pinned():
    x, t, off, layers = two_sheets(n=4, gap=0.006, layers=(0, 0))
    cc = build_cloth_contact(x, t, off, layers, thickness=H)
    xs = x.copy()
    xe = x.copy()
    upper = np.arange(off[1], off[2])
    xe[upper, 1] -= 0.012  # the upper sheet moves 6 mm through the lower one
    inv = np.ones(x.shape[0])
    inv[: off[1]] = 0.0  # the lower sheet is pinned
    c = cc.collide(xs, xe, inv)
    np.testing.assert_array_equal(xe[: off[1]], x[: off[1]])
    assert c[CK.N_CONTACTS] > 0 and c[CK.N_CORRECTED] > 0 and c[CK.N_LEFT] == 0
    edges_u = np.isin(cc.edges[:, 0], upper)
    tris_l = cc.tri_garment == 0
    assert CK.count_edge_triangle_crossings(xe, cc.edges, cc.triangles, edges_u, tris_l) == 0
    # upper particles over the lower sheet end above it by about the thickness
    over = (xe[upper, 0] < 0.1) & (xe[upper, 2] < 0.1)
    assert np.all(xe[upper][over, 1] > 0.0)


def test_contract_errors():
    x, t, off, layers = two_sheets()
    with pytest.raises(ContractError):
        build_cloth_contact(x, t, [0, 5, 3], layers)
    bad = t.copy()
    bad[0, 2] = off[1] + 1  # spans both garments
    with pytest.raises(ContractError):
        build_cloth_contact(x, bad, off, layers)
    with pytest.raises(ContractError):
        build_cloth_contact(x, t, off, layers, thickness=0.004, layer_depth=0.001)


# ---------------------------------------------------------------------------------------------
# (b)-(d) small simulations

def folded_sheet(n=12, length=0.3, width=0.2, gap=0.03, height=0.1):
    """A sheet bent into a hairpin: a lower half, a half-circle fold of diameter `gap`, an upper half."""
    nu = 2 * n + 6
    u = np.linspace(0.0, 1.0, nu)
    half = length / 2
    arc = np.pi * gap / 2
    s = u * (2 * half + arc)
    px = np.where(s < half, s, np.where(s < half + arc, half + gap / 2 * np.sin((s - half) / (gap / 2)),
                                        half - (s - half - arc)))
    py = np.where(s < half, 0.0, np.where(s < half + arc, gap / 2 - gap / 2 * np.cos((s - half) / (gap / 2)), gap))
    x, t = grid_sheet(nu, n, 1.0, width)
    iu = np.repeat(np.arange(nu), n)
    x[:, 0] = px[iu]
    x[:, 1] = py[iu] + height
    return x, t


def test_folded_cloth_does_not_pass_through_itself():
    x, t = folded_sheet()
    v0 = np.random.default_rng(0).normal(0, 0.002, x.shape)  # a random initial velocity: layers slide and twist
    sim = SheetSim(x, t, [0, x.shape[0]], dt=1 / 240, thickness=H, ground_y=0.0)
    sim.xp -= v0
    cc = sim.cc
    everything_e = np.ones(cc.edges.shape[0], bool)
    everything_t = np.ones(t.shape[0], bool)
    for _ in range(120):
        sim.step()
        assert CK.count_edge_triangle_crossings(sim.x, cc.edges, cc.triangles, everything_e, everything_t) == 0
    assert sim.counters[CK.N_CONTACTS] > 0 and sim.counters[CK.N_LEFT] == 0
    # it fell onto the ground, so the upper half lies on the lower one within a few thicknesses
    assert sim.x[:, 1].max() < 0.1
    # the control: the same drop without the phase does pass through itself
    ctrl = SheetSim(x, t, [0, x.shape[0]], dt=1 / 240, thickness=H, ground_y=0.0, contact=False)
    ctrl.xp -= v0
    crossings = 0
    for _ in range(120):
        ctrl.step()
        crossings = max(crossings, CK.count_edge_triangle_crossings(ctrl.x, cc.edges, cc.triangles, everything_e,
                                                                    everything_t))
    assert crossings > 0


def radial_order_violations(upper, lower_x, lower_t, centre):
    """Upper-sheet particles whose ray from `centre` meets the lower sheet farther out than they are."""
    bad = 0
    a, b, c = (lower_x[lower_t[:, k]] - centre for k in range(3))
    e1, e2 = b - a, c - a
    for p in upper - centre:
        d = p / np.linalg.norm(p)
        pv = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, pv)
        ok = np.abs(det) > 1e-14
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        tv = -a
        u = np.einsum("ij,ij->i", tv, pv) * inv
        q = np.cross(tv, e1)
        v = (q @ d) * inv
        dist = np.einsum("ij,ij->i", e2, q) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (dist > 0)
        if hit.any() and dist[hit].max() > np.linalg.norm(p):
            bad += 1
    return bad


def test_stacked_sheets_on_a_sphere_stay_ordered():
    n = 11
    xa, ta = grid_sheet(n, n, 0.5, 0.5, (-0.25, 0.22, -0.25))
    xb, tb = grid_sheet(n, n, 0.5, 0.5, (-0.23, 0.235, -0.26))  # offset: its vertices fall between the lower's
    x = np.concatenate([xa, xb])
    t = np.concatenate([ta, tb + xa.shape[0]])
    off = [0, xa.shape[0], x.shape[0]]
    centre = np.zeros(3)
    sim = SheetSim(x, t, off, layers=[0, 0], dt=1 / 240, thickness=H, sphere=(centre, 0.2))
    lower = slice(0, off[1])
    upper = slice(off[1], off[2])
    for step in range(100):
        sim.step()
        if step % 5 == 4:
            assert radial_order_violations(sim.x[upper], sim.x[lower], ta, centre) == 0
    assert sim.counters[CK.N_CONTACTS] > 0
    # the sheets did drape (the rim fell well below the sphere's top)
    assert sim.x[:, 1].min() < 0.1


def test_layered_sheet_starting_inside_ends_outside():
    # inner garment (layer 0) at y = 5 mm, outer (layer 1) starting 2 mm BELOW it, both on the ground
    xi, ti = grid_sheet(9, 9, 0.2, 0.2, (0.0, 0.005, 0.0))
    xo, to = grid_sheet(7, 7, 0.15, 0.15, (0.025, 0.003, 0.025))
    x = np.concatenate([xi, xo])
    t = np.concatenate([ti, to + xi.shape[0]])
    off = [0, xi.shape[0], x.shape[0]]
    outer = slice(off[1], off[2])
    results = {}
    for layers in ([0, 1], [0, 0]):
        sim = SheetSim(x, t, off, layers=layers, dt=1 / 240, thickness=H, ground_y=0.0)
        for _ in range(60):
            sim.step()
        # the inner sheet stays flat on the ground: compare heights directly
        results[tuple(layers)] = sim.x[outer, 1] - sim.x[: off[1], 1].max()
    layered = results[(0, 1)]
    assert np.all(layered > 0.0), layered.min()
    # without the layer order the start side is kept: the outer sheet stays under
    assert np.all(results[(0, 0)] < 0.0)


def test_once_per_frame_keeps_layers_apart_and_drops_the_approach_velocity():
    # the per-frame integration: sub-steps without the phase, one swept call per frame
    x, t, off, _ = two_sheets(n=8, gap=0.008, layers=(0, 0))
    sim = SheetSim(x + [0.0, 0.1, 0.0], t, off, layers=[0, 0], dt=1 / 300, thickness=H, ground_y=0.0)
    sim.inv_mass[: off[1]] = 0.0  # the lower sheet is pinned 10 cm up; the upper one falls on it
    cc, args = sim.cc, sim.args
    upper = np.arange(off[1], off[2])
    over = (sim.x[upper, 0] < 0.1) & (sim.x[upper, 2] < 0.1)
    counters = np.zeros(CK.N_COUNTERS, np.int64)
    for _ in range(30):
        x0 = sim.x.copy()
        sim.cc = None
        for _ in range(10):
            sim.step()
        sim.cc = cc
        x_before = sim.x.copy()
        CK.collide_cloth(x0, sim.x, sim.inv_mass, *args, counters)
        xp_before = sim.xp.copy()
        CK.contact_velocity(x_before, sim.x, sim.xp, cc.corrected)
        moved = cc.corrected.astype(bool)
        d = sim.x[moved] - x_before[moved]
        v_old = x_before[moved] - xp_before[moved]
        v_new = sim.x[moved] - sim.xp[moved]
        # no velocity against the correction; the part across it unchanged
        assert np.all(np.einsum("ij,ij->i", v_new, d) >= -1e-15)
        dn = d / np.linalg.norm(d, axis=1, keepdims=True)
        across = lambda v: v - np.einsum("ij,ij->i", v, dn)[:, None] * dn  # noqa: E731
        np.testing.assert_allclose(across(v_new), across(v_old), atol=1e-12)
        np.testing.assert_array_equal(sim.xp[~moved], xp_before[~moved])
        assert np.all(sim.x[upper][over, 1] > 0.1)  # above the pinned sheet over its whole area
    assert counters[CK.N_CONTACTS] > 0 and counters[CK.N_LEFT] == 0
    # resting, not bouncing
    assert np.abs(sim.x[upper] - sim.xp[upper]).max() < 0.003


def test_same_input_same_output():
    rng = np.random.default_rng(11)
    x, t, off, layers = two_sheets(n=6)
    xs = x + rng.normal(0.0, 0.002, x.shape)
    xe = xs + rng.normal(0.0, 0.006, x.shape)
    outs = []
    for _ in range(2):
        cc = build_cloth_contact(x, t, off, layers, thickness=H)
        xx = xe.copy()
        c = cc.collide(xs, xx, np.ones(x.shape[0]))
        outs.append((xx, c))
    assert outs[0][1][CK.N_CONTACTS] > 0
    np.testing.assert_array_equal(outs[0][0], outs[1][0])
    # the counters (the last ones are CPU cycles: timings)
    np.testing.assert_array_equal(outs[0][1][:CK.N_CYC_BUILD], outs[1][1][:CK.N_CYC_BUILD])


def test_outward_signs_from_the_body():
    # a tube around the y axis (body points on the axis), once as built and once with flipped triangles
    from stages.sim.cloth_contact.setup import outward_signs
    x, t = grid_sheet(12, 5, 1.0, 0.3)
    ang = x[:, 0] * 2 * np.pi * 11 / 12
    tube = np.stack([0.2 * np.cos(ang), x[:, 2], 0.2 * np.sin(ang)], axis=1)
    both = np.concatenate([tube, tube * [1.2, 1.0, 1.2]])
    tris = np.concatenate([t, t[:, ::-1] + tube.shape[0]]).astype(np.int32)
    tri_garment = np.repeat([0, 1], t.shape[0])
    body = np.stack([np.zeros(20), np.linspace(0, 0.3, 20), np.zeros(20)], axis=1)
    s = outward_signs(both, tris, tri_garment, 2, body)
    n = np.cross(tube[t[0, 1]] - tube[t[0, 0]], tube[t[0, 2]] - tube[t[0, 0]])
    built_outward = np.dot(n, tube[t[0]].mean(0) * [1, 0, 1]) > 0
    assert s.tolist() == ([1.0, -1.0] if built_outward else [-1.0, 1.0])
