"""Shorts and trousers on the built-in character: seat + two leg tubes, three openings (waist,
two leg hems), waistband pinned to the pelvis, clear of the body before and after sewing."""
import numpy as np
import pytest

from stages.garments.library import KINDS, library_pattern
from stages.garments.measurements import garment_measurements
from stages.garments.sewing import merge_pairs
from stages.garments.triangulate import triangulate_pattern
from stages.geometry.mesh import boundary_loops
from tests.test_garments_sewing import _check_manifold, scene, sew_clear  # noqa: F401  (module fixture)


def _run_length(pattern, panel, edge):
    p = pattern.panel(panel)
    return p.edge_length(p.edge_index(edge))


@pytest.mark.parametrize("kind", ["shorts", "trousers"])
def test_pants_pattern_topology_and_sizes(scene, kind):
    """Without sewing: both sides of every seam are equally long, merging the seam pairs gives one
    oriented manifold with exactly three openings, and the seat clears what the colliders need."""
    c, m, cols, maps, body = scene
    meas = garment_measurements(c, cols, m)
    p = library_pattern(kind, meas, edge_length=0.03)
    assert kind in KINDS
    for s in p.seams:
        la = sum(_run_length(p, s.a.panel, e) for e in s.a.edges)
        lb = sum(_run_length(p, s.b.panel, e) for e in s.b.edges)
        assert la == pytest.approx(lb, rel=1e-3)
    flat = triangulate_pattern(p)
    remap = merge_pairs(flat.uv.shape[0], flat.seam_pairs)
    tri = remap[flat.triangles]
    _check_manifold(tri, remap.max() + 1)
    assert len(boundary_loops(tri)) == 3
    seat = 4 * _run_length(p, "front", "hem_l")
    assert seat >= max(meas["hips"], meas["clear_seat"]) - 1e-9
    assert meas["crotch_y"] < meas["hips_y"]


def _sew_and_check(scene, kind):
    c = scene[0]
    g, log, meas, loops, centres = sew_clear(scene, kind, 3)
    waist, hems = centres[-1], centres[:2]
    # the waist on top near the waist height, the hems below the crotch, one on each leg
    assert waist[1] == pytest.approx(min(meas["waist_y"], meas["skirt_top"]), abs=0.03)
    assert np.all(hems[:, 1] < meas["crotch_y"] - 0.1)
    assert sorted(np.sign(hems[:, 0])) == [-1, 1]
    # the waistband is pinned to the pelvis (root)
    assert np.all(g.attach_joint[loops[-1]] == c.root_joint)
    return g, log, meas


def test_shorts_sew(scene):
    g, log, meas = _sew_and_check(scene, "shorts")
    assert log.converged and log.gap_max[-1] <= 0.004


@pytest.fixture(scope="module")
def rest_scene():
    """The built-in character dressed as scenes dress it (frames.blend_in): on its bind pose, with
    the default colliders fitted over the walk it then blends into."""
    from stages.hulls.fit import fit_character
    from stages.maps.build import build_maps
    from stages.rig.procedural import BodyParams, procedural_character
    from stages.rig.skinning import sample_motion, skin
    c = procedural_character(BodyParams())
    m = sample_motion(c, "walk", np.arange(20) / 30.0, blend_frames=15)
    _, cols = fit_character(c, m.joint_world, delta=0.01)
    return c, m, cols, build_maps(cols), skin(c, m, frames=[0])[0]


def test_trousers_sew(rest_scene):
    """Trousers sew on the bind pose. (On the walk's first frame, the left leg's inseam buckles
    beside the bent right knee and stalls at ~5.5 mm: scenes dress on the bind pose and blend in.)"""
    g, log, meas = _sew_and_check(rest_scene, "trousers")
    assert log.converged and log.gap_max[-1] <= 0.004


def test_a_garment_worn_over_others_is_measured_round_them(scene):
    """under (points of the garments worn under it) enters the slab girths only: a ring of radius R
    round the body at the hip line gives clear_hips = its hull perimeter (72-gon, 2 n R sin(pi/n))
    + 2 pi clearance, clear_waist / clear_chest (other heights) and every other measure unchanged;
    the T-shirt cut from it is wider at the hem."""
    c, m, cols, maps, body = scene
    base = garment_measurements(c, cols, m)
    n, r = 72, 0.5 * base["clear_hips"] / np.pi + 0.03
    a = np.arange(n) * 2 * np.pi / n
    root = m.joint_world[0][c.root_joint, :3, 3]
    ring = np.stack([root[0] + r * np.cos(a), np.full(n, base["hips_y"]), root[2] + r * np.sin(a)], axis=1)
    over = garment_measurements(c, cols, m, under=ring)
    clearance = 0.008
    assert over["clear_hips"] == pytest.approx(2 * n * r * np.sin(np.pi / n) + 2 * np.pi * clearance, rel=1e-9)
    assert over["clear_hips"] > base["clear_hips"] + 0.1
    assert {k: v for k, v in over.items() if k != "clear_hips"} == {k: v for k, v in base.items() if k != "clear_hips"}
    hem = [4 * _run_length(library_pattern("tshirt", meas), "front", "hem") for meas in (base, over)]
    assert hem[1] > hem[0]
