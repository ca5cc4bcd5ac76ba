"""Sewing on the built-in character: sewn garments are one oriented manifold, clear of the body."""
import numpy as np
import pytest

from stages.garments.library import library_pattern, make_garment
from stages.garments.measurements import garment_measurements
from stages.garments.sewing import merge_pairs
from stages.garments.types import STRETCH
from stages.geometry.mesh import boundary_loops
from tests.scene_setup import scene_parts


@pytest.fixture(scope="module")
def scene():
    from stages.hulls import fit_colliders
    from stages.maps.build import build_maps
    from stages.rig.procedural import BodyParams, procedural_character
    from stages.rig.regions import split_regions
    from stages.rig.skinning import sample_motion, skin
    c = procedural_character(BodyParams())
    m = sample_motion(c, "walk", np.arange(4) / 30.0)
    cols = fit_colliders(c, split_regions(c, threshold=0.9), delta=0.01, min_triangles=40, max_offset=0.02)
    return c, m, cols, build_maps(cols), skin(c, m, frames=[0])[0]


def _check_manifold(tri, n):
    e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    key = np.sort(e, axis=1)
    _, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    assert cnt.max() <= 2
    # consistent orientation: each interior edge is walked once in each direction
    _, dcnt = np.unique(e, axis=0, return_counts=True)
    assert dcnt.max() == 1
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    ncomp, _ = connected_components(coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)), directed=False)
    assert ncomp == 1
    assert np.unique(tri).size == n


@pytest.mark.parametrize("kind,openings", [("short_skirt", 2), ("long_skirt", 2), ("cape", 1)])
def test_sewn_garment_is_clean_and_clear_of_the_body(scene, kind, openings):
    from stages.geometry.winding import winding_number
    c, m, cols, maps, body = scene
    p = library_pattern(kind, garment_measurements(c, cols, m), edge_length=0.03)
    g, log, build = make_garment(p, c, m, cols, maps)
    _check_manifold(g.triangles, g.n_particles)
    assert len(boundary_loops(g.triangles)) == openings           # waist + hem; the cape's outline
    assert log.converged and log.gap_max[-1] <= 0.004
    assert np.all(winding_number(body, c.triangles, g.positions) < 0.5)
    # rest lengths come from the flat panels: a sewn skirt keeps the pattern's size
    stretch = g.kinds == STRETCH
    assert np.median(g.rest_lengths[stretch]) == pytest.approx(0.03, rel=0.15)
    assert (1 / g.inverse_mass[g.inverse_mass > 0]).sum() < p.density * sum(x.area for x in p.panels)
    assert abs(g.rest_lengths.sum() - g.rest_lengths.sum()) == 0
    assert g.attached.size > 0                                     # waistband / cape corners pinned
    # the sewing log: iteration 0 is the placed state; positions subsampled
    assert log.positions.shape[1] == build.placed_positions.shape[0] and log.logged[0] == 0


def test_merge_pairs_groups_chains():
    r = merge_pairs(6, np.array([[0, 3], [3, 5], [1, 2]]))
    assert r[0] == r[3] == r[5] and r[1] == r[2] and len(set(r.tolist())) == 3 and r.max() == 2


def sew_clear(scene, kind: str, n_openings: int):
    """Sew the library garment `kind` on the scene's character and check what every sewn garment
    must be: nothing inside the body, placed or sewn; one oriented manifold with `n_openings`
    boundary loops. Returns (garment, sewing log, measurements, loops, loop centres), the loops
    ordered by the height of their centre, lowest first."""
    from stages.geometry.winding import winding_number
    c, m, cols, maps, body = scene
    meas = garment_measurements(c, cols, m)
    g, log, build = make_garment(library_pattern(kind, meas), c, m, cols, maps)
    assert np.all(winding_number(body, c.triangles, build.placed_positions) < 0.5)
    assert np.all(winding_number(body, c.triangles, g.positions) < 0.5)
    _check_manifold(g.triangles, g.n_particles)
    loops = boundary_loops(g.triangles)
    assert len(loops) == n_openings
    centres = np.array([g.positions[lp].mean(axis=0) for lp in loops])
    order = np.argsort(centres[:, 1])
    return g, log, meas, [loops[k] for k in order], centres[order]


def test_tshirt_sews(scene):
    """The T-shirt sized to the colliders sews on the built-in character: every seam closed, nothing
    inside the body, one manifold with four openings (neck, hem, two sleeve ends)."""
    c, m = scene[:2]
    g, log, _, _, centres = sew_clear(scene, "tshirt", 4)
    assert log.converged and log.gap_max[-1] <= 0.004
    # the openings are where they belong: the neck on top, the hem lowest, the sleeve ends outside
    hem, neck = centres[0], centres[-1]
    cuffs = centres[1:3]
    assert neck[1] > m.joint_world[0][c.joint_names.index("chest"), 1, 3]
    assert abs(hem[0]) < 0.03 and abs(neck[0]) < 0.03
    assert sorted(np.sign(cuffs[:, 0])) == [-1, 1] and np.all(np.abs(cuffs[:, 0]) > 0.25)
    assert g.attached.size > 0


