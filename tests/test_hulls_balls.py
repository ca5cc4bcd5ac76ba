"""Skinned balls (stages/hulls/balls.py) against independent references."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings, strategies as st
from scipy.sparse import csr_matrix

from stages.hulls.balls import _greedy_cover, ball_check_poses, fit_balls, skin_points
from stages.rig.motion_range import bone_deviation
from stages.rig.regions import split_by_motion
from stages.rig.skinning import skin_poses


def _walk():
    from stages.rig.procedural import procedural_character
    from stages.rig.skinning import sample_motion
    c = procedural_character()
    clip = c.clip("walk")
    poses = sample_motion(c, "walk", clip.times[::6] - clip.times[0]).joint_world
    return c, poses, skin_poses(c, poses)


def test_ball_centres_skin_like_vertices():
    """skin_points equals a plain-Python linear-blend skinning of random points and influences, for
    many poses and for one pose (no leading axis)."""
    c, poses, _ = _walk()
    rng = np.random.default_rng(3)
    pts = c.vertices[rng.integers(0, c.vertices.shape[0], 40)] + rng.normal(0, 0.01, (40, 3))
    joints = rng.integers(0, c.n_joints, (40, 3))
    weights = rng.random((40, 3))
    weights /= weights.sum(axis=1, keepdims=True)
    got = skin_points(pts, joints, weights, c.inverse_bind, poses)
    assert got.shape == (poses.shape[0], 40, 3)
    for f in (0, poses.shape[0] - 1):
        for p in range(40):
            want = np.zeros(3)
            for k in range(3):
                m = poses[f, joints[p, k]] @ c.inverse_bind[joints[p, k]]
                want += weights[p, k] * (m[:3, :3] @ pts[p] + m[:3, 3])
            assert np.allclose(got[f, p], want, atol=1e-12)
    assert np.allclose(skin_points(pts, joints, weights, c.inverse_bind, poses[2]), got[2], atol=1e-12)


def test_balls_hold_every_flexible_vertex_they_claim_at_every_check_pose():
    """Brute force: every flexible vertex not listed as unheld is within radius - (1 - cover) delta
    of some ball centre at every check pose; every ball centre is inside the skinned body there and
    its ball stands at most the loosest slack + delta out of the skin."""
    from stages.geometry.skin_distance import SkinDistance
    from stages.geometry.skin_distance import distance_to_mesh_brute
    from stages.geometry.winding import winding_number
    c, poses, x = _walk()
    delta, cover = 0.01, 0.6
    split = split_by_motion(c, bone_deviation(c, poses, x), 0.005)
    slack = (0.005, 0.01)
    balls = fit_balls(c, split, poses, x, SkinDistance(c), delta=delta, cover=cover, slack=slack)
    assert balls.radius.size > 0
    flex = np.setdiff1d(np.flatnonzero(~split.rigid), balls.unheld)
    assert flex.size > 0
    inner = balls.radius.size - balls.on_skin                      # the balls inside the body
    centers = balls.centers(c.inverse_bind, poses)[:, :inner]      # (F, B, 3)
    reach = balls.radius[:inner] - (1 - cover) * delta
    for f in ball_check_poses(poses.shape[0]):
        d = np.linalg.norm(x[f, flex][:, None] - centers[f][None], axis=2)
        assert (d <= reach[None] + 1e-12).any(axis=1).all(), f
        assert (winding_number(x[f], c.triangles, centers[f]) >= 0.5).all(), f
        depth = np.zeros(centers.shape[1])        # brute force over every triangle
        distance_to_mesh_brute(centers[f], x[f], c.triangles.astype(np.int64), depth)
        assert (balls.radius[:inner] <= depth + max(slack) + delta + 1e-9).all(), f   # stands out at most slack + delta


def test_skin_balls_hold_the_skin_no_ball_inside_the_body_holds():
    """With no slack (balls inside the body may not stand out of the skin) some skin of the walk's
    flexible triangles (vertices, centroids, edge midpoints) is out of every ball inside the body at
    a check pose; the skin balls put all of it inside some ball. Each skin ball sits on the bind-pose
    skin and, at every check pose, within radius - delta of the skinned skin (it stands out of the
    skin by at most its radius, as a hull stands out by delta). Brute force over every triangle."""
    from stages.geometry.skin_distance import SkinDistance
    from stages.geometry.skin_distance import distance_to_mesh_brute
    from stages.hulls.balls import _skin_features
    c, poses, x = _walk()
    delta = 0.01
    split = split_by_motion(c, bone_deviation(c, poses, x), 0.005)
    balls = fit_balls(c, split, poses, x, SkinDistance(c), delta=delta, slack=(0.0,))
    assert balls.on_skin > 0
    inner = balls.radius.size - balls.on_skin
    centers = balls.centers(c.inverse_bind, poses)
    tri_index, edges = _skin_features(c.triangles, ~split.rigid)
    tri = c.triangles[tri_index]
    flex = np.flatnonzero(~split.rigid)
    tris = c.triangles.astype(np.int64)
    out_inner, out_all = 0, 0
    for f in ball_check_poses(poses.shape[0]):
        skin = np.concatenate([x[f, flex], x[f][tri].mean(axis=1), x[f][edges].mean(axis=1)])
        d = np.linalg.norm(skin[:, None] - centers[f][None], axis=2) - balls.radius[None]
        out_inner += int((d[:, :inner].min(axis=1) > 0).sum())
        out_all += int((d.min(axis=1) > 0).sum())
        off = np.zeros(balls.on_skin)
        distance_to_mesh_brute(np.ascontiguousarray(centers[f, inner:]), x[f], tris, off)
        assert (off <= balls.radius[inner:] - delta + 1e-9).all(), f
    assert out_inner > 0 and out_all == 0, (out_inner, out_all)
    on_bind = np.zeros(balls.on_skin)
    distance_to_mesh_brute(np.ascontiguousarray(balls.bind_center[inner:]), c.vertices, tris, on_bind)
    assert on_bind.max() < 1e-9 and (balls.radius[inner:] >= delta).all()


def _greedy_reference(held: np.ndarray, need: np.ndarray) -> list[int]:
    """Plain greedy set cover of the needed targets: the row holding most targets still needed (ties: lower row)."""
    need = need.copy()
    out = []
    while True:
        gain = (held & need[None]).sum(axis=1)
        r = int(np.argmax(gain))
        if gain[r] == 0:
            return out
        out.append(r)
        need &= ~held[r]


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 12), st.integers(1, 20), st.integers(0, 2**31 - 1), st.floats(0.05, 0.6), st.booleans())
def test_lazy_greedy_cover_equals_plain_greedy(rows, cols, seed, density, some_held):
    rng = np.random.default_rng(seed)
    held = rng.random((rows, cols)) < density
    need = rng.random(cols) < 0.6 if some_held else np.ones(cols, bool)   # a tier after a tighter one
    chosen, left = _greedy_cover(csr_matrix(held), need)
    assert chosen.tolist() == _greedy_reference(held, need)
    assert np.flatnonzero(left).tolist() == np.flatnonzero(need & ~held.any(axis=0)).tolist()


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 30), st.integers(0, 60), st.integers(1, 4), st.integers(0, 2**31 - 1), st.floats(0.01, 0.3))
def test_pair_search_equals_brute_force(n_centres, n_targets, n_poses, seed, cell):
    """pairs_in_reach (a grid of the targets at the first pose) finds exactly the pairs a brute
    force over every pair and pose finds, with the same largest distance, cols ascending."""
    from stages.hulls.balls_kernels import pairs_in_reach
    rng = np.random.default_rng(seed)
    centers = rng.random((n_poses, n_centres, 3)) * 0.5
    targets = rng.random((n_poses, n_targets, 3)) * 0.5
    reach = rng.random(n_centres) * 0.3
    indptr, cols, far = pairs_in_reach(centers, targets, reach, cell)
    d = np.linalg.norm(centers[:, :, None] - targets[:, None], axis=3).max(axis=0)     # (C, T)
    want = d <= reach[:, None]
    assert indptr.tolist() == [0] + np.cumsum(want.sum(axis=1)).tolist()
    for c in range(n_centres):
        assert cols[indptr[c]:indptr[c + 1]].tolist() == np.flatnonzero(want[c]).tolist()
        assert np.allclose(far[indptr[c]:indptr[c + 1]], d[c, want[c]], atol=1e-12)


def test_body_scale_leaves_human_sizes_alone_and_follows_others():
    from stages.hulls.balls import body_scale
    box = lambda h: np.array([[0.0, 0.0, 0.0], [0.3 * h, h, 0.2 * h]])   # noqa: E731
    assert body_scale(box(1.75)) == 1.0 and body_scale(box(0.5)) == 1.0 and body_scale(box(2.5)) == 1.0
    assert np.isclose(body_scale(box(10.0)), 4.0) and np.isclose(body_scale(box(0.1)), 0.2)


def test_a_body_held_by_balls_alone_builds_maps_and_simulates():
    """Colliders with no hull (a body whose every region is flexible, as a glTF tube with smooth
    weights: here the bent tube's balls without its rigid hulls): no hull maps, and the cloth still
    collides with the balls (none of it ends inside a collider)."""
    from stages.garments.simple import rectangle_cloth
    from stages.garments.types import build_garment
    from stages.hulls.fit import fit_character
    from stages.maps.build import build_maps
    from stages.sim import simulate
    from stages.sim.types import SimParams
    from tests.toy_rig import bend_motion, bent_tube
    c = bent_tube()
    motion = bend_motion(c, np.linspace(0.0, 90.0, 12))
    from dataclasses import replace
    _, cs = fit_character(c, motion.joint_world)
    cs = replace(cs, hulls=())
    assert cs.balls.radius.size > 0
    maps = build_maps(cs)
    assert len(maps.maps) == 0 and maps.arrays.planes.shape == (0, 4)
    biggest = cs.balls.bind_center[np.argmax(cs.balls.radius)]
    x, tri = rectangle_cloth(0.3, 0.3, 8, 8, center=tuple(biggest + [0.0, cs.balls.radius.max() + 0.03, 0.0]))
    r = simulate(c, motion, cs, maps, [build_garment("cloth", x, tri)], SimParams.preset("default"))
    assert r.penetrations_colliders[1:].max() == 0
