"""Particles pinched between overlapping colliders (issue 6): when collide's pass budget is spent,
stages.sim.body_escape.escape_union moves the particle out of the union instead of leaving it inside."""
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from stages.hulls.types import ColliderSet, SphereCollider
from stages.maps.kernels import METHOD_BRUTE, METHOD_PAPER, collide_points
from stages.sim.body_collide import PINCH_LIMB, PINCH_MIDPOINT, PINCHED, PUSH_EPS
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


# -- SimParams.pinch 'midpoint': cloth pressed between two joints' colliders stays in their overlap --

def test_lens_between_two_joints_is_pinched_at_its_middle():
    """The lens above with the two spheres on different joints and pinch on: the budget ends on one
    sphere's boundary (x = 0.5 or 1.0) inside the other, whose push runs along x into the first: the
    particle is left halfway, x = 0.75 (by hand), marked PINCHED, not counted as inside."""
    centres = np.array([[0.0, 0.0, 0.0], [1.5, 0.0, 0.0]])
    col = _collider_arrays(_spheres(*zip(centres, [1.0, 1.0])), None, np.tile(np.eye(4), (2, 1, 1)))
    p0 = np.array([[0.75, 0.0, 0.0], [0.6, 0.0, 0.0], [2.0, 3.0, 0.0]])
    for passes in (1, 4, 50):
        out, xp, corr, ins = _collide(col, p0, p0, passes=passes, pinch=True)
        np.testing.assert_allclose(out[:2], [[0.75, 0.0, 0.0]] * 2, atol=1e-6)
        assert list(ins) == [PINCHED, PINCHED, 0] and list(corr) == [1, 1, 0]
        np.testing.assert_array_equal(out[2], p0[2])           # a free particle is left alone
        assert ((out[:2] - xp[:2]) @ np.array([1.0, 0.0, 0.0]) <= 1e-12).all()   # inelastic


def test_one_joints_overlap_is_still_escaped():
    """A hull and a sphere of the same joint overlapping (one bone's own colliders), a tight budget:
    no pinch, issue 6's escape bit for bit, every particle outside both."""
    rng = np.random.default_rng(11)
    cs_h, maps = _one_hull_maps(3)
    joint = cs_h.hulls[0].bone
    s = SphereCollider(joint, "s", np.array([0.12, 0.0, 0.0]), 0.25, np.zeros((0, 3)))
    col = _collider_arrays(ColliderSet(hulls=cs_h.hulls, spheres=(s,), delta=0.0, min_triangles=4), maps,
                           np.tile(np.eye(4), (joint + 1, 1, 1)))
    pts = rng.uniform(-0.45, 0.45, (400, 3))
    a = _collide(col, pts, pts, method=METHOD_PAPER, passes=1, pinch=True)
    b = _collide(col, pts, pts, method=METHOD_PAPER, passes=1, pinch=False)
    for u, v in zip(a, b):
        np.testing.assert_array_equal(u, v)
    in_h, _ = collide_points(maps, a[0], 0, METHOD_BRUTE)
    assert not in_h.any() and (np.linalg.norm(a[0] - s.center, axis=1) >= s.radius).all()
    assert not (a[3] == PINCHED).any() and a[2].sum() > 50


@settings(max_examples=60, deadline=None)
@given(st.floats(0.3, 2.0), st.floats(0.3, 2.0), st.floats(0.05, 0.95), st.floats(0.0, 1.0),
       st.integers(1, 6))
def test_pinch_on_the_axis_ends_in_the_middle_of_the_lens(r1, r2, overlap, where, passes):
    """Spheres of radii r1, r2 on two joints overlapping by a share of the smaller radius, a particle
    anywhere on the axis inside their lens: the pushes run along the axis between the lens' ends
    a = d - r2 and b = r1 until the budget is spent; the particle ends at (a + b) / 2, pinched."""
    d = r1 + r2 - overlap * min(r1, r2)
    a, b = d - r2, r1
    x0 = a + (b - a) * (0.05 + 0.9 * where)
    col = _collider_arrays(_spheres(([0.0, 0.0, 0.0], r1), ([d, 0.0, 0.0], r2)), None, np.tile(np.eye(4), (2, 1, 1)))
    out, _, corr, ins = _collide(col, np.array([[x0, 0.0, 0.0]]), np.array([[x0, 0.0, 0.0]]), passes=passes,
                                 pinch=True)
    assert ins[0] == PINCHED and corr[0] == 1
    np.testing.assert_allclose(out[0], [(a + b) / 2, 0.0, 0.0], atol=1e-6 * max(1.0, d))


# -- SimParams.pinch 'limb': the deeper limb's collider acts, the body's yields ---------------------------

def _family(depths, parents):
    """collider_family rows for colliders on joints 0..n-1 with these parents and depths."""
    return np.array([[j, p, d] for j, (p, d) in enumerate(zip(parents, depths))], np.int32)


@settings(max_examples=60, deadline=None)
@given(st.floats(0.3, 2.0), st.floats(0.3, 2.0), st.floats(0.05, 0.95), st.floats(0.0, 1.0),
       st.integers(1, 6), st.booleans())
