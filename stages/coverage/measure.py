"""How well the colliders fit the body, as a garment sees it: coverage and excess.

At each sampled frame the skinned body and every collider (posed by its joint) are compared:
- coverage: the share of points sampled inside the skinned body that lie inside some collider. The
  samples are a jittered grid (one point per cell, cell size chosen for >= `interior_samples`
  inside the body); inside the body = generalised winding number >= 0.5 (open meshes too).
- excess: points sampled uniformly on the surface of the union of the colliders (a collider's
  surface point inside another collider is hidden from the cloth and skipped) that lie outside the
  body; their distance to the skin, p50 / p95 / max. This is how far the colliders hold cloth off.
- shell: the grid cells inside some collider and outside the body, as a share of the body volume.
- skin exposed: the share of the skin's points (vertices, triangle centroids, edge midpoints) out of
  every collider: where cloth resting on the colliders can show the skin through it. Coverage counts
  volume and missed CesiumMan's armpits and chest, up to 11.6 mm out (stages/hulls/balls.py).
Per collider: the excess of its own (union-surface) samples, its shell share, and the coverage of
the body points whose nearest skin vertex belongs to its region (which collider a hole is near).

Frames: points in the relative frame of each frame (stages/rig/types.py); colliders bone-local.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from stages.checks import ContractError, check_array
from stages.errors import InputError
from stages.geometry.skin_distance import SkinDistance
from stages.coverage import kernels as K
from stages.jit import threaded
from stages.hulls.types import ColliderSet
from stages.rig.skinning import skin
from stages.rig.types import Character, Motion

COVERAGE_WARN = 0.99       # warn below this coverage at any sampled frame
MAX_REFINE = 4             # grid refinements to reach interior_samples (each ~x(n / needed)^(1/3))
MIN_INSIDE = 50            # fewer grid points inside the body than this: it has no volume to measure
EXCESS_P95_WARN = 0.03     # m: warn above this p95 excess
SKIN_EXPOSED_WARN = 0.01   # warn above this share of skin points out of every collider at a sampled frame (the
                            # built-in body's hull seams at bent knees and elbows reach 0.6 %, where no garment rests)
MAX_GRID_CELLS = 4_000_000   # cells of a frame's jittered grid at most (coarser beyond): a body of almost no
                             # volume (a flat or open mesh) asked for cells of 0.3 mm over its whole box
MAX_SURFACE_SAMPLES = 200_000   # collider-surface samples per frame at most (spacing grows beyond: a 10 m glTF
                                # with 1,233 balls had 7 million at 1 cm, and its coverage took 475 s)


@dataclass(frozen=True)
class ColliderFigures:
    """Fit figures of one collider over every sampled frame (distances in m).

    coverage: share of the body points nearest its region that are inside some collider (nan when
    no body point is nearest its region). excess_*: over its union-surface samples outside the body
    (0 when it has none). shell_share: (collider volume outside the body) / body volume, mean over
    the sampled frames (overlapping colliders each count the shared part).
    """

    name: str
    kind: str
    joint: int
    coverage: float
    excess_p50: float
    excess_p95: float
    excess_max: float
    shell_share: float


@dataclass(frozen=True)
class CoverageReport:
    """Coverage and excess of a character's colliders at sampled frames.

    frames: (S,) int64, the motion frames measured. interior_samples: (S,) int64, grid points
    inside the body. coverage: (S,) float64 in [0, 1]. excess_p50 / excess_p95 / excess_max: (S,)
    float64, m. shell_share: (S,) float64, shell volume / body volume. body_volume: (S,) float64,
    m^3 (grid estimate). skin_exposed: (S,) float64 in [0, 1], the share of skin points out of every
    collider. cell: grid cell edge, m. surface_samples: union-surface points per frame.
    colliders: one ColliderFigures per collider (hulls first, then spheres, ColliderSet order).
    """

    frames: np.ndarray
    interior_samples: np.ndarray
    coverage: np.ndarray
    excess_p50: np.ndarray
    excess_p95: np.ndarray
    excess_max: np.ndarray
    shell_share: np.ndarray
    body_volume: np.ndarray
    skin_exposed: np.ndarray
    cell: float
    surface_samples: int
    colliders: tuple
    samples: tuple = ()   # keep_samples: per frame {'grid', 'in_body', 'surface', 'owner', 'exposed', 'outside'}

    def __post_init__(self):
        o = "CoverageReport"
        s = check_array(o, "frames", self.frames, (None,), np.int64).size
        check_array(o, "interior_samples", self.interior_samples, (s,), np.int64)
        for name in ("coverage", "excess_p50", "excess_p95", "excess_max", "shell_share", "body_volume", "skin_exposed"):
            check_array(o, name, getattr(self, name), (s,), np.float64)
        if s and (self.coverage.min() < 0 or self.coverage.max() > 1):
            raise ContractError(f"{o}.coverage: expected shares in [0, 1]")

    def totals(self) -> dict:
        """Worst sampled frame of each figure (coverage min, excess and shell max)."""
        return {"frames": int(self.frames.size), "coverage_min": float(self.coverage.min()),
                "excess_p50": float(self.excess_p50.max()), "excess_p95": float(self.excess_p95.max()),
                "excess_max": float(self.excess_max.max()), "shell_share": float(self.shell_share.max()),
                "skin_exposed": float(self.skin_exposed.max()),
                "interior_samples_min": int(self.interior_samples.min()), "colliders": len(self.colliders)}

    def warnings(self) -> list[str]:
        """One line per figure out of range, naming the colliders responsible."""
        out = []
        if self.coverage.min() < COVERAGE_WARN:
            low = sorted((c for c in self.colliders if c.coverage < COVERAGE_WARN), key=lambda c: c.coverage)
            names = ", ".join(f"{c.name} {c.coverage * 100:.1f} %" for c in low[:6]) or "none singled out"
            out.append(f"collider coverage {self.coverage.min() * 100:.2f} % at frame "
                       f"{int(self.frames[np.argmin(self.coverage)])} (below {COVERAGE_WARN * 100:.0f} %): "
                       f"body left uncovered near {names}")
        if self.skin_exposed.max() > SKIN_EXPOSED_WARN:
            out.append(f"skin out of every collider: {self.skin_exposed.max() * 100:.2f} % of its points at frame "
                       f"{int(self.frames[np.argmax(self.skin_exposed)])} (above {SKIN_EXPOSED_WARN * 100:.2f} %): "
                       "cloth resting on the colliders can show the skin there")
        if self.excess_p95.max() > EXCESS_P95_WARN:
            hi = sorted((c for c in self.colliders if c.excess_p95 > EXCESS_P95_WARN), key=lambda c: -c.excess_p95)
            names = ", ".join(f"{c.name} {c.excess_p95 * 100:.1f} cm" for c in hi[:6]) or "none singled out"
            out.append(f"collider excess p95 {self.excess_p95.max() * 100:.1f} cm (above "
                       f"{EXCESS_P95_WARN * 100:.0f} cm): colliders standing off the skin: {names}")
        return out


@dataclass(frozen=True)
class ColliderArrays:
    """Every collider as flat arrays for `kernels.inside_colliders` (hulls first, then spheres).

    joint (C,) int32; kind (C,) int32 (KIND_HULL / KIND_SPHERE); bcenter (C, 3), bradius (C,):
    bone-local bounding balls; plane_start (C+1,) int64 into planes (F, 4) (bone-local, hulls only);
    sph_center (C, 3), sph_radius (C,); names, kinds: per collider.
    """

    joint: np.ndarray
    kind: np.ndarray
    bcenter: np.ndarray
    bradius: np.ndarray
    plane_start: np.ndarray
    planes: np.ndarray
    sph_center: np.ndarray
    sph_radius: np.ndarray
    names: tuple
    kinds: tuple


def collider_arrays(colliders: ColliderSet) -> ColliderArrays:
    joint, kind, bc, br, ps, planes, sc, sr, names, kinds = [], [], [], [], [0], [], [], [], [], []
    for h in colliders.hulls:
        v = h.simplified.vertices
        c = v.mean(axis=0)
        joint.append(h.bone)
        kind.append(K.KIND_HULL)
        bc.append(c)
        br.append(np.linalg.norm(v - c, axis=1).max() * (1 + 1e-9) + 1e-9)
        planes.append(h.simplified.planes)
        ps.append(ps[-1] + h.simplified.faces.shape[0])
        sc.append(np.zeros(3))
        sr.append(0.0)
        names.append(h.name)
        kinds.append(h.kind)
    for s in colliders.spheres:
        joint.append(s.pose_index)
        kind.append(K.KIND_SPHERE)
        bc.append(s.center)
        br.append(s.radius * (1 + 1e-9) + 1e-9)
        ps.append(ps[-1])
        sc.append(s.center)
        sr.append(s.radius)
        names.append(s.name)
        kinds.append("sphere")
    nc = len(joint)
    return ColliderArrays(
        joint=np.array(joint, np.int32), kind=np.array(kind, np.int32),
        bcenter=np.array(bc, np.float64).reshape(nc, 3), bradius=np.array(br, np.float64),
        plane_start=np.array(ps, np.int64),
        planes=np.ascontiguousarray(np.concatenate(planes) if planes else np.zeros((0, 4))),
        sph_center=np.array(sc, np.float64).reshape(nc, 3), sph_radius=np.array(sr, np.float64),
        names=tuple(names), kinds=tuple(kinds))


def _posed(arrays: ColliderArrays, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(to_local (C, 4, 4), wcenter (C, 3)): each collider's relative frame -> bone-local transform at
    `pose` (J, 4, 4) and its bounding ball's centre posed."""
    m = pose[arrays.joint]
    to_local = np.ascontiguousarray(np.linalg.inv(m))
    wcenter = np.ascontiguousarray(np.einsum("cij,cj->ci", m[:, :3, :3], arrays.bcenter) + m[:, :3, 3])
    return to_local, wcenter


