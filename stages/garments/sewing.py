"""Sewing ('collision sewing' under micro-gravity, paper A §3.3): seam springs pull matched vertex
pairs of the placed panels together through the public simulation stage (gravity reduced,
collisions on), until every seam gap is below a tolerance; then sewn pairs are merged into one
mesh whose rest lengths come from the flat panels.

Each sewing iteration is one short `stages.sim.simulate` call on the bind pose held still, with the
seam pairs as extra stretch springs of (almost) zero rest length; the panels' own springs keep their
flat rest lengths. Attachments are applied only to the sewn garment (pins would hold seam ends apart).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from stages.checks import ContractError
from stages.garments.types import build_garment


# the sewing's bend springs start as stiff as the edges (see sew); where the largest gap falls by less than
# STALL_GAIN over STALL_WINDOW iterations they are halved, down to MIN_SEW_BEND (the simulation's default 0.2
# let CesiumMan's trousers fold through themselves when used from the start)
STALL_WINDOW = 4
STALL_GAIN = 0.1
MIN_SEW_BEND = 0.25
# the cloth within this many (median) edge lengths of a seam's vertices is not collided with the cloth
# near any seam while sewing: the seam springs pull the two sides together, and the contacts would hold
# them a thickness apart (seam_zones). Half an edge: the seams' own vertices (and the triangles and
# edges touching them); at 1.5 the strips either side passed through each other (dress_pencil on the
# CMU walk: 61 edges through the sewn garment, 3 at 0.5). One zone for every seam: with a zone per seam,
# the cloth where seams meet (an armhole's corner at the side seam) held the seams open (5 of 8
# GarmentCode garments on CesiumMan and the CMU walk stalled 5.6-30 mm open; with one, the CMU walk's
# pants, tee and jumpsuit closed)
SEAM_ZONE_EDGES = 0.5
# the cloth within this many edge lengths of cloth left through cloth after untangling the placement is not
# collided with itself while sewing (a jumpsuit's legs placed through each other at CesiumMan's crotch:
# caught there, its seams stayed 21 mm open)
TANGLE_ZONE_EDGES = 2.0


@dataclass(frozen=True)
class SewParams:
    """Sewing settings.

    tolerance: m, largest seam gap accepted. target: m, the gap the sewing goes on closing to once
    within the tolerance (at most the tolerance), while it still falls (a seam 4 mm open is joined with a visible pucker;
    the last millimetres take a few more iterations). max_iterations: simulate calls at most.
    frames_per_iteration: frames per call. dt, substeps, iterations: simulation step settings
    (iterations = spring correction rounds). gravity_scale: share of g applied (micro-gravity).
    damping, friction: as in SimParams (damping per 1/30 s: 0.36 removes 0.2 per step of 1/60 s). seam_rest: m, rest length of the seam springs (> 0).
    log_every: keep the positions of every k-th iteration in the log (plus the first and last).
    min_iterations: simulate calls at least (panels placed with their seams already closed still
    settle under micro-gravity and get pushed out of the colliders).
    self_collision: the cloth collided with itself while sewing (but the cloth at the seams against
    the cloth at the seams, seam_zones), the placed panels untangled first (the contacts would hold
    cloth placed through cloth where it is); off: the seams pull the panels through each other
    where their way crosses (stages.garments.untangle then repairs what it can). The built-in
    patterns are sewn without: with it a T-shirt's loose collar (fit_band 1.1 on the built-in
    character) stayed 5.9 mm open after 40 iterations.
    """

    tolerance: float = 0.004
    target: float = 0.002
    max_iterations: int = 40
    frames_per_iteration: int = 10
    dt: float = 1.0 / 30.0
    substeps: int = 2
    iterations: int = 16
    gravity_scale: float = 0.005
    damping: float = 0.36
    friction: float = 0.0
    seam_rest: float = 1e-4
    log_every: int = 2
    min_iterations: int = 2
    self_collision: bool = False

    def __post_init__(self):
        if not (self.tolerance > 0 and self.target > 0 and self.seam_rest > 0 and self.max_iterations >= 1 and
                0 <= self.min_iterations <= self.max_iterations and
                self.frames_per_iteration >= 2 and self.log_every >= 1 and 0 <= self.gravity_scale <= 1):
            raise ContractError(f"SewParams: invalid settings {self}")


@dataclass(frozen=True)
class SewingLog:
    """What the sewing did.

    gap_max, gap_mean: (I,) float64, m, seam gaps after each iteration (index 0: placed, before
    sewing). positions: (K, N, 3) float32, m, unsewn-mesh positions at iterations `logged`
    (K,) int32. triangles: (T, 3) int32 of the unsewn mesh. seconds: wall time of the sewing loop.
    converged: every gap below the tolerance. penetrations: particles inside a collider after the
    last iteration (from the simulation's count).
    """

    gap_max: np.ndarray
    gap_mean: np.ndarray
    positions: np.ndarray
    logged: np.ndarray
    triangles: np.ndarray
    seconds: float
    converged: bool
    penetrations: int
    notes: tuple = field(default_factory=tuple)

    @property
    def iterations(self) -> int:
        return int(self.gap_max.size - 1)


def hold_motion(motion, n_frames: int, dt: float):
    """The motion's first frame held still for n_frames (root translation 0)."""
    from stages.rig.types import Motion
    jw = np.broadcast_to(motion.joint_world[0], (n_frames,) + motion.joint_world.shape[1:]).copy()
    return Motion("sewing", np.arange(n_frames, dtype=np.float64) * dt, jw, np.zeros((n_frames, 3)))


def seam_gaps(x: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    if pairs.size == 0:
        return np.zeros(0)
    return np.linalg.norm(x[pairs[:, 0]] - x[pairs[:, 1]], axis=1)


SEAM_BIT, TANGLE_BIT = 0, 1   # the zones of the seams and of the cloth left through cloth after untangling


def seam_zones(rest: np.ndarray, triangles: np.ndarray, pairs: np.ndarray, reach_edges: float = SEAM_ZONE_EDGES,
               tangled=None) -> np.ndarray:
    """(N,) uint64 exclusion zones (Garment.contact_zones) of an unsewn mesh: SEAM_BIT on every
    particle within `reach_edges` median edge lengths of a vertex of a seam pair (K, 2), measured in
    the rest shape `rest` (N, 3) (the flat panels: the distance along the cloth). tangled: optional
    vertex indices of the cloth placed through cloth (tangled_vertices): TANGLE_BIT on them and
    within TANGLE_ZONE_EDGES of them."""
    from scipy.spatial import cKDTree
    n = rest.shape[0]
    zones = np.zeros(n, np.uint64)
    e = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    edge = float(np.median(np.linalg.norm(rest[e[:, 0]] - rest[e[:, 1]], axis=1)))
    tree = cKDTree(rest)

    def mark(verts, reach, bit):
        near = tree.query_ball_point(rest[np.unique(verts)], reach)
        zones[np.unique(np.concatenate([np.asarray(v, np.int64) for v in near]))] |= np.uint64(1) << np.uint64(bit)

    if pairs.size:
        mark(pairs, reach_edges * edge, SEAM_BIT)
    if tangled is not None and len(tangled):
        mark(np.asarray(tangled), TANGLE_ZONE_EDGES * edge, TANGLE_BIT)
    return zones


def tangled_vertices(x: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """The vertices of the edges through the mesh's own triangles and of the triangles they cross."""
    from stages.garments.untangle import crossing_pairs
    from stages.geometry.mesh import mesh_edges
    from stages.sim.audit import crossing_flags
    tris = np.ascontiguousarray(triangles, np.int32)
    edges = mesh_edges(tris)
    own, _, _ = crossing_flags(x, edges, np.zeros(len(edges), np.int32), tris, np.zeros(len(tris), np.int32))
    hits = crossing_pairs(x, edges, tris, np.flatnonzero(own))
    if not hits:
        return np.zeros(0, np.int64)
    e, t = np.array(hits).T
    return np.unique(np.concatenate([edges[e].ravel(), tris[t].ravel()])).astype(np.int64)


def sew(name: str, positions: np.ndarray, triangles: np.ndarray, triangle_rest: np.ndarray, pairs: np.ndarray,
        character, motion, colliders, maps, params: SewParams = SewParams(), *, density: float = 0.2,
        flat_positions=None, pair_stage=None, pins=(), bind=None, progress=None):
    """Sew the placed panels. Returns (sewn positions of the UNSEWN mesh (N, 3), SewingLog).

    positions: (N, 3) placed panels; triangles (T, 3); triangle_rest (T, 3) flat edge lengths;
    pairs (K, 2) seam vertex pairs; flat_positions: (N, 3) panels laid out flat side by side (keeps
    coincident seam vertices from being welded before sewing). pair_stage: optional (K,) sewing
    stage of each pair: the pairs of stage k join the seam springs once every earlier pair is within
    2 x tolerance, or after max_iterations / (2 x stages) iterations of the stage.
    pins: Attachment selectors (stages.garments.types) of vertices held in place while sewing,
    with `bind` (bind_pose of the character); the hold motion is still, so they stay where placed.
    progress: optional callback(iteration, max_iterations) after each sewing iteration.
    """
    from stages.sim import SimParams, simulate
    from stages.sim.types import SimulationDiverged

    t0 = time.perf_counter()
    x = np.ascontiguousarray(positions, dtype=np.float64)
    notes = []
    knot = None
    if params.self_collision:
        from stages.garments.untangle import untangle
        x, left, tangled = untangle(x, triangles)
        if tangled:
            notes.append(f"placed panels untangled: {tangled - left} of {tangled} edges through the panels moved back out")
        if left:
            knot = tangled_vertices(x, triangles)
    stage_of = np.zeros(len(pairs), np.int64) if pair_stage is None else np.asarray(pair_stage, np.int64).ravel()
    if stage_of.shape != (len(pairs),):
        raise ContractError(f"sew {name!r}: pair_stage must give one stage per seam pair")
    stages = np.unique(stage_of) if stage_of.size else np.zeros(1, np.int64)
    si = 0
    zones = seam_zones(np.asarray(positions if flat_positions is None else flat_positions, np.float64),
                       np.asarray(triangles), np.asarray(pairs), tangled=knot)

    def garment_for(x, active):
        g = build_garment(name, x, triangles, rest_positions=flat_positions, density=density,
                          attachments=tuple(pins), bind=bind if pins else None,
                          triangle_rest=triangle_rest, extra_springs=pairs[active],
                          extra_rest_lengths=np.full(int(active.sum()), params.seam_rest),
                          yield_swept=False)   # the sewing holds the body still
        if g.n_particles != x.shape[0]:
            raise ContractError(f"sew {name!r}: the unsewn mesh must be clean (got {g.n_particles} of {x.shape[0]} vertices)")
        return replace(g, contact_zones=zones)

    active = stage_of <= stages[si]
    g = garment_for(x, active)
    budget = max(1, params.max_iterations // (2 * len(stages)))
    in_stage = 0
    # no tethers: they would tie each panel's free particles to its own pins at flat-panel
    # distances, against the seam springs (a waistband placed a little stretched never closes).
    # Bend springs as stiff as the edges (not the simulation's 0.2): the panels wrap round the body
    # as stiff sheets; softer, CesiumMan's trousers were sewn with 5 edges through themselves.
    # Self collision: without it the seams pulled cloth through cloth (dress_pencil on the CMU walk:
    # 99 edges through the garment placed, 249 sewn), and a cape's top gathering at the neck folded
    # it through itself; the simulation keeps the crossings it starts with. The cloth near a seam is
    # not collided with the cloth near a seam (seam_zones): the two sides are meant to meet.
    # A garment without seams (a cape) is always sewn with it.
    sp = SimParams(dt=params.dt, substeps=params.substeps, iterations=params.iterations,
                   gravity=(0.0, -9.81 * params.gravity_scale, 0.0), damping=params.damping, drag=0.0, lift=0.0,
                   friction=params.friction, body_audit=False, tethers=False, bend_stiffness=1.0,
                   cloth_collision=params.self_collision or len(pairs) == 0)
    hold = hold_motion(motion, params.frames_per_iteration, params.dt)
    gaps = seam_gaps(x, pairs)
    gmax, gmean = [float(gaps.max(initial=0.0))], [float(gaps.mean()) if gaps.size else 0.0]
    logged, snaps = [0], [x.astype(np.float32)]
    pen = 0
    it = 0
    stalled_at = 0
    target = min(params.target, params.tolerance)
    finished = False    # within the tolerance, the gap stalled above the target with the bend springs at their softest

    def stalled():
        return it - stalled_at >= STALL_WINDOW and gmax[-1] > (1.0 - STALL_GAIN) * gmax[-1 - STALL_WINDOW]

    while (gmax[-1] > params.tolerance or (gmax[-1] > target and not finished) or si + 1 < len(stages)
           or it < params.min_iterations) and it < params.max_iterations:
        it += 1
        try:
            r = simulate(character, hold, colliders, maps, [g], sp, threads=1)
        except SimulationDiverged as exc:
            raise ContractError(f"sew {name!r}: the sewing simulation diverged at iteration {it}: {exc}") from None
        x = r.garments[0].positions[-1].astype(np.float64)
        pen = int(r.penetrations_colliders[-1])
        g = replace(g, positions=x)
        gaps = seam_gaps(x, pairs)
        gmax.append(float(gaps.max(initial=0.0)))
        gmean.append(float(gaps.mean()) if gaps.size else 0.0)
        in_stage += 1
        if si + 1 < len(stages) and (gaps[active].max(initial=0.0) <= 2 * params.tolerance or in_stage >= budget):
            si += 1
            in_stage = 0
            active = stage_of <= stages[si]
            g = garment_for(x, active)
            notes.append(f"stage {int(stages[si])} from iteration {it}")
        if si + 1 == len(stages) and target < gmax[-1] <= params.tolerance and sp.bend_stiffness <= MIN_SEW_BEND \
                and stalled():
            finished = True     # closed to the tolerance and no longer closing: more rounds would not help
        if (si + 1 == len(stages) and gmax[-1] > target and sp.bend_stiffness > MIN_SEW_BEND
                and stalled()):
            # the last millimetres stall where stiff panels must curl into a tube's closing corner
            # (CesiumMan's shorts: an inseam's hem end at 4.7 mm from iteration 4 on, 40 or 120
            # iterations alike): the bend springs soften, halving each time it stalls again
            sp = replace(sp, bend_stiffness=max(MIN_SEW_BEND, 0.5 * sp.bend_stiffness))
            stalled_at = it
            notes.append(f"bend stiffness {sp.bend_stiffness:g} from iteration {it} (gap stalled at "
                         f"{gmax[-1] * 1000:.1f} mm)")
        if progress is not None:
            progress(it, params.max_iterations)
        if it % params.log_every == 0:
            logged.append(it)
            snaps.append(x.astype(np.float32))
    if logged[-1] != it:
        logged.append(it)
        snaps.append(x.astype(np.float32))
    converged = gmax[-1] <= params.tolerance
    if not converged:
        notes.append(f"seam gaps did not fall below {params.tolerance} m in {it} iterations (max {gmax[-1]:.4f} m)")
    log = SewingLog(np.array(gmax), np.array(gmean), np.stack(snaps), np.array(logged, np.int32),
                    np.ascontiguousarray(triangles, dtype=np.int32), time.perf_counter() - t0, bool(converged), pen,
                    tuple(notes))
    return x, log


def merge_pairs(n: int, pairs: np.ndarray) -> np.ndarray:
    """(n,) new index of every vertex after merging the pairs' connected groups (union-find)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    if pairs.size == 0:
        return np.arange(n)
    adj = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, label = connected_components(adj, directed=False)
    # number groups in order of their first vertex (deterministic, keeps panel order)
    first = np.full(label.max() + 1, n)
    np.minimum.at(first, label, np.arange(n))
    rank = np.empty_like(first)
    rank[np.argsort(first, kind="stable")] = np.arange(first.size)
    return rank[label]


def merged_mesh(x: np.ndarray, triangles: np.ndarray, pairs: np.ndarray):
    """(positions (M, 3): group means, triangles (T, 3) int32, remap (N,)) of the sewn mesh."""
    remap = merge_pairs(x.shape[0], pairs)
    m = remap.max() + 1
    cnt = np.bincount(remap, minlength=m).astype(np.float64)
    pos = np.stack([np.bincount(remap, weights=x[:, k], minlength=m) for k in range(3)], axis=1) / cnt[:, None]
    return pos, remap[triangles].astype(np.int32), remap
