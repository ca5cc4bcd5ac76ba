"""The poses a character's colliders must fit, and how far each vertex moves in each bone's frame.

- `range_of_motion`: a built-in range-of-motion sample for a character without motion (`clip:
  rest`): the rest pose, then every joint that has a parent and a child turned alone by +-angle
  about each of its own three axes. It is what "moves rigidly with bone b" means when no clip says.
- `bone_deviation`: per vertex and influence slot, the largest distance over the poses between the
  vertex (linear-blend skinned) seen in that bone's frame and where it sits in that frame in the
  bind pose. 0 means the vertex moves rigidly with the bone over the whole sample.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from stages.rig.skinning import skin_poses
from stages.rig.transforms import forward_kinematics
from stages.rig.types import Character

ROM_ANGLE_DEG = 30.0


def range_of_motion(character: Character, angle_deg: float = ROM_ANGLE_DEG) -> np.ndarray:
    """(F, J, 4, 4) joint world transforms (model frame): rest pose + 6 single-joint turns per
    inner joint (a joint with a parent and at least one child), F = 1 + 6 * inner joints."""
    local = character.rest_local
    has_child = np.zeros(character.n_joints, bool)
    has_child[character.parents[character.parents >= 0]] = True
    inner = [j for j in range(character.n_joints) if character.parents[j] >= 0 and has_child[j]]
    turns = Rotation.from_rotvec(np.deg2rad(angle_deg) * np.concatenate([np.eye(3), -np.eye(3)])).as_matrix()
    poses = [local]
    for j in inner:
        for r in turns:
            p = local.copy()
            p[j, :3, :3] = local[j, :3, :3] @ r
            poses.append(p)
    return forward_kinematics(character.parents, np.stack(poses))


def bone_deviation(character: Character, poses: np.ndarray, skinned: np.ndarray | None = None) -> np.ndarray:
    """(V, K) float64, metres: max over poses of |inv(poses[f, b]) x_f(v) - inverse_bind[b] v|
    for b = skin_joints[v, k] (x_f: the skinned vertex at pose f)."""
    sj = character.skin_joints
    x = skin_poses(character, poses) if skinned is None else skinned
    ib = character.inverse_bind[sj]                                     # (V, K, 4, 4)
    bind_local = np.einsum("vkij,vj->vki", ib[..., :3, :3], character.vertices) + ib[..., :3, 3]
    inv = np.linalg.inv(poses)
    dev = np.zeros(sj.shape)
    for f in range(poses.shape[0]):
        m = inv[f][sj]                                                   # (V, K, 4, 4)
        local = np.einsum("vkij,vj->vki", m[..., :3, :3], x[f]) + m[..., :3, 3]
        np.maximum(dev, np.linalg.norm(local - bind_local, axis=-1), out=dev)
    return dev


def local_tracks(character: Character, poses: np.ndarray, vertices: np.ndarray, bone: int,
                 skinned: np.ndarray) -> np.ndarray:
    """(F * n, 3) positions of `vertices` (n,) in bone `bone`'s frame at every pose (skinned:
    (F, V, 3) from `stages.rig.skinning.skin_poses`), plus their bind-pose positions in that frame."""
    inv = np.linalg.inv(poses[:, bone])                                  # (F, 4, 4)
    x = skinned[:, vertices]                                             # (F, n, 3)
    local = np.einsum("fij,fnj->fni", inv[:, :3, :3], x) + inv[:, None, :3, 3]
    ib = character.inverse_bind[bone]
    bind = character.vertices[vertices] @ ib[:3, :3].T + ib[:3, 3]
    return np.concatenate([bind, local.reshape(-1, 3)])
