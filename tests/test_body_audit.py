"""The body audit (stages.sim.body_audit): body edges through cloth triangles and cloth edges through
body triangles, against an independent count over every edge-triangle pair (numpy orientations,
rational arithmetic where float64 cannot tell the sign), on synthetic cases and on the frames of a
real run read back from its recording."""
from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from stages.garments.simple import rectangle_cloth
from stages.geometry.mesh import mesh_edges
from stages.sim.body_audit import BodyFrames, audit_body_crossings, frame_crossings, in_self_overlap
from stages.sim.types import GarmentTrack, SimParams, SimResult

REPO = Path(__file__).resolve().parent.parent


# -- the reference ---------------------------------------------------------------------------------
def _orient_q(a, b, c, d) -> int:
    m = [[Fraction(float(a[k])) - Fraction(float(d[k])) for k in range(3)],
         [Fraction(float(b[k])) - Fraction(float(d[k])) for k in range(3)],
         [Fraction(float(c[k])) - Fraction(float(d[k])) for k in range(3)]]
    det = (m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
           + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]))
    return (det > 0) - (det < 0)


def _orient_np(a, b, c, d):
    """Signs of det[a - d, b - d, c - d] over broadcast (..., 3) arrays: +-1, or 0 where float64
    cannot be trusted (|det| below a generous bound; those are recomputed exactly)."""
    u, v, w = a - d, b - d, c - d
    det = np.einsum("...i,...i->...", u, np.cross(v, w))
    size = np.linalg.norm(u, axis=-1) * np.linalg.norm(v, axis=-1) * np.linalg.norm(w, axis=-1)
    return np.where(np.abs(det) > 1e-12 * size, np.sign(det), 0).astype(np.int8), det


def _brute_edges(x, edges, tris) -> np.ndarray:
    """(E,) bool: each edge crosses some triangle (no shared vertex; endpoints strictly on both sides
    of the plane and the three edge-line orientations strictly of one sign). Every pair is tested
    (pairs whose bounding boxes are apart cannot cross: their signs are not computed)."""
    out = np.zeros(len(edges), bool)
    tb = x[tris]
    tlo, thi = tb.min(axis=1), tb.max(axis=1)
    for lo in range(0, len(edges), 512):
        e = edges[lo:lo + 512]
        eb = x[e]
        elo, ehi = eb.min(axis=1), eb.max(axis=1)
        near = np.all((elo[:, None] <= thi[None]) & (ehi[:, None] >= tlo[None]), axis=2)
        for k in range(3):
            near &= (tris[None, :, k] != e[:, 0, None]) & (tris[None, :, k] != e[:, 1, None])
        i, t = np.nonzero(near)
        p, q = x[e[i, 0]], x[e[i, 1]]
        a, b, c = (x[tris[t, k]] for k in range(3))
        s = np.stack([_orient_np(a, b, c, p)[0], _orient_np(a, b, c, q)[0], _orient_np(p, q, a, b)[0],
                      _orient_np(p, q, b, c)[0], _orient_np(p, q, c, a)[0]])         # (5, n)
        # exact signs where a float sign is 0 and the pair could still cross
        for m in np.flatnonzero((s == 0).any(axis=0) & ~((s[0] == s[1]) & (s[0] != 0))):
            pp, qq, ta, tb_, tc = p[m], q[m], a[m], b[m], c[m]
            s[:, m] = [_orient_q(ta, tb_, tc, pp), _orient_q(ta, tb_, tc, qq), _orient_q(pp, qq, ta, tb_),
                       _orient_q(pp, qq, tb_, tc), _orient_q(pp, qq, tc, ta)]
        cross = (s[0] * s[1] < 0) & (s[2] != 0) & (s[2] == s[3]) & (s[3] == s[4])
        out[lo + np.unique(i[cross])] = True
    return out


def brute_counts(cloth, cloth_tris, body, body_tris) -> tuple[int, int]:
    """(body edges through the cloth, cloth edges through the body), every pair tested."""
    x = np.concatenate([cloth, body]).astype(np.float64)
    n = len(cloth)
    be = mesh_edges(body_tris) + n
    ce = mesh_edges(cloth_tris)
    return int(_brute_edges(x, be, cloth_tris).sum()), int(_brute_edges(x, ce, body_tris + n).sum())


