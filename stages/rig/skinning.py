"""Clip sampling, motion (skinning matrices per frame) and linear blend skinning.

Frame conventions are those of `stages.rig.types`: `Motion.joint_world[f, j]` is joint j's global
transform at t_f in the relative frame (root translation of frame f minus frame 0 removed): it maps
bone-local points to relative-frame points; the skinning matrix is `joint_world @ inverse_bind`.
The relative frame equals world at frame 0.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse

from scipy.spatial.transform import Rotation

from stages.rig.blend import blend_schedule
from stages.rig.kernels import lbs_kernel
from stages.rig.transforms import forward_kinematics, slerp, trs_to_matrix
from stages.rig.types import Character, Clip, Motion


def clip_local_time(clip: Clip, times: np.ndarray) -> np.ndarray:
    """Clip key time for each playback time (seconds from the clip's start): wrap or clamp."""
    t = np.asarray(times, np.float64)
    if clip.loop and clip.duration > 0:
        return clip.times[0] + np.mod(t, clip.duration)
    return np.clip(clip.times[0] + t, clip.times[0], clip.times[-1])


def sample_clip(character: Character, clip: Clip, times) -> np.ndarray:
    """Local joint transforms (F, J, 4, 4) at playback `times` (F,) seconds from the clip start.

    linear: lerp translation / scale, slerp rotation between the two surrounding keys;
    step: hold the last key at or before the time. Looping clips wrap, others clamp.
    """
    if clip.translations.shape[1] != character.n_joints:
        raise ValueError(f"clip {clip.name!r} animates {clip.translations.shape[1]} joints, "
                         f"character {character.name!r} has {character.n_joints}")
    tl = np.atleast_1d(clip_local_time(clip, times))
    kt = clip.times
    if kt.size == 1:
        i = np.zeros(tl.size, np.int64)
        return trs_to_matrix(clip.translations[i], clip.rotations[i], clip.scales[i])
    i = np.clip(np.searchsorted(kt, tl, side="right") - 1, 0, kt.size - 1)
    if clip.interpolation == "step":
        return trs_to_matrix(clip.translations[i], clip.rotations[i], clip.scales[i])
    i = np.minimum(i, kt.size - 2)
    u = np.clip((tl - kt[i]) / (kt[i + 1] - kt[i]), 0.0, 1.0)[:, None]
    t = (1 - u)[..., None] * clip.translations[i] + u[..., None] * clip.translations[i + 1]
    s = (1 - u)[..., None] * clip.scales[i] + u[..., None] * clip.scales[i + 1]
    r = slerp(clip.rotations[i], clip.rotations[i + 1], u)
    return trs_to_matrix(t, r, s)


def _motion_from_globals(name: str, times: np.ndarray, globals_: np.ndarray, character: Character) -> Motion:
    root = globals_[:, character.root_joint, :3, 3]
    root_translation = root - root[0]
    joint_world = globals_.copy()
    joint_world[..., :3, 3] -= root_translation[:, None, :]
    return Motion(clip_name=name, times=np.asarray(times, np.float64), joint_world=joint_world,
                  root_translation=root_translation)


def sample_motion(character: Character, clip_key, times, *, blend_frames: int = 0) -> Motion:
    """The clip `clip_key` (name or index) sampled at playback `times` (F,) seconds from the clip start.

    blend_frames: prepend that many frames, at the spacing of `times`, that carry the character from
    its rest pose (`rest_local`) into the running clip (`stages.rig.blend`: the clip's weight and its
    speed both rise along smootherstep, so the blend ends at times[0] at the clip's own speed;
    translations and scales lerped, rotations slerped). Garments dressed on the rest pose can then
    follow any clip from any start. The returned Motion.times count from its first frame.
    """
    clip = character.clip(clip_key)
    times = np.atleast_1d(np.asarray(times, np.float64))
    local = sample_clip(character, clip, times)
    if blend_frames > 0:
        if times.size < 2:
            raise ValueError("sample_motion: blend_frames needs at least 2 clip times (for the spacing)")
        dt = times[1] - times[0]
        weights, clip_times = blend_schedule(blend_frames, dt, times[0])
        target = sample_clip(character, clip, clip_times)   # before 0: wrapped, or the first pose held
        local = np.concatenate([blend_local_each(character.rest_local, target, weights), local])
        times = times[0] + dt * np.arange(-blend_frames, times.size, dtype=np.float64)
    # Motion.times count from the first frame (the contract); the clip was sampled at `times`.
    return _motion_from_globals(clip.name, times - times[0], forward_kinematics(character.parents, local), character)


def blend_local_each(a: np.ndarray, b: np.ndarray, u: np.ndarray) -> np.ndarray:
    """(U, J, 4, 4) local transforms between a (J, 4, 4) and b[k] (U, J, 4, 4) at weights u (U,)."""
    return np.stack([blend_local(a, b[k], u[k:k + 1])[0] for k in range(len(u))]) if len(u) else b[:0]


def blend_local(a: np.ndarray, b: np.ndarray, u: np.ndarray) -> np.ndarray:
    """(U, J, 4, 4) local transforms between a and b (J, 4, 4) at weights u (U,): TRS blend."""
    def trs(m):
        scale = np.linalg.norm(m[:, :3, :3], axis=1)                    # column norms
        rot = Rotation.from_matrix(m[:, :3, :3] / scale[:, None, :]).as_quat()
        return m[:, :3, 3], rot, scale
    ta, ra, sa = trs(a)
    tb, rb, sb = trs(b)
    w = np.asarray(u, np.float64)[:, None, None]
    t = (1 - w) * ta + w * tb
    s = (1 - w) * sa + w * sb
    r = slerp(np.broadcast_to(ra, (len(u),) + ra.shape), np.broadcast_to(rb, (len(u),) + rb.shape),
              np.broadcast_to(np.asarray(u, np.float64)[:, None], (len(u), ra.shape[0])))
    return trs_to_matrix(t, r, s)


def rest_motion(character: Character, n_frames: int, dt: float) -> Motion:
    """The rest pose (`rest_local`) held for n_frames frames dt seconds apart."""
    if n_frames < 1:
        raise ValueError(f"rest_motion: n_frames must be >= 1, got {n_frames}")
    times = np.arange(n_frames, dtype=np.float64) * dt
    g = forward_kinematics(character.parents, character.rest_local)
    return _motion_from_globals("rest", times, np.broadcast_to(g, (n_frames,) + g.shape).copy(), character)


def skinning_matrices(character: Character, motion: Motion, frames=None) -> np.ndarray:
    """(F, J, 4, 4) joint_world @ inverse_bind: bind-pose model-frame points -> relative frame."""
    g = motion.joint_world if frames is None else motion.joint_world[np.atleast_1d(frames)]
    if g.shape[1] != character.n_joints:
        raise ValueError(f"motion {motion.clip_name!r} has {g.shape[1]} joints, character has {character.n_joints}")
    return g @ character.inverse_bind


def skin(character: Character, motion: Motion, frames=None) -> np.ndarray:
    """Linear-blend-skinned vertices (F, V, 3) float64 in the relative frame.

    frames: indices into the motion's frames (None = all). Add motion.root_translation[f] for world.
    """
    g = motion.joint_world if frames is None else motion.joint_world[np.atleast_1d(frames)]
    if g.shape[1] != character.n_joints:
        raise ValueError(f"motion {motion.clip_name!r} has {g.shape[1]} joints, character has {character.n_joints}")
    return skin_poses(character, g)


def skin_poses(character: Character, poses: np.ndarray) -> np.ndarray:
    """(F, V, 3) linear-blend-skinned vertices for joint world transforms `poses` (F, J, 4, 4)."""
    m = np.ascontiguousarray(poses @ character.inverse_bind)
    out = np.empty((m.shape[0], character.vertices.shape[0], 3))
    lbs_kernel(m, character.vertices, character.skin_joints, character.skin_weights, out)
    return out


def skin_numpy(character: Character, motion: Motion, frames=None) -> np.ndarray:
    """Vectorised numpy LBS (same result as `skin`; kept for the benchmark)."""
    m = skinning_matrices(character, motion, frames)
    v_h = np.concatenate([character.vertices, np.ones((character.vertices.shape[0], 1))], axis=1)
    out = np.empty((m.shape[0], v_h.shape[0], 3))
    for f in range(m.shape[0]):
        blend = np.einsum("vk,vkab->vab", character.skin_weights, m[f][character.skin_joints][:, :, :3, :])
        out[f] = np.einsum("vab,vb->va", blend, v_h)
    return out


def benchmark_skin(character: Character, n_frames: int = 100, repeats: int = 5) -> dict:
    """Best-of-`repeats` seconds of `skin` (numba) and `skin_numpy` on n_frames rest frames."""
    import time

    motion = rest_motion(character, n_frames, 1 / 30)
    skin(character, motion, [0])  # compile / load the cache outside the timing
    out = {}
    for fn in (skin, skin_numpy):
        best = np.inf
        for _ in range(repeats):
            t0 = time.perf_counter()
            fn(character, motion)
            best = min(best, time.perf_counter() - t0)
        out[fn.__name__] = best
    return out


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals for (V, 3) positions or a (F, V, 3) stack of them.

    Vertices in no non-degenerate triangle get 0. One sparse vertex-triangle incidence product per
    call, so a whole animation's normals cost one matrix multiply.
    """
    v = np.asarray(vertices, np.float64)
    p = v if v.ndim == 3 else v[None]
    tri = np.asarray(triangles, np.int64)
    f, nv, t = p.shape[0], p.shape[1], tri.shape[0]
    a = p[:, tri[:, 0]]
    fn = np.cross(p[:, tri[:, 1]] - a, p[:, tri[:, 2]] - a)  # (F, T, 3), |fn| = 2 * area
    incidence = scipy.sparse.csr_matrix((np.ones(3 * t), (tri.T.ravel(), np.tile(np.arange(t), 3))), shape=(nv, t))
    n = (incidence @ fn.transpose(1, 0, 2).reshape(t, -1)).reshape(nv, f, 3).transpose(1, 0, 2)
    length = np.linalg.norm(n, axis=-1, keepdims=True)
    n = np.divide(n, length, out=np.zeros_like(n), where=length > 1e-300)
    return n if v.ndim == 3 else n[0]


def pose_distance(character, local_a: np.ndarray, local_b: np.ndarray) -> float:
    """Farthest any skin vertex is between two poses (local transforms (J, 4, 4) each), with the root
    joints put on one another (relative simulation removes the root's translation), m."""
    g = forward_kinematics(character.parents, np.stack([local_a, local_b]))
    g = g.copy()
    g[..., :3, 3] -= g[:, character.root_joint, None, :3, 3]
    x = skin_poses(character, g)
    return float(np.linalg.norm(x[1] - x[0], axis=1).max(initial=0.0))
