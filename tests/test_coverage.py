"""Collider coverage and excess (stages/coverage) against independent brute-force references."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from stages.coverage.measure import CollidersAtPose, collider_arrays, inside_matrix, measure_coverage
from stages.geometry.skin_distance import SkinDistance, distance_to_mesh_brute
from stages.geometry.winding import winding_numbers_brute
from stages.hulls.fit import fit_character
from stages.rig.skinning import skin
from tests.toy_rig import bend_motion, bent_tube


@pytest.fixture(scope="module")
def tube():
    c = bent_tube()
    motion = bend_motion(c, [0.0, 20.0, 45.0, 70.0])
    return c, motion


def _brute_distance(points, vertices, triangles):
    out = np.empty(points.shape[0])
    distance_to_mesh_brute(np.ascontiguousarray(points), vertices, triangles.astype(np.int64), out)
    return out


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2 ** 31 - 1), angle=st.floats(0.0, 90.0))
def test_tree_distance_equals_every_triangle_and_trimesh(seed, angle):
    c = bent_tube()
    v = skin(c, bend_motion(c, [angle]))[0]
    rng = np.random.default_rng(seed)
    p = rng.uniform(v.min(0) - 0.1, v.max(0) + 0.1, size=(300, 3))
    body = SkinDistance(c)
    body.refit(v)
    tree = body.distance(p)
    brute = _brute_distance(p, v, c.triangles)
    assert np.allclose(tree, brute, rtol=0, atol=1e-12)
    _, ref, _ = trimesh.proximity.closest_point(trimesh.Trimesh(v, c.triangles, process=False), p)
    # trimesh's own closest point is off by up to ~1e-5 m near the surface (seed 185982, angle 0.5:
    # 0.1096 mm here, 0.1209 mm from trimesh, and the brute force agrees with us to 1e-12)
    assert np.allclose(tree, ref, rtol=0, atol=5e-5)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2 ** 31 - 1), angle=st.floats(0.0, 90.0))
def test_tree_nearest_triangle_is_at_the_brute_force_distance(seed, angle):
    """SkinDistance.nearest_triangle: the triangle it names is as near as the nearest of all (ties
    may name another triangle at the same distance)."""
    from stages.geometry.skin_distance import point_triangle_distance2
    c = bent_tube()
    v = skin(c, bend_motion(c, [angle]))[0]
    p = np.random.default_rng(seed).uniform(v.min(0) - 0.1, v.max(0) + 0.1, size=(200, 3))
    body = SkinDistance(c)
    body.refit(v)
    tri = body.nearest_triangle(p)
    t = c.triangles
    got = np.sqrt([point_triangle_distance2(*q, v, *t[k]) for q, k in zip(p, tri)])
    assert np.allclose(got, _brute_distance(p, v, t), rtol=0, atol=1e-12)


def _reference_ball_centres(colliders, character, pose):
    """(B, 3) skinned ball centres, one weighted bone transform at a time (plain Python)."""
    b = colliders.balls
    out = np.zeros((b.radius.size, 3))
    for k in range(b.radius.size):
        for j, w in zip(b.joints[k], b.weights[k]):
            m = pose[j] @ character.inverse_bind[j]
            out[k] += w * (m[:3, :3] @ b.bind_center[k] + m[:3, 3])
    return out


def _reference_inside(points, colliders, pose, character=None):
    """(P, C) inside flags by plain numpy: hull planes / sphere distance in the posed bone frame
    (a skinned ball: distance to its centre skinned by _reference_ball_centres)."""
    cols = [(h.bone, h.simplified.planes, None) for h in colliders.hulls] + \
           [(s.joint, None, (s.center, s.radius)) for s in colliders.spheres if s.frame < 0]
    out = np.zeros((points.shape[0], len(cols) + sum(s.frame >= 0 for s in colliders.spheres)), bool)
    if colliders.balls is not None:
        centres = _reference_ball_centres(colliders, character, pose)
        for k in range(centres.shape[0]):
            out[:, len(cols) + k] = np.linalg.norm(points - centres[k], axis=1) <= colliders.balls.radius[k]
    for c, (bone, planes, sphere) in enumerate(cols):
        inv = np.linalg.inv(pose[bone])
        q = points @ inv[:3, :3].T + inv[:3, 3]
        if planes is not None:
            out[:, c] = (q @ planes[:, :3].T <= planes[:, 3]).all(axis=1)
        else:
            out[:, c] = np.linalg.norm(q - sphere[0], axis=1) <= sphere[1]
    return out


MODES = [("motion", "swept"), ("weights", "sphere"), ("motion", "balls")]


@pytest.mark.parametrize("mode", MODES)
def test_inside_colliders_equals_plain_numpy(tube, mode):
    c, motion = tube
    _, cs = fit_character(c, motion.joint_world, split=mode[0], flexible=mode[1])
    assert (cs.balls is not None and cs.balls.radius.size > 0) == (mode[1] == "balls")
    arrays = collider_arrays(cs)
    rng = np.random.default_rng(1)
    for f in range(motion.n_frames):
        p = rng.uniform([-0.4, -0.1, -0.2], [0.4, 0.8, 0.2], size=(4000, 3))
        got = inside_matrix(p, arrays, cs.frame_poses(c.inverse_bind, motion.joint_world[f])).astype(bool)
        assert (got == _reference_inside(p, cs, motion.joint_world[f], c)).all()


@pytest.mark.parametrize("mode", MODES)
def test_gridded_inside_tests_equal_every_pair_tested(tube, mode):
    # the cells list only the colliders whose bounding ball meets them: any / excluded / per-collider
    # counts must be those of the full matrix, for points inside, outside, on the balls' rims and far
    # off the grid
    c, motion = tube
    _, cs = fit_character(c, motion.joint_world, split=mode[0], flexible=mode[1])
    arrays = collider_arrays(cs)
    rng = np.random.default_rng(7)
    for f in range(motion.n_frames):
        pose = cs.frame_poses(c.inverse_bind, motion.joint_world[f])
        posed = CollidersAtPose(arrays, pose)
        rim = posed.wcenter[rng.integers(0, arrays.joint.size, 2000)]
        d = rng.normal(size=rim.shape)
        rim += d / np.linalg.norm(d, axis=1, keepdims=True) * arrays.bradius[rng.integers(0, arrays.joint.size, 2000), None]
        p = np.concatenate([rng.uniform([-0.4, -0.1, -0.2], [0.4, 0.8, 0.2], size=(4000, 3)), rim,
                            rng.uniform(-5.0, 5.0, size=(200, 3))])
        full = inside_matrix(p, arrays, pose).astype(bool)
        assert full.any() and not full.all()
        assert (posed.inside_any(p) == full.any(axis=1)).all()
        assert (posed.inside_counts(p) == full.sum(axis=0)).all()
        ex = rng.integers(-1, arrays.joint.size, p.shape[0])
        masked = full.copy()
        masked[np.arange(p.shape[0])[ex >= 0], ex[ex >= 0]] = False
        assert (posed.inside_any(p, exclude=ex) == masked.any(axis=1)).all()
        # a point that is not finite falls in no cell (no index computed from it): outside, no crash
        assert not posed.inside_any(np.array([[np.nan, 0.0, 0.0], [0.0, np.inf, 0.0]])).any()


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2 ** 31 - 1), spread=st.floats(0.01, 3.0))
def test_gridded_inside_tests_equal_every_pair_on_random_balls(seed, spread):
    # spheres of very different sizes (one cell per median ball, so the big ones span many cells)
    from stages.hulls.types import ColliderSet, SphereCollider
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 40))
    radii = np.exp(rng.uniform(np.log(0.005), np.log(0.5), n))
    from scipy.spatial.transform import Rotation
    spheres = tuple(SphereCollider(k, f"s{k}", rng.uniform(-spread, spread, 3), float(radii[k]), np.zeros((0, 3)))
                    for k in range(n))
    arrays = collider_arrays(ColliderSet(hulls=(), spheres=spheres, delta=0.0, min_triangles=4))
    pose = np.tile(np.eye(4), (n, 1, 1))    # one joint per sphere, each turned and moved its own way
    pose[:, :3, :3] = Rotation.random(n, random_state=seed).as_matrix()
    pose[:, :3, 3] = rng.uniform(-0.3, 0.3, (n, 3))
    posed = CollidersAtPose(arrays, pose)
    p = rng.uniform(-spread - 0.6, spread + 0.6, size=(3000, 3))
    full = inside_matrix(p, arrays, pose).astype(bool)
    assert (posed.inside_any(p) == full.any(axis=1)).all()
    assert (posed.inside_counts(p) == full.sum(axis=0)).all()


@pytest.mark.parametrize("mode", MODES)
def test_reported_figures_equal_a_brute_force_recount(tube, mode):
    """Coverage, shell and excess recomputed from the same samples with exact winding numbers
    (every triangle), plain-numpy collider tests and trimesh's closest points."""
    c, motion = tube
    _, cs = fit_character(c, motion.joint_world, split=mode[0], flexible=mode[1])
    rep = measure_coverage(c, motion, cs, frames=[0, 2, 3], interior_samples=3000, keep_samples=True, seed=3)
    v_all = skin(c, motion, rep.frames)
    for k, f in enumerate(rep.frames):
        s = rep.samples[k]
        v = v_all[k]
        w = np.empty(s["grid"].shape[0])
        winding_numbers_brute(s["grid"], v, c.triangles, w)
        in_body = w >= 0.5
        assert (in_body == s["in_body"]).all()
        assert in_body.sum() >= 3000
        any_col = _reference_inside(s["grid"], cs, motion.joint_world[f], c).any(axis=1)
        assert rep.coverage[k] == pytest.approx((in_body & any_col).sum() / in_body.sum(), abs=1e-12)
        assert rep.shell_share[k] == pytest.approx((~in_body & any_col).sum() / in_body.sum(), abs=1e-12)
        # skin exposed: vertices, triangle centroids and edge midpoints out of every collider
        edges = {tuple(sorted(e)) for t in c.triangles.tolist() for e in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))}
        skin_pts = np.concatenate([v, v[c.triangles].mean(axis=1), np.array([(v[a] + v[b]) / 2 for a, b in sorted(edges)])])
        out = ~_reference_inside(skin_pts, cs, motion.joint_world[f], c).any(axis=1)
        assert rep.skin_exposed[k] == pytest.approx(out.mean(), abs=1e-12)
        # excess: surface samples not inside another collider, outside the body, distance to the skin
        ins = _reference_inside(s["surface"], cs, motion.joint_world[f], c)
        ins[np.arange(ins.shape[0]), s["owner"]] = False
        ws = np.empty(s["surface"].shape[0])
        winding_numbers_brute(s["surface"], v, c.triangles, ws)
        outside = ~ins.any(axis=1) & (ws < 0.5)
        assert (outside == s["outside"]).all()
        _, d, _ = trimesh.proximity.closest_point(trimesh.Trimesh(v, c.triangles, process=False), s["surface"][outside])
        assert rep.excess_p95[k] == pytest.approx(np.percentile(d, 95), abs=1e-5)
        assert rep.excess_max[k] == pytest.approx(d.max(), abs=1e-5)
        assert rep.excess_p50[k] == pytest.approx(np.percentile(d, 50), abs=1e-5)


