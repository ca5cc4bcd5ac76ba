"""The colliders' poses at every sub-step of a chunk of frames (simulate.py hands them to the step
loop, stages.sim.step): joint matrices interpolated between frames (slerp + lerp for rigid rigs),
their inverses, and the root translation over each step (the relative simulation's terms).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def _is_rigid(m: np.ndarray) -> bool:
    r = m[..., :3, :3]
    return bool(np.allclose(np.einsum("...ij,...kj->...ik", r, r), np.eye(3), atol=1e-6))


def interpolate_poses(a: np.ndarray, b: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Poses between (J, 4, 4) a and b at fractions u (S,): (S, J, 4, 4); slerp + lerp when rigid,
    plain matrix lerp otherwise (scaled rigs)."""
    s, j = u.size, a.shape[0]
    if not (_is_rigid(a) and _is_rigid(b)):
        return (1 - u)[:, None, None, None] * a[None] + u[:, None, None, None] * b[None]
    from stages.rig.transforms import slerp
    qa = Rotation.from_matrix(a[:, :3, :3]).as_quat()
    qb = Rotation.from_matrix(b[:, :3, :3]).as_quat()
    q = slerp(np.broadcast_to(qa, (s, j, 4)), np.broadcast_to(qb, (s, j, 4)), np.broadcast_to(u[:, None], (s, j)))
    out = np.zeros((s, j, 4, 4))
    out[..., :3, :3] = Rotation.from_quat(q.reshape(-1, 4)).as_matrix().reshape(s, j, 3, 3)
    out[..., :3, 3] = (1 - u)[:, None, None] * a[None, :, :3, 3] + u[:, None, None] * b[None, :, :3, 3]
    out[..., 3, 3] = 1.0
    return out


def frame_poses(joint_world: np.ndarray, f: int, substeps: int):
    """End-of-step poses (S, J, 4, 4), their inverses, and the start-of-step inverses, frame f-1 -> f."""
    a, b = joint_world[f - 1], joint_world[f]
    if substeps == 1:
        fwd = b[None]
    else:
        fwd = interpolate_poses(a, b, np.arange(1, substeps + 1) / substeps)
        fwd[-1] = b  # exact at the frame
    inv = np.linalg.inv(fwd)
    inv0 = np.concatenate([np.linalg.inv(a)[None], inv[:-1]])
    return fwd, inv, inv0


def shift_tail(joint_world: np.ndarray) -> int:
    """The first of the trailing frames that only translate at every frame (a skinned ball's,
    ColliderSet.frame_poses); joint_world.shape[1] when none does."""
    r = joint_world[..., :3, :3]
    fixed = (r == np.eye(3)).all(axis=(0, 2, 3)) & (joint_world[..., 3, :] == [0, 0, 0, 1]).all(axis=(0, 2))
    k = fixed.size
    while k > 0 and fixed[k - 1]:
        k -= 1
    return k


def chunk_poses(motion, f0: int, f1: int, substeps: int, s: float, d_last):
    """Pose and root-translation arrays of the steps of frames f0..f1-1 (frame f steps from f-1 to f).

    Returns fwd, inv, inv0 ((f1 - f0) * substeps, J, 4, 4), d_prev, d_next ((f1 - f0) * substeps, 3),
    tr (substeps + 1, 3) the root translation at the step boundaries of frame f1 - 1 (relative to
    world, for obstacles), and the last step's d_next (the next chunk's d_prev).
    """
    root = motion.root_translation
    jw = motion.joint_world
    k = shift_tail(jw[f0 - 1:f1])       # frames k.. only translate: lerp and negate, no slerp or inverse
    n_steps, n = (f1 - f0) * substeps, jw.shape[1]
    fwd, inv, inv0 = (np.empty((n_steps, n, 4, 4)) for _ in range(3))
    if substeps == 1:
        fwd[:, :k] = jw[f0:f1, :k]
        inv_all = np.linalg.inv(jw[f0 - 1:f1, :k])
        inv[:, :k], inv0[:, :k] = inv_all[1:], inv_all[:-1]
    else:
        for i, f in enumerate(range(f0, f1)):
            s0 = i * substeps
            fwd[s0:s0 + substeps, :k], inv[s0:s0 + substeps, :k], inv0[s0:s0 + substeps, :k] = \
                frame_poses(jw[:, :k], f, substeps)
    if k < n:
        u = np.arange(1, substeps + 1) / substeps
        ta, tb = jw[f0 - 1:f1 - 1, k:, :3, 3], jw[f0:f1, k:, :3, 3]                  # (F, B, 3)
        t = (1 - u)[None, :, None, None] * ta[:, None] + u[None, :, None, None] * tb[:, None]
        t[:, -1] = tb                                                                 # exact at the frame
        t = t.reshape(n_steps, n - k, 3)
        t0 = np.concatenate([ta[:1], t[:-1]])
        for m, sign, tt in ((fwd, 1.0, t), (inv, -1.0, t), (inv0, -1.0, t0)):
            m[:, k:] = np.eye(4)
            m[:, k:, :3, 3] = sign * tt
    u = np.arange(substeps + 1) / substeps
    tr = root[f0 - 1:f1 - 1, None, :] + (root[f0:f1] - root[f0 - 1:f1 - 1])[:, None, :] * u[None, :, None]
    if s > 0:
        d_next = np.diff(tr, axis=1).reshape(-1, 3)
    else:
        d_next = np.zeros(((f1 - f0) * substeps, 3))
    d_prev = np.empty_like(d_next)
    d_prev[1:] = d_next[:-1]
    d_prev[0] = d_next[0] if d_last is None else d_last
    c = np.ascontiguousarray
    return c(fwd), c(inv), c(inv0), c(d_prev), c(d_next), tr[-1], d_next[-1].copy()
