"""What holds a garment's most strained edges: the joints whose colliders they touch at a frame.

On a real character the strain a run warns about is mostly set by the colliders, not the solver
(docs/decisions.md, "Limbs, strain and the body"): a limb the animation swings within a centimetre
of the body traps the cloth between the two (CesiumMan's hands at the hips). This names them, so a
user can tell a trapped garment from a badly cut one, and choose (garments[].ignore_colliders).

    sources = strain_sources(positions, edges, strain, colliders, poses)   # {joint: share}
"""
from __future__ import annotations

import numpy as np

from stages.checks import ContractError, check_array
from stages.garments.band import collider_list as _colliders, signed_distance as _signed_distance

TOP_SHARE = 0.01    # the most strained edges: this share of them (the p99's tail), at least one
TOUCH = 0.005       # m: an edge touches a collider when an end is within this of its surface


def collider_distances(colliders, poses: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(C, N) signed distances (m, negative inside) of relative-frame points (N, 3) to every collider
    of `colliders` posed by `poses` (J + B, 4, 4: ColliderSet.frame_poses of the frame), and (C,)
    the joint each collider belongs to. Spheres: exact; hulls: the largest face-plane distance (exact
    inside, a lower bound outside, near corners slightly more than the true distance)."""
    cols = _colliders(colliders)
    out = np.empty((len(cols), points.shape[0]))
    for k, (_, _, collider, frame) in enumerate(cols):
        m = np.linalg.inv(poses[frame])
        out[k] = _signed_distance(collider, points @ m[:3, :3].T + m[:3, 3])
    return out, np.array([bone for bone, _, _, _ in cols], np.int64)


def strain_sources(positions: np.ndarray, edges: np.ndarray, strain: np.ndarray, colliders, poses: np.ndarray, *,
                   top: float = TOP_SHARE, reach: float = TOUCH) -> dict[int, float]:
    """{joint: share} of one garment's most strained edges at one frame (the `top` share of them
    by `strain`, at least one) with an end within `reach` (m) of a collider of that joint, largest
    share first; an edge touching several joints counts for each.

    positions: (N, 3) float64 m, relative frame (the colliders' frame at that frame);
    edges: (E, 2) int particle pairs; strain: (E,) their strain at that frame;
    poses: (J + B, 4, 4) the frame's collider poses (ColliderSet.frame_poses)."""
    n = check_array("strain_sources", "positions", positions, (None, 3), np.float64).shape[0]
    edges = np.asarray(edges, np.int64)
    if edges.ndim != 2 or edges.shape[1] != 2:
        raise ContractError(f"strain_sources.edges: expected shape (N, 2), got {edges.shape}")
    e = edges.shape[0]
    check_array("strain_sources", "strain", strain, (e,), np.float64)
    if e == 0 or colliders is None or not (colliders.hulls or colliders.spheres):
        return {}
    k = max(1, int(round(top * e)))
    hot = np.argsort(-strain, kind="stable")[:k]
    ends = np.unique(edges[hot].ravel())
    d, owner = collider_distances(colliders, poses, positions[ends])
    near = np.zeros((owner.max() + 1, n), bool)
    for c in range(d.shape[0]):
        near[owner[c], ends] |= d[c] < reach
    shares = {int(j): float((near[j, edges[hot, 0]] | near[j, edges[hot, 1]]).mean()) for j in np.unique(owner)}
    return dict(sorted(((j, s) for j, s in shares.items() if s > 0), key=lambda js: (-js[1], js[0])))