def inside_matrix(points: np.ndarray, arrays: ColliderArrays, pose: np.ndarray) -> np.ndarray:
    """(P, C) uint8: point p (relative frame) inside collider c posed by `pose` (J, 4, 4). Every
    pair is tested: the reference of `CollidersAtPose`."""
    to_local, wcenter = _posed(arrays, pose)
    out = np.zeros((points.shape[0], arrays.joint.size), np.uint8)
    if points.shape[0] and arrays.joint.size:
        threaded(K.inside_colliders)(np.ascontiguousarray(points, np.float64), to_local, arrays.kind, arrays.bcenter,
                           wcenter, arrays.bradius, arrays.plane_start, arrays.planes, arrays.sph_center,
                           arrays.sph_radius, out)
    return out


MAX_CELLS = 2_000_000   # cells of a CollidersAtPose grid at most (coarser cells beyond)


class CollidersAtPose:
    """The colliders posed at one frame, with a uniform grid over their bounding balls: inside tests
    of many points against many colliders test only the colliders listed in each point's cell
    (kernels.collider_cells). The answers are inside_matrix's: the same test of each pair, and a
    point outside a collider's cells is outside its ball, which the test rejects first.

    Cell edge: twice the median bounding radius (about one ball a cell; a hull spans many)."""

    def __init__(self, arrays: ColliderArrays, pose: np.ndarray):
        self.arrays = arrays
        self.to_local, self.wcenter = _posed(arrays, pose)
        r = arrays.bradius
        nc = r.size
        lo = (self.wcenter - r[:, None]).min(axis=0) if nc else np.zeros(3)
        hi = (self.wcenter + r[:, None]).max(axis=0) if nc else np.zeros(3)
        cell = max(2.0 * float(np.median(r)) if nc else 1.0, 1e-6)
        while True:
            dims = np.floor((hi - lo) / cell).astype(np.int64) + 1
            if int(np.prod(dims)) <= MAX_CELLS:
                break
            cell *= 1.5
        self.lo, self.cell, self.dims = np.ascontiguousarray(lo, np.float64), float(cell), dims
        self.start, self.items = K.collider_cells(self.wcenter, r, self.lo, self.cell, self.dims)

    def _args(self):
        a = self.arrays
        return (self.to_local, a.kind, self.wcenter, a.bradius, a.plane_start, a.planes, a.sph_center, a.sph_radius,
                self.lo, self.cell, self.dims, self.start, self.items)

    def inside_any(self, points: np.ndarray, exclude: np.ndarray | None = None) -> np.ndarray:
        """(P,) bool: point p (relative frame) inside some collider other than exclude[p] ((P,) int,
        -1 or None: none excluded) = inside_matrix(...) with column exclude[p] zeroed, any(axis=1)."""
        p = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
        ex = np.full(p.shape[0], -1, np.int64) if exclude is None else np.ascontiguousarray(exclude, np.int64)
        out = np.zeros(p.shape[0], np.uint8)
        if p.shape[0] and self.arrays.joint.size:
            threaded(K.inside_any_cells)(p, ex, *self._args(), out)
        return out.astype(bool)

    def inside_counts(self, points: np.ndarray) -> np.ndarray:
        """(C,) int64: per collider the points inside it = inside_matrix(...).sum(axis=0)."""
        counts = np.zeros(self.arrays.joint.size, np.int64)
        p = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
        if p.shape[0] and counts.size:
            K.inside_counts_cells(p, *self._args(), counts)
        return counts