def audit_counts(cloth, cloth_tris, body, body_tris) -> tuple[int, int]:
    hb, hc, pts, joints, _, _ = frame_crossings(cloth, cloth_tris, mesh_edges(cloth_tris), body, body_tris,
                                             mesh_edges(body_tris), np.zeros(len(body), np.int32))
    assert len(pts) == len(joints) == len(hb) + len(hc)
    return len(hb), len(hc)


# -- synthetic cases ---------------------------------------------------------------------------------
def _box(lo, hi):
    """A closed box mesh (12 triangles) between corners lo and hi."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    v = np.array([[(hi if (i >> k) & 1 else lo)[k] for k in range(3)] for i in range(8)])
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    t = [[a, b, c] for a, b, c, d in quads] + [[a, c, d] for a, b, c, d in quads]
    return v, np.array(t, np.int32)


def _sheet(n=11, y=0.5):
    x, t = rectangle_cloth(1.0, 1.0, n, n, center=(0.0, y, 0.0))
    return x.astype(np.float32), t.astype(np.int32)


def test_a_rod_through_a_sheet():
    """A thin box standing through a horizontal sheet: its 4 vertical edges and the 4 face diagonals
    pierce the sheet (8 body edges); the sheet's edges cross the rod's walls where they pass it."""
    cloth, ct = _sheet()
    body, bt = _box([0.013, 0.2, 0.021], [0.047, 0.8, 0.066])
    body = body.astype(np.float32)
    nb, nc = audit_counts(cloth, ct, body, bt)
    assert nb == 8
    assert (nb, nc) == brute_counts(cloth, ct, body, bt)
    # a rod touching the sheet from below (its top face in the sheet's plane) does not count
    body, bt = _box([0.013, 0.2, 0.021], [0.047, 0.5, 0.066])
    body = body.astype(np.float32)
    assert audit_counts(cloth, ct, body, bt) == (0, 0) == brute_counts(cloth, ct, body, bt)


def test_a_sheet_folded_round_a_box():
    """A sheet folded into a U round a box, then the box pushed through its bottom: the count is
    the brute force's, and zero while the box sits inside the fold."""
    x, t = rectangle_cloth(1.0, 0.6, 21, 13, center=(0.0, 0.0, 0.0))
    # fold: z in [-0.3, 0.3] wrapped into a U under a box 0.4 wide
    z = x[:, 2]
    folded = np.column_stack([x[:, 0], np.where(np.abs(z) > 0.2, 0.5 + (np.abs(z) - 0.2), 0.5),
                              np.clip(z, -0.2, 0.2) * 1.05]).astype(np.float32)
    box, bt = _box([-0.2, 0.52, -0.19], [0.2, 0.9, 0.19])
    box = box.astype(np.float32)
    assert audit_counts(folded, t, box, bt) == (0, 0) == brute_counts(folded, t, box, bt)
    low = (box - np.float32(0.1) * np.float32([0, 1, 0])).astype(np.float32)   # through the fold's bottom
    got = audit_counts(folded, t, low, bt)
    assert got[0] + got[1] > 0
    assert got == brute_counts(folded, t, low, bt)


def test_coplanar_touching_and_through_a_vertex_do_not_count():
    cloth, ct = _sheet(n=3)       # vertices on x, z in {-0.5, 0, 0.5} at y = 0.5
    # a body triangle lying in the sheet's plane (coplanar: no crossing either way)
    flat = np.array([[-0.3, 0.5, -0.3], [0.3, 0.5, -0.2], [0.0, 0.5, 0.3]], np.float32)
    tri = np.array([[0, 1, 2]], np.int32)
    assert audit_counts(cloth, ct, flat, tri) == (0, 0) == brute_counts(cloth, ct, flat, tri)
    # a body edge through a sheet vertex (a touch of edges, not through a triangle's inside)
    spike = np.array([[0.0, 0.2, 0.0], [0.0, 0.8, 0.0], [0.01, 0.8, 0.3]], np.float32)
    assert audit_counts(cloth, ct, spike, tri)[0] == brute_counts(cloth, ct, spike, tri)[0]
    # an endpoint exactly on the sheet
    touch = np.array([[0.1, 0.5, 0.1], [0.1, 0.8, 0.1], [0.2, 0.8, 0.3]], np.float32)
    assert audit_counts(cloth, ct, touch, tri) == (0, 0) == brute_counts(cloth, ct, touch, tri)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), grid=st.booleans(), n_body=st.integers(4, 12), n_tris=st.integers(1, 10))
