"""Flexible regions held by skinned balls: spheres whose centres move with the skin.

Skin near a joint turns with none of its bones, so a collider rigid in one bone's frame stands
off it by how far the skin moves in that frame, and one convex hull of a patch bridges the saddle
of an armpit or a crotch (swept hulls, 60-frame walk, delta 1 cm: CesiumMan excess p95 3.5 cm,
max 8.3 cm, shell 57 % of the body; fitted and measured at one frame only still 3.2-3.4 cm).
A ball whose centre is skinned like a vertex (the linear-blend weights of its nearest skin vertex
applied to its bind-pose position) follows the flexible skin itself, and a ball inscribed in the
body fits a saddle from inside.

Fitting (`fit_balls`), over the check poses (every `every`-th pose of the motion sample):
- candidates: points of a grid (spacing `spacing`) inside the bind-pose body, near flexible vertices;
- radius: the candidate's smallest depth under the skin at the check poses, plus `slack` (how far a
  ball may stand out of the skin at its worst pose), plus delta (the inflation);
- targets: the flexible vertices and every third candidate (the body's interior there);
  a ball holds a target when the target is within radius - (1 - cover) * delta of its centre at
  every check pose;
- greedy set cover: the ball holding most targets not yet held, until none is left (or no ball
  holds any of those left: listed in `BallSet.unheld`).

Measured by `python -m pipeline bench coverage` (60-frame walk, delta 1 cm, slack 1 cm, rigid
regions as hulls), coverage min / excess p95 / max / shell: built-in 99.78 % / 1.8 / 2.9 cm / 40 % (82
balls), CesiumMan 99.76 % / 1.8 / 2.8 cm / 37 % (250), CMU BVH skin 99.98 % / 1.8 / 2.5 cm / 51 % (233);
swept hulls on the same walks: 99.71 / 1.7 / 3.4 / 39, 99.91 / 3.5 / 8.3 / 57, 99.95 / 2.9 / 6.9 / 59.
Slack trades coverage for excess (CesiumMan, the same measures in a one-off script): 0 -> 98.72 % / 1.23 cm / 22 %
(695 balls), 7.5 mm -> 99.56 % / 1.58 cm / 32 % (309), 1 cm -> 99.78 % / 1.80 cm / 37 % (250).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix
from scipy.spatial import cKDTree

from stages.checks import ContractError, check_array
from stages.rig.types import Character, RegionSplit

BALL_SPACING = 0.01    # m: candidate centres on a grid inside the bind-pose body
BALL_SLACK = 0.01      # m: a ball may stand this far out of the skin at its worst check pose
BALL_COVER = 0.6       # a target is held within radius - (1 - BALL_COVER) * delta of the centre
MIN_DEPTH = 0.005      # m: candidates shallower than this at some check pose are dropped
NEAR_FLEXIBLE = 0.06   # m: candidates farther than this from every flexible vertex are dropped
CHECK_POSES = 24       # at most this many poses of the motion sample are checked (evenly spread)
INTERIOR_STRIDE = 3    # every this-many-th candidate is also a target (the interior to hold)


@dataclass(frozen=True)
class BallSet:
    """B skinned balls.

    bind_center: (B, 3) float64, m, model frame (bind pose). joints, weights: (B, K) int64 / float64,
    the linear-blend influences of each centre (its nearest skin vertex's; rows sum to 1).
    radius: (B,) float64, m, inflated by delta. joint: (B,) int64, the flexible region's joint each
    ball was chosen for (the joint of the first flexible vertex it holds; for names and reports).
    unheld: (U,) int64 flexible vertices no ball holds at every check pose.
    """

    bind_center: np.ndarray
    joints: np.ndarray
    weights: np.ndarray
    radius: np.ndarray
    joint: np.ndarray
    unheld: np.ndarray

    def __post_init__(self):
        b = self.bind_center.shape[0] if self.bind_center.ndim == 2 else -1
        check_array("BallSet", "bind_center", self.bind_center, (None, 3), np.float64)
        check_array("BallSet", "joints", self.joints, (b, None), np.int64)
        check_array("BallSet", "weights", self.weights, (b, self.joints.shape[1]), np.float64)
        check_array("BallSet", "radius", self.radius, (b,), np.float64)
        check_array("BallSet", "joint", self.joint, (b,), np.int64)
        check_array("BallSet", "unheld", self.unheld, (None,), np.int64)
        if b and not np.allclose(self.weights.sum(axis=1), 1.0, atol=1e-9):
            raise ContractError("BallSet.weights: every row must sum to 1")
        if not (np.isfinite(self.radius).all() and (self.radius > 0).all()):
            raise ContractError("BallSet.radius: expected positive radii")

    def centers(self, inverse_bind: np.ndarray, joint_world: np.ndarray) -> np.ndarray:
        """(..., B, 3) ball centres for joint transforms (..., J, 4, 4), skinned like a vertex."""
        return skin_points(self.bind_center, self.joints, self.weights, inverse_bind, joint_world)


def skin_points(points: np.ndarray, joints: np.ndarray, weights: np.ndarray, inverse_bind: np.ndarray,
                joint_world: np.ndarray) -> np.ndarray:
    """(..., P, 3) linear-blend skinning of bind-pose points (P, 3) with influences (P, K)."""
    m = joint_world @ inverse_bind                                         # (..., J, 4, 4)
    mk = m[..., joints, :, :]                                               # (..., P, K, 4, 4)
    x = np.einsum("...pkij,pj->...pki", mk[..., :3, :3], points) + mk[..., :3, 3]
    return np.einsum("...pki,pk->...pi", x, weights)


def check_pose_indices(n_poses: int, most: int = CHECK_POSES) -> np.ndarray:
    """(k,) int64 indices of at most `most` poses evenly spread over n_poses (first and last included)."""
    return np.unique(np.linspace(0, n_poses - 1, min(most, n_poses)).round().astype(np.int64))


def fit_balls(character: Character, split: RegionSplit, poses: np.ndarray, skinned: np.ndarray, body, *,
              delta: float, spacing: float = BALL_SPACING, slack: float = BALL_SLACK,
              cover: float = BALL_COVER) -> BallSet:
    """Skinned balls holding the flexible vertices of `split` and the body's interior near them
    (module doc). poses: (F, J, 4, 4) the motion sample; skinned: (F, V, 3) its skinned vertices;
    body: stages.coverage.measure.SkinDistance (refitted to the bind pose on return)."""
    flex = np.flatnonzero(~split.rigid)
    empty = BallSet(np.zeros((0, 3)), np.zeros((0, 1), np.int64), np.zeros((0, 1)), np.zeros(0),
                    np.zeros(0, np.int64), np.zeros(0, np.int64))
    if flex.size == 0:
        return empty
    bind = character.vertices
    lo, hi = bind[flex].min(axis=0) - NEAR_FLEXIBLE, bind[flex].max(axis=0) + NEAR_FLEXIBLE
    axes = [np.arange(a, b + spacing, spacing) for a, b in zip(lo, hi)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    grid = grid[cKDTree(bind[flex]).query(grid, distance_upper_bound=NEAR_FLEXIBLE)[0] < NEAR_FLEXIBLE]
    body.refit(bind)
    grid = grid[body.inside(grid)] if grid.size else grid
    _, nearest = cKDTree(bind).query(grid)
    joints = character.skin_joints[nearest].astype(np.int64)
    weights = character.skin_weights[nearest].astype(np.float64)
    weights /= weights.sum(axis=1, keepdims=True)
    check = check_pose_indices(poses.shape[0])
    centers = skin_points(grid, joints, weights, character.inverse_bind, poses[check])   # (S, C, 3)
    depth = np.full(grid.shape[0], np.inf)
    for s, f in enumerate(check):
        body.refit(skinned[f])
        inside = body.inside(centers[s])
        depth = np.minimum(depth, np.where(inside, body.distance(centers[s]), 0.0))
    body.refit(bind)
    keep = depth > MIN_DEPTH
    grid, joints, weights, depth, centers = grid[keep], joints[keep], weights[keep], depth[keep], centers[:, keep]
    if grid.shape[0] == 0:
        return BallSet(empty.bind_center, empty.joints, empty.weights, empty.radius, empty.joint, flex.astype(np.int64))
    radius = depth + slack + delta
    reach = radius - (1.0 - cover) * delta
    # targets: the flexible vertices, then the candidates (the interior), at every check pose
    # (every INTERIOR_STRIDE-th candidate: neighbours a spacing apart add little)
    targets = np.concatenate([skinned[check][:, flex], centers[:, ::INTERIOR_STRIDE]], axis=1)   # (S, T, 3)
    held = _held(centers, reach, targets)                                    # (C, T) sparse bool
    chosen, unheld = _greedy_cover(held)
    owner = np.array([flex[held[k].indices[0]] if held[k].nnz and held[k].indices[0] < flex.size else -1
                      for k in chosen], np.int64)
    joint = np.where(owner >= 0, split.region_joint[np.maximum(owner, 0)],
                     joints[chosen, np.argmax(weights[chosen], axis=1)]).astype(np.int64)
    return BallSet(np.ascontiguousarray(grid[chosen]), np.ascontiguousarray(joints[chosen]),
                   np.ascontiguousarray(weights[chosen]), np.ascontiguousarray(radius[chosen]), joint,
                   flex[unheld[unheld < flex.size]].astype(np.int64))


def _held(centers: np.ndarray, reach: np.ndarray, targets: np.ndarray, chunk: int = 200_000) -> csr_matrix:
    """(C, T) sparse bool: target t within reach[c] of centre c at every check pose (centers
    (S, C, 3), targets (S, T, 3)). Pairs come from the first pose's ball query, then each pair is
    checked at every pose."""
    tree = cKDTree(targets[0])
    lists = tree.query_ball_point(centers[0], reach)
    rows = np.repeat(np.arange(len(lists)), [len(x) for x in lists])
    cols = np.concatenate([np.asarray(x, np.int64) for x in lists]) if rows.size else np.zeros(0, np.int64)
    ok = np.ones(rows.size, bool)
    for a in range(0, rows.size, chunk):
        r, c = rows[a:a + chunk], cols[a:a + chunk]
        d = np.linalg.norm(centers[:, r] - targets[:, c], axis=2).max(axis=0)
        ok[a:a + chunk] = d <= reach[r]
    return csr_matrix((np.ones(int(ok.sum()), bool), (rows[ok], cols[ok])), shape=(centers.shape[1], targets.shape[1]))


def _greedy_cover(held: csr_matrix) -> tuple[np.ndarray, np.ndarray]:
    """(chosen rows in order, targets no row holds): the row holding most targets not yet held,
    repeatedly (ties: lower row). Lazy: a row's gain only falls, so a stale gain is an upper bound."""
    import heapq
    n_rows, n_targets = held.shape
    need = np.ones(n_targets, bool)
    gains = np.diff(held.indptr)
    heap = [(-int(g), r) for r, g in enumerate(gains) if g > 0]
    heapq.heapify(heap)
    chosen = []
    while heap:
        g, r = heapq.heappop(heap)
        cols = held.indices[held.indptr[r]:held.indptr[r + 1]]
        now = int(need[cols].sum())
        if now == 0:
            continue
        if heap and (-now, r) > heap[0]:     # another row may still beat it (or tie with a lower index)
            heapq.heappush(heap, (-now, r))
            continue
        chosen.append(r)
        need[cols] = False
    return np.array(chosen, np.int64), np.flatnonzero(need)
