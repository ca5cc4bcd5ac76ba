"""GarmentCode tops closed over the shoulders, not through them.

GarmentCode lays a top's front and back panels upright in front of and behind its body, their
shoulder seams 20-25 cm apart front to back; the sewing pulls the two edges straight together, so
they meet half-way between, wherever that is. Mapped onto a character, those seams start a few
centimetres below the top of its shoulders (the sampled tee on the CMU walk: up to 5.6 cm under the
shoulders' skin and colliders), so the seam closed inside the shoulders, was pushed out below them
and the top slid down the sloping shoulders: the tee's top sank 10 cm in the first 2 sewing rounds
and went on sinking, and the settled tee hung from its waistband at the hips. Here the placed
garment is lifted until every shoulder seam would close above the shoulders it crosses.
"""
from __future__ import annotations

import numpy as np

SEAM_DEPTH = 0.05   # m: a stitch whose pairs start this far apart front to back (median) crosses the shoulders
SURFACE_RADIUS = 0.03   # m: the shoulders' height under a seam point: the highest point this near it, from above
UNDER_LIMB = 0.1    # m: a seam point this far or more under the surface above it is under an arm, not on a shoulder


def shoulder_pairs(placed: np.ndarray, flat, arm_panel: np.ndarray, axis: np.ndarray, above: float,
                   below: float) -> np.ndarray:
    """(K, 2) the seam pairs of `flat` (FlatPattern) of the stitches that join a panel in front of the
    character's vertical axis (axis: (3,), x and z used) to one behind it over the top of the body:
    both sides not arm panels (arm_panel: (P,) bool by panel), each pair with one vertex in front
    and one behind, SEAM_DEPTH or more apart front to back (median over the stitch) and above the
    height `above` (m, median), both panels mostly (median) below the height `below` (the top of the
    shoulders: a hood's seams to the neckline, over the head, are not shoulder seams; counted, they
    lifted the sampled hoodie 25 cm, off the shoulders onto the head)."""
    pairs, pv = flat.seam_pairs, flat.panel_of_vertex
    if pairs.size == 0:
        return pairs.reshape(0, 2)
    keep = np.zeros(len(pairs), bool)
    level = np.array([np.median(placed[pv == k, 1]) if (pv == k).any() else np.inf for k in range(len(arm_panel))])
    for j in np.unique(flat.seam_index):
        sel = np.flatnonzero(flat.seam_index == j)
        a, b = pairs[sel, 0], pairs[sel, 1]
        if arm_panel[pv[a]].any() or arm_panel[pv[b]].any() or (level[pv[a]] >= below).any() or (level[pv[b]] >= below).any():
            continue
        za, zb = placed[a, 2] - axis[2], placed[b, 2] - axis[2]
        across = (za * zb < 0) & (np.abs(za - zb) >= SEAM_DEPTH)
        mid_y = 0.5 * (placed[a, 1] + placed[b, 1])
        if np.median(np.abs(za - zb)) >= SEAM_DEPTH and np.median(mid_y) > above:
            keep[sel[across]] = True
    return pairs[keep]


def shoulder_lift(placed: np.ndarray, pairs: np.ndarray, surface: np.ndarray, clearance: float) -> float:
    """How far (m, >= 0) the garment must go up for each pair's midpoint (where its straight-line
    closing meets) to lie `clearance` above the highest point of `surface` ((N, 3): skin and collider
    points of the shoulders, the neck and head left out) within SURFACE_RADIUS of it, seen from above.
    Points with nothing under them (a seam end beside the neck) ask for nothing, nor do points
    UNDER_LIMB or more under that surface: they are under an arm, not on the shoulders (a sampled
    hoodie's stitch runs from the shoulder down the side, and on the CMU walk its pairs at the armpit
    asked for 29 cm, lifting the top off the shoulders onto the head; seams placed on the shoulders
    start at most 5.6 cm under them)."""
    if len(pairs) == 0 or len(surface) == 0:
        return 0.0
    from scipy.spatial import cKDTree
    mid = 0.5 * (placed[pairs[:, 0]] + placed[pairs[:, 1]])
    tree = cKDTree(surface[:, [0, 2]])
    need = 0.0
    for q, near in zip(mid, tree.query_ball_point(mid[:, [0, 2]], SURFACE_RADIUS)):
        if near and float(surface[near, 1].max()) - float(q[1]) < UNDER_LIMB:
            need = max(need, float(surface[near, 1].max()) + clearance - float(q[1]))
    return need


def shoulder_surface(character, colliders, motion) -> np.ndarray:
    """(N, 3) the skin's vertices and the colliders' surface points at frame 0 (relative frame) but the
    neck's and head's (a seam end beside the neck would otherwise be lifted over the head)."""
    from stages.garments.placement import bind_geometry, collider_points, frame_poses0
    from stages.rig.humanoid import humanoid_joints, subtree
    skinned, _, dominant = bind_geometry(character, motion)
    pts, owner = [skinned], [dominant]
    for j, p in collider_points(colliders, frame_poses0(colliders, character, motion)):
        pts.append(p)
        owner.append(np.full(len(p), j))
    pts, owner = np.concatenate(pts), np.concatenate(owner)
    neck = humanoid_joints(character).neck
    if neck < 0:
        return pts
    return pts[~np.isin(owner, list(subtree(np.asarray(character.parents), neck)))]
