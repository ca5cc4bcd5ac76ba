"""Flexible regions fitted by swept hulls: convex hulls of the flexible vertices over the motion.

A flexible vertex does not move rigidly with any bone, but it moves least with one of its bones.
The flexible vertices are cut by that bone, then into connected pieces of the mesh: a piece's
collider is the convex hull, in b's frame, of where its vertices are at every pose of the motion
sample (and in the bind pose), inflated by delta and simplified like a rigid hull. It holds its vertices at every sampled pose by construction, follows b rigidly, and
goes through the map stage's queries like any hull.

Each part also takes the one-ring of its vertices (the vertices sharing a triangle with them), so
that neighbouring colliders overlap by a strip of triangles and no gap opens at a region border.
A piece too small joins the nearest piece of its bone; one still too flat for a hull becomes the
paper's joint sphere (listed in the notes).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from stages.rig.motion_range import local_tracks
from stages.rig.regions import is_hull_ready
from stages.rig.types import Character, RegionSplit

SNAP = 1e-5      # m: swept positions are snapped to this grid (far below delta) before the hull
RING_REACH = 0.01  # m: a ring vertex's sweep in the piece's frame is clamped to this far from its bind place
RING_EDGE = 3.0  # the one-ring follows edges up to this many times the median edge (not a web)
MIN_PART = 8     # vertices: a smaller piece of a flexible region joins a neighbour
CORE_STEP = 0.01  # m: spacing of the bone points added to a hull (bone_core)


def one_ring(triangles: np.ndarray, vertices: np.ndarray, n_vertices: int, max_edge: float = np.inf,
             positions: np.ndarray | None = None) -> np.ndarray:
    """Sorted (m,) int64: `vertices` plus every vertex joined to one of them by a mesh edge no
    longer than max_edge (measured on `positions`, the bind pose): long edges (a web of triangles
    between two limbs) do not bring in the far side."""
    mark = np.zeros(n_vertices, bool)
    mark[vertices] = True
    e = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    if positions is not None and np.isfinite(max_edge):
        e = e[np.linalg.norm(positions[e[:, 0]] - positions[e[:, 1]], axis=1) <= max_edge]
    out = mark.copy()
    out[e[mark[e[:, 0]], 1]] = True
    out[e[mark[e[:, 1]], 0]] = True
    return np.flatnonzero(out)


def median_edge(character: Character) -> float:
    """Median edge length of the bind-pose mesh, m."""
    e = character.triangles
    return float(np.median(np.linalg.norm(character.vertices[e] - character.vertices[np.roll(e, 1, axis=1)], axis=2)))


def components(triangles: np.ndarray, vertices: np.ndarray, n_vertices: int) -> list[np.ndarray]:
    """Connected components of `vertices` along the mesh edges between two of them."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    mark = np.zeros(n_vertices, bool)
    mark[vertices] = True
    e = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    e = e[mark[e[:, 0]] & mark[e[:, 1]]]
    local = np.full(n_vertices, -1, np.int64)
    local[vertices] = np.arange(vertices.size)
    g = coo_matrix((np.ones(len(e)), (local[e[:, 0]], local[e[:, 1]])), shape=(vertices.size,) * 2)
    n, label = connected_components(g, directed=False)
    return [vertices[label == k] for k in range(n)]


def swept_parts(character: Character, split: RegionSplit, deviation: np.ndarray,
                min_vertices: int = MIN_PART) -> tuple[list, list[str]]:
    """[(joint, bone, vertices (n,) int64)] parts of the flexible vertices, and notes.

    deviation: (V, K) per influence slot (stages.rig.motion_range.bone_deviation). A flexible
    vertex goes to the influencing bone (weight > 0) it deviates least from; the flexible vertices
    of one joint moving with one bone are cut into connected pieces of the mesh (one hull each, so
    a hull never bridges two separate patches); a piece of fewer than `min_vertices` joins an
    adjacent bigger piece (within RING_EDGE median edges in the bind pose; moving with the same bone
    first, then of the same joint; never a piece moving with a bone that is not the same, the parent
    or a child: touching skin of two limbs), or stays a piece of its own."""
    sj, w = character.skin_joints, character.skin_weights
    dev = np.where(w > 0, deviation, np.inf)
    frame = sj[np.arange(sj.shape[0]), np.argmin(dev, axis=1)]
    flex = np.flatnonzero(~split.rigid)
    x = character.vertices
    pieces = []                                  # (joint, bone, vertices)
    for j, b in sorted({(int(split.region_joint[v]), int(frame[v])) for v in flex}):
        sel = flex[(split.region_joint[flex] == j) & (frame[flex] == b)]
        pieces += [(j, b, p) for p in components(character.triangles, sel, x.shape[0])]
    big = [p for p in pieces if p[2].size >= min_vertices]
    small = sorted((p for p in pieces if p[2].size < min_vertices), key=lambda p: -p[2].size)
    reach = RING_EDGE * median_edge(character)
    for j, b, p in small:
        # an adjacent bigger piece: moving with the same bone first, then of the same joint
        gap = [np.linalg.norm(x[q[2]][:, None] - x[p][None], axis=2).min() for q in big]
        near = [k for k in range(len(big)) if gap[k] <= reach and _adjacent(character.parents, big[k][1], b)]
        if not near:
            big.append((j, b, p))
            continue
        k = min(near, key=lambda k: (big[k][1] != b, big[k][0] != j, gap[k]))
        big[k] = (big[k][0], big[k][1], np.concatenate([big[k][2], p]))
    parts = [(j, b, np.sort(p).astype(np.int64)) for j, b, p in big]
    notes = []
    return parts, notes


