"""Degenerate geometry never crashes a run: every hull / OBB / map / coverage / placement path gets a
fallback (a thickened hull) or one InputError naming the item, and the sizes that grew with a big
body (a 9.55 m RiggedSimple: 65,430 balls, past 8 GB) are bounded."""
from __future__ import annotations

import numpy as np
import pytest

from stages.errors import InputError
from stages.hulls.fit import containment, fit_character, fit_hull
from stages.hulls.hull import convex_hull, mesh_volume
from stages.maps.build import build_hull_map, build_maps
from stages.rig.transforms import forward_kinematics
from stages.rig.types import Character, Motion
from tests.toy_rig import bent_tube

RNG = np.random.default_rng(7)
PLATE = np.c_[np.full(40, 0.3), RNG.uniform(-0.1, 0.1, (40, 2))]          # a robot's plate: all x the same

DEGENERATE = {
    "one point": np.array([[0.1, 0.2, 0.3]]),
    "one point repeated": np.tile([[0.1, 0.2, 0.3]], (9, 1)),
    "two points": np.array([[0.0, 0.0, 0.0], [0.0, 0.2, 0.0]]),
    "three points": np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.0, 0.1, 0.0]]),
    "four coplanar": np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.2, 0.1, 0.0], [0.0, 0.1, 0.0]]),
    "four points": np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0], [0.0, 0.0, 0.1]]),
    "same x": PLATE,
    "coplanar tilted": PLATE @ np.linalg.qr(RNG.normal(size=(3, 3)))[0].T,
    "collinear": np.outer(np.linspace(0.0, 1.0, 12), [0.2, 0.5, -0.1]),
    "duplicates": np.repeat(RNG.uniform(size=(5, 3)) * 0.1, 4, axis=0),
    "huge scale": RNG.uniform(size=(30, 3)) * 1e4,
    "tiny scale": RNG.uniform(size=(30, 3)) * 1e-6,
    "far from the origin": RNG.uniform(size=(30, 3)) * 0.1 + 1e6,
    "flat and far": PLATE + [1e5, -2e5, 3e5],
}


def _check_hull(mesh, points, tol):
    assert np.isfinite(mesh.vertices).all() and mesh.faces.shape[0] >= 4
    assert mesh_volume(mesh) > 0
    assert np.isfinite(mesh.planes).all()
    assert containment(points, mesh) <= tol


@pytest.mark.parametrize("name", sorted(DEGENERATE))
def test_hull_of_degenerate_points_is_a_thickened_hull(name):
    pts = DEGENERATE[name]
    t = 0.01 * max(float(np.ptp(pts, axis=0).max()), 1e-3)
    mesh = convex_hull(pts, source=f"bone {name!r}", flat_thickness=t)
    scale = float(np.abs(pts).max()) + t
    _check_hull(mesh, pts, 1e-9 * scale)
    # thickened by t across: the hull reaches t beyond the points in every direction across them
    if np.linalg.matrix_rank(pts - pts.mean(axis=0), tol=1e-12 * scale) < 3:
        assert np.ptp(mesh.vertices, axis=0).min() >= 2 * t * (1 - 1e-6)


@pytest.mark.parametrize("name", ["one point", "one point repeated", "two points", "three points", "same x", "collinear"])
def test_without_a_thickness_degenerate_points_are_one_line(name):
    with pytest.raises(InputError) as err:
        convex_hull(DEGENERATE[name], source="bone 'plate'")
    msg = str(err.value)
    assert "bone 'plate'" in msg and "\n" not in msg
    assert any(w in msg for w in ("distinct", "collinear", "coplanar"))


@pytest.mark.parametrize("bad, what", [
    (np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, np.nan, 0.0], [0.0, 0.0, 1.0]]), "non-finite"),
    (np.array([[0.0, 0.0, np.inf]] * 5), "non-finite"),
    (np.zeros((0, 3)), "no points"),
])
def test_bad_points_name_the_region(bad, what):
    with pytest.raises(InputError) as err:
        fit_hull(bad, 0.01, 40, source="hull 'visor'")
    assert "hull 'visor'" in str(err.value) and what in str(err.value)


