"""Skinned balls (stages/hulls/balls.py) against independent references."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings, strategies as st
from scipy.sparse import csr_matrix

from stages.hulls.balls import _greedy_cover, check_pose_indices, fit_balls, skin_points
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
    """skin_points of the character's own vertices equals the skinning kernel's output."""
    c, poses, x = _walk()
    got = skin_points(c.vertices, c.skin_joints.astype(np.int64), c.skin_weights, c.inverse_bind, poses)
    assert np.allclose(got, x, atol=1e-9)


def test_balls_hold_every_flexible_vertex_they_claim_at_every_check_pose():
    """Brute force: every flexible vertex not listed as unheld is within radius - (1 - cover) delta
    of some ball centre at every check pose; every ball centre is inside the skinned body there."""
    from stages.coverage.measure import SkinDistance
    from stages.sim import winding_number
    c, poses, x = _walk()
    delta, cover = 0.01, 0.6
    split = split_by_motion(c, bone_deviation(c, poses, x), 0.005)
    balls = fit_balls(c, split, poses, x, SkinDistance(c), delta=delta, cover=cover)
    assert balls.radius.size > 0
    flex = np.setdiff1d(np.flatnonzero(~split.rigid), balls.unheld)
    assert flex.size > 0
    centers = balls.centers(c.inverse_bind, poses)                 # (F, B, 3)
    reach = balls.radius - (1 - cover) * delta
    for f in check_pose_indices(poses.shape[0]):
        d = np.linalg.norm(x[f, flex][:, None] - centers[f][None], axis=2)
        assert (d <= reach[None] + 1e-12).any(axis=1).all(), f
        assert (winding_number(x[f], c.triangles, centers[f]) >= 0.5).all(), f


def _greedy_reference(held: np.ndarray) -> list[int]:
    """Plain greedy set cover: the row holding most targets not yet held (ties: lower row)."""
    need = np.ones(held.shape[1], bool)
    out = []
    while True:
        gain = (held & need[None]).sum(axis=1)
        r = int(np.argmax(gain))
        if gain[r] == 0:
            return out
        out.append(r)
        need &= ~held[r]


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 12), st.integers(1, 20), st.integers(0, 2**31 - 1), st.floats(0.05, 0.6))
def test_lazy_greedy_cover_equals_plain_greedy(rows, cols, seed, density):
    held = np.random.default_rng(seed).random((rows, cols)) < density
    chosen, unheld = _greedy_cover(csr_matrix(held))
    assert chosen.tolist() == _greedy_reference(held)
    assert unheld.tolist() == np.flatnonzero(~held.any(axis=0)).tolist()