def test_a_missing_collider_shows_as_a_coverage_hole_named_in_the_warning(tube):
    c, motion = tube
    _, cs = fit_character(c, motion.joint_world)
    full = measure_coverage(c, motion, cs, frames=[0, 3], interior_samples=3000)
    assert full.coverage.min() > 0.995
    from dataclasses import replace
    dropped = cs.hulls[0].name
    holed = replace(cs, hulls=cs.hulls[1:])
    rep = measure_coverage(c, motion, holed, frames=[0, 3], interior_samples=3000)
    assert rep.coverage.max() < 0.8
    assert any("coverage" in w for w in rep.warnings())
    assert rep.shell_share.max() < full.shell_share.max()


def test_same_seed_same_figures(tube):
    c, motion = tube
    _, cs = fit_character(c, motion.joint_world)
    a = measure_coverage(c, motion, cs, frames=[1], interior_samples=2000, seed=5)
    b = measure_coverage(c, motion, cs, frames=[1], interior_samples=2000, seed=5)
    assert a.coverage.tolist() == b.coverage.tolist() and a.excess_max.tolist() == b.excess_max.tolist()


def test_a_skin_without_volume_is_one_clear_error_not_an_endless_refinement(tube):
    from dataclasses import replace

    from stages.errors import InputError
    c, motion = tube
    _, cs = fit_character(c, motion.joint_world)
    inside_out = replace(c, triangles=np.ascontiguousarray(c.triangles[:, ::-1]))
    with pytest.raises(InputError, match="encloses no volume"):
        measure_coverage(inside_out, motion, cs, frames=[0], interior_samples=3000)
