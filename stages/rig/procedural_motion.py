"""Procedural clips for the procedural humanoid (stages.rig.procedural): rest, walk, arm_raise, turn.

Every clip keys all joints at `params.keys_per_second`, as local TRS in the parent's frame
(quaternions xyzw). The procedural skeleton's bind rotations are the identity, so a joint's local
rotation is expressed in world-aligned axes of its parent: about +X bends in the sagittal plane
(positive swings a downward limb backward), about +Z raises the left arm, about +Y turns left.

Looping a translating clip: the walk's root (pelvis) translation advances along +Z at
`params.walk_speed`; wrapping it would teleport the character back, so the walk clip has
loop=False and is `params.walk_cycles` gait cycles long instead. Rotations repeat exactly every
cycle, so a longer walk is just a larger `walk_cycles`.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from stages.checks import ContractError
from stages.rig.transforms import forward_kinematics, trs_to_matrix
from stages.rig.types import Clip

CLIP_NAMES = ("rest", "walk", "arm_raise", "turn")


def make_clip(name: str, joint_names, parents, rest_local: np.ndarray, params) -> Clip:
    """Build procedural clip `name` for the procedural skeleton (joint names as in
    `humanoid_skeleton`). rest_local: (J, 4, 4) bind-pose local transforms (identity rotations)."""
    builders = {"rest": rest_clip, "walk": walk_clip, "arm_raise": arm_raise_clip, "turn": turn_clip}
    if name not in builders:
        raise ContractError(f"make_clip: unknown procedural clip {name!r}; available: {list(CLIP_NAMES)}")
    return builders[name](tuple(joint_names), np.asarray(parents), rest_local, params)


def _keys(duration, params):
    n = max(int(round(duration * params.keys_per_second)), 1)
    return np.linspace(0.0, duration, n + 1)


def _base(times, rest_local):
    k, j = times.size, rest_local.shape[0]
    trans = np.broadcast_to(rest_local[:, :3, 3], (k, j, 3)).copy()
    rots = np.zeros((k, j, 4))
    rots[..., 3] = 1.0
    return trans, rots, np.ones((k, j, 3))


def _rot(axis, angles):
    """(K,4) quaternions for rotations of `angles` (radians, (K,)) about a world axis."""
    axis = np.asarray(axis, dtype=np.float64)
    return Rotation.from_rotvec(np.asarray(angles)[:, None] * axis).as_quat()


def _ease(u):
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def rest_clip(names, parents, rest_local, params) -> Clip:
    """The bind pose held for one second (loops trivially)."""
    t = np.array([0.0, 1.0])
    tr, rot, sc = _base(t, rest_local)
    return Clip("rest", t, tr, rot, sc, loop=True)


def walk_clip(names, parents, rest_local, params) -> Clip:
    """Walk along +Z: legs swing +-20 degrees with knee flexion in swing, opposite arm swing, pelvis
    twist with counter-rotating chest; the pelvis height follows from keeping the lower foot on the
    ground (forward kinematics), which gives the natural double-support dip. Root z = speed * t."""
    ix = {n: i for i, n in enumerate(names)}
    period = params.walk_period
    t = _keys(period * params.walk_cycles, params)
    tr, rot, sc = _base(t, rest_local)
    phi = 2.0 * np.pi * t / period
    x, y = [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]
    hip_a, arm_a = np.radians(20.0), np.radians(18.0)
    for side, ph in (("l", phi), ("r", phi + np.pi)):
        thigh = -hip_a * np.sin(ph)  # negative about X = forward
        knee = np.radians(4.0) + np.radians(50.0) * np.maximum(0.0, np.cos(ph)) ** 2
        foot = -0.8 * (thigh + knee) + np.radians(3.0)
        rot[:, ix[f"thigh_{side}"]] = _rot(x, thigh)
        rot[:, ix[f"shin_{side}"]] = _rot(x, knee)
        rot[:, ix[f"foot_{side}"]] = _rot(x, foot)
        rot[:, ix[f"toes_{side}"]] = _rot(x, -np.radians(15.0) * np.maximum(0.0, -np.cos(ph)))
        # arm opposite to the same-side leg
        rot[:, ix[f"upperarm_{side}"]] = _rot(x, arm_a * np.sin(ph))
        rot[:, ix[f"forearm_{side}"]] = _rot(x, -np.radians(12.0) - np.radians(10.0) * (1 - np.sin(ph)) / 2)
    twist = np.radians(5.0) * np.sin(phi)
    rot[:, ix["pelvis"]] = _rot(y, twist)
    rot[:, ix["spine"]] = _rot(y, -1.5 * twist)
    tr[:, ix["pelvis"], 2] += params.walk_speed * t
    # ground the lower foot: drop the pelvis by how far the lowest foot joint rose above its rest
    world = forward_kinematics(parents, trs_to_matrix(tr, rot, sc))
    rest_world = forward_kinematics(parents, rest_local)
    feet = [ix[n] for n in ("foot_l", "foot_r", "toes_l", "toes_r")]
    rise = (world[:, feet, 1, 3] - rest_world[feet, 1, 3]).min(axis=1)
    tr[:, ix["pelvis"], 1] -= rise
    return Clip("walk", t, tr, rot, sc, loop=False)


def arm_raise_clip(names, parents, rest_local, params) -> Clip:
    """Both arms rise sideways 80 degrees from the bind pose (1.2 s), hold (0.6 s), lower (1.2 s);
    ends where it starts, so it loops."""
    ix = {n: i for i, n in enumerate(names)}
    t = _keys(3.0, params)
    tr, rot, sc = _base(t, rest_local)
    u = np.where(t < 1.5, _ease(t / 1.2), _ease((3.0 - t) / 1.2))
    a = np.radians(80.0) * u
    z = [0.0, 0.0, 1.0]
    rot[:, ix["upperarm_l"]] = _rot(z, a)
    rot[:, ix["upperarm_r"]] = _rot(z, -a)
    rot[:, ix["clavicle_l"]] = _rot(z, 0.15 * a)
    rot[:, ix["clavicle_r"]] = _rot(z, -0.15 * a)
    rot[:, ix["forearm_l"]] = _rot(z, 0.1 * a)
    rot[:, ix["forearm_r"]] = _rot(z, -0.1 * a)
    return Clip("arm_raise", t, tr, rot, sc, loop=True)


def turn_clip(names, parents, rest_local, params) -> Clip:
    """One full turn to the left about +Y in place (pelvis), eased in and out over 4 s; it ends in
    its start pose at rest speed, so it loops."""
    ix = {n: i for i, n in enumerate(names)}
    t = _keys(4.0, params)
    tr, rot, sc = _base(t, rest_local)
    rot[:, ix["pelvis"]] = _rot([0.0, 1.0, 0.0], 2.0 * np.pi * _ease(t / 4.0))
    return Clip("turn", t, tr, rot, sc, loop=True)
