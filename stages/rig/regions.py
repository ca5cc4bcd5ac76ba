"""Skinning-aware region split (paper A §3.1): rigid regions per bone, flexible regions per joint.

Two splits (scene key `colliders.split`):
- `motion` (default): a vertex is rigid for bone b when, over the scene's motion (or a range-of-
  motion sample), it stays within a tolerance of its bind position in b's frame (`split_by_motion`).
  This is what a hull in b's frame needs; joints that barely move in the clip leave no flexible band.
- `weights` (the paper's reading with LBS weights): rigid when the dominant weight >= threshold
  (`split_regions`).
Shared rules:
- Influences of one vertex on the same joint (the joint repeated in several slots) are summed first.
- weights: rigid region of bone b = vertices whose dominant weight >= threshold (1e-6 slack for
  the renormalisation round-off) and whose dominant joint is b.
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


def _between(character: Character, w: np.ndarray):
    """Per vertex: dominant joint and weight, and the joint between its two heaviest bones (the
    child's joint if one is the other's parent, else the deeper, ties: larger index), and whether
    it has a second influence at all."""
    sj = character.skin_joints
    rows = np.arange(sj.shape[0])
    k_dom = np.argmax(w, axis=1)
    dom_j = sj[rows, k_dom].astype(np.int32)
    dom_w = w[rows, k_dom]
    w_other = np.where(sj == dom_j[:, None], -1.0, w)
    k_sec = np.argmax(w_other, axis=1)
    sec_j = sj[rows, k_sec]
    has_sec = w_other[rows, k_sec] > 0
    parents = character.parents
    depth = _depths(parents)
    a, b = dom_j.astype(np.int64), sec_j.astype(np.int64)
    between = np.where(parents[b] == a, b,
                       np.where(parents[a] == b, a,
                                np.where((depth[b] > depth[a]) | ((depth[b] == depth[a]) & (b > a)), b, a)))
    return dom_j, dom_w, between.astype(np.int32), has_sec


def _merge_small(character: Character, rigid: np.ndarray, region: np.ndarray, min_points: int,
                 flat_tol: float) -> list[str]:
    """Rigid regions that cannot carry a hull join a flexible region (see module doc); in place."""
    notes = []
    parents = character.parents
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
    return notes


def split_regions(character: Character, threshold: float = 0.9, min_points: int = 4,
                  flat_tol: float = 1e-3) -> RegionSplit:
    """Split by skin weights (the paper's reading with LBS weights): rigid = dominant weight >=
    threshold; see module doc."""
    w = _combined_weights(character.skin_joints, character.skin_weights)
    dom_j, dom_w, between, has_sec = _between(character, w)
    rigid = dom_w >= threshold - _RIGID_SLACK
    region = np.where(rigid | ~has_sec, dom_j, between).astype(np.int32)
    rigid = rigid | ~has_sec  # a vertex with a single influence is rigid whatever the threshold
    notes = _merge_small(character, rigid, region, min_points, flat_tol)
    return RegionSplit(
        dominant_joint=dom_j, dominant_weight=dom_w.astype(np.float64), rigid=rigid, region_joint=region,
        hull_bones=tuple(int(x) for x in np.unique(region[rigid])),
        sphere_joints=tuple(int(x) for x in np.unique(region[~rigid])),
        threshold=float(threshold), notes=tuple(notes))


def split_by_motion(character: Character, deviation: np.ndarray, tolerance: float, min_points: int = 4,
                    flat_tol: float = 1e-3) -> RegionSplit:
    """Split by how vertices move: rigid for bone b when the vertex stays within `tolerance` (m) of
    its bind position in b's frame over the motion sample (`deviation` (V, K) from
    stages.rig.motion_range.bone_deviation, per influence slot). Among the bones it is rigid for, a
    vertex takes the heaviest; the others are flexible, at the joint between their two heaviest
    bones (as the weight split). Small or flat rigid regions merge as in `split_regions`."""
    sj = character.skin_joints
    w = _combined_weights(sj, character.skin_weights)
    if deviation.shape != sj.shape:
        raise ValueError(f"split_by_motion: deviation has shape {deviation.shape}, skin_joints {sj.shape}")
    dom_j, dom_w, between, _ = _between(character, w)
    ok = (deviation <= tolerance) & (w > 0)
    rigid = ok.any(axis=1)
    best = np.argmax(np.where(ok, w, -1.0), axis=1)
    rigid_bone = sj[np.arange(sj.shape[0]), best]
    region = np.where(rigid, rigid_bone, between).astype(np.int32)
    notes = _merge_small(character, rigid, region, min_points, flat_tol)
    return RegionSplit(
        dominant_joint=dom_j, dominant_weight=dom_w.astype(np.float64), rigid=rigid, region_joint=region,
        hull_bones=tuple(int(x) for x in np.unique(region[rigid])),
        sphere_joints=tuple(int(x) for x in np.unique(region[~rigid])),
        threshold=1.0, notes=tuple(notes), method="motion", tolerance=float(tolerance),
        deviation=np.where(w > 0, deviation, np.inf).min(axis=1))


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
