"""A small two-bone character for collider-fit tests: a closed tube along y that bends at its middle."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from stages.rig.transforms import forward_kinematics
from stages.rig.types import Character, Motion


def bent_tube(radius: float = 0.06, length: float = 0.6, rings: int = 25, around: int = 16,
              blend: float = 0.06) -> Character:
    """Tube from y = 0 to `length` (closed by two fans), bone 0 at the origin, bone 1 at mid length.
    Vertices within `blend` of the middle are weighted linearly between the two bones."""
    y = np.linspace(0.0, length, rings)
    th = np.linspace(0.0, 2 * np.pi, around, endpoint=False)
    ring = np.stack(np.broadcast_arrays(radius * np.cos(th)[None], y[:, None], radius * np.sin(th)[None]), -1)
    v = np.concatenate([ring.reshape(-1, 3), [[0.0, 0.0, 0.0], [0.0, length, 0.0]]])
    tris = []
    for r in range(rings - 1):
        for a in range(around):
            p, q = r * around + a, r * around + (a + 1) % around
            tris += [[p, q + around, q], [p, p + around, q + around]]
    bottom, top = rings * around, rings * around + 1
    for a in range(around):
        tris.append([bottom, a, (a + 1) % around])
        t0 = (rings - 1) * around
        tris.append([top, t0 + (a + 1) % around, t0 + a])
    tris = np.array(tris, np.int32)
    mid = length / 2
    w1 = np.clip((v[:, 1] - (mid - blend)) / (2 * blend), 0.0, 1.0)
    joints = np.tile(np.array([0, 1], np.int32), (v.shape[0], 1))
    weights = np.stack([1 - w1, w1], axis=1)
    rest = np.tile(np.eye(4), (2, 1, 1))
    rest[1, 1, 3] = mid
    inv_bind = np.linalg.inv(forward_kinematics(np.array([-1, 0]), rest))
    return Character(name="tube", vertices=v, triangles=tris, primitive_ids=np.zeros(v.shape[0], np.int32),
                     joint_names=("base", "tip"), parents=np.array([-1, 0], np.int32), rest_local=rest,
                     inverse_bind=inv_bind, skin_joints=joints, skin_weights=weights, source="test")


def bend_motion(character: Character, angles_deg) -> Motion:
    """Bone 1 turned about z by each angle (degrees), one frame each."""
    a = np.asarray(angles_deg, float)
    local = np.tile(character.rest_local, (a.size, 1, 1, 1))
    local[:, 1, :3, :3] = Rotation.from_euler("z", a[:, None], degrees=True).as_matrix()
    world = forward_kinematics(character.parents, local)
    return Motion("bend", np.arange(a.size) / 30.0, world, np.zeros((a.size, 3)))
