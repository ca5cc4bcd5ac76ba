"""Attachments that another bone's collider sweeps through yield to the collision response."""
import warnings

import numpy as np
import pytest

from stages.garments.simple import tube_skirt
from stages.garments.band import swept_attachments
from stages.garments.types import attach_top_loop, bind_pose, build_garment
from stages.hulls.types import ColliderSet, SphereCollider
from stages.rig.types import Character, Motion
from stages.sim import SimParams, simulate

RADIUS, DELTA = 0.1, 0.01
N_FRAMES = 40


def root_and_arm() -> Character:
    """Joints 'root' and 'arm' (its child), both at the origin, and a tiny body far away (-5 m)."""
    eye = np.eye(4)
    tet = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]) * 0.01 - 5.0
    return Character(name="arm", vertices=tet, triangles=np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]], np.int32),
                     primitive_ids=np.zeros(4, np.int32), joint_names=("root", "arm"), parents=np.array([-1, 0], np.int32),
                     rest_local=np.stack([eye, eye]), inverse_bind=np.stack([eye, eye]),
                     skin_joints=np.zeros((4, 1), np.int32), skin_weights=np.ones((4, 1)), source="procedural")


def _arm_scene():
    """Joint 0 'root' still; joint 1 'arm' carries a sphere along x at waist height, through the
    waistband of a skirt pinned to the root (top ring: radius 0.3 at y = 1)."""
    ch = root_and_arm()
    jw = np.tile(np.eye(4), (N_FRAMES, 2, 1, 1))
    jw[:, 1, 0, 3] = np.linspace(-0.8, 0.8, N_FRAMES)   # the arm sweeps along x ...
    jw[:, 1, 1, 3] = 1.0                                # ... at the waistband's height
    mo = Motion("sweep", np.arange(N_FRAMES) / 30.0, jw, np.zeros((N_FRAMES, 3)))
    sphere = SphereCollider(1, "arm", np.zeros(3), RADIUS, np.zeros((0, 3)))
    cs = ColliderSet(hulls=(), spheres=(sphere,), delta=DELTA, min_triangles=4)
    x, tri = tube_skirt(0.3, 0.35, 0.3, 24, 4, center=(0.0, 1.0, 0.0))
    return ch, mo, cs, x, tri


def test_swept_attachments_match_brute_force():
    ch, mo, cs, x, tri = _arm_scene()
    bind = bind_pose(ch, mo, cs)
    top = np.flatnonzero(np.isclose(x[:, 1], 1.0))
    local = x[top]                          # the root's frame is the identity
    hit, names = swept_attachments(bind, local, np.zeros(top.size, np.int32), DELTA)
    # brute force: the sphere's centre at each frame against each pinned point
    centres = mo.joint_world[:, 1, :3, 3]
    want = np.array([any(np.linalg.norm(p - c) < RADIUS - DELTA for c in centres) for p in local])
    assert want.any() and not want.all()
    np.testing.assert_array_equal(hit, want)
    assert names == ["arm"]
    # a skinned ball (<joint>_ball<k>) is named by its joint
    from dataclasses import replace
    balls = replace(cs, spheres=(replace(cs.spheres[0], name="arm_ball17"),))
    assert swept_attachments(bind_pose(ch, mo, balls), local, np.zeros(top.size, np.int32), DELTA)[1] == ["arm"]
    # a particle following the sphere's own bone is never swept by it
    hit_own, _ = swept_attachments(bind, local - [0.0, 1.0, 0.0], np.ones(top.size, np.int32), DELTA)
    assert not hit_own.any()


def test_swept_attachments_yield_and_leave_no_particle_inside():
    ch, mo, cs, x, tri = _arm_scene()
    bind = bind_pose(ch, mo, cs)
    with pytest.warns(UserWarning, match=r"attached particles yield to collisions: the colliders arm"):
        g = build_garment("skirt", x, tri, attachments=[attach_top_loop("root")], bind=bind)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rigid = build_garment("skirt", x, tri, attachments=[attach_top_loop("root")], bind=bind, yield_swept=False)
    y = g.yielding
    assert y.size > 0 and np.array_equal(g.attached, rigid.attached)
    assert np.all(g.inverse_mass[y] > 0) and np.all(rigid.inverse_mass[rigid.attached] == 0)

    params = SimParams(body_audit=False)
    pos = simulate(ch, mo, cs, None, [g], params)
    old = simulate(ch, mo, cs, None, [rigid], params)
    centres = mo.joint_world[:, 1, :3, 3]

    def inside(r):
        p = r.garments[0].positions.astype(np.float64)
        return (np.linalg.norm(p - centres[:, None], axis=2) < RADIUS - 1e-5).sum(axis=1)

    assert inside(old).max() > 0                # rigid: the sphere passes through the waistband
    assert inside(pos).max() == 0 and (pos.penetrations_colliders == 0).all()
    p = pos.garments[0].positions.astype(np.float64)
    a = g.attached
    off = np.linalg.norm(p[:, a] - g.attach_local[a], axis=2)        # root frame = identity
    rigid_a = np.setdiff1d(a, y)
    assert off[:, np.isin(a, rigid_a)].max() < 1e-6                  # rigid ones never move
    assert off[:, np.isin(a, y)].max() > 0.02                        # yielding ones are pushed ...
    far = np.linalg.norm(g.attach_local[y][None] - centres[:, None], axis=2).min(axis=1) > RADIUS + 0.05
    assert off[np.ix_(far, np.isin(a, y))].max() < 1e-6              # ... and back on the bone after


def test_a_garment_ignoring_the_sweeping_joint_keeps_its_attachments_rigid_and_lets_it_through():
    """The arm's joint in ignore_joints: nothing yields (no warning), and simulate with the same
    joint ignored lets the sphere pass through the rigid waistband without pushing anything."""
    ch, mo, cs, x, tri = _arm_scene()
    bind = bind_pose(ch, mo, cs)
    hit, names = swept_attachments(bind, x[np.isclose(x[:, 1], 1.0)], np.zeros(int(np.isclose(x[:, 1], 1.0).sum()),
                                                                                np.int32), DELTA, ignore={1})
    assert not hit.any() and names == []
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        g = build_garment("skirt", x, tri, attachments=[attach_top_loop("root")], bind=bind, ignore_joints=(1,))
    assert g.yielding.size == 0 and np.all(g.inverse_mass[g.attached] == 0)
    r = simulate(ch, mo, cs, None, [g], SimParams(body_audit=False), ignore_colliders=[(1,)])
    assert (r.penetrations_colliders == 0).all() and (r.corrected == 0).all()
    centres = mo.joint_world[:, 1, :3, 3]
    p = r.garments[0].positions.astype(np.float64)
    assert (np.linalg.norm(p - centres[:, None], axis=2) < RADIUS - 1e-5).sum() > 0   # it went through
