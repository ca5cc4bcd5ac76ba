"""Clip sampling, motion frames, LBS kernel and vertex normals against plain-Python references."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation, Slerp

from stages.rig.skinning import rest_motion, sample_clip, sample_motion, skin, skin_numpy, vertex_normals
from stages.rig.transforms import forward_kinematics, trs_to_matrix
from stages.rig.types import Character, Clip


def make_character(seed: int, n_joints: int = 4, n_verts: int = 30, k: int = 4, clips=()) -> Character:
    rng = np.random.default_rng(seed)
    parents = np.array([-1] + [int(rng.integers(0, j)) for j in range(1, n_joints)], np.int32)
    rest_t = rng.normal(0, 0.3, (n_joints, 3))
    rest_q = Rotation.random(n_joints, random_state=seed).as_quat()
    rest_local = trs_to_matrix(rest_t, rest_q)
    inverse_bind = np.linalg.inv(forward_kinematics(parents, rest_local))
    w = rng.uniform(0, 1, (n_verts, k))
    w[rng.uniform(size=w.shape) < 0.3] = 0.0
    w[:, 0] += 1e-3
    w /= w.sum(axis=1, keepdims=True)
    return Character(
        name=f"random{seed}", vertices=rng.normal(0, 1, (n_verts, 3)),
        triangles=rng.integers(0, n_verts, (n_verts, 3)).astype(np.int32),
        primitive_ids=np.zeros(n_verts, np.int32), joint_names=tuple(f"j{i}" for i in range(n_joints)),
        parents=parents, rest_local=rest_local, inverse_bind=inverse_bind,
        skin_joints=rng.integers(0, n_joints, (n_verts, k)).astype(np.int32), skin_weights=w,
        clips=tuple(clips))


def make_clip(seed: int, n_joints: int, n_keys: int = 5, interpolation="linear", loop=False) -> Clip:
    rng = np.random.default_rng(seed)
    times = np.cumsum(rng.uniform(0.1, 0.5, n_keys))
    times -= times[0]
    return Clip(name=f"clip{seed}", times=times, translations=rng.normal(0, 0.3, (n_keys, n_joints, 3)),
                rotations=Rotation.random(n_keys * n_joints, random_state=seed).as_quat().reshape(n_keys, n_joints, 4),
                scales=rng.uniform(0.8, 1.2, (n_keys, n_joints, 3)), interpolation=interpolation, loop=loop)


def reference_local(clip: Clip, t: float) -> np.ndarray:
    """Local transforms at clip time t by scipy Slerp and np.interp, joint by joint."""
    kt = clip.times
    nj = clip.translations.shape[1]
    out = np.empty((nj, 4, 4))
    for j in range(nj):
        if clip.interpolation == "step" or kt.size == 1:
            i = int(np.flatnonzero(kt <= t)[-1])
            tr, r, s = clip.translations[i, j], Rotation.from_quat(clip.rotations[i, j]), clip.scales[i, j]
        else:
            tr = np.array([np.interp(t, kt, clip.translations[:, j, c]) for c in range(3)])
            s = np.array([np.interp(t, kt, clip.scales[:, j, c]) for c in range(3)])
            r = Slerp(kt, Rotation.from_quat(clip.rotations[:, j]))([t])[0]
        m = np.eye(4)
        m[:3, :3] = r.as_matrix() @ np.diag(s)
        m[:3, 3] = tr
        out[j] = m
    return out


@pytest.mark.parametrize("interpolation", ["linear", "step"])
def test_sample_clip_matches_reference(interpolation):
    clip = make_clip(1, 3, interpolation=interpolation)
    c = make_character(1, n_joints=3, clips=[clip])
    ts = np.linspace(0, clip.duration, 23)
    got = sample_clip(c, clip, ts)
    for f, t in enumerate(ts):
        np.testing.assert_allclose(got[f], reference_local(clip, t), atol=1e-10)


def test_sample_clip_loop_wraps_and_clamps():
    looped = make_clip(2, 2, loop=True)
    clamped = make_clip(2, 2, loop=False)
    c = make_character(2, n_joints=2, clips=[looped])
    d = looped.duration
    np.testing.assert_allclose(sample_clip(c, looped, [d + 0.1, 2 * d + 0.1]),
                               sample_clip(c, looped, [0.1, 0.1]), atol=1e-10)
    np.testing.assert_allclose(sample_clip(c, clamped, [d + 5.0, -1.0]),
                               sample_clip(c, clamped, [d, 0.0]), atol=1e-12)


def test_single_key_clip():
    clip = make_clip(3, 2, n_keys=1)
    c = make_character(3, n_joints=2, clips=[clip])
    got = sample_clip(c, clip, [0.0, 1.0])
    np.testing.assert_allclose(got[1], reference_local(clip, 0.0), atol=1e-12)


def reference_lbs(c: Character, m: np.ndarray) -> np.ndarray:
    out = np.zeros((c.vertices.shape[0], 3))
    for v in range(c.vertices.shape[0]):
        x = np.append(c.vertices[v], 1.0)
        for k in range(c.skin_joints.shape[1]):
            out[v] += c.skin_weights[v, k] * (m[c.skin_joints[v, k]] @ x)[:3]
    return out


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), k=st.sampled_from([4, 8]))
def test_skin_kernel_matches_per_vertex_reference(seed, k):
    clip = make_clip(seed, 5, loop=True)
    c = make_character(seed, n_joints=5, k=k, clips=[clip])
    m = sample_motion(c, 0, np.linspace(0, 3, 4))
    got = skin(c, m)
    assert got.shape == (4, c.vertices.shape[0], 3) and got.dtype == np.float64
    for f in range(4):
        np.testing.assert_allclose(got[f], reference_lbs(c, m.joint_world[f] @ c.inverse_bind), atol=1e-10)
    np.testing.assert_allclose(skin_numpy(c, m), got, atol=1e-10)
    np.testing.assert_allclose(skin(c, m, frames=[2])[0], got[2], atol=0)


def test_motion_relative_frame():
    clip = make_clip(4, 4, loop=True)
    c = make_character(4, n_joints=4, clips=[clip])
    times = np.array([0.0, 0.3, 0.7])
    m = sample_motion(c, clip.name, times)
    g = forward_kinematics(c.parents, sample_clip(c, clip, times))
    root = g[:, c.root_joint, :3, 3]
    np.testing.assert_allclose(m.root_translation, root - root[0], atol=1e-12)
    world = m.joint_world.copy()
    world[..., :3, 3] += m.root_translation[:, None, :]
    np.testing.assert_allclose(world, g, atol=1e-12)
    np.testing.assert_allclose(m.joint_world[0], g[0], atol=1e-12)  # relative == world at frame 0
    later = sample_motion(c, clip.name, times + 0.25)
    np.testing.assert_allclose(later.times, times)  # Motion.times count from the first frame
    with pytest.raises(KeyError, match="no clip 'nope'"):
        sample_motion(c, "nope", times)


def test_rest_motion_reproduces_bind_mesh():
    c = make_character(5)
    m = rest_motion(c, 3, 1 / 30)
    np.testing.assert_allclose(m.times, [0, 1 / 30, 2 / 30])
    np.testing.assert_allclose(m.root_translation, 0.0)
    np.testing.assert_allclose(skin(c, m), np.broadcast_to(c.vertices, (3,) + c.vertices.shape), atol=1e-10)


def test_vertex_normals_against_reference():
    rng = np.random.default_rng(9)
    v = rng.normal(size=(20, 3))
    tri = rng.integers(0, 20, (40, 3))
    tri = tri[(tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2])]
    ref = np.zeros_like(v)
    for a, b, cc in tri:
        n = np.cross(v[b] - v[a], v[cc] - v[a])  # length 2 * area: area weighting
        for i in (a, b, cc):
            ref[i] += n
    used = np.linalg.norm(ref, axis=1) > 0
    ref[used] /= np.linalg.norm(ref[used], axis=1, keepdims=True)
    got = vertex_normals(v, tri.astype(np.int32))
    np.testing.assert_allclose(got, ref, atol=1e-12)
    # a closed box: outward normals along the corner diagonals
    import trimesh
    box = trimesh.creation.box()
    n = vertex_normals(box.vertices, box.faces)
    np.testing.assert_allclose(np.einsum("ij,ij->i", n, box.vertices / np.linalg.norm(box.vertices, axis=1, keepdims=True)),
                               1.0, atol=0.1)


def test_blend_in_starts_at_rest_and_joins_the_clip():
    clip = make_clip(7, 4, loop=True)
    c = make_character(7, n_joints=4, clips=[clip])
    times = np.linspace(0.2, 0.8, 7)
    plain = sample_motion(c, 0, times)
    blended = sample_motion(c, 0, times, blend_frames=5)
    assert blended.n_frames == 12
    np.testing.assert_allclose(blended.times, np.arange(12) * 0.1, atol=1e-12)
    rest = forward_kinematics(c.parents, c.rest_local)
    world0 = blended.joint_world[0].copy()
    world0[:, :3, 3] += blended.root_translation[0]
    np.testing.assert_allclose(world0, rest, atol=1e-9)          # frame 0 is the rest pose
    # after the blend the poses are the clip's; the relative frames differ by a constant offset
    a = blended.joint_world[5:].copy()
    a[..., :3, 3] += blended.root_translation[5:, None, :]
    b = plain.joint_world.copy()
    b[..., :3, 3] += plain.root_translation[:, None, :]
    shift = a[0, c.root_joint, :3, 3] - b[0, c.root_joint, :3, 3]
    b[..., :3, 3] += shift
    np.testing.assert_allclose(a, b, atol=1e-9)