@pytest.mark.parametrize("name", sorted(DEGENERATE))
def test_fit_hull_and_its_map_on_degenerate_regions(name):
    pts = DEGENERATE[name]
    size = float(np.ptp(pts, axis=0).max())
    delta = 0.01 * max(size, 1e-3)
    raw, inflated, simplified, report = fit_hull(pts, delta, 40, source=f"hull {name!r}", max_offset=0.5 * delta)
    scale = float(np.abs(pts).max()) + delta
    for mesh in (raw, inflated, simplified):
        _check_hull(mesh, pts, 1e-7 * scale)
    assert report.contains_region or report.worst_violation <= 1e-7 * scale
    # the map: an OBB holding every vertex, finite planar meshes and cells
    hm = build_hull_map(simplified)
    assert np.isfinite(hm.center).all() and np.isfinite(hm.axes).all() and (hm.half_extents > 0).all()
    assert np.allclose(hm.axes @ hm.axes.T, np.eye(3), atol=1e-9)
    local = (simplified.vertices - hm.center) @ hm.axes.T
    assert (np.abs(local) <= hm.half_extents * (1 + 1e-9) + 1e-12 * scale).all()
    assert hm.upper_faces.shape[0] > 0 and hm.lower_faces.shape[0] > 0
    assert hm.cell_tris.size > 0 and hm.cell_start[-1] == hm.cell_tris.size