def test_random_meshes_equal_the_brute_force(seed, grid, n_body, n_tris):
    """Random cloth and body triangles, on a small integer lattice (many coplanar, collinear and
    touching cases) or in floats; body and cloth share positions sometimes (coincident vertices)."""
    rng = np.random.default_rng(seed)
    pts = (lambda n: rng.integers(-2, 3, size=(n, 3)).astype(np.float32)) if grid else \
        (lambda n: rng.normal(size=(n, 3)).astype(np.float32))
    cloth = pts(9)
    body = pts(n_body)
    if rng.random() < 0.5:
        body[: min(3, n_body)] = cloth[: min(3, n_body)]
    ct = np.array([rng.choice(9, 3, replace=False) for _ in range(8)], np.int32)
    bt = np.array([rng.choice(n_body, 3, replace=False) for _ in range(n_tris)], np.int32)
    assert audit_counts(cloth, ct, body, bt) == brute_counts(cloth, ct, body, bt)


# -- the stage -------------------------------------------------------------------------------------
def _result(tracks, nf):
    z = np.zeros(nf, np.int32)
    return SimResult(tuple(tracks), np.arange(nf) / 30.0, z, z, z, np.zeros(nf), np.zeros(nf), {}, 0, SimParams())


def test_stage_counts_per_frame_joints_points_and_warning():
    """A rod moving down through a sheet: 0 crossings at frame 0, then 8 body edges, named by the
    joint of the rod's end nearer the sheet; the warning looks from first_frame on."""
    cloth, ct = _sheet()
    body, bt = _box([0.013, 0.55, 0.021], [0.047, 0.9, 0.066])
    nf = 4
    bodies = np.stack([body - [0.0, 0.1 * f, 0.0] for f in range(nf)]).astype(np.float32)
    joint = np.where(body[:, 1] < 0.6, 1, 0).astype(np.int32)      # the lower end: joint 'hand'
    frames = BodyFrames(bodies, bt, joint, ("arm", "hand"))
    track = GarmentTrack("sheet", ct, np.repeat(cloth[None], nf, axis=0), np.zeros(nf, np.int32), np.zeros(nf, np.int32))
    audit = audit_body_crossings(_result([track], nf), frames, first_frame=2)
    g = audit.garment("sheet")
    want = [brute_counts(cloth, ct, bodies[f], bt) for f in range(nf)]
    assert list(zip(g.body_edges.tolist(), g.cloth_edges.tolist())) == want
    assert g.body_edges.tolist() == [0, 8, 8, 8]
    assert g.joint_counts.sum(axis=1).tolist() == (g.body_edges + g.cloth_edges).tolist()
    # the rod's lower end (0.35 to 0.7 high, sheet at 0.5) is 'hand', for its edges and its walls
    assert g.joint_counts[2].tolist() == [0, 8 + g.cloth_edges[2]] and g.cloth_edges[2] > 0
    assert np.allclose(g.points[2][:8, 1], 0.5, atol=1e-6)      # on the sheet
    assert audit.first_frame == 2 and len(audit.warnings) == 1 and f"hand {8 + g.cloth_edges[2]}" in audit.warnings[0]
    s = audit.summary()
    assert any(v.startswith(f"8 at frame 2 (hand {8 + g.cloth_edges[2]})") for v in s.values())