def surface_samples(colliders: ColliderSet, spacing: float, rng: np.random.Generator,
                    max_per_collider: int = 6000, max_total: int = MAX_SURFACE_SAMPLES
                    ) -> tuple[list[np.ndarray], np.ndarray]:
    """Uniform random points on each collider's surface, bone-local: (list of (n_c, 3), areas (C,)).

    About one point per spacing^2 of area (at least 64, at most max_per_collider per collider); a
    coarser spacing where that would make more than about max_total in all (a big body)."""
    hull_tris = []
    for h in colliders.hulls:
        v, f = h.simplified.vertices, h.simplified.faces
        a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
        hull_tris.append((a, b, c, 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)))
    areas = np.array([float(t[3].sum()) for t in hull_tris] + [4 * np.pi * s.radius ** 2 for s in colliders.spheres])
    spacing = max(spacing, float(np.sqrt(areas.sum() / max_total)))
    count = lambda area: int(np.clip(area / spacing ** 2, 64, max_per_collider))   # noqa: E731
    pts = []
    for (a, b, c, tri_area), area in zip(hull_tris, areas):
        n = count(area)
        t = rng.choice(tri_area.size, size=n, p=tri_area / area if area > 0 else None)   # a flat hull: any face
        u, w = rng.random(n), rng.random(n)
        flip = u + w > 1
        u[flip], w[flip] = 1 - u[flip], 1 - w[flip]
        pts.append(a[t] + u[:, None] * (b[t] - a[t]) + w[:, None] * (c[t] - a[t]))
    for s, area in zip(colliders.spheres, areas[len(hull_tris):]):
        n = count(area)
        d = rng.normal(size=(n, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        pts.append(s.center + s.radius * d)
    return pts, areas


def _world_boxes(arrays: ColliderArrays, colliders: ColliderSet, pose: np.ndarray) -> np.ndarray:
    """(2, 3) box around every collider posed by `pose` (relative frame)."""
    lo, hi = [], []
    for c in range(arrays.joint.size):
        m = pose[arrays.joint[c]]
        ctr = m[:3, :3] @ arrays.bcenter[c] + m[:3, 3]
        lo.append(ctr - arrays.bradius[c])
        hi.append(ctr + arrays.bradius[c])
    return np.array([np.min(lo, axis=0), np.max(hi, axis=0)])


def _pct(a: np.ndarray, q: float) -> float:
    return float(np.percentile(a, q)) if a.size else 0.0


def measure_coverage(character: Character, motion: Motion, colliders: ColliderSet, *, frames=None,
                     every: int = 10, interior_samples: int = 20000, surface_spacing: float = 0.01,
                     vertex_collider: np.ndarray | None = None, seed: int = 0,
                     keep_samples: bool = False, progress=None) -> CoverageReport:
    """Coverage, excess and shell of `colliders` on the skinned `character` at sampled frames.

    frames: motion frame indices (default every `every`-th frame and the last). interior_samples:
    the grid is refined until at least this many of its points are inside the body at each frame.
    surface_spacing: about one collider-surface sample per spacing^2 (m; coarser when that would
    exceed MAX_SURFACE_SAMPLES). vertex_collider: (V,)
    int, the collider index (ColliderSet order, hulls then spheres) whose region holds each vertex,
    -1 for none: per-collider coverage (default: from the colliders' region vertex indices).
    seed: the jitter and surface samples (same seed, same figures). keep_samples: keep every
    frame's sample points in `CoverageReport.samples` (for tests against a reference).
    progress: optional callback(done, total) after each measured frame.
    """
    if frames is None:
        frames = sorted(set(range(0, motion.n_frames, max(1, int(every)))) | {motion.n_frames - 1})
    frames = np.asarray(frames, np.int64)
    if frames.size == 0 or frames.min() < 0 or frames.max() >= motion.n_frames:
        raise ContractError(f"measure_coverage: frames must be in [0, {motion.n_frames}), got {frames.tolist()}")
    arrays = collider_arrays(colliders)
    nc = arrays.joint.size
    if vertex_collider is None:
        vertex_collider = region_owner(colliders, character.vertices.shape[0])
    rng = np.random.default_rng(seed)
    local_surface, _ = surface_samples(colliders, surface_spacing, rng)
    owner_surface = np.concatenate([np.full(p.shape[0], c, np.int64) for c, p in enumerate(local_surface)]) \
        if nc else np.zeros(0, np.int64)
    skinned = skin(character, motion, frames)
    body = SkinDistance(character)
    bind_volume = abs(_mesh_volume(character.vertices, character.triangles))
    cell = (max(bind_volume, 1e-6) / (1.3 * interior_samples)) ** (1 / 3)

    rows = {k: [] for k in ("n_in", "coverage", "p50", "p95", "max", "shell", "volume", "exposed")}
    from stages.geometry.mesh import mesh_edges
    edges = mesh_edges(character.triangles)
    per_in = np.zeros(nc)        # body points nearest each collider's region
    per_cov = np.zeros(nc)       # ... of them inside some collider
    per_shell = np.zeros(nc)     # shell cells inside each collider, summed over frames (in body volumes)
    per_excess = [[] for _ in range(nc)]
    kept = []
    for k, f in enumerate(frames):
        v = skinned[k]
        pose = colliders.frame_poses(character.inverse_bind, motion.joint_world[f])
        body.refit(v)
        box = _world_boxes(arrays, colliders, pose) if nc else np.array([v.min(0), v.max(0)])
        box = np.array([np.minimum(box[0], v.min(0)), np.maximum(box[1], v.max(0))])
        coarsest = (float(np.prod(np.maximum(box[1] - box[0], 1e-9))) / MAX_GRID_CELLS) ** (1 / 3)
        h = max(cell, coarsest)
        posed = CollidersAtPose(arrays, pose)
        balls = (posed.wcenter, arrays.bradius)
        for _ in range(MAX_REFINE):
            grid, in_body = _body_grid(body, box, h, balls, rng)
            if in_body.sum() >= interior_samples:
                break
            if in_body.sum() < MIN_INSIDE:   # no volume: finer cells would only cost memory
                raise InputError(f"collider coverage at frame {int(f)}", f"the skinned mesh encloses no volume "
                                 f"({int(in_body.sum())} of {grid.shape[0]} grid points inside; an open or "
                                 "inside-out mesh?): coverage and excess cannot be measured")
            if h <= coarsest:       # MAX_GRID_CELLS: no finer grid
                break
            h = max(h * 0.85 * (in_body.sum() / interior_samples) ** (1 / 3), coarsest)
        any_col = posed.inside_any(grid)
        n_in = int(in_body.sum())
        vol_cell = h ** 3
        body_vol = n_in * vol_cell
        rows["n_in"].append(n_in)
        rows["coverage"].append(float((in_body & any_col).sum() / n_in))
        rows["shell"].append(float((~in_body & any_col).sum() / n_in))
        rows["volume"].append(body_vol)
        per_shell += posed.inside_counts(grid[~in_body]) / n_in
        skin_pts = np.concatenate([v, v[character.triangles].mean(axis=1), v[edges].mean(axis=1)])
        rows["exposed"].append(float((~posed.inside_any(skin_pts)).mean()))
        if nc:
            near = cKDTree(v).query(grid[in_body])[1]
            owner = vertex_collider[near]
            ok = owner >= 0
            per_in += np.bincount(owner[ok], minlength=nc)
            per_cov += np.bincount(owner[ok], weights=any_col[in_body][ok].astype(float), minlength=nc)
        # excess: union-surface samples outside the body
        if nc:
            world = np.concatenate([_apply(pose[arrays.joint[c]], p) for c, p in enumerate(local_surface)])
            exposed = ~posed.inside_any(world, exclude=owner_surface)   # a point is on its own surface
            outside = exposed.copy()             # inside tests only for the exposed points (most are hidden)
            outside[exposed] = ~body.inside(world[exposed])
            d = body.distance(world[outside])
            own = owner_surface[outside]
            for c in range(nc):
                per_excess[c].append(d[own == c])
            if keep_samples:
                kept.append({"grid": grid, "in_body": in_body, "cell": h, "surface": world, "owner": owner_surface,
                             "exposed": exposed, "outside": outside})
        else:
            d = np.zeros(0)
        rows["p50"].append(_pct(d, 50))
        rows["p95"].append(_pct(d, 95))
        rows["max"].append(float(d.max()) if d.size else 0.0)
        if progress is not None:
            progress(k + 1, len(frames))

    figures = []
    for c in range(nc):
        e = np.concatenate(per_excess[c]) if per_excess[c] else np.zeros(0)
        figures.append(ColliderFigures(
            name=arrays.names[c], kind=arrays.kinds[c], joint=int(arrays.joint[c]),
            coverage=float(per_cov[c] / per_in[c]) if per_in[c] else float("nan"),
            excess_p50=_pct(e, 50), excess_p95=_pct(e, 95), excess_max=float(e.max()) if e.size else 0.0,
            shell_share=float(per_shell[c] / frames.size)))
    f64 = lambda key: np.array(rows[key], np.float64)  # noqa: E731
    return CoverageReport(frames=frames, interior_samples=np.array(rows["n_in"], np.int64),
                          coverage=f64("coverage"), excess_p50=f64("p50"), excess_p95=f64("p95"),
                          excess_max=f64("max"), shell_share=f64("shell"), body_volume=f64("volume"),
                          skin_exposed=f64("exposed"),
                          cell=float(cell), surface_samples=int(owner_surface.size), colliders=tuple(figures),
                          samples=tuple(kept))


def region_owner(colliders: ColliderSet, n_vertices: int) -> np.ndarray:
    """(V,) int64: the collider (hulls then spheres) whose region holds each vertex, -1 for none.

    A vertex in several regions (swept hulls share their border ring) goes to the first."""
    owner = np.full(n_vertices, -1, np.int64)
    for c, col in enumerate(tuple(colliders.hulls) + tuple(colliders.spheres)):
        idx = col.region_vertices
        free = idx[owner[idx] < 0]
        owner[free] = c
    return owner


def _apply(m: np.ndarray, p: np.ndarray) -> np.ndarray:
    return p @ m[:3, :3].T + m[:3, 3]


BLOCK = 4  # cells per block edge in the inside test


def _body_grid(body: "SkinDistance", box: np.ndarray, h: float, balls, rng: np.random.Generator):
    """Jittered grid points (one uniform random point per cell of edge h, cells from box[0]) and
    their inside-body flags, over the blocks of BLOCK^3 cells that can matter.

    A block the skin does not pass through (its centre farther from the skin than its half
    diagonal) is all inside or all outside: it takes its centre's answer, and when that is outside
    and no collider's ball (`balls`: posed centres (C, 3), radii (C,)) reaches it, it holds neither
    body nor collider and is left out. The points of the other blocks are tested one by one. Same
    figures as testing every cell of the box, for a closed skin."""
    bh = BLOCK * h
    nb = np.maximum(np.ceil((box[1] - box[0]) / bh).astype(np.int64), 1)
    bidx = np.indices(tuple(nb)).reshape(3, -1).T
    centres = box[0] + (bidx + 0.5) * bh
    half = 0.5 * np.sqrt(3.0) * bh
    far = body.distance(centres) > half
    inside = np.zeros(far.size, bool)
    inside[far] = body.inside(centres[far])
    wc, wr = balls
    touch = np.zeros(far.size, bool)
    for c in range(wr.size):            # one vector pass per collider (CesiumMan's 1,013: 15 ms a frame)
        touch |= np.linalg.norm(centres - wc[c], axis=1) <= wr[c] + half
    keep = np.flatnonzero(~far | inside | touch)
    sub = np.indices((BLOCK,) * 3).reshape(3, -1).T                      # cells of a block
    cells = (bidx[keep][:, None, :] * BLOCK + sub[None]).reshape(-1, 3)
    grid = box[0] + (cells + rng.random(cells.shape)) * h
    in_body = np.repeat(inside[keep], sub.shape[0])
    near = np.repeat(~far[keep], sub.shape[0])
    in_body[near] = body.inside(grid[near])
    return grid, in_body


def _mesh_volume(v: np.ndarray, t: np.ndarray) -> float:
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)