def _random_set(rng, kind):
    """A random degenerate or nearly degenerate point set, turned and moved off the origin."""
    n = int(rng.integers(1, 60))
    s, thin = 10.0 ** rng.uniform(-4, 2), 10.0 ** rng.uniform(-9, -1)
    p = [lambda: rng.normal(size=(n, 3)) * [1, 1, 0],                            # coplanar
         lambda: np.outer(rng.normal(size=n), rng.normal(size=3)),               # collinear
         lambda: np.repeat(rng.normal(size=(max(1, n // 10), 3)), 10, axis=0),   # few points, repeated
         lambda: rng.normal(size=(n, 3)) * [1, thin, 1],                         # nearly flat
         lambda: rng.normal(size=(n, 3)) * [1, thin, thin],                      # nearly collinear
         lambda: rng.uniform(size=(n, 3)).round(1),                              # on a grid: coplanar facets
         lambda: np.c_[rng.normal(size=(n, 1)), np.round(rng.normal(size=(n, 1))) * thin,
                       rng.normal(size=(n, 1))]][kind]()                         # a few thin layers
    turn = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    return (p @ turn.T) * s + rng.normal(size=3) * s * 10 ** rng.uniform(0, 4), s


def test_random_nearly_degenerate_regions_fit_and_map():
    """Thin, far-off, gridded sets: Qhull's slivers and joggled facets folded the inflated hull (up to
    0.3 % of its size) and build_hull_map refused it; every one now gives a convex, containing hull."""
    rng = np.random.default_rng(11)
    for i in range(140):
        pts, s = _random_set(rng, i % 7)
        delta = 0.01 * s
        _, _, simplified, report = fit_hull(pts, delta, 40, source=f"case {i}", max_offset=0.5 * delta)
        assert report.worst_violation <= 1e-6 * (np.abs(pts).max() + delta), i
        hm = build_hull_map(simplified)
        assert np.isfinite(hm.planes).all() and (hm.half_extents > 0).all(), i


def test_when_qhull_gives_nothing_usable_the_hull_is_the_box(monkeypatch):
    from stages.hulls import hull
    pts = DEGENERATE["far from the origin"]
    monkeypatch.setattr(hull, "_qhull_mesh", lambda points, shift, options=None: None)
    box = convex_hull(pts, source="bone 'x'")
    assert box.vertices.shape == (8, 3) and box.faces.shape == (12, 3)
    _check_hull(box, pts, 1e-15 * np.abs(pts).max())     # planes' rounding at 1e6 m
    assert hull._convexity(box) <= 1e-12 * np.abs(pts).max()


def test_a_map_failure_names_the_collider():
    from dataclasses import replace

    from stages.hulls.types import ConvexMesh
    tube = bent_tube()
    from tests.toy_rig import bend_motion
    _, colliders = fit_character(tube, bend_motion(tube, [0.0, 30.0]).joint_world, split="weights",
                                 flexible="sphere", delta=0.01)
    h = colliders.hulls[0]
    # a simplified mesh with a vertex off its convex surface (a corrupted collider)
    v = h.simplified.vertices.copy()
    v[0] *= 0.5
    bad = replace(colliders, hulls=(replace(h, simplified=ConvexMesh(v, h.simplified.faces)),) + colliders.hulls[1:])
    with pytest.raises(InputError) as err:
        build_maps(bad)
    assert f"collider {h.name!r}" in str(err.value) and "not convex" in str(err.value) and "\n" not in str(err.value)
    from stages.maps.build import surface_obb
    from stages.checks import ContractError
    v[0] = np.nan        # ConvexMesh refuses it; the OBB of raw arrays says so too
    with pytest.raises(ContractError, match="non-finite"):
        surface_obb(v, h.simplified.faces)


def test_swept_points_survive_a_qhull_failure(monkeypatch):
    """Points Qhull rejects after the rank test are kept whole (convex_hull then thickens them)."""
    from scipy.spatial import QhullError

    from stages.hulls import swept
    from tests.toy_rig import bend_motion
    tube = bent_tube()
    motion = bend_motion(tube, [0.0, 20.0, 40.0])
    from stages.rig.skinning import skin_poses
    skinned = skin_poses(tube, motion.joint_world)
    idx = np.flatnonzero(np.abs(tube.vertices[:, 1] - 0.3) < 0.05)
    kept = swept.swept_points(tube, motion.joint_world, skinned, 1, idx)

    def fail(*a, **k):
        raise QhullError("QH6013 qhull input error: input is less than 3-dimensional since all points have the same x")
    monkeypatch.setattr(swept, "ConvexHull", fail)
    every = swept.swept_points(tube, motion.joint_world, skinned, 1, idx)
    assert every.shape[0] > kept.shape[0]
    assert {tuple(p) for p in kept} <= {tuple(p) for p in every}


# -- a character with a flat rigid region (a robot's plate) -----------------------------------------
def plated_tube() -> Character:
    """The bent tube plus a square plate (zero thickness, both sides) on a third bone 'plate', child of
    'tip', beside the tube in the plane x = 0.2: its rigid region has every x the same."""
    tube = bent_tube()
    n = tube.vertices.shape[0]
    plate = np.array([[0.2, 0.35, -0.1], [0.2, 0.35, 0.1], [0.2, 0.55, 0.1], [0.2, 0.55, -0.1],
                      [0.2, 0.45, 0.0]])
    tris = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    tris = np.concatenate([tris, tris[:, ::-1]]) + n
    rest = np.concatenate([tube.rest_local, np.eye(4)[None]])
    rest[2, :3, 3] = [0.2, 0.15, 0.0]           # model (0.2, 0.45, 0) under the tip at (0, 0.3, 0)
    parents = np.array([-1, 0, 1], np.int32)
    joints = np.concatenate([tube.skin_joints, np.tile(np.array([2, 1], np.int32), (5, 1))])
    weights = np.concatenate([tube.skin_weights, np.tile([1.0, 0.0], (5, 1))])
    return Character(name="plated tube", vertices=np.concatenate([tube.vertices, plate]),
                     triangles=np.concatenate([tube.triangles, tris]).astype(np.int32),
                     primitive_ids=np.zeros(n + 5, np.int32), joint_names=("base", "tip", "plate"), parents=parents,
                     rest_local=rest, inverse_bind=np.linalg.inv(forward_kinematics(parents, rest)),
                     skin_joints=joints, skin_weights=weights, source="test")


def plated_motion(character: Character, angles_deg) -> Motion:
    from scipy.spatial.transform import Rotation
    a = np.asarray(angles_deg, float)
    local = np.tile(character.rest_local, (a.size, 1, 1, 1))
    local[:, 1, :3, :3] = Rotation.from_euler("z", a[:, None], degrees=True).as_matrix()
    return Motion("bend", np.arange(a.size) / 30.0, forward_kinematics(character.parents, local), np.zeros((a.size, 3)))


def _plate_held(ch, motion, colliders):
    """Are the plate's vertices inside some collider at frame 0?"""
    from stages.garments.placement import near_colliders
    from stages.garments.types import bind_pose
    return near_colliders(bind_pose(ch, motion, colliders), ch.vertices[-5:], 1e-9).all()


@pytest.mark.parametrize("split, flexible", [("weights", "sphere"), ("motion", "balls"), ("motion", "swept")])
def test_a_flat_rigid_region_through_the_colliders_and_maps(split, flexible):
    """The split turns the flat plate's region flexible (regions._merge_small); its colliders hold it."""
    ch = plated_tube()
    motion = plated_motion(ch, [0.0, 15.0, 30.0, 45.0])
    regions, colliders = fit_character(ch, motion.joint_world, split=split, flexible=flexible, delta=0.01)
    assert not regions.rigid[-5:].any() and any("flat" in n for n in regions.notes)
    for h in colliders.hulls:
        assert np.isfinite(h.simplified.vertices).all() and mesh_volume(h.simplified) > 0
        assert h.report.contains_region, h.name
    assert _plate_held(ch, motion, colliders)
    maps = build_maps(colliders)
    assert len(maps.maps) == len(colliders.hulls)
    for m in maps.maps:
        assert np.isfinite(m.center).all() and (m.half_extents > 0).all()


def test_a_flat_region_kept_rigid_gets_a_slab_hull_and_a_map():
    """A split that keeps the plate rigid (no merge): its hull is the plate thickened by delta."""
    from stages.hulls.fit import fit_colliders
    from stages.rig.regions import split_regions
    ch = plated_tube()
    motion = plated_motion(ch, [0.0, 30.0])
    regions = split_regions(ch, flat_tol=-1.0)          # every region "hull ready": the plate stays rigid
    assert regions.rigid[-5:].all() and 2 in regions.hull_bones
    colliders = fit_colliders(ch, regions, delta=0.01, flexible="sphere")
    plate = [h for h in colliders.hulls if h.bone == 2][0]
    assert plate.report.contains_region and mesh_volume(plate.raw) > 0
    local = plate.raw.vertices
    assert np.ptp(local, axis=0).min() == pytest.approx(0.02, rel=1e-6)     # +-delta across the plate
    assert _plate_held(ch, motion, colliders)
    m = build_maps(colliders).maps[list(colliders.hulls).index(plate)]
    assert np.isfinite(m.axes).all() and m.half_extents.min() > 0.01


def test_a_flat_region_through_coverage():
    from stages.coverage.measure import measure_coverage
    ch = plated_tube()
    motion = plated_motion(ch, [0.0, 30.0])
    _, colliders = fit_character(ch, motion.joint_world, split="weights", flexible="sphere", delta=0.01)
    report = measure_coverage(ch, motion, colliders, interior_samples=3000)
    for key in ("coverage", "excess_p95", "shell_share", "skin_exposed"):
        assert np.isfinite(getattr(report, key)).all()
    assert report.coverage.min() > 0.9


def test_coverage_of_a_body_without_volume_is_one_line_not_a_huge_grid(monkeypatch):
    """A flat 'body' (a double-sided square): its volume ~0 asked for a grid of 0.3 mm cells over the
    whole box; the cells are capped and the stage says the mesh encloses no volume."""
    from stages.coverage import measure
    from stages.hulls.types import ColliderSet, SphereCollider
    v = np.array([[-0.5, 0.0, -0.5], [0.5, 0.0, -0.5], [0.5, 0.0, 0.5], [-0.5, 0.0, 0.5]])
    tri = np.array([[0, 1, 2], [0, 2, 3], [0, 2, 1], [0, 3, 2]], np.int32)
    rest = np.eye(4)[None]
    flat = Character(name="sheet", vertices=v, triangles=tri, primitive_ids=np.zeros(4, np.int32),
                     joint_names=("root",), parents=np.array([-1], np.int32), rest_local=rest,
                     inverse_bind=rest.copy(), skin_joints=np.zeros((4, 1), np.int32), skin_weights=np.ones((4, 1)))
    motion = Motion("rest", np.zeros(1), rest[None].copy(), np.zeros((1, 3)))
    cs = ColliderSet(hulls=(), spheres=(SphereCollider(joint=0, name="root", center=np.zeros(3), radius=0.1,
                                                      region_points=np.zeros((0, 3))),), delta=0.01, min_triangles=40)
    sizes = []
    grid = measure._body_grid
    monkeypatch.setattr(measure, "_body_grid", lambda body, box, h, balls, rng: (
        sizes.append(np.prod(np.ceil((box[1] - box[0]) / h))), grid(body, box, h, balls, rng))[1])
    with pytest.raises(InputError) as err:
        measure.measure_coverage(flat, motion, cs)
    assert "no volume" in str(err.value)
    assert max(sizes) <= measure.MAX_GRID_CELLS * 1.1       # whole blocks of BLOCK^3 cells


# -- placement and triangulation -----------------------------------------------------------------------
def test_placement_on_coincident_joints_is_one_line():
    from types import SimpleNamespace

    from stages.garments import placement
    from stages.rig.humanoid import Limb
    ch = SimpleNamespace(joint_names=("hip", "knee", "ankle"), parents=np.array([-1, 0, 1]), root_joint=0)
    origins = np.array([[0.1, 0.9, 0.0], [0.1, 0.9, 0.0], [0.1, 0.1, 0.0]])
    pose = np.tile(np.eye(4), (3, 1, 1))
    pose[:, :3, 3] = origins
    orig = placement.limb
    try:
        placement.limb = lambda character, kind, side: Limb((0, 1, 2), (0, 1, 2), origins, frozenset({0, 1, 2}))
        with pytest.raises(InputError) as err:
            placement.body_axis(ch, "leg_l", pose)
    finally:
        placement.limb = orig
    assert "'hip'" in str(err.value) and "'knee'" in str(err.value) and "same place" in str(err.value)


def test_segment_distance_within_reach_is_the_full_one():
    from stages.garments.triangulate import _inside, _segment_distance
    rng = np.random.default_rng(3)
    ang = np.sort(rng.uniform(0, 2 * np.pi, 300))
    poly = np.c_[np.cos(ang), 0.6 * np.sin(ang)] * rng.uniform(0.8, 1.2, (300, 1))
    pts = rng.uniform(-1.3, 1.3, (5000, 2))
    full = _segment_distance(pts, poly)
    for reach in (0.01, 0.05, 0.3):
        near = _segment_distance(pts, poly, reach)
        within = full <= reach
        assert np.array_equal(near[within], full[within])
        assert (near[~within] > reach).all()
    # the chunked even-odd test: the same answers
    from stages.garments import triangulate
    big = _inside(poly, pts)
    old, triangulate.INSIDE_CHUNK = triangulate.INSIDE_CHUNK, 64
    try:
        assert np.array_equal(_inside(poly, pts), big)
    finally:
        triangulate.INSIDE_CHUNK = old
    assert 0.2 < big.mean() < 0.4


def test_near_colliders_without_the_matrix_gives_the_same_answers(monkeypatch):
    """Many colliders: hulls one by one and spheres only near their centres, the matrix's answers."""
    from stages.garments import placement
    from stages.garments.types import bind_pose
    from tests.toy_rig import bend_motion
    tube = bent_tube()
    motion = bend_motion(tube, [0.0, 20.0, 40.0])
    _, colliders = fit_character(tube, motion.joint_world, split="motion", flexible="balls", delta=0.01)
    assert colliders.hulls and len(colliders.spheres) > 3
    bind = bind_pose(tube, motion, colliders)
    pts = np.random.default_rng(5).uniform([-0.12, -0.05, -0.12], [0.12, 0.65, 0.12], (4000, 3))
    for gap in (0.0, 0.004, -0.002):
        full = placement.near_colliders(bind, pts, gap)
        monkeypatch.setattr(placement, "MAX_DISTANCES", 10)
        pruned = placement.near_colliders(bind, pts, gap)
        monkeypatch.setattr(placement, "MAX_DISTANCES", 16_000_000)
        assert 0.05 < full.mean() < 0.95
        assert np.array_equal(full, pruned)


# -- sizes bounded for a 10 m body -----------------------------------------------------------------------
def test_ball_candidates_and_skin_samples_are_bounded_for_a_ten_metre_body():
    from stages.hulls import balls

    class Inside:            # the body filter: a cylinder of radius 1 m, 10 m tall (RiggedSimple's size)
        def inside(self, p):
            return (np.hypot(p[:, 0], p[:, 2]) < 1.0) & (p[:, 1] > 0) & (p[:, 1] < 10.0)

    ang = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    ring = np.c_[np.cos(ang), np.zeros(40), np.sin(ang)]
    skin = np.concatenate([ring + [0, y, 0] for y in np.linspace(0, 10, 41)])
    scale = balls.body_scale(skin)
    grid = balls.candidate_grid(skin, Inside(), balls.BALL_SPACING * scale, balls.NEAR_FLEXIBLE * scale,
                                max_grid=400_000, max_candidates=20_000)
    assert 0 < grid.shape[0] <= 20_000
    assert Inside().inside(grid).all()
    # the spacing grew only as much as needed: a tenth of it would be over the cap
    tris = np.array([[i, i + 1, i + 40] for i in range(40 * 40 - 1)])
    n, step = balls.skin_sample_counts(skin, tris, balls.SKIN_STEP * scale, most=30_000)
    assert ((n + 1) * (n + 2) // 2).sum() <= 30_000 and step > balls.SKIN_STEP * scale
    n0, step0 = balls.skin_sample_counts(skin, tris, balls.SKIN_STEP * scale, most=10 ** 9)
    assert step0 == balls.SKIN_STEP * scale and ((n0 + 1) * (n0 + 2) // 2).sum() > 30_000


def test_too_many_ball_pairs_is_one_line_before_the_memory_goes(monkeypatch):
    from stages.hulls import balls
    from tests.toy_rig import bend_motion
    tube = bent_tube()
    motion = bend_motion(tube, [0.0, 20.0, 40.0])
    monkeypatch.setattr(balls, "MAX_PAIRS", 1000)
    with pytest.raises(InputError) as err:
        fit_character(tube, motion.joint_world, split="motion", flexible="balls", delta=0.01)
    msg = str(err.value)
    assert "'tube'" in msg and "more than 1,000" in msg and "colliders.delta" in msg and "\n" not in msg


def test_riggedsimple_ball_fit_is_bounded(assets_dir, monkeypatch):
    """RiggedSimple (a 9.55 m bending cylinder, every vertex flexible) had 775,705 skin samples and
    65,430 balls (2.6 GB in the colliders stage, past 8 GB in the garments stage): every size of the
    fit is capped now."""
    from stages.hulls import balls
    from stages.rig.gltf import load_gltf
    from stages.rig.skinning import sample_motion
    ch = load_gltf(assets_dir / "RiggedSimple.glb")
    motion = sample_motion(ch, 0, np.arange(30) / 30.0)
    seen = []
    real = balls.pairs_in_reach

    def recording(centers, targets, reach, cell):
        out = real(centers, targets, reach, cell)
        seen.append((centers.shape[1], targets.shape[1], out[1].size))
        return out
    monkeypatch.setattr(balls, "pairs_in_reach", recording)
    _, colliders = fit_character(ch, motion.joint_world, split="motion", flexible="balls", delta=0.01)
    (candidates, _, pairs), (skin_samples, _, skin_pairs) = seen
    assert candidates <= balls.MAX_CANDIDATES and skin_samples <= balls.MAX_SKIN_SAMPLES
    assert max(pairs, skin_pairs) <= balls.MAX_PAIRS
    assert 0 < len(colliders.spheres) < 10_000


def test_a_panel_too_big_for_its_edge_length_is_one_line():
    from stages.garments.library import square
    from stages.garments.triangulate import MAX_PANEL_VERTICES, triangulate_pattern
    ok = triangulate_pattern(square({"height": 1.75}, size=1.0))
    assert 1000 < ok.uv.shape[0] < MAX_PANEL_VERTICES
    with pytest.raises(InputError) as err:
        triangulate_pattern(square({"height": 1.75}, size=12.0, name="tarp"))
    msg = str(err.value)
    assert "pattern 'tarp' panel 'square'" in msg and "more than 100,000" in msg and "edge_length" in msg


def test_cross_sections_of_no_levels_is_one_line():
    from stages.garments.placement import BodyAxis, _cross_sections
    axis = BodyAxis(np.zeros(3), np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]))
    pts = np.random.default_rng(0).normal(size=(50, 3)) * 0.01
    assert _cross_sections(pts, axis, np.arange(-0.01, 0.011, 0.01), 0.0, True).shape == (3, 2)
    with pytest.raises(InputError, match="no levels"):
        _cross_sections(pts, axis, np.arange(0.02, 0.015, 0.01), 0.0, True)     # a 1.5 cm CesiumMan's skirt range


@pytest.mark.parametrize("name", ["one point", "two points", "same x", "collinear", "duplicates", "tiny scale"])
def test_body_cross_sections_of_degenerate_points(name):
    """The placement's cross-section ellipses (also the garment measurements' girths) of degenerate
    body points: finite, at least the 1 cm floor, never shrinking downwards for the hips."""
    from stages.garments.placement import BodyAxis, _cross_sections
    axis = BodyAxis(np.zeros(3), np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]))
    pts = DEGENERATE[name]
    levels = np.arange(-0.05, 0.3, 0.01)
    ab = _cross_sections(pts, axis, levels, 0.005, True)
    assert ab.shape == (levels.size, 2) and np.isfinite(ab).all() and (ab >= 0.015 - 1e-12).all()
    assert (np.diff(ab, axis=0) <= 1e-12).all()


def test_surface_samples_of_a_flat_hull():
    """A collider of zero area (every vertex in one plane) gets samples on its faces, not a division by 0."""
    from types import SimpleNamespace

    from stages.coverage.measure import surface_samples
    from stages.hulls.types import ConvexMesh
    flat = ConvexMesh(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]),
                      np.array([[0, 1, 2], [1, 3, 2], [0, 2, 1], [1, 2, 3]], np.int32))
    cs = SimpleNamespace(hulls=[SimpleNamespace(simplified=flat)], spheres=[])
    pts, areas = surface_samples(cs, 0.1, np.random.default_rng(0))
    assert areas[0] > 0 and pts[0].shape[0] >= 64 and np.isfinite(pts[0]).all()
    zero = ConvexMesh(np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]]),
                      np.array([[0, 1, 2], [1, 3, 2], [0, 2, 1], [1, 2, 3]], np.int32))
    pts, areas = surface_samples(SimpleNamespace(hulls=[SimpleNamespace(simplified=zero)], spheres=[]), 0.1,
                                 np.random.default_rng(0))
    assert areas[0] == 0 and np.isfinite(pts[0]).all() and (pts[0][:, 1:] == 0).all()
