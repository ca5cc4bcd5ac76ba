"""The body audit: where the body passes through the cloth between its particles (all frames).

A stage of its own, run after the simulation: `audit_body_crossings(result, body)` -> BodyCrossings.

The simulation's own body audit counts cloth *particles* inside the skinned mesh; a limb can also
pass through the cloth between particles (a hand through a skirt, an elbow through a sleeve) with
every particle outside. Per frame and garment this counts
- body edges through the cloth: body-mesh edges crossing a triangle of the garment;
- cloth edges through the body: garment edges crossing a body triangle;
each edge once however many triangles it crosses, by the exact test of stages.sim.audit_kernels
(touching and coplanar contacts do not count). Crossings where the body meets itself (an animation
that sinks a forearm into the hip: two parts of the skin pass through each other, and cloth between
them must cross one) are flagged and counted apart (`in_self_overlap`); the figure judged is the rest. Each crossing is located (where the edge meets the
triangle) and named by the body's joint nearest it: the dominant skin joint of the body vertex
nearest the crossing point (of the body edge, or of the body triangle).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from stages.checks import ContractError, check_array
from stages.geometry.mesh import mesh_edges
from stages.geometry.winding import winding_numbers_brute
from stages.jit import threaded
from stages.rig.skinning import vertex_normals
from stages.sim import audit_kernels as AK
from stages.sim import body_audit_kernels as BK
from stages.sim.audit import crosses_exact


@dataclass(frozen=True)
class BodyFrames:
    """The skinned body the cloth is checked against.

    positions: (F, V, 3) float32, metres, WORLD frame (skin + root translation), per frame.
    triangles: (T, 3) int32, indices into the V vertices.
    vertex_joint: (V,) int32, each vertex's dominant skin joint (largest weight).
    joint_names: J names, indexed by vertex_joint.
    """

    positions: np.ndarray
    triangles: np.ndarray
    vertex_joint: np.ndarray
    joint_names: tuple

    def __post_init__(self):
        o = "BodyFrames"
        p = check_array(o, "positions", self.positions, (None, None, 3), np.float32)
        check_array(o, "triangles", self.triangles, (None, 3), np.int32)
        check_array(o, "vertex_joint", self.vertex_joint, (p.shape[1],), np.int32)
        if self.triangles.size and not (0 <= self.triangles.min() and self.triangles.max() < p.shape[1]):
            raise ContractError(f"{o}.triangles: indices outside [0, {p.shape[1]})")
        if self.vertex_joint.size and not (0 <= self.vertex_joint.min() and self.vertex_joint.max() < len(self.joint_names)):
            raise ContractError(f"{o}.vertex_joint: joints outside [0, {len(self.joint_names)})")

    @classmethod
    def of(cls, character, motion, skinned: np.ndarray) -> BodyFrames:
        """From a Character, its Motion and skin(character, motion) (F, V, 3) relative frame."""
        world = (np.asarray(skinned, np.float64) + motion.root_translation[:, None, :]).astype(np.float32)
        heaviest = np.argmax(character.skin_weights, axis=1)
        joint = character.skin_joints[np.arange(len(heaviest)), heaviest].astype(np.int32)
        return cls(world, np.asarray(character.triangles, np.int32), joint, tuple(character.joint_names))


@dataclass(frozen=True)
class GarmentCrossings:
    """One garment's crossings with the body over F frames.

    body_edges: (F,) int32, body-mesh edges crossing a triangle of the garment.
    cloth_edges: (F,) int32, garment edges crossing a body triangle.
    joint_counts: (F, J) int32, both kinds of crossing per nearest joint (sums to body + cloth edges).
    points: per frame, (c, 3) float32 world metres: where each crossing edge meets the triangle
        (body edges first, then cloth edges), c = body_edges[f] + cloth_edges[f].
    self_overlap: per frame, (c,) bool, aligned with points: the crossing is where the body meets
        itself (in_self_overlap: two parts of the body pass through each other or touch there, and
        no cloth between them can avoid one of them).
    """

    name: str
    body_edges: np.ndarray
    cloth_edges: np.ndarray
    joint_counts: np.ndarray
    points: tuple
    self_overlap: tuple

    def __post_init__(self):
        o = f"GarmentCrossings[{self.name!r}]"
        f = check_array(o, "body_edges", self.body_edges, (None,), np.int32).shape[0]
        check_array(o, "cloth_edges", self.cloth_edges, (f,), np.int32)
        check_array(o, "joint_counts", self.joint_counts, (f, None), np.int32)
        if len(self.points) != f:
            raise ContractError(f"{o}.points: {len(self.points)} frames, expected {f}")
        if [len(k) for k in self.self_overlap] != [len(p) for p in self.points]:
            raise ContractError(f"{o}.self_overlap: expected one flag per crossing point of each frame")

    def body_edges_free(self) -> np.ndarray:
        """(F,) int32 body edges through the cloth away from where the body meets itself: the limb
        through the cloth that collision handling should have prevented."""
        return (self.body_edges - self.body_edges_in_overlap()).astype(np.int32)

    def body_edges_in_overlap(self) -> np.ndarray:
        """(F,) int32 body edges through the cloth where the body meets itself (the cloth pinched)."""
        return np.array([int(np.count_nonzero(k[:n])) for k, n in zip(self.self_overlap, self.body_edges)], np.int32)


@dataclass(frozen=True)
class BodyCrossings:
    """The body audit of a SimResult.

    garments: one GarmentCrossings per garment, in the result's order.
    joint_names: J names (GarmentCrossings.joint_counts' columns).
    first_frame: the first frame the warnings and `worst` look at (after the blend-in; >= 1).
    exact_pairs: edges the float64 filter left undecided, decided in rational arithmetic.
    warnings: per garment, one line if a body edge passes through it away from where the body meets
        itself at or after first_frame, and one if it does where the body meets itself.
    """

    garments: tuple
    joint_names: tuple
    first_frame: int
    exact_pairs: int
    warnings: tuple

    def __post_init__(self):
        for g in self.garments:
            if g.joint_counts.shape[1] != len(self.joint_names):
                raise ContractError(f"BodyCrossings.garments[{g.name!r}].joint_counts: {g.joint_counts.shape[1]} "
                                    f"joints, expected {len(self.joint_names)}")
        if self.first_frame < 1:
            raise ContractError(f"BodyCrossings.first_frame: expected >= 1 (frame 0 is as dressed), got {self.first_frame}")

    def garment(self, name: str) -> GarmentCrossings:
        for g in self.garments:
            if g.name == name:
                return g
        raise KeyError(f"no garment {name!r}")

    def body_edges_after(self, in_overlap: bool = False) -> np.ndarray:
        """(F - first_frame,) body edges through any garment per frame from first_frame on, away from
        where the body meets itself (the figure judged), or (in_overlap) where it does."""
        if not self.garments:
            return np.zeros(0, np.int32)
        per = [g.body_edges_in_overlap() if in_overlap else g.body_edges_free() for g in self.garments]
        return np.sum([p[self.first_frame:] for p in per], axis=0).astype(np.int32)

    def worst(self, g: GarmentCrossings, in_overlap: bool = False) -> tuple[int, int]:
        """(frame, body edges away from where the body meets itself, or in_overlap: where it does) of the
        garment's worst frame from first_frame on ((first_frame, 0) when none)."""
        counts = g.body_edges_in_overlap() if in_overlap else g.body_edges_free()
        tail = counts[self.first_frame:]
        if not tail.size:
            return self.first_frame, 0
        f = self.first_frame + int(np.argmax(tail))
        return f, int(counts[f])

    def joints_at(self, g: GarmentCrossings, frame: int, top: int = 3) -> str:
        """'name n, name n' of the joints with the most crossings of the garment at `frame`."""
        row = g.joint_counts[frame]
        order = [j for j in np.argsort(-row, kind="stable")[:top] if row[j] > 0]
        return ", ".join(f"{self.joint_names[j]} {int(row[j])}" for j in order)

    def summary(self) -> dict:
        """Figures for the run summary, per garment: the worst frame after the blend-in."""
        out = {}
        for g in self.garments:
            f, n = self.worst(g)
            fo, no = self.worst(g, in_overlap=True)
            cloth = int(g.cloth_edges[self.first_frame:].max(initial=0))
            where = f" at frame {f} ({self.joints_at(g, f)})" if n else ""
            out[f"{g.name}: body edges through the cloth (elsewhere / where the body meets itself) / cloth edges "
                f"through the body (max per frame {blend_in_note(self.first_frame)})"] = (
                f"{n}{where} / {no}{f' at frame {fo}' if no else ''} / {cloth}")
        return out


def _segment_points(x: np.ndarray, edges: np.ndarray, tris: np.ndarray):
    """(points (n, 3), t (n,)): where each edge p -> q meets the plane of its triangle, t along pq."""
    p, q = x[edges[:, 0]], x[edges[:, 1]]
    a, b, c = (x[tris[:, k]] for k in range(3))
    n = np.cross(b - a, c - a)
    dp = np.einsum("ij,ij->i", p - a, n)
    dq = np.einsum("ij,ij->i", q - a, n)
    t = np.clip(dp / np.where(dp != dq, dp - dq, 1.0), 0.0, 1.0)
    return p + t[:, None] * (q - p), t


def _grid(x: np.ndarray, tris: np.ndarray, cell: float):
    """build_triangle_grid over the rows of x the triangles use (x[:hi], hi = 1 + their largest
    index: the cloth's rows come first, so its grid spans the cloth, not the body)."""
    hi = int(tris.max()) + 1
    extent = np.ptp(x[:hi], axis=0)
    while np.prod(np.floor(extent / cell) + 1) > AK.GRID_MAX_CELLS:
        cell *= 2.0
    return (*AK.build_triangle_grid(np.ascontiguousarray(x[:hi]), tris, cell), cell)


def _decide(x, edges, tris, unknown: np.ndarray, hit: np.ndarray) -> int:
    """Edges the kernel left undecided: their first crossing triangle (or -1) in rational arithmetic."""
    for e in unknown:
        p, q = edges[e]
        lo, hi = np.minimum(x[p], x[q]), np.maximum(x[p], x[q])
        tb = x[tris]
        near = np.all(tb.min(axis=1) <= hi, axis=1) & np.all(tb.max(axis=1) >= lo, axis=1)
        near &= ~np.any((tris == p) | (tris == q), axis=1)
        hit[e] = next((t for t in np.flatnonzero(near) if crosses_exact(x[p], x[q], *x[tris[t]])), -1)
    return len(unknown)


def edges_through(x: np.ndarray, edges: np.ndarray, tris: np.ndarray, cell: float) -> tuple[np.ndarray, int]:
    """(hit (E,) int64, exact pairs): per edge (rows of x, float64) the first triangle it crosses, or -1."""
    hit = np.full(edges.shape[0], -1, np.int64)
    if edges.shape[0] == 0 or tris.shape[0] == 0:
        return hit, 0
    lo, dims, start, items, cell = _grid(x, tris, cell)
    status = np.zeros(edges.shape[0], np.uint8)
    threaded(BK.first_crossings)(x, edges, tris, lo, dims, cell, start, items, status, hit)
    n = _decide(x, edges, tris, np.flatnonzero(status == AK.CROSS_UNKNOWN), hit)
    return hit, n


def _near_box(x: np.ndarray, items: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Indices of the rows of items (edges or triangles, indices into x) whose box overlaps [lo, hi]."""
    pts = x[items]
    return np.flatnonzero(np.all(pts.min(axis=1) <= hi, axis=1) & np.all(pts.max(axis=1) >= lo, axis=1))


SELF_GAP = 0.002    # m: see in_self_overlap


def frame_crossings(cloth: np.ndarray, cloth_tris: np.ndarray, cloth_edges: np.ndarray, body: np.ndarray,
                    body_tris: np.ndarray, body_edges: np.ndarray, vertex_joint: np.ndarray):
    """One frame, one garment: (body hits, cloth hits, points (c, 3) float32, joints (c,), normals, exact pairs).

    cloth (N, 3), body (V, 3) float positions; *_tris (T, 3), *_edges (E, 2) int32 into them. Body
    hits: (k, 2) int64 rows (index into body_edges, cloth triangle it crosses); cloth hits: (m, 2)
    rows (index into cloth_edges, body triangle); points, joints and normals (c, 3) float32 (the body's
    outward unit normal at each point): body hits first."""
    nc = cloth.shape[0]
    x = np.concatenate([cloth, body]).astype(np.float64)   # cloth rows first (see _grid)
    lo, hi = x[:nc].min(axis=0), x[:nc].max(axis=0)
    ib = _near_box(x, body_edges + nc, lo, hi)     # only body parts where the cloth is can cross it
    it = _near_box(x, body_tris + nc, lo, hi)
    be, bt = body_edges[ib] + nc, body_tris[it] + nc
    length = np.linalg.norm(x[cloth_edges[:, 1]] - x[cloth_edges[:, 0]], axis=1) if len(cloth_edges) else np.ones(1)
    cell = max(2.0 * float(np.median(length)), 1e-6)
    hb, nb = edges_through(x, be, cloth_tris, cell)
    hc, ncl = edges_through(x, cloth_edges, bt, cell)
    kb, kc = np.flatnonzero(hb >= 0), np.flatnonzero(hc >= 0)
    pb, tb = _segment_points(x, be[kb], cloth_tris[hb[kb]])
    pc, _ = _segment_points(x, cloth_edges[kc], bt[hc[kc]])
    # the body's outward normal there: along the body edge, its ends' normals; on a body triangle, its own
    vn = vertex_normals(x[nc:], body_tris)
    nb_ = (1.0 - tb)[:, None] * vn[be[kb, 0] - nc] + tb[:, None] * vn[be[kb, 1] - nc]
    a, b, c = (x[bt[hc[kc], k]] for k in range(3))
    normals = _unit(np.concatenate([nb_, np.cross(b - a, c - a)]))
    # the joint nearest: the body edge's nearer end; the body triangle's nearest corner
    ends = np.where(tb < 0.5, be[kb, 0], be[kb, 1]) - nc
    corners = bt[hc[kc]] - nc
    d = np.linalg.norm(x[nc:][corners] - pc[:, None, :], axis=2)
    near = corners[np.arange(len(kc)), np.argmin(d, axis=1)] if len(kc) else np.zeros(0, np.int64)
    joints = vertex_joint[np.concatenate([ends, near]).astype(np.int64)]
    points = np.concatenate([pb, pc]).astype(np.float32)
    hits_b = np.column_stack([ib[kb], hb[kb]]).astype(np.int64)
    hits_c = np.column_stack([kc, it[hc[kc]]]).astype(np.int64)
    return hits_b, hits_c, points, joints, normals.astype(np.float32), nb + ncl


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=1, keepdims=True)
    return v / np.where(n > 0.0, n, 1.0)


def in_self_overlap(body: np.ndarray, body_tris: np.ndarray, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(c,) bool: the crossing points where the body meets itself: the point SELF_GAP outside the body's
    surface there (along its outward normal) is still inside the body, in another part of it (a forearm
    sunk into the hip by the animation; surfaces closer than SELF_GAP). No cloth can lie between two
    parts there without one of them passing through it. Inside: generalised winding number > 1/2
    (stages.geometry.winding, exact sum over every body triangle; only crossing points are evaluated)."""
    if not len(points):
        return np.zeros(0, bool)
    x = np.asarray(body, np.float64)
    a, b, c = (x[body_tris[:, k]] for k in range(3))
    sign = 1.0 if np.einsum("ij,ij->", a, np.cross(b, c)) >= 0.0 else -1.0    # an inward-wound body: both flip
    q = np.asarray(points, np.float64) + (sign * SELF_GAP) * np.asarray(normals, np.float64)
    w = np.zeros(len(q))
    threaded(winding_numbers_brute)(q, x, np.asarray(body_tris, np.int32), w)
    return sign * w > 0.5


def body_orientation(vertices: np.ndarray, triangles: np.ndarray) -> float:
    """+1 for a body wound outwards (its signed volume positive), -1 for one wound inwards."""
    x = np.asarray(vertices, np.float64)
    a, b, c = (x[triangles[:, k]] for k in range(3))
    return 1.0 if np.einsum("ij,ij->", a, np.cross(b, c)) >= 0.0 else -1.0


def inside_where_body_meets_itself(tree, points: np.ndarray, sign: float = 1.0) -> np.ndarray:
    """(N,) bool: of cloth `points` inside the body, those held where the body meets itself: the body
    surface nearest the point is itself inside the body (the point SELF_GAP outside it, along its
    triangle's outward normal, has a winding number over 1/2): another part of the body is sunk into
    this one there (a forearm into the hip, a chibi's arm into its side), and cloth lying on either
    surface is inside the other. Counted apart from the particles inside the body, as the body edges
    of in_self_overlap are. tree: the body's WindingTree refitted to the frame; sign: body_orientation."""
    import trimesh
    from stages.geometry.skin_distance import nearest_on_mesh
    p = np.asarray(points, np.float64).reshape(-1, 3)
    if not len(p):
        return np.zeros(0, bool)
    corners = tree.vertices[tree.tris[nearest_on_mesh(tree, p)[1]]]
    surface = trimesh.triangles.closest_point(corners, p)
    normal = _unit(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]))
    return sign * tree.winding_refitted(surface + (sign * SELF_GAP) * normal) > 0.5