def test_crossings_where_the_body_meets_itself_are_counted_apart():
    """A rod sunk into a slab (two parts of one body passing through each other, as an animation sinks a
    forearm into the hip) through a sheet lying inside the slab: the rod's edges cross the sheet inside
    the slab (flagged), the slab's own edges cross it away from the rod (not flagged); the sheet's edges
    through the rod's walls inside the slab are flagged, through the slab's walls not. Either winding
    of the body. The audit counts the flagged body edges apart and judges the rest."""
    cloth, ct = _sheet()
    rod, rt = _box([0.013, 0.2, 0.021], [0.047, 0.8, 0.066])
    slab, slt = _box([-0.2, 0.45, -0.2], [0.25, 0.55, 0.25])
    body = np.concatenate([rod, slab]).astype(np.float32)
    for bt in (np.concatenate([rt, slt + 8]), np.concatenate([rt, slt + 8])[:, ::-1].copy()):
        be = mesh_edges(bt)
        hb, hc, pts, _, normals, _ = frame_crossings(cloth, ct, mesh_edges(ct), body, bt, be, np.zeros(16, np.int32))
        flags = in_self_overlap(body, bt, pts, normals)
        rod_edge = (be[hb[:, 0]] < 8).all(axis=1)
        assert rod_edge.sum() == 8 and (~rod_edge).sum() > 0
        assert flags[:len(hb)].tolist() == rod_edge.tolist()
        rod_wall = (bt[hc[:, 1]] < 8).all(axis=1)
        assert rod_wall.any() and (~rod_wall).any()
        assert flags[len(hb):].tolist() == rod_wall.tolist()
        track = GarmentTrack("sheet", ct, np.repeat(cloth[None], 2, axis=0), np.zeros(2, np.int32), np.zeros(2, np.int32))
        audit = audit_body_crossings(_result([track], 2), BodyFrames(np.stack([body, body]), bt, np.zeros(16, np.int32),
                                                                     ("j",)))
        g = audit.garment("sheet")
        assert g.body_edges_in_overlap().tolist() == [8, 8] and g.body_edges_free().tolist() == [len(hb) - 8] * 2
        assert audit.body_edges_after().tolist() == [len(hb) - 8]
        assert audit.body_edges_after(in_overlap=True).tolist() == [8]
        assert any("one part of the body into another" in w for w in audit.warnings)
    # the rod alone: nothing where the body meets itself
    hb, hc, pts, _, normals, _ = frame_crossings(cloth, ct, mesh_edges(ct), rod.astype(np.float32), rt, mesh_edges(rt),
                                                 np.zeros(8, np.int32))
    assert len(pts) and not in_self_overlap(rod.astype(np.float32), rt, pts, normals).any()


# -- a real run, read back from its recording ------------------------------------------------------
@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    from pipeline.run import run_scene
    from pipeline.scene import load_scene
    scene = load_scene(REPO / "scenes" / "default.yaml")
    out = tmp_path_factory.mktemp("rec") / "default.rrd"
    summary = run_scene(scene, output=out, frames=4, progress=False)
    return out, summary


def _two_balls():
    """One body mesh of two unit balls sunk 0.5 m into each other (centres 0 and 1.5 on x)."""
    import trimesh
    a = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    v = np.concatenate([a.vertices, a.vertices + [1.5, 0.0, 0.0]])
    t = np.concatenate([a.faces, a.faces + len(a.vertices)]).astype(np.int32)
    return v, t


def test_particles_inside_where_the_body_meets_itself_are_told_apart():
    """A particle inside one ball whose nearest surface is the other ball's, sunk inside the first,
    is held where the body meets itself; one inside a ball by its own free surface is not (against
    the brute force: nearest surface point over every triangle, exact winding numbers)."""
    import trimesh

    from stages.geometry.winding import WindingTree, winding_numbers_brute
    from stages.sim.body_audit import SELF_GAP, body_orientation, inside_where_body_meets_itself
    v, t = _two_balls()
    tree = WindingTree(v, t)
    p = np.array([[0.45, 0.0, 0.0],     # inside A, under B's surface (x = 0.5), which is inside A
                  [0.7, 0.1, 0.0],      # inside both: nearest B's surface, inside A
                  [-0.9, 0.0, 0.0],     # inside A, its own free surface nearest
                  [1.5, 0.95, 0.0]])    # inside B, its own free surface nearest
    assert tree.inside(v, p).all()
    got = inside_where_body_meets_itself(tree, p, body_orientation(v, t))
    assert got.tolist() == [True, True, False, False]
    rng = np.random.default_rng(3)
    q = rng.uniform([-1.0, -1.0, -1.0], [2.5, 1.0, 1.0], size=(400, 3))
    q = q[tree.inside(v, q)]
    got = inside_where_body_meets_itself(tree, q, 1.0)
    mesh = trimesh.Trimesh(v, t, process=False)
    near, _, tri = trimesh.proximity.closest_point(mesh, q)
    w = np.zeros(len(q))
    winding_numbers_brute(near + SELF_GAP * mesh.face_normals[tri], v, t, w)
    ref = w > 0.5
    assert 0 < ref.sum() < len(q) and (got == ref).mean() > 0.98    # ties between the two balls' surfaces aside


