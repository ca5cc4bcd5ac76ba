"""Particles pinched between overlapping colliders (issue 6): when collide's pass budget is spent,
stages.sim.body_collide.escape_union moves the particle out of the union instead of leaving it inside."""
import math

import numpy as np
from hypothesis import given, settings, strategies as st

from stages.hulls.types import ColliderSet, SphereCollider
from stages.maps.kernels import METHOD_BRUTE, METHOD_PAPER, collide_points
from stages.sim.body_collide import PUSH_EPS
from tests.test_sim_kernels import _collide, _collider_arrays, _one_hull_maps


def _spheres(*specs):
    return ColliderSet(hulls=(), spheres=tuple(SphereCollider(j, f"s{j}", np.asarray(c, float), r, np.zeros((0, 3)))
                                             for j, (c, r) in enumerate(specs)), delta=0.0, min_triangles=4)


def _old_collide_ref(p, centres, radii, passes):
    """Plain reference of the pre-escape response for spheres only (paper eq. 6, cyclic visits,
    budget passes * nc): the final point and whether it is still inside."""
    p = np.asarray(p, float).copy()
    nc = len(radii)

    def push(c, p):
        d = p - centres[c]
        n = np.linalg.norm(d)
        return centres[c] + d / n * (radii[c] + PUSH_EPS)

    budget = passes * nc
    last, c, streak = -1, 0, 0
    for c in range(nc):                       # stage 0: every collider once in order
        if np.linalg.norm(p - centres[c]) < radii[c]:
            p, last = push(c, p), c
    if last < 0:
        return p, False
    c, streak = last, 1
    while streak < nc:
        c = (c + 1) % nc
        budget -= 1
        if budget < 0:
            break
        if np.linalg.norm(p - centres[c]) < radii[c]:
            p, last, streak = push(c, p), c, 1
            continue
        streak += 1
    inside = any(np.linalg.norm(p - centres[k]) < radii[k] - 1e-12 for k in range(nc))
    return p, inside


def test_lens_between_two_spheres_is_escaped():
    """Two unit spheres 1.5 apart; a particle in the middle of their lens is pushed A -> B -> A ...
    for ever (each push lands 0.5 deep in the other). The old loop left it inside (checked by the
    plain reference); now it ends outside both, within the hand-computed escape length."""
    centres = np.array([[0.0, 0.0, 0.0], [1.5, 0.0, 0.0]])
    radii = [1.0, 1.0]
    p0 = np.array([[0.75, 0.0, 0.0]])
    for passes in (1, 4, 50):
        ref_p, ref_inside = _old_collide_ref(p0[0], centres, radii, passes)
        assert ref_inside                                  # the old response fails here
        col = _collider_arrays(_spheres(*zip(centres, radii)), None, np.tile(np.eye(4), (2, 1, 1)))
        out, xp, corr, ins = _collide(col, p0, p0, passes=passes)
        d = np.linalg.norm(out[0] - centres, axis=1)
        assert corr[0] == 1 and ins[0] == 0
        assert (d >= np.asarray(radii)).all()
        # by hand: the budget ends at ref_p (x = 0.5 or 1.0, on one sphere's boundary); the shortest
        # candidate is perpendicular to x: out of the other sphere, sqrt(1 - 0.5^2) = 0.866 from it
        assert abs(out[0, 0] - ref_p[0]) < 1e-6
        np.testing.assert_allclose(np.linalg.norm(out[0] - ref_p), math.sqrt(0.75), atol=1e-6)
        # inelastic: no outward velocity along the escape
        e = (out[0] - ref_p) / np.linalg.norm(out[0] - ref_p)
        assert (out[0] - xp[0]) @ e <= 1e-12


def test_escape_is_deterministic_and_leaves_free_particles_alone():
    centres = [(0.0, 0.0, 0.0), (1.5, 0.0, 0.0)]
    col = _collider_arrays(_spheres((centres[0], 1.0), (centres[1], 1.0)), None, np.tile(np.eye(4), (2, 1, 1)))
    rng = np.random.default_rng(5)
    pts = rng.uniform(-1.5, 3.0, (3000, 3))
    a = _collide(col, pts, pts, passes=2)
    b = _collide(col, pts, pts, passes=2)
    for u, v in zip(a, b):
        assert np.array_equal(u, v)
    out, _, corr, ins = a
    d = np.linalg.norm(out[:, None] - np.asarray(centres)[None], axis=2)
    assert not ins.any() and (d >= 1.0).all()
    free = (np.linalg.norm(pts[:, None] - np.asarray(centres)[None], axis=2) >= 1.0).all(axis=1)
    assert np.array_equal(out[free], pts[free]) and not corr[free].any()


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 10_000), st.integers(1, 3))
def test_hull_and_spheres_pinch_ends_outside_all(seed, passes):
    """A random hull with two spheres overlapping it and each other, a tight budget: every particle
    ends outside all three (brute plane test for the hull, |p - c| >= r for the spheres)."""
    rng = np.random.default_rng(seed)
    cs_h, maps = _one_hull_maps(seed % 7)
    s = [SphereCollider(k, f"s{k}", rng.uniform(-0.15, 0.15, 3), float(rng.uniform(0.15, 0.3)), np.zeros((0, 3)))
         for k in range(2)]
    cs = ColliderSet(hulls=cs_h.hulls, spheres=tuple(s), delta=0.0, min_triangles=4)
    col = _collider_arrays(cs, maps, np.tile(np.eye(4), (2, 1, 1)))
    pts = rng.uniform(-0.45, 0.45, (400, 3))
    out, _, corr, ins = _collide(col, pts, pts, method=METHOD_PAPER, passes=passes)
    in_h, _ = collide_points(maps, out, 0, METHOD_BRUTE)
    in_s = [np.linalg.norm(out - q.center, axis=1) < q.radius for q in s]
    still = in_h | in_s[0] | in_s[1]
    assert np.array_equal(still, ins.astype(bool))
    assert not still.any()


def test_escape_follows_the_bones_pose():
    """The same pinch with both bones rotated and moved: the escape happens in world and gives the
    posed image of the unposed result (query frames are affine, exits are frame-independent)."""
    from scipy.spatial.transform import Rotation
    cs = _spheres(((0.0, 0.0, 0.0), 1.0), ((1.5, 0.0, 0.0), 1.0))
    p0 = np.array([[0.75, 0.0, 0.0], [0.7, 0.1, -0.05]])
    ref = _collide(_collider_arrays(cs, None, np.tile(np.eye(4), (2, 1, 1))), p0, p0, passes=2)[0]
    m = np.eye(4)
    m[:3, :3] = Rotation.from_euler("xyz", [0.4, -1.1, 0.7]).as_matrix()
    m[:3, 3] = [0.3, -0.2, 0.5]
    pw = p0 @ m[:3, :3].T + m[:3, 3]
    out, _, corr, ins = _collide(_collider_arrays(cs, None, np.tile(m, (2, 1, 1))), pw, pw, passes=2)
    assert corr.all() and not ins.any()
    back = (out - m[:3, 3]) @ m[:3, :3]
    assert (np.linalg.norm(back[:, None] - np.array([[0.0, 0, 0], [1.5, 0, 0]])[None], axis=2) >= 1.0).all()
    # the lens-centred particle: every direction perpendicular to the centre line escapes by the
    # same length, so it does not depend on which world axes the perpendicular candidates come from
    np.testing.assert_allclose(np.linalg.norm(out[0] - pw[0]), np.linalg.norm(ref[0] - p0[0]), atol=1e-6)
