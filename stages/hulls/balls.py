"""Flexible regions held by skinned balls: spheres whose centres move with the skin (the default
`colliders.flexible`).

Skin near a joint turns with none of its bones, so a collider rigid in one bone's frame stands
off it by how far the skin moves in that frame, and one convex hull of a patch bridges the saddle
of an armpit or a crotch (swept hulls, 60-frame walk, delta 1 cm: CesiumMan excess p95 3.5 cm,
max 8.3 cm, shell 57 % of the body; fitted and measured at one frame only still 3.2-3.4 cm).
A ball whose centre is skinned like a vertex (the linear-blend weights of its nearest skin vertex
applied to its bind-pose position) follows the flexible skin itself, and a ball inscribed in the
body fits a saddle from inside.

Fitting (`fit_balls`), over the check poses (about every CHECK_EVERY-th pose of the motion sample):
- candidates: points of a grid (spacing `spacing`) inside the bind-pose body, near flexible vertices;
- radius: the candidate's smallest depth under the skin at the check poses, plus a slack (how far a
  ball may stand out of the skin at its worst pose), plus delta (the inflation);
- targets: the flexible vertices, the skin between them (centroids and edge midpoints of their
  triangles) and the candidates (the body's interior there); a ball holds a target when the target
  is within radius - (1 - cover) * delta of its centre at every check pose;
- greedy set cover per slack tier, tightest first: the ball holding most targets not yet held,
  until no ball of the tier holds any; the next tier's looser balls take what is left (targets no
  tier holds: their vertices are listed in `BallSet.unheld`);
- skin balls where the skin is still unheld (`_skin_balls`): the triangles around the unheld
  targets are sampled every SKIN_STEP; a sample skinned with its corners' blended influences
  drifts `dev` from the skin point it samples, so its ball of radius delta + dev holds that point at
  every pose and stands out of the skin by delta + dev at most; a set cover picks among them the
  balls that hold the samples out of every other collider at some check pose. Without
  them CesiumMan's armpits and chest (18 unheld vertices on 4-8 cm triangles) stood up to 11.6 mm out
  of every collider, and its skin showed through the T-shirt.

Bounded sizes: the candidates, the skin samples and the (ball, target) pairs grow with the flexible
volume / area over the spacing (a body all flexible and metres wide). The spacing and the skin step grow
beyond MAX_GRID / MAX_CANDIDATES / MAX_SKIN_SAMPLES (skin balls then reach the extra step farther), and
more than MAX_PAIRS pairs is one InputError before they are searched.

Measured by `python -m pipeline bench coverage` (60-frame walk, delta 1 cm, tiers 5 mm + 1 cm, rigid
regions as hulls), coverage min / excess p95 / max / shell: built-in 99.80 % / 1.6 / 2.9 cm / 38 % (140
balls), CesiumMan 99.91 % / 1.5 / 2.8 cm / 34 % (744), CMU BVH skin 99.98 % / 1.6 / 2.5 cm / 47 % (711).
One 1 cm slack tier with only vertices and every third candidate as targets: CesiumMan 99.76 % / 1.8 /
2.8 cm / 37 % (250 balls), and garment bands resting on them sat 2.0-2.3 cm off the skin; a 0 slack:
98.72 % coverage, its holes mostly under 4 mm deep between the vertices held (hence the skin targets).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix
from scipy.spatial import cKDTree

from stages.checks import ContractError, check_array
from stages.errors import InputError
from stages.hulls.balls_kernels import pairs_in_reach
from stages.rig.types import Character, RegionSplit

BALL_SPACING = 0.01    # m: candidate centres on a grid inside the bind-pose body
BALL_SLACK = (0.005, 0.01)   # m: tiers of how far a ball may stand out of the skin at its worst check pose
BALL_COVER = 0.6       # a target is held within radius - (1 - BALL_COVER) * delta of the centre
MIN_DEPTH = 0.005      # m: candidates shallower than this at some check pose are dropped
NEAR_FLEXIBLE = 0.06   # m: candidates farther than this from every flexible vertex are dropped
CHECK_POSES = 24       # at most this many poses of the motion sample are checked (evenly spread) ...
CHECK_EVERY = 5        # ... about one in this many (60-frame walks: 12 poses fit as 24 did, in half the time) ...
CHECK_LEAST = 12       # ... and at least this many (6 over a 30-frame clip left a CesiumMan long skirt's seam open)
PAIR_CELL = 0.02       # m: grid cell of the (ball, target) pair search
SKIN_STEP = 0.005      # m: spacing of the skin samples skin balls are chosen from
DEPTH_BALLS = 32       # the nearest ball centres a skin sample's depth is taken over
HUMAN_SIZE = (0.5, 2.5)   # m: the lengths above are for bodies this tall (bind-pose extent); others scale them
# Sizes that would otherwise grow with the flexible volume / area over the (unscaled) delta. RiggedSimple
# (9.55 m, every vertex flexible) had 775,705 skin samples, 63,751 skin balls and 2.6 GB here, and the
# garments stage then went past 8 GB; CesiumMan has 33,713 candidates and 11,017 skin samples.
MAX_GRID = 6_000_000         # candidate grid points before the body filters (a coarser spacing beyond)
MAX_CANDIDATES = 200_000     # candidates inside the body near flexible skin (a coarser spacing beyond)
MAX_SKIN_SAMPLES = 100_000   # skin samples (a coarser step beyond, the skin balls grown by the extra step)
MAX_PAIRS = 50_000_000       # (ball, target) pairs held (16 bytes each, twice while the kernel grows them): more
                             # is one InputError, not an OOM kill (CesiumMan: 4.3 million, RiggedSimple: 13.6)


@dataclass(frozen=True)
class BallSet:
    """B skinned balls.

    bind_center: (B, 3) float64, m, model frame (bind pose). joints, weights: (B, K) int64 / float64,
    the linear-blend influences of each centre (its nearest skin vertex's; rows sum to 1).
    radius: (B,) float64, m, inflated by delta. joint: (B,) int64, the flexible region's joint each
    ball was chosen for (the joint of the first flexible vertex it holds; for names and reports).
    unheld: (U,) int64 flexible vertices no ball inside the body holds at every check pose (skin balls
      hold them). on_skin: how many of the balls, the last ones, are skin balls (centred on the
      bind-pose skin, radius delta + their drift).
    """

    bind_center: np.ndarray
    joints: np.ndarray
    weights: np.ndarray
    radius: np.ndarray
    joint: np.ndarray
    unheld: np.ndarray
    on_skin: int = 0

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
        if not 0 <= self.on_skin <= self.radius.size:
            raise ContractError(f"BallSet.on_skin: expected 0..{self.radius.size}, got {self.on_skin}")

    def centers(self, inverse_bind: np.ndarray, joint_world: np.ndarray) -> np.ndarray:
        """(..., B, 3) ball centres for joint transforms (..., J, 4, 4), skinned like a vertex."""
        return skin_points(self.bind_center, self.joints, self.weights, inverse_bind, joint_world)


def skin_points(points: np.ndarray, joints: np.ndarray, weights: np.ndarray, inverse_bind: np.ndarray,
                joint_world: np.ndarray) -> np.ndarray:
    """(..., P, 3) linear-blend skinning of bind-pose points (P, 3) with influences (P, K), for joint
    transforms (..., J, 4, 4): the skinning kernel the body uses."""
    from stages.rig.kernels import lbs_kernel
    lead = joint_world.shape[:-3]
    m = np.ascontiguousarray((joint_world @ inverse_bind).reshape(-1, *joint_world.shape[-3:]))
    out = np.empty((m.shape[0], points.shape[0], 3))
    lbs_kernel(m, np.ascontiguousarray(points, np.float64), np.ascontiguousarray(joints, np.int32),
               np.ascontiguousarray(weights, np.float64), out)
    return out.reshape(*lead, points.shape[0], 3)


def check_pose_indices(n_poses: int, most: int = CHECK_POSES) -> np.ndarray:
    """(k,) int64 indices of at most `most` poses evenly spread over n_poses (first and last included)."""
    return np.unique(np.linspace(0, n_poses - 1, min(most, n_poses)).round().astype(np.int64))


def body_scale(vertices: np.ndarray) -> float:
    """1 for a body whose bind-pose extent is within HUMAN_SIZE, else extent / the nearer bound: the
    fit's lengths (spacing, slack, ...) then scale with it (a 10 m glTF stored in other units)."""
    extent = float(np.ptp(vertices, axis=0).max()) if vertices.size else 1.0
    lo, hi = HUMAN_SIZE
    return extent / hi if extent > hi else extent / lo if extent < lo else 1.0


def ball_check_poses(n_poses: int) -> np.ndarray:
    """(k,) int64 indices of the poses the balls are fitted at: about every CHECK_EVERY-th, at least
    CHECK_LEAST (or all), at most CHECK_POSES."""
    return check_pose_indices(n_poses, min(CHECK_POSES, max(CHECK_LEAST, -(-n_poses // CHECK_EVERY))))


def fit_balls(character: Character, split: RegionSplit, poses: np.ndarray, skinned: np.ndarray, body, *,
              delta: float, spacing: float = BALL_SPACING, slack: tuple | float = BALL_SLACK,
              cover: float = BALL_COVER, hulls=()) -> BallSet:
    """Skinned balls holding the flexible vertices of `split` and the body's interior near them
    (module doc). poses: (F, J, 4, 4) the motion sample; skinned: (F, V, 3) its skinned vertices;
    body: stages.geometry.skin_distance.SkinDistance (refitted to the bind pose on return). hulls: the rigid
    hulls (HullCollider); skin they hold needs no skin ball."""
    flex = np.flatnonzero(~split.rigid)
    empty = BallSet(np.zeros((0, 3)), np.zeros((0, 1), np.int64), np.zeros((0, 1)), np.zeros(0),
                    np.zeros(0, np.int64), np.zeros(0, np.int64))
    if flex.size == 0:
        return empty
    bind = character.vertices
    scale = body_scale(bind)
    spacing, near, min_depth = spacing * scale, NEAR_FLEXIBLE * scale, MIN_DEPTH * scale
    body.refit(bind)
    grid = candidate_grid(bind[flex], body, spacing, near)
    _, nearest = cKDTree(bind).query(grid)
    joints = character.skin_joints[nearest].astype(np.int64)
    weights = character.skin_weights[nearest].astype(np.float64)
    weights /= weights.sum(axis=1, keepdims=True)
    check = ball_check_poses(poses.shape[0])
    centers = skin_points(grid, joints, weights, character.inverse_bind, poses[check])   # (S, C, 3)
    depth = np.full(grid.shape[0], np.inf)
    for s, f in enumerate(check):   # a candidate shallower than min_depth at one pose is out: not checked again
        alive = np.flatnonzero(depth > min_depth)
        body.refit(skinned[f])
        d = body.distance(centers[s, alive])
        deep = d > min_depth
        d[deep] = np.where(body.inside(centers[s, alive[deep]]), d[deep], 0.0)
        depth[alive] = np.minimum(depth[alive], d)
    body.refit(bind)
    keep = depth > min_depth
    grid, joints, weights, depth, centers = grid[keep], joints[keep], weights[keep], depth[keep], centers[:, keep]
    if grid.shape[0] == 0:
        return BallSet(empty.bind_center, empty.joints, empty.weights, empty.radius, empty.joint, flex.astype(np.int64))
    # targets: the flexible vertices, the skin between them, then the candidates (the interior), at
    # every check pose
    tri_index, edges = _skin_features(character.triangles, ~split.rigid)
    tri = character.triangles[tri_index]
    targets = np.concatenate([skinned[check][:, flex], skinned[check][:, tri].mean(axis=2),
                              skinned[check][:, edges].mean(axis=2), centers], axis=1)   # (S, T, 3)
    tiers = np.sort(np.atleast_1d(np.asarray(slack, np.float64))) * scale
    margin = (1.0 - cover) * delta
    reach = depth + tiers[-1] + delta - margin
    check_pairs(centers[0], targets[0], reach, f"the skinned balls of {character.name!r}")
    indptr, cols, far = pairs_in_reach(np.ascontiguousarray(centers), np.ascontiguousarray(targets), reach,
                                       PAIR_CELL * scale)
    pair_row = np.repeat(np.arange(grid.shape[0]), np.diff(indptr))
    need = np.ones(targets.shape[1], bool)
    rows, radii, first = [], [], []      # first: each chosen ball's lowest held target (a vertex names its joint)
    for tier in tiers:    # the tightest balls first; a looser tier holds what they cannot
        radius = depth + tier + delta
        ok = far <= (radius - margin)[pair_row]
        held = csr_matrix((np.ones(int(ok.sum()), bool), cols[ok],
                           np.concatenate([[0], np.cumsum(np.bincount(pair_row[ok], minlength=grid.shape[0]))])),
                          shape=(grid.shape[0], targets.shape[1]))             # (C, T): t held by c at every pose
        chosen, need = _greedy_cover(held, need)
        rows.append(chosen)
        radii.append(radius[chosen])
        first.append(held.indices[held.indptr[chosen]])     # a chosen ball holds at least one target
    chosen, radius, first = np.concatenate(rows), np.concatenate(radii), np.concatenate(first).astype(np.int64)
    unheld = np.flatnonzero(need)
    joint = np.where(first < flex.size, split.region_joint[flex[np.minimum(first, flex.size - 1)]],
                     joints[chosen, np.argmax(weights[chosen], axis=1)]).astype(np.int64)
    # the skin no ball inside the body holds: balls on the skin of the triangles around it where it
    # is out of every collider
    loose = unheld[unheld < flex.size + tri.shape[0] + edges.shape[0]]
    loose_v = flex[loose[loose < flex.size]]
    loose_t = loose[(loose >= flex.size) & (loose < flex.size + tri.shape[0])] - flex.size
    loose_e = edges[loose[loose >= flex.size + tri.shape[0]] - flex.size - tri.shape[0]]
    around = np.isin(character.triangles, loose_v).any(axis=1)
    around[tri_index[loose_t]] = True
    t = character.triangles.astype(np.int64)
    n_v = character.vertices.shape[0]
    pair = np.sort(np.stack([t, np.roll(t, -1, axis=1)], axis=2), axis=2)           # (T, 3, 2) its edges
    around |= np.isin(pair[..., 0] * n_v + pair[..., 1], loose_e[:, 0].astype(np.int64) * n_v + loose_e[:, 1]).any(axis=1)
    sk = _skin_balls(character, split, character.triangles[around], poses[check], skinned[check], delta, margin,
                     SKIN_STEP * scale, PAIR_CELL * scale, centers[:, chosen], radius, hulls)
    return BallSet(np.ascontiguousarray(np.concatenate([grid[chosen], sk[0]])),
                   np.ascontiguousarray(np.concatenate([joints[chosen], sk[1]])),
                   np.ascontiguousarray(np.concatenate([weights[chosen], sk[2]])),
                   np.concatenate([radius, sk[3]]), np.concatenate([joint, sk[4]]).astype(np.int64),
                   flex[unheld[unheld < flex.size]].astype(np.int64), on_skin=int(sk[3].size))


def candidate_grid(flexible: np.ndarray, body, spacing: float, near: float, *, max_grid: int = MAX_GRID,
                   max_candidates: int = MAX_CANDIDATES) -> np.ndarray:
    """(C, 3) points of a grid of `spacing` (m) within `near` of the flexible vertices (F, 3) and inside
    the body (SkinDistance at the bind pose). The spacing grows by 1.25 until the grid has at most
    max_grid points and the candidates are at most max_candidates: their count grows with the
    flexible volume over spacing^3, and every later array of the fit with it."""
    lo, hi = flexible.min(axis=0) - near, flexible.max(axis=0) + near
    tree = cKDTree(flexible)
    while True:
        axes = [np.arange(a, b + spacing, spacing) for a, b in zip(lo, hi)]
        if np.prod([float(a.size) for a in axes]) <= max_grid:
            grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
            grid = grid[tree.query(grid, distance_upper_bound=near)[0] < near]
            if grid.shape[0] <= max_candidates:
                return grid[body.inside(grid)] if grid.size else grid
            inside = body.inside(grid)
            if int(inside.sum()) <= max_candidates:
                return grid[inside]
        spacing *= 1.25


def check_pairs(centers: np.ndarray, targets: np.ndarray, reach: np.ndarray, where: str, most: int | None = None) -> None:
    """InputError when the (centre, target) pairs within reach at one pose (centres (C, 3), targets
    (T, 3), reach (C,), m), estimated from at most 4,000 evenly spread centres, exceed `most`
    (default MAX_PAIRS): pairs_in_reach holds them all (an upper bound: it keeps the pairs within
    reach at every pose)."""
    most = MAX_PAIRS if most is None else most
    if centers.shape[0] == 0 or targets.shape[0] == 0:
        return
    every = max(1, centers.shape[0] // 4000)
    found = cKDTree(targets).query_ball_point(centers[::every], np.maximum(reach[::every], 0.0), return_length=True)
    estimate = float(np.mean(found)) * centers.shape[0]
    if estimate > most:
        raise InputError(where, f"about {estimate:.3g} (ball, target) pairs to check, more than {most:,} "
                         f"(~{32 * estimate / 1e9:.1f} GB): colliders.delta is too fine for a body this size, "
                         "or use colliders.flexible: swept or sphere")


def skin_sample_counts(vertices: np.ndarray, triangles: np.ndarray, step: float,
                       most: int = MAX_SKIN_SAMPLES) -> tuple[np.ndarray, float]:
    """(per triangle the barycentric grid's steps per side (M,) int64, the step used (m)): `step`, or
    coarser (x 1.25 at a time) until the samples, (n + 1)(n + 2) / 2 a triangle, are at most `most`.
    A side of length L gets ceil(L / step) steps (at least 1)."""
    longest = [max(np.linalg.norm(v[i] - v[(i + 1) % 3]) for i in range(3)) for v in vertices[triangles]]
    while True:
        n = np.array([max(1, int(np.ceil(e / step))) for e in longest], np.int64)
        if int(((n + 1) * (n + 2) // 2).sum()) <= most or (n == 1).all():
            return n, step
        step *= 1.25


def _depth_in(points: np.ndarray, poses: np.ndarray, ball_centers: np.ndarray, ball_radius: np.ndarray,
              hulls) -> np.ndarray:
    """(P,) how deep (m) points (S, P, 3) are in the deepest of the balls (centres (S, B, 3), radii
    (B,)) and hulls at each pose of poses (S, J, 4, 4), the least over the poses (negative: outside)."""
    depth = np.full(points.shape[1], np.inf)
    reach = float(ball_radius.max()) if ball_radius.size else 0.0
    bounds = []         # per hull: planes, bounding ball (bone-local); points beyond the ball skip the planes
    for h in hulls:
        v = h.simplified.vertices
        mid = 0.5 * (v.min(axis=0) + v.max(axis=0))
        bounds.append((h.bone, h.simplified.planes, mid, float(np.linalg.norm(v - mid, axis=1).max())))
    for s in range(points.shape[0]):
        now = np.full(points.shape[1], -np.inf)
        if ball_radius.size:     # the DEPTH_BALLS nearest centres (a deeper ball farther off is missed: less depth)
            dist, near = cKDTree(ball_centers[s]).query(points[s], k=min(DEPTH_BALLS, ball_radius.size),
                                                        distance_upper_bound=reach)
            dist, near = dist.reshape(points.shape[1], -1), near.reshape(points.shape[1], -1)
            ok = near < ball_radius.size
            now = np.where(ok, ball_radius[np.minimum(near, ball_radius.size - 1)] - dist, -np.inf).max(axis=1)
        for bone, pl, mid, r in bounds:
            m = np.linalg.inv(poses[s, bone])
            q = points[s] @ m[:3, :3].T + m[:3, 3]
            near = np.flatnonzero(np.einsum("pd,pd->p", q - mid, q - mid) <= r * r)
            now[near] = np.maximum(now[near], -(q[near] @ pl[:, :3].T - pl[:, 3]).max(axis=1))
        depth = np.minimum(depth, now)
    return depth


def _skin_balls(character: Character, split: RegionSplit, triangles: np.ndarray, poses: np.ndarray,
                skinned: np.ndarray, delta: float, margin: float, step: float, cell: float,
                ball_centers: np.ndarray, ball_radius: np.ndarray, hulls):
    """Balls on the skin of `triangles` (M, 3) that hold what of it is out of every other collider
    (balls centred at ball_centers (S, B, 3) with radii (B,), hulls) at some pose of poses (S, J, 4, 4)
    / skinned (S, V, 3): (bind centres (B', 3), joints (B', K), weights (B', K), radii (B',), joint (B',)).

    Each triangle is sampled every `step` (barycentric grid, corners included). A sample's centre is
    its bind position skinned with its corners' influences blended by its barycentric weights (the K
    heaviest); it drifts `dev` (the largest over the poses) from the skin point it samples (the same
    blend of the skinned corners), so its ball of radius delta + dev holds that point within
    radius - margin; the greedy set cover picks the balls that hold every sample out of the other
    colliders. cell: m, the pair search's grid cell."""
    k = character.skin_joints.shape[1]
    empty = (np.zeros((0, 3)), np.zeros((0, k), np.int64), np.zeros((0, k)), np.zeros(0), np.zeros(0, np.int64))
    if triangles.shape[0] == 0:
        return empty
    # only the triangles whose corners, centroid or edge midpoints lie less than margin deep in the
    # other colliders at some pose are sampled (the seams of a body's hulls are mostly held)
    feature = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1], [1, 1, 0], [0, 1, 1], [1, 0, 1]]) / \
        np.array([1, 1, 1, 3, 2, 2, 2])[:, None]
    at = np.einsum("fc,sncd->snfd", feature, skinned[:, triangles]).reshape(skinned.shape[0], -1, 3)
    shallow = _depth_in(at, poses, ball_centers, ball_radius, hulls).reshape(-1, 7).min(axis=1) < margin
    triangles = triangles[shallow]
    if triangles.shape[0] == 0:
        return empty
    # a coarser step (a big body) leaves samples farther apart: each ball reaches that much farther,
    # so that it still holds the samples next to it
    steps, used = skin_sample_counts(character.vertices, triangles, step)
    extra = used - step
    corners, bary = [], []
    for t, n in zip(triangles, steps):
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = i + j <= n
        b = np.stack([i[keep], j[keep], n - i[keep] - j[keep]], axis=1) / n
        corners.append(np.broadcast_to(t, b.shape))
        bary.append(b)
    corners, bary = np.concatenate(corners).astype(np.int64), np.concatenate(bary)
    bind = np.einsum("sc,scd->sd", bary, character.vertices[corners])
    dense = np.zeros((bind.shape[0], character.n_joints))
    rows = np.repeat(np.arange(bind.shape[0]), 3 * k)
    np.add.at(dense, (rows, character.skin_joints[corners].reshape(-1)),
              (bary[:, :, None] * character.skin_weights[corners]).reshape(-1))
    joints = np.argsort(-dense, axis=1, kind="stable")[:, :k]
    weights = np.take_along_axis(dense, joints, axis=1)
    weights /= weights.sum(axis=1, keepdims=True)
    centers = skin_points(bind, joints, weights, character.inverse_bind, poses)       # (S, P, 3)
    points = np.einsum("pc,spcd->spd", bary, skinned[:, corners])                     # the skin they sample
    radius = delta + extra + np.linalg.norm(centers - points, axis=2).max(axis=0)
    need = _depth_in(points, poses, ball_centers, ball_radius, hulls) < 0.0      # out of them at some pose
    check_pairs(centers[0], points[0], radius - margin, f"the skin balls of {character.name!r}")
    indptr, cols, _ = pairs_in_reach(np.ascontiguousarray(centers), np.ascontiguousarray(points), radius - margin, cell)
    held = csr_matrix((np.ones(cols.size, bool), cols, indptr), shape=(bind.shape[0], bind.shape[0]))
    chosen, _ = _greedy_cover(held, need)
    joint = split.region_joint[corners[chosen, np.argmax(bary[chosen], axis=1)]]
    return bind[chosen], joints[chosen].astype(np.int64), weights[chosen], radius[chosen], joint.astype(np.int64)


def _skin_features(triangles: np.ndarray, flexible: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(indices of the triangles with a flexible corner (M,), their edges (E, 2), each once, sorted):
    the skin between the flexible vertices is sampled at their centroids and edge midpoints. Balls that
    hold only the vertices leave the skin between them out where they are small."""
    from stages.geometry.mesh import mesh_edges
    index = np.flatnonzero(flexible[triangles].any(axis=1))
    return index, mesh_edges(triangles[index]).astype(triangles.dtype)


def _greedy_cover(held: csr_matrix, need: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(chosen rows in order, (T,) bool: targets still needed after them): the row holding most needed
    targets (default: all), repeatedly (ties: lower row). Lazy: a row's gain only falls, so a stale
    gain is an upper bound."""
    import heapq
    need = np.ones(held.shape[1], bool) if need is None else need.copy()
    gains = held.astype(np.int64) @ need.astype(np.int64)
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
    return np.array(chosen, np.int64), need