def test_the_series_and_markers_are_logged_and_summarised(recorded):
    from tests.rrd_read import entity_paths, rows
    out, summary = recorded
    paths = entity_paths(out)
    assert "/sim/penetrations/body_edges/skirt" in paths and "/sim/penetrations/cloth_edges/skirt" in paths
    assert "/sim/skirt/body_cuts" in paths and "/sim/penetrations/body_edges_self_overlap/skirt" in paths
    series = rows(out, "sim/penetrations/body_edges/skirt", "Scalars:scalars")
    assert [f for f, _ in series] == list(range(summary.frames))
    assert all(v.size == 1 and v[0] >= 0 for _, v in series)
    assert any("body edges through the cloth" in k for k in summary.penetrations)
    assert any(s.name == "body audit" for s in summary.stages)


def test_recorded_frames_equal_the_brute_force(recorded):
    """The cloth and body as the recording holds them (float32), as simulated and with the body
    shifted through the cloth (a real body's edges, many crossings): the audit's counts are the
    brute force's."""
    from tests.rrd_read import rows
    out, summary = recorded
    cloth = rows(out, "sim/skirt/mesh", "Mesh3D:vertex_positions")
    ct = rows(out, "sim/skirt/mesh", "Mesh3D:triangle_indices", static=True)[0][1].astype(np.int32)
    body = rows(out, "rig/mesh", "Mesh3D:vertex_positions")
    bt = rows(out, "rig/mesh", "Mesh3D:triangle_indices", static=True)[0][1].astype(np.int32)
    for f in (1, len(cloth) - 1):
        c, b = cloth[f][1].astype(np.float32), body[f][1].astype(np.float32)
        for shift in ([0.0, 0.0, 0.0], [0.0, 0.0, 0.05], [0.03, -0.04, 0.0]):
            bs = (b + np.float32(shift)).astype(np.float32)
            got = audit_counts(c, ct, bs, bt)
            assert got == brute_counts(c, ct, bs, bt)
            if any(shift):
                assert got[0] > 0


def test_tables_report_the_body_edges_and_only_the_corpus_judges_them():
    """The sweep row's body_edges_max comes from the run's BodyCrossings (after the blend-in); the
    corpus fails a pair on it, the dressing matrix shows it in a column without failing."""
    from pipeline import corpus, matrix
    from pipeline.sweep_job import COLUMNS, INT_COLUMNS, _metrics
    cloth, ct = _sheet()
    body, bt = _box([0.013, 0.55, 0.021], [0.047, 0.9, 0.066])
    bodies = np.stack([body - [0.0, 0.1 * f, 0.0] for f in range(3)]).astype(np.float32)
    track = GarmentTrack("sheet", ct, np.repeat(cloth[None], 3, axis=0), np.zeros(3, np.int32), np.zeros(3, np.int32))
    audit = audit_body_crossings(_result([track], 3), BodyFrames(bodies, bt, np.zeros(8, np.int32), ("j",)),
                                 first_frame=2)
    assert "body_edges_max" in COLUMNS and "body_edges_max" in INT_COLUMNS
    assert _metrics({"body_crossings": audit}, None)["body_edges_max"] == 8
    ok = {"status": "ok", "particles": 1000, "in_body_max": 0, "crossings_self_max": 0, "crossings_between_max": 0,
          "strain_p99_pct": 4.0, "body_edges_max": 0}
    assert corpus.verdict(ok) == []
    assert "8 body edges through the cloth" in corpus.verdict({**ok, "body_edges_max": 8})[0]
    row = {**ok, "body_edges_max": 8, "character": "c", "pair": "p", "verdict": corpus.verdict({**ok, "body_edges_max": 8})}
    assert "body edges through cloth" in corpus.table([row]).splitlines()[0]
    r = {"status": "ok", "seam_gap_mm": 1.0, "in_colliders": 0, "in_body_pct": 0.1, "body_edges": 8, "fit_gap_cm": 0.5,
         "floor_cm": 3.0, "seconds": 1.0}
    text = matrix.table({"c": {"tshirt": r}})
    assert "body edges through cloth" in text.splitlines()[0] and "| 0.10 | 8 |" in text