def _adjacent(parents: np.ndarray, a: int, b: int) -> bool:
    return a == b or parents[a] == b or parents[b] == a


def part_names(character: Character, parts: list) -> list[str]:
    """'<joint>_flex' (moving with the joint's own bone) or '<joint>_flex_<bone>', numbered when
    several pieces share a name."""
    names = character.joint_names
    base = [f"{names[j]}_flex" if b == j else f"{names[j]}_flex_{names[b]}" for j, b, _ in parts]
    out = []
    for i, n in enumerate(base):
        k = base[:i].count(n)
        out.append(n if base.count(n) == 1 else f"{n}_{k + 1}")
    return out


def swept_points(character: Character, poses: np.ndarray, skinned: np.ndarray, bone: int,
                 vertices: np.ndarray) -> np.ndarray:
    """(p, 3) bone-local points a swept hull of `vertices` is fitted to: where they are at every pose
    and in the bind pose, and where their one-ring is, swept at most RING_REACH from its bind place."""
    ring = one_ring(character.triangles, vertices, character.vertices.shape[0],
                    RING_EDGE * median_edge(character), character.vertices)
    ring = np.union1d(vertices, ring[near_bone(character, ring, bone)])
    track = local_tracks(character, poses, ring, bone, skinned).reshape(-1, ring.size, 3)   # bind pose first
    # the ring's own vertices move with other bones: swept here in full, they would stand off the skin
    # by their deviation in this bone's frame (centimetres over a walk)
    other = ~np.isin(ring, vertices)
    move = track[1:, other] - track[0, other]
    move *= np.minimum(1.0, RING_REACH / np.maximum(np.linalg.norm(move, axis=2, keepdims=True), 1e-12))
    track[1:, other] = track[0, other] + move
    pts = track.reshape(-1, 3)
    # poses repeat positions (a held pose, the bind pose): near-duplicates make Qhull slivers
    pts = np.unique(np.round(pts / SNAP), axis=0) * SNAP
    if is_hull_ready(pts):
        try:
            pts = pts[ConvexHull(pts).vertices]      # only the extreme points matter to the hull
        except QhullError:      # nearly flat for Qhull's precision: convex_hull thickens it (all points kept)
            pass
    return np.ascontiguousarray(pts)


def near_bone(character: Character, vertices: np.ndarray, bone: int) -> np.ndarray:
    """(n,) bool: the vertices skinned (weight > 0) to `bone`, its parent or a child of it. The one-ring
    of a piece reaches its neighbours' skin; where two limbs' skin touches (a heavy body's inner
    thighs) it would reach the other limb, whose sweep in this bone's frame is a metre wide."""
    near = {bone, int(character.parents[bone])} | set(np.flatnonzero(character.parents == bone).tolist())
    sj, w = character.skin_joints[vertices], character.skin_weights[vertices]
    return (np.isin(sj, list(near)) & (w > 0)).any(axis=1)


def bone_core(character: Character, bone: int, vertices: np.ndarray) -> np.ndarray:
    """(k, 3) bind-pose model-frame points on bone `bone` (its origin to each child's origin, every
    CORE_STEP) no farther from `vertices` than the patch reaches around the bone. A hull of a patch
    of skin plus those of them inside the body (the caller's filter) reaches down to the bone, so
    neighbouring hulls meet inside the body instead of leaving a hollow under a patch."""
    x = character.vertices[vertices]
    joints = np.linalg.inv(character.inverse_bind)[:, :3, 3]
    pts = [joints[bone][None]]
    for k in np.flatnonzero(character.parents == bone):
        n = max(int(np.ceil(np.linalg.norm(joints[k] - joints[bone]) / CORE_STEP)), 1)
        pts.append(joints[bone] + np.linspace(0.0, 1.0, n + 1)[1:, None] * (joints[k] - joints[bone]))
    seg = np.concatenate(pts)
    d = np.linalg.norm(seg[:, None] - x[None], axis=2).min(axis=1)
    reach = np.linalg.norm(x[:, None] - seg[None], axis=2).min(axis=1).max()
    return seg[d <= reach]