class InsideBody:
    """The simulation's count of cloth particles inside the skinned body (generalised winding number
    >= 1/2), and of them those held where the body meets itself (inside_where_body_meets_itself)."""

    def __init__(self, character):
        from stages.geometry.winding import WindingTree
        self.tree = WindingTree(character.vertices, character.triangles)
        self.sign = body_orientation(character.vertices, character.triangles)

    def classify(self, skinned: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(inside, held) (N,) bool of `points` against the body's `skinned` vertices (V, 3)."""
        inside = self.tree.inside(skinned, points)
        held = np.zeros_like(inside)
        if inside.any():
            held[inside] = inside_where_body_meets_itself(self.tree, points[inside], self.sign)
        return inside, held


def blend_in_note(first_frame: int) -> str:
    """Which frames a figure covers, for the summary and the warnings."""
    return f"from frame {first_frame}, after the blend-in" if first_frame > 1 else "after frame 0"


def audit_body_crossings(result, body: BodyFrames, *, first_frame: int = 1) -> BodyCrossings:
    """The crossings of every garment of `result` (SimResult, world-frame positions) with the body
    at every frame. first_frame: where the blend-in ends (the warnings look from there on; >= 1,
    frame 0 is the state as dressed)."""
    nf = result.n_frames
    if body.positions.shape[0] != nf:
        raise ContractError(f"audit_body_crossings: the body has {body.positions.shape[0]} frames, the result {nf}")
    first = max(int(first_frame), 1)
    nj = len(body.joint_names)
    b_edges = mesh_edges(body.triangles) if body.triangles.size else np.zeros((0, 2), np.int32)
    out, warnings, n_exact = [], [], 0
    for track in result.garments:
        c_edges = mesh_edges(track.triangles)
        nb = np.zeros(nf, np.int32)
        nc = np.zeros(nf, np.int32)
        per_joint = np.zeros((nf, nj), np.int32)
        points, overlap = [], []
        for f in range(nf):
            hb, hc, pts, joints, normals, k = frame_crossings(track.positions[f], track.triangles, c_edges,
                                                              body.positions[f], body.triangles, b_edges,
                                                              body.vertex_joint)
            nb[f], nc[f], n_exact = len(hb), len(hc), n_exact + k
            per_joint[f] = np.bincount(joints, minlength=nj)
            points.append(pts)
            overlap.append(in_self_overlap(body.positions[f], body.triangles, pts, normals))
        out.append(GarmentCrossings(track.name, nb, nc, per_joint, tuple(points), tuple(overlap)))
    audit = BodyCrossings(tuple(out), tuple(body.joint_names), first, int(n_exact), ())
    for g in out:
        f, n = audit.worst(g)
        if n:
            frames = int(np.count_nonzero(g.body_edges_free()[first:]))
            warnings.append(f"garment {g.name!r}: {n} body edges through the cloth at frame {f} "
                            f"({audit.joints_at(g, f)}); body edges through it in {frames} frames "
                            f"{blend_in_note(first)}")
        f, n = audit.worst(g, in_overlap=True)
        if n:
            frames = int(np.count_nonzero(g.body_edges_in_overlap()[first:]))
            warnings.append(f"garment {g.name!r}: the animation puts one part of the body into another where the "
                            f"cloth is ({n} body edges through the cloth there at frame {f}, in {frames} frames "
                            f"{blend_in_note(first)}): no cloth can lie between them there; counted apart")
    return replace(audit, warnings=tuple(warnings))
