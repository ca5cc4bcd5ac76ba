"""Skinning-aware region split (paper A §3.1): rigid regions per bone, flexible regions per joint.

- Influences of one vertex on the same joint (the joint repeated in several slots) are summed first.
- Rigid region of bone b: vertices whose dominant weight >= threshold (1e-6 slack for the
  renormalisation round-off) and whose dominant joint is b.
- Flexible region: every other vertex goes to the joint between its two heaviest bones a, b: the
  child's joint if one is the other's parent, otherwise the deeper of the two (ties: larger index).
- A rigid region that cannot carry a hull (fewer than `min_points` vertices, or its centred points
  have rank < 3: smallest singular value <= flat_tol * largest) is merged into the flexible region
  of the joint nearest to its centroid among bone b's own joint and its children's joints (in the
  bind pose). Why not the parent bone's hull: those vertices move with b, not with the parent, so
  they would leave the parent's hull as soon as b rotates; a sphere at b's joint (or at the end of
  b) is rotation-invariant about its centre. Each merge is listed in `notes`.
- Joints whose flexible region ends up empty get no sphere.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from stages.rig.types import Character, RegionSplit

_RIGID_SLACK = 1e-6


def _combined_weights(joints: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(V, K) weights with every slot holding the total weight of its joint in that vertex."""
    same = joints[:, :, None] == joints[:, None, :]
    return np.einsum("vkl,vl->vk", same, weights)


def _depths(parents: np.ndarray) -> np.ndarray:
    d = np.zeros(parents.size, np.int64)
    for j in range(1, parents.size):
        d[j] = d[parents[j]] + 1
    return d


def is_hull_ready(points: np.ndarray, min_points: int = 4, flat_tol: float = 1e-3) -> bool:
    """Whether `points` (N, 3) can carry a 3D convex hull: >= min_points and rank 3 with tolerance."""
    if points.shape[0] < max(min_points, 4):
        return False
    sv = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    return bool(sv[0] > 0 and sv[2] > flat_tol * sv[0])


def split_regions(character: Character, threshold: float = 0.9, min_points: int = 4,
                  flat_tol: float = 1e-3) -> RegionSplit:
    """Split the bind-pose mesh into rigid (hull) and flexible (sphere) regions; see module doc."""
    sj = character.skin_joints
    w = _combined_weights(sj, character.skin_weights)
    nv = sj.shape[0]
    rows = np.arange(nv)
    k_dom = np.argmax(w, axis=1)
    dom_j = sj[rows, k_dom].astype(np.int32)
    dom_w = w[rows, k_dom]
    w_other = np.where(sj == dom_j[:, None], -1.0, w)
    k_sec = np.argmax(w_other, axis=1)
    sec_j = sj[rows, k_sec]
    has_sec = w_other[rows, k_sec] > 0

    parents = character.parents
    depth = _depths(parents)
    rigid = dom_w >= threshold - _RIGID_SLACK
    a, b = dom_j.astype(np.int64), sec_j.astype(np.int64)
    between = np.where(parents[b] == a, b,
                       np.where(parents[a] == b, a,
                                np.where((depth[b] > depth[a]) | ((depth[b] == depth[a]) & (b > a)), b, a)))
    region = np.where(rigid | ~has_sec, dom_j, between).astype(np.int32)
    rigid = rigid | ~has_sec  # a vertex with a single influence is rigid whatever the threshold

    notes = []
    bind_joint_pos = np.linalg.inv(character.inverse_bind)[:, :3, 3]
    children = [np.flatnonzero(parents == j) for j in range(character.n_joints)]
    names = character.joint_names
    for bone in np.unique(region[rigid]):
        idx = np.flatnonzero(rigid & (region == bone))
        pts = character.vertices[idx]
        if is_hull_ready(pts, min_points, flat_tol):
            continue
        candidates = np.concatenate([[bone], children[bone]])
        d = np.linalg.norm(bind_joint_pos[candidates] - pts.mean(axis=0), axis=1)
        target = int(candidates[np.argmin(d)])
        rigid[idx] = False
        region[idx] = target
        why = "fewer than %d points" % max(min_points, 4) if idx.size < max(min_points, 4) else "flat (rank < 3)"
        notes.append(f"rigid region of bone {bone} ({names[bone]}): {idx.size} vertices, {why}; "
                     f"merged into the flexible region of joint {target} ({names[target]})")

    hull_bones = tuple(int(x) for x in np.unique(region[rigid]))
    sphere_joints = tuple(int(x) for x in np.unique(region[~rigid]))
    return RegionSplit(
        dominant_joint=dom_j,
        dominant_weight=dom_w.astype(np.float64),
        rigid=rigid,
        region_joint=region,
        hull_bones=hull_bones,
        sphere_joints=sphere_joints,
        threshold=float(threshold),
        notes=tuple(notes),
    )


def region_report(split: RegionSplit, joint_names: Sequence[str] | None = None) -> list[dict]:
    """One row per region: kind ('rigid' hull / 'flexible' sphere), joint index, name, vertex count."""
    rows = []
    for kind, joints, mask in (("rigid", split.hull_bones, split.rigid), ("flexible", split.sphere_joints, ~split.rigid)):
        for j in joints:
            rows.append({
                "kind": kind,
                "joint": int(j),
                "name": joint_names[j] if joint_names is not None else f"joint_{j}",
                "vertices": int(np.count_nonzero(mask & (split.region_joint == j))),
            })
    return rows