def test_limb_rule_holds_cloth_in_the_middle_of_the_lens_in_one_pass(r1, r2, overlap, where, passes, swap):
    """A 'torso' sphere (depth 0) and a 'hand' sphere (depth 2, not its child) overlapping, a particle on
    the axis inside their lens: whichever is visited first, the particle goes to the middle of the two
    exits (a + b) / 2 at once, marked PINCHED; the body's push is never made alone. Colliders listed
    either way round give the same point."""
    d = r1 + r2 - overlap * min(r1, r2)
    a, b = d - r2, r1
    x0 = a + (b - a) * (0.05 + 0.9 * where)
    specs = [([0.0, 0.0, 0.0], r1), ([d, 0.0, 0.0], r2)]
    fam = _family([0, 2], [-1, 1])
    if swap:
        specs, fam = specs[::-1], fam[::-1].copy()
        fam[:, 0] = [0, 1]
        fam[:, 1] = [1, -1]
    col = _collider_arrays(_spheres(*specs), None, np.tile(np.eye(4), (2, 1, 1)))
    p = np.array([[x0, 0.0, 0.0]])
    out, xp, corr, ins = _collide(col, p, p, passes=passes, pinch=PINCH_LIMB, family=fam)
    assert ins[0] == PINCHED and corr[0] == 1
    np.testing.assert_allclose(out[0], [(a + b) / 2, 0.0, 0.0], atol=1e-6 * max(1.0, d))


def test_limb_rule_leaves_the_body_alone_elsewhere_and_adjacent_joints_to_the_midpoint_rule():
    """Away from the limb the body's collider pushes as always; a particle in the body's collider whose
    push would land in the limb goes halfway (PINCHED); with the limb the body's child (a shoulder and
    its upper arm) nothing outranks: the same result as the midpoint rule, bit for bit."""
    centres = np.array([[0.0, 0.0, 0.0], [1.5, 0.0, 0.0]])
    col = _collider_arrays(_spheres(*zip(centres, [1.0, 1.0])), None, np.tile(np.eye(4), (2, 1, 1)))
    p0 = np.array([[-0.9, 0.1, 0.0], [0.45, 0.0, 0.0], [2.0, 3.0, 0.0]])
    out, xp, corr, ins = _collide(col, p0, p0, passes=4, pinch=PINCH_LIMB, family=_family([0, 2], [-1, 1]))
    np.testing.assert_allclose(np.linalg.norm(out[0]), 1.0, atol=1e-6)       # pushed out of the body
    assert list(ins) == [0, PINCHED, 0] and list(corr) == [1, 1, 0]
    np.testing.assert_allclose(out[1], [0.725, 0.0, 0.0], atol=1e-6)          # halfway to the body's surface
    np.testing.assert_array_equal(out[2], p0[2])
    pts = np.random.default_rng(3).uniform(-1.0, 2.5, (300, 3))
    a = _collide(col, pts, pts, passes=2, pinch=PINCH_LIMB, family=_family([0, 1], [-1, 0]))
    b = _collide(col, pts, pts, passes=2, pinch=PINCH_MIDPOINT, family=_family([0, 1], [-1, 0]))
    for u, v in zip(a, b):
        np.testing.assert_array_equal(u, v)


def _cube_planes(half=1.0):
    n = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], np.float64)
    return np.ascontiguousarray(np.hstack([n, np.full((6, 1), half)])), np.array([0, 6], np.int64)


def _entry_reference(inside, q, o, n=20001):
    """The first point from q towards o (sampled) that is outside, or None when o is inside."""
    if inside(o):
        return None
    ts = np.linspace(0.0, 1.0, n)
    for t in ts:
        p = q + t * (o - q)
        if not inside(p):
            return p
    return None


def test_entry_side_leaves_a_box_by_the_face_it_came_in_by():
    from stages.sim.body_escape import _entry_side
    planes, fs = _cube_planes()
    rng = np.random.default_rng(5)
    inside = lambda p: bool(np.all(np.abs(p) <= 1.0))     # noqa: E731
    for _ in range(200):
        q = rng.uniform(-0.99, 0.99, 3)
        o = rng.uniform(-3, 3, 3)
        found, r0, r1, r2, n0, n1, n2 = _entry_side(False, 0.0, fs, planes, 0, *q, *o)
        ref = _entry_reference(inside, q, o)
        assert found == (ref is not None)
        if found:
            np.testing.assert_allclose([r0, r1, r2], ref, atol=5e-4 * np.linalg.norm(o - q))
            r = np.array([r0, r1, r2])
            k = int(np.argmax(np.abs(r)))
            want = np.zeros(3)
            want[k] = np.sign(r[k])
            np.testing.assert_allclose([n0, n1, n2], want)   # the face it is on
    # cloth pushed past a thin limb's middle from below: out below (the map's centre-out ray: above)
    found, r0, r1, r2, n0, n1, n2 = _entry_side(False, 0.0, fs, planes, 0, 0.0, 0.4, 0.0, 0.0, -3.0, 0.0)
    assert found and r1 == pytest.approx(-1.0) and n1 == -1.0


def test_entry_side_on_a_sphere():
    from stages.sim.body_escape import _entry_side
    planes, fs = _cube_planes()
    rng = np.random.default_rng(6)
    inside = lambda p: bool(p @ p <= 1.0)     # noqa: E731
    for _ in range(200):
        q = rng.normal(size=3)
        q *= rng.uniform(0.0, 0.99) / np.linalg.norm(q)
        o = rng.uniform(-3, 3, 3)
        found, r0, r1, r2, n0, n1, n2 = _entry_side(True, 1.0, fs, planes, 0, *q, *o)
        ref = _entry_reference(inside, q, o)
        assert found == (ref is not None)
        if found:
            np.testing.assert_allclose([r0, r1, r2], ref, atol=5e-4 * np.linalg.norm(o - q))
            np.testing.assert_allclose([n0, n1, n2], np.array([r0, r1, r2]) / np.linalg.norm([r0, r1, r2]))
