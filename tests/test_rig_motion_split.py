"""The motion split (rigid = moves with a bone over the motion) and swept flexible hulls."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stages.hulls.fit import fit_character
from stages.rig.motion_range import bone_deviation, range_of_motion
from stages.rig.skinning import skin_poses
from stages.rig.regions import split_by_motion
from tests.toy_rig import bend_motion, bent_tube


def _reference_deviation(c, poses):
    """Plain loops: for every vertex and slot, the farthest its LBS position gets, in that bone's
    frame, from its bind position in that frame."""
    out = np.zeros(c.skin_joints.shape)
    for v in range(c.vertices.shape[0]):
        x_bind = np.append(c.vertices[v], 1.0)
        for k in range(c.skin_joints.shape[1]):
            b = c.skin_joints[v, k]
            ref = (c.inverse_bind[b] @ x_bind)[:3]
            for pose in poses:
                m = sum(c.skin_weights[v, i] * pose[c.skin_joints[v, i]] @ c.inverse_bind[c.skin_joints[v, i]]
                        for i in range(c.skin_joints.shape[1]))
                x = m @ x_bind
                out[v, k] = max(out[v, k], np.linalg.norm((np.linalg.inv(pose[b]) @ x)[:3] - ref))
    return out


@settings(max_examples=10, deadline=None)
@given(angles=st.lists(st.floats(-80.0, 80.0), min_size=1, max_size=3))
def test_bone_deviation_equals_plain_loops(angles):
    c = bent_tube(rings=7, around=5)
    poses = bend_motion(c, angles).joint_world
    assert np.allclose(bone_deviation(c, poses), _reference_deviation(c, poses), atol=1e-12)


def test_a_joint_that_never_bends_leaves_no_flexible_region():
    c = bent_tube()
    poses = bend_motion(c, [0.0, 0.0]).joint_world
    split = split_by_motion(c, bone_deviation(c, poses), 0.005)
    assert split.rigid.all() and split.sphere_joints == ()
    # the blended band goes to the heavier bone, as the dominant weight says
    assert (split.region_joint == split.dominant_joint).all()


@settings(max_examples=10, deadline=None)
@given(angle=st.floats(30.0, 90.0), tol=st.floats(0.001, 0.004))
def test_rigid_vertices_stay_within_tolerance_of_their_bone_at_every_pose(angle, tol):
    c = bent_tube()
    poses = bend_motion(c, [0.0, angle / 2, angle]).joint_world
    dev = bone_deviation(c, poses)
    split = split_by_motion(c, dev, tol)
    x = skin_poses(c, poses)
    for v in np.flatnonzero(split.rigid):
        b = split.region_joint[v]
        ref = c.inverse_bind[b, :3, :3] @ c.vertices[v] + c.inverse_bind[b, :3, 3]
        inv = np.linalg.inv(poses[:, b])
        local = np.einsum("fij,fj->fi", inv[:, :3, :3], x[:, v]) + inv[:, :3, 3]
        assert np.linalg.norm(local - ref, axis=1).max() <= tol + 1e-12
    assert (~split.rigid).any()                         # the band across the bend is flexible
    assert split.rigid[c.skin_weights.max(axis=1) == 1.0].all()


def _held_at_every_pose(c, cs, poses, tol=1e-9):
    x = skin_poses(c, poses)
    for h in cs.hulls:
        pl = h.simplified.planes
        inv = np.linalg.inv(poses[:, h.bone])
        local = np.einsum("fij,fnj->fni", inv[:, :3, :3], x[:, h.region_vertices]) + inv[:, None, :3, 3]
        worst = (local.reshape(-1, 3) @ pl[:, :3].T - pl[:, 3]).max()
        assert worst <= tol, (h.name, worst)


def test_every_collider_holds_its_vertices_at_every_pose_on_the_tube():
    c = bent_tube()
    poses = bend_motion(c, [0.0, 30.0, 60.0, 90.0]).joint_world
    split, cs = fit_character(c, poses, flexible="swept")
    assert {h.kind for h in cs.hulls} == {"rigid", "swept"} and not cs.spheres
    assert len({h.name for h in cs.hulls}) == len(cs.hulls)
    _held_at_every_pose(c, cs, poses)
    # every vertex belongs to some collider
    owned = np.zeros(c.vertices.shape[0], bool)
    for h in cs.hulls:
        owned[h.region_vertices] = True
    assert owned.all()


def test_the_built_in_character_walk_every_collider_holds_its_vertices():
    from stages.rig.procedural import procedural_character
    from stages.rig.skinning import sample_motion
    c = procedural_character()
    clip = c.clip("walk")
    poses = sample_motion(c, "walk", clip.times[::4] - clip.times[0]).joint_world
    split, cs = fit_character(c, poses)
    assert split.method == "motion"
    _held_at_every_pose(c, cs, poses)


def test_range_of_motion_turns_each_inner_joint_alone():
    c = bent_tube()
    poses = range_of_motion(c, 30.0)
    assert poses.shape == (1 + 6 * 0, 2, 4, 4)           # the tube's tip joint has no child
    from stages.rig.procedural import procedural_character
    c = procedural_character()
    poses = range_of_motion(c, 30.0)
    inner = sum(1 for j in range(c.n_joints) if c.parents[j] >= 0 and (c.parents == j).any())
    assert poses.shape[0] == 1 + 6 * inner
    rest = poses[0]
    for f in (1, 7, poses.shape[0] - 1):                 # a turn moves a subtree, not the root
        assert np.allclose(poses[f, 0], rest[0])
        assert not np.allclose(poses[f], rest)


@pytest.mark.parametrize("flexible", ["sphere", "swept"])
def test_both_split_modes_run_with_both_flexible_kinds(flexible):
    c = bent_tube()
    poses = bend_motion(c, [0.0, 60.0]).joint_world
    for split in ("motion", "weights"):
        s, cs = fit_character(c, poses, split=split, flexible=flexible)
        assert cs.flexible == flexible and s.method == split
        assert (len(cs.spheres) > 0) == (flexible == "sphere")


def test_swept_core_points_stay_inside_the_body_at_every_pose():
    """The bone points a swept hull reaches down to (own bone and parent's) are inside the skinned
    body at the bind pose and at every pose: checked with the winding number directly."""
    from stages.geometry.skin_distance import SkinDistance
    from stages.hulls import swept
    from stages.hulls.fit import core_points
    from stages.rig.procedural import procedural_character
    from stages.rig.skinning import sample_motion
    from stages.geometry.winding import winding_number
    c = procedural_character()
    clip = c.clip("walk")
    poses = sample_motion(c, "walk", clip.times[::6] - clip.times[0]).joint_world
    x = skin_poses(c, poses)
    dev = bone_deviation(c, poses, x)
    split = split_by_motion(c, dev, 0.005)
    parts, _ = swept.swept_parts(c, split, dev)
    body = SkinDistance(c)
    body.refit(c.vertices)
    cores = core_points(c, parts, poses, x, body)
    assert sum(k.shape[0] for k in cores) > 0
    for (_, b, _), local in zip(parts, cores):
        if local.shape[0] == 0:
            continue
        bind = np.linalg.inv(c.inverse_bind[b])
        assert (winding_number(c.vertices, c.triangles, local @ bind[:3, :3].T + bind[:3, 3]) >= 0.5).all()
        for f in range(poses.shape[0]):
            world = local @ poses[f, b, :3, :3].T + poses[f, b, :3, 3]
            assert (winding_number(x[f], c.triangles, world) >= 0.5).all(), (c.joint_names[b], f)