def test_a_collar_sewn_off_the_body_is_sewn_again_held(scene):
    """Sewing with a free collar can leave it off the body (the tall-slim and BVH T-shirts: its
    corners stand 3-4 cm off the hollow between neck and shoulders); then the garment is sewn again
    with the collar held where it was hugged, kept when its seams close and the collar sits closer.
    Here a band cut 1.35 x its hugged loop (loose) leaves the collar 2.4 cm out sewn free (at 1.1 the
    sewing, going on to its 2 mm target, settles it at 2.25 cm free, closer than held)."""
    import dataclasses
    import re

    from stages.geometry.skin_distance import SkinDistance
    from stages.garments.fit import FIT_GAP_MAX, signed_skin_distance
    c, m, cols, maps, skin0 = scene
    pattern = dataclasses.replace(library_pattern("tshirt", garment_measurements(c, cols, m)), fit_band=1.35)
    g, log, build = make_garment(pattern, c, m, cols, maps)
    held = [n for n in log.notes if n.startswith("fit edges held")]
    assert len(held) == 1, log.notes
    free_cm, held_cm = (float(v) for v in re.findall(r"([\d.]+) cm", held[0]))
    assert held_cm < free_cm and free_cm > FIT_GAP_MAX * 100
    assert log.converged and log.gap_max[-1] <= 0.004
    body = SkinDistance(c)
    body.refit(np.ascontiguousarray(skin0, np.float64))
    # the note's figure is the garment's: the collar of the sewn garment sits where it says
    assert abs(np.median(signed_skin_distance(body, g.positions[build.fit_vertices])) * 100 - held_cm) < 0.3


@pytest.mark.assets
@pytest.mark.parametrize("asset", ["CesiumMan.glb", "cmu_131_01_walk.bvh"])
def test_a_cape_is_dressed_without_passing_through_itself(assets_dir, asset):
    # its top gathered onto the neck folded it through itself while sewing (CesiumMan 19 edges, the
    # BVH's 28 at frame 0, kept by the simulation to the end); a garment without seams is sewn with
    # self collision
    from stages.hulls import fit_colliders
    from stages.maps.build import build_maps
    from stages.rig.regions import split_regions
    from stages.rig.skinning import rest_motion
    from stages.sim.audit import crossing_flags
    if asset.endswith(".bvh"):
        from stages.rig.bvh_character import load_bvh_character
        c = load_bvh_character(assets_dir / asset)
    else:
        from stages.rig.gltf import load_gltf
        c = load_gltf(assets_dir / asset)
    m = rest_motion(c, 2, 1 / 30)
    cols = fit_colliders(c, split_regions(c, threshold=0.9), delta=0.01, min_triangles=40, max_offset=0.02)
    g, log, build = make_garment(library_pattern("cape", garment_measurements(c, cols, m)), c, m, cols,
                                 build_maps(cols))
    tri = g.triangles
    edges = np.unique(np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1), axis=0)
    own, _, _ = crossing_flags(g.positions, edges, np.zeros(len(edges)), tri, np.zeros(len(tri)))
    assert own.sum() == 0
    # the top follows one bone of the torso: pinned to the nearest bones, its corners rode the upper
    # arms and the swinging arm tore the cape (CesiumMan diverged at frame 55, an edge 509 % long)
    pinned = np.unique(g.attach_joint[g.attach_joint >= 0])
    assert pinned.size == 1
    arm_joints = {j for j in range(c.n_joints) if "arm" in c.joint_names[j].lower()}
    assert int(pinned[0]) not in arm_joints
    # laid on the shoulders at its own width: stretched round 120 degrees of CesiumMan's T-posed
    # shoulders and arm roots, its top rows started 304 % long (p99; 3.8 % now)
    stretch = g.kinds == 0
    length = np.linalg.norm(np.diff(g.positions[g.springs[stretch]], axis=1)[:, 0], axis=1)
    if asset == "CesiumMan.glb":
        assert np.percentile(length / g.rest_lengths[stretch] - 1.0, 99) < 0.1


@pytest.mark.assets
def test_cesium_shorts_sew_closed_and_untangled(assets_dir, tmp_path):
    # CesiumMan's shorts, the scene starting 0.5 s into the walk: with bend springs as stiff as the
    # edges, the left inseam's hem end stalled at 4.7 mm from iteration 4 on (40 or 120 iterations
    # alike; tolerance 4 mm): "sewing did not close seam leg_l.under_a / leg_l.under_b"
    from pipeline.dressing import build_pattern_garment
    from stages.maps.build import build_maps
    p = tmp_path / "shorts.yaml"
    p.write_text(f"character: {{source: gltf, path: {assets_dir / 'CesiumMan.glb'}, clip: 0}}\n"
                 "frames: {start: 0.5, count: 30}\ngarments: [{type: pattern, kind: shorts}]\n")
    scene, c, m, cols = scene_parts(p)
    g, log, build = build_pattern_garment(scene, 0, c, m, cols, build_maps(cols))
    assert log.converged and log.gap_max[-1] <= 0.004
    assert any(n.startswith("bend stiffness") for n in log.notes)
    # and 3 edges of the right leg's inseam through the leg at the hem, after sewing (kept by the
    # simulation to the last frame), are moved back out (stages.garments.untangle)
    from tests.test_garments_untangle import crossing_count
    assert crossing_count(g.positions, g.triangles) == 0
    assert any(n.startswith("untangled") for n in log.notes)
