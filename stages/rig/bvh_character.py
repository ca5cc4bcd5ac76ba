"""A skinned character from a BVH file: its skeleton (stages/rig/bvh.py), a skin generated around a
bind pose, and its motion.

Character bind pose (`load_bvh_character(bind_pose=...)`): the skin is generated around it, so
whatever touches there stays joined for the whole clip. 'neutral' (default, `stages.rig.neutral_pose`)
re-poses the skeleton upright with the limbs apart; 'frame0' is a frame of the clip, where the CMU
subject has the hands on the hips; 'rest' is the BVH rest pose (all channels zero), in the CMU
capture legs splayed ~20 degrees and arms straight down.
"""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from stages.rig.bvh import BvhData, bvh_clip, parse_bvh
from stages.rig.transforms import forward_kinematics, trs_to_matrix
from stages.rig.types import Character, Clip


BIND_POSES = ("neutral", "frame0", "rest")


def _bind_locals(data: BvhData, clip: Clip, bind_pose: str, bind_frame: int):
    """Bind-pose local translations (J, 3) and rotations (J, 4), root moved over the origin, and
    the `Humanoid` parts when the neutral pose was built (else None)."""
    from stages.rig.neutral_pose import neutral_pose

    if bind_pose not in BIND_POSES:
        raise ValueError(f"bind_pose must be one of {', '.join(BIND_POSES)}, got {bind_pose!r}")
    if bind_frame is None or not -data.n_frames <= bind_frame < data.n_frames:
        hint = " (the BVH rest pose is bind_pose='rest')" if bind_frame is None else ""
        raise ValueError(f"bind_frame {bind_frame} out of range [0, {data.n_frames}){hint}")
    trans, rots, parts = clip.translations[bind_frame].copy(), clip.rotations[bind_frame].copy(), None
    if bind_pose == "rest":  # offsets only, no rotation
        trans, rots = data.offsets.copy(), np.tile([0.0, 0.0, 0.0, 1.0], (data.n_joints, 1))
    elif bind_pose == "neutral":
        first = forward_kinematics(data.parents, trs_to_matrix(clip.translations[0], clip.rotations[0]))
        neutral, parts, note = neutral_pose(data.parents, clip.translations[0], data.joint_names, first[:, :3, 3])
        if neutral is None:
            warnings.warn(f"{data.source}: no neutral bind pose, {note}; the skin is built around "
                          f"frame {bind_frame} instead", stacklevel=3)
        else:
            trans, rots = clip.translations[0].copy(), neutral
    trans[0, [0, 2]] = 0.0  # the root's horizontal position is not part of the pose
    return trans, rots, parts


def _lowest_skinned_point(vertices, skin_joints, skin_weights, joint_matrices) -> float:
    """Lowest y of the linear-blend-skinned mesh for one frame's skinning matrices (J, 4, 4)."""
    m = joint_matrices[:, 1, :]  # only the y row is needed
    y = np.einsum("vki,vi->vk", m[skin_joints][..., :3], vertices) + m[skin_joints][..., 3]
    return float((skin_weights * y).sum(axis=1).min())


def load_bvh_character(path, *, scale: float = 1.0, body=None, bind_pose: str = "neutral",
                       bind_frame: int = 0, name: str | None = None) -> Character:
    """A skinned character from a BVH file: its skeleton, a generated skin and its motion.

    bind_pose: the pose the skin is generated around and bound in (`inverse_bind`, `rest_local`):
    'neutral' (default): the skeleton upright, legs straight and slightly apart, arms in an A-pose,
    facing as at the clip's frame 0 (`stages.rig.neutral_pose`), so no limb is fused to another;
    a skeleton not recognised as a humanoid falls back to frame `bind_frame` with a warning.
    'frame0': frame `bind_frame`'s pose (default 0, the first frame). 'rest': the BVH rest pose
    (offsets only). The root is moved over the origin in every case.
    Skin: `stages.rig.capsule_skin.skin_skeleton` around the bind-pose joint positions (end sites
    included), with `body` (a `BodyParams`, default when None); weights from that generator, and
    in the neutral pose smoothed across the crotch (`stages.rig.neutral_pose.soften_seam`).
    Placement: the bind mesh is shifted to stand on y = 0; the clip's root translation is shifted
    by one constant so that at the clip's frame 0 the root is over the origin (x = z = 0) and the
    skinned mesh's lowest point is on y = 0 (with 'frame0' and bind_frame=0, frame 0 IS the bind
    pose). Y up, metres after `scale`; the root joint (index 0) is the character's root.
    """
    from stages.rig.neutral_pose import soften_seam, subtree
    from stages.rig.capsule_skin import skin_skeleton
    from stages.rig.procedural import BodyParams

    data = parse_bvh(path, scale=scale)
    stem = Path(path).stem
    clip = bvh_clip(data, name=stem)
    bind_t, bind_r, parts = _bind_locals(data, clip, bind_pose, bind_frame)
    rest_local = trs_to_matrix(bind_t, bind_r)
    bind_world = forward_kinematics(data.parents, rest_local)
    vertices, triangles, skin_joints, skin_weights = skin_skeleton(
        data.joint_names, data.parents, bind_world[:, :3, 3].copy(), body if body is not None else BodyParams())
    vertices = np.asarray(vertices, dtype=np.float64)
    skin_joints = np.asarray(skin_joints, dtype=np.int32)
    skin_weights = np.asarray(skin_weights, dtype=np.float64)
    if parts is not None:  # the thighs touch at the crotch: spread the jump between them
        legs = [subtree(data.parents, chain[0]) for chain in parts.legs]
        skin_joints, skin_weights = soften_seam(triangles, skin_joints, skin_weights, *legs)

    lift = -float(vertices[:, 1].min())
    vertices = vertices + [0.0, lift, 0.0]
    rest_local[0, 1, 3] += lift  # the root has no parent: its local frame is the model frame
    bind_world[:, 1, 3] += lift
    inverse_bind = np.linalg.inv(bind_world)

    # Place the clip: frame 0's root over the origin, frame 0's skinned mesh on the floor.
    trans = clip.translations.copy()
    trans[:, 0, [0, 2]] -= trans[0, 0, [0, 2]]
    first = forward_kinematics(data.parents, trs_to_matrix(trans[0], clip.rotations[0]))
    trans[:, 0, 1] -= _lowest_skinned_point(vertices, skin_joints, skin_weights, first @ inverse_bind)
    clip = Clip(name=clip.name, times=clip.times, translations=trans, rotations=clip.rotations,
                scales=clip.scales, interpolation=clip.interpolation, loop=clip.loop)

    return Character(
        name=name or stem,
        vertices=vertices,
        triangles=np.asarray(triangles, dtype=np.int32),
        primitive_ids=np.zeros(vertices.shape[0], dtype=np.int32),
        joint_names=data.joint_names,
        parents=data.parents,
        rest_local=rest_local,
        inverse_bind=inverse_bind,
        skin_joints=skin_joints,
        skin_weights=skin_weights,
        clips=(clip,),
        root_joint=0,
        source=str(path),
    )
