"""Rigid-body transform helpers shared by every rig source (glTF, BVH, procedural).

Quaternions are xyzw (scipy order). Matrices are (..., 4, 4) float64 acting on column vectors.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def trs_to_matrix(translation: np.ndarray, rotation: np.ndarray, scale: np.ndarray | None = None) -> np.ndarray:
    """Compose T @ R @ S.

    translation: (..., 3); rotation: (..., 4) unit quaternions xyzw; scale: (..., 3) or None.
    Returns (..., 4, 4) float64.
    """
    translation = np.asarray(translation, dtype=np.float64)
    rotation = np.asarray(rotation, dtype=np.float64)
    batch = translation.shape[:-1]
    r = Rotation.from_quat(rotation.reshape(-1, 4)).as_matrix().reshape(batch + (3, 3))
    if scale is not None:
        r = r * np.asarray(scale, dtype=np.float64)[..., None, :]
    m = np.zeros(batch + (4, 4))
    m[..., :3, :3] = r
    m[..., :3, 3] = translation
    m[..., 3, 3] = 1.0
    return m


def forward_kinematics(parents: np.ndarray, local: np.ndarray, base: np.ndarray | None = None) -> np.ndarray:
    """Global joint transforms from local ones.

    parents: (J,) int, parents[j] < j, -1 for roots. local: (..., J, 4, 4).
    base: optional (4, 4) transform of whatever sits above the roots (glTF ancestor nodes).
    Returns (..., J, 4, 4): world[j] = world[parents[j]] @ local[j].
    """
    world = np.empty_like(local)
    for j, p in enumerate(parents):
        if p < 0:
            world[..., j, :, :] = local[..., j, :, :] if base is None else base @ local[..., j, :, :]
        else:
            world[..., j, :, :] = world[..., p, :, :] @ local[..., j, :, :]
    return world


def slerp(q0: np.ndarray, q1: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Shortest-arc spherical interpolation of unit quaternions.

    q0, q1: (..., 4) xyzw; u: broadcastable to (...,) in [0, 1]. Returns (..., 4) unit quaternions.
    """
    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin = np.sin(theta)
    near = sin < 1e-9  # nearly parallel: lerp is exact to rounding
    safe = np.where(near, 1.0, sin)
    w0 = np.where(near, 1.0 - u, np.sin((1.0 - u) * theta) / safe)
    w1 = np.where(near, u, np.sin(u * theta) / safe)
    q = w0 * q0 + w1 * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def transform_points(m: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply (4, 4) transform m to (N, 3) points."""
    return points @ m[:3, :3].T + m[:3, 3]
