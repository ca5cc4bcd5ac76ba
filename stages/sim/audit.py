"""The cloth audit: edge strain and cloth-cloth crossings of a simulated result (all frames).

A stage of its own, run after the simulation: `audit_cloth(result, garments)` -> ClothAudit.

Strain of an edge (a stretch / shear spring = a mesh edge): |L - L0| / L0 at the frame, L0 its
rest length (from the flat pattern panels for sewn garments, else the initial mesh). Per frame and
garment: mean, 99th percentile and max over the edges; per vertex (optional): the largest strain
of its edges.

Crossings: cloth edges that cross a cloth triangle, by the exact test of stages.sim.audit_kernels
(an edge sharing a vertex with the triangle does not count; touching / coplanar contacts do not
count). Per frame: per garment the edges crossing a triangle of the same garment (self), and the
edges crossing a triangle of another garment (between; an edge counts once however many triangles
it crosses).
"""
from __future__ import annotations

from dataclasses import dataclass
import math
from fractions import Fraction

import numpy as np

from stages.checks import ContractError, check_array
from stages.garments.types import STRETCH
from stages.geometry.mesh import mesh_edges
from stages.jit import threaded
from stages.sim import audit_kernels as AK

STRAIN_MEAN_LIMIT = 0.02     # warn above: mean edge strain of a frame
STRAIN_P99_LIMIT = 0.10      # warn above: 99th percentile edge strain of a frame


@dataclass(frozen=True)
class GarmentAudit:
    """One garment's audit over F frames.

    strain_mean, strain_p99, strain_max: (F,) float64, relative edge length change |L - L0| / L0
        (0.02 = 2 %) over the garment's stretch springs.
    vertex_strain: (F, N) float32, per particle the largest strain of its edges, or None.
    crossings_self: (F,) int32, edges of this garment crossing one of its own triangles.
    crossings_other: (F,) int32, edges of this garment crossing a triangle of another garment.
    """

    name: str
    strain_mean: np.ndarray
    strain_p99: np.ndarray
    strain_max: np.ndarray
    vertex_strain: np.ndarray | None
    crossings_self: np.ndarray
    crossings_other: np.ndarray

    def __post_init__(self):
        o = f"GarmentAudit[{self.name!r}]"
        f = check_array(o, "strain_mean", self.strain_mean, (None,), np.float64).shape[0]
        for k in ("strain_p99", "strain_max"):
            check_array(o, k, getattr(self, k), (f,), np.float64)
        for k in ("crossings_self", "crossings_other"):
            check_array(o, k, getattr(self, k), (f,), np.int32)
        if self.vertex_strain is not None:
            check_array(o, "vertex_strain", self.vertex_strain, (f, None), np.float32)


@dataclass(frozen=True)
class ClothAudit:
    """Strain and crossings of every garment of a SimResult.

    garments: one GarmentAudit per garment, in the result's order.
    crossings_between: (F,) int32, edges crossing a triangle of another garment (all garments).
    exact_pairs: edge-triangle pairs the float64 filter could not decide, decided exactly.
    warnings: human-readable out-of-range figures (strain mean > 2 %, p99 > 10 % at any frame;
        any crossing after frame 0).
    """

    garments: tuple
    crossings_between: np.ndarray
    exact_pairs: int
    warnings: tuple

    def __post_init__(self):
        f = check_array("ClothAudit", "crossings_between", self.crossings_between, (None,), np.int32).shape[0]
        for g in self.garments:
            if g.strain_mean.shape[0] != f:
                raise ContractError(f"ClothAudit.garments[{g.name!r}]: {g.strain_mean.shape[0]} frames, expected {f}")

    def garment(self, name: str) -> GarmentAudit:
        for g in self.garments:
            if g.name == name:
                return g
        raise KeyError(f"no garment {name!r}")

    def summary(self) -> dict:
        """Figures for the run summary: last frame and worst frame after frame 0."""
        out = {}
        for g in self.garments:
            worst = 1 + int(np.argmax(g.strain_p99[1:])) if g.strain_p99.size > 1 else 0
            out[f"{g.name} strain (last frame: mean / p99 / max)"] = (
                f"{100 * g.strain_mean[-1]:.2f} / {100 * g.strain_p99[-1]:.1f} / {100 * g.strain_max[-1]:.0f} %; "
                f"worst p99 {100 * g.strain_p99[worst]:.1f} % at frame {worst}")
            out[f"{g.name} self-crossing edges (max per frame after frame 0 / at frame 0)"] = (
                f"{int(g.crossings_self[1:].max(initial=0))} / {int(g.crossings_self[0])}")
        if len(self.garments) > 1:
            b = self.crossings_between
            out["edges crossing another garment (max per frame after frame 0 / at frame 0)"] = (
                f"{int(b[1:].max(initial=0))} / {int(b[0])}")
        return out


# -- strain ---------------------------------------------------------------------------------------
def edge_strains(positions: np.ndarray, edges: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """(F, E) |L - L0| / L0 of edges (E, 2) at positions (F, N, 3)."""
    p = np.asarray(positions, dtype=np.float64)
    length = np.linalg.norm(p[:, edges[:, 1]] - p[:, edges[:, 0]], axis=-1)
    return np.abs(length / rest - 1.0)


def vertex_strains(strain: np.ndarray, edges: np.ndarray, n: int) -> np.ndarray:
    """(F, N) float32: per vertex the largest strain (F, E) of its edges (0 for a vertex without)."""
    out = np.zeros((strain.shape[0], n))
    for k in (0, 1):
        np.maximum.at(out.T, edges[:, k], strain.T)
    return out.astype(np.float32)


# -- crossings -----------------------------------------------------------------------------------
def _orient_exact(a, b, c, d) -> int:
    """Exact sign of det[a - d, b - d, c - d] (integer arithmetic on the float values, each a
    multiple of 2^-1074: scaled by the smallest power of two among them)."""
    vals = [float(v) for p in (a, b, c, d) for v in p]
    if not all(math.isfinite(v) for v in vals):
        return _orient_fraction(a, b, c, d)
    ratios = [v.as_integer_ratio() for v in vals]
    den = max(r[1] for r in ratios)             # powers of two: the largest is a multiple of the others
    a, b, c, d = (ratios[k:k + 3] for k in range(0, 12, 3))
    return _det_sign(*([n * (den // m) for n, m in p] for p in (a, b, c, d)))


def _orient_fraction(a, b, c, d) -> int:
    """Exact sign of det[a - d, b - d, c - d] (rational arithmetic on the float values)."""
    return _det_sign(*([Fraction(float(v)) for v in p] for p in (a, b, c, d)))


def _det_sign(a, b, c, d) -> int:
    """Sign of det[a - d, b - d, c - d] for points of exact numbers (int or Fraction: no rounding)."""
    ad = [a[k] - d[k] for k in range(3)]
    bd = [b[k] - d[k] for k in range(3)]
    cd = [c[k] - d[k] for k in range(3)]
    det = (ad[2] * (bd[0] * cd[1] - cd[0] * bd[1]) + bd[2] * (cd[0] * ad[1] - ad[0] * cd[1])
           + cd[2] * (ad[0] * bd[1] - bd[0] * ad[1]))
    return (det > 0) - (det < 0)


def crosses_exact(p, q, a, b, c) -> bool:
    """The crossing test of stages.sim.audit_kernels in exact arithmetic: segment pq strictly
    through the inside of triangle abc."""
    sp, sq = _orient_exact(a, b, c, p), _orient_exact(a, b, c, q)
    if sp == 0 or sq == 0 or sp == sq:
        return False
    s1, s2, s3 = _orient_exact(p, q, a, b), _orient_exact(p, q, b, c), _orient_exact(p, q, c, a)
    return s1 != 0 and s1 == s2 == s3


ORIENT_ERR = 1e-14   # relative error bound of a float orientation (Shewchuk's orient3d: 7.8e-16, with room)


def _orient_sure(a, b, c, d) -> np.ndarray:
    """(M,) sign of det[a - d, b - d, c - d] for rows of (M, 3) points where the float value is sure
    of it, 0 where it is not (then only exact arithmetic decides)."""
    ad, bd, cd = a - d, b - d, c - d
    t1 = bd[:, 0] * cd[:, 1] - cd[:, 0] * bd[:, 1]
    t2 = cd[:, 0] * ad[:, 1] - ad[:, 0] * cd[:, 1]
    t3 = ad[:, 0] * bd[:, 1] - bd[:, 0] * ad[:, 1]
    det = ad[:, 2] * t1 + bd[:, 2] * t2 + cd[:, 2] * t3
    a_, b_, c_ = np.abs(ad), np.abs(bd), np.abs(cd)
    perm = (a_[:, 2] * (b_[:, 0] * c_[:, 1] + c_[:, 0] * b_[:, 1]) + b_[:, 2] * (c_[:, 0] * a_[:, 1] + a_[:, 0] * c_[:, 1])
            + c_[:, 2] * (a_[:, 0] * b_[:, 1] + b_[:, 0] * a_[:, 1]))
    return np.where(np.abs(det) > ORIENT_ERR * perm, np.sign(det), 0.0)


def _decide_exact(x, edges, tris, e, want_same, edge_group, tri_group, nearby) -> bool:
    """Whether edge e crosses a triangle of its own group (want_same) or another, exactly (the
    triangles that sure float orientations rule out are not tested in exact arithmetic).
    nearby: indices of the triangles it may cross (a superset: every one whose box meets its box)."""
    p, q = edges[e]
    lo = np.minimum(x[p], x[q])
    hi = np.maximum(x[p], x[q])
    nearby = np.sort(np.asarray(nearby, np.int64))
    tb = x[tris[nearby]]
    near = np.all(tb.min(axis=1) <= hi, axis=1) & np.all(tb.max(axis=1) >= lo, axis=1)
    near &= (tri_group[nearby] == edge_group[e]) == want_same
    near &= ~np.any((tris[nearby] == p) | (tris[nearby] == q), axis=1)
    cand = nearby[near]
    if cand.size:
        a, b, c = (x[tris[cand, k]] for k in range(3))
        xp, xq = np.broadcast_to(x[p], a.shape), np.broadcast_to(x[q], a.shape)
        sp, sq = _orient_sure(a, b, c, xp), _orient_sure(a, b, c, xq)
        s1, s2, s3 = _orient_sure(xp, xq, a, b), _orient_sure(xp, xq, b, c), _orient_sure(xp, xq, c, a)
        # ruled out: both ends surely on one side, or two sides of the triangle surely disagree
        apart = (sp * sq > 0) | (s1 * s2 < 0) | (s2 * s3 < 0) | (s1 * s3 < 0)
        cand = cand[~apart]
    return any(crosses_exact(x[p], x[q], *x[tris[t]]) for t in cand)


def crossing_flags(x: np.ndarray, edges: np.ndarray, edge_group: np.ndarray, tris: np.ndarray,
                   tri_group: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """(own (E,) bool, other (E,) bool, exact pairs decided): per edge whether it crosses a triangle
    of its own group / of another group, at positions x (N, 3) (any float dtype; tested in float64)."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    edges = np.ascontiguousarray(edges, dtype=np.int32)
    tris = np.ascontiguousarray(tris, dtype=np.int32)
    edge_group = np.ascontiguousarray(edge_group, dtype=np.int32)
    tri_group = np.ascontiguousarray(tri_group, dtype=np.int32)
    if edges.shape[0] == 0 or tris.shape[0] == 0:
        z = np.zeros(edges.shape[0], bool)
        return z, z.copy(), 0
    length = np.linalg.norm(x[edges[:, 1]] - x[edges[:, 0]], axis=1)
    cell = max(2.0 * float(np.median(length)), 1e-9)
    extent = np.ptp(x, axis=0)
    while np.prod(np.floor(extent / cell) + 1) > AK.GRID_MAX_CELLS:
        cell *= 2.0
    lo, dims, start, items = AK.build_triangle_grid(x, tris, cell)
    out = np.zeros((edges.shape[0], 2), np.uint8)
    threaded(AK.edge_crossings)(x, edges, edge_group, tris, tri_group, lo, dims, cell, start, items, out)
    flags = out == AK.CROSS_YES
    n_exact = 0
    unknown = np.nonzero(out == AK.CROSS_UNKNOWN)
    if unknown[0].size:
        from stages.geometry.mesh import triangles_near_edges
        nearby = triangles_near_edges(x, edges[unknown[0]], tris)
        for e, k, near in zip(*unknown, nearby):
            n_exact += 1
            flags[e, k] = _decide_exact(x, edges, tris, e, k == 0, edge_group, tri_group, near)
    return flags[:, 0], flags[:, 1], n_exact


# -- the stage ------------------------------------------------------------------------------------
def audit_cloth(result, garments, *, vertex_strain: bool = False, crossings: bool = True) -> ClothAudit:
    """Strain and crossings of every frame of `result` (SimResult); garments: the simulated Garments
    (same names and order, for the rest lengths). vertex_strain: also per-vertex strain (F, N);
    crossings: False skips the crossing count (zeros)."""
    names = [g.name for g in result.garments]
    if [g.name for g in garments] != names:
        raise ContractError(f"audit_cloth: garments {[g.name for g in garments]} do not match the result's {names}")
    nf = result.n_frames
    offsets = np.cumsum([0] + [g.positions.shape[1] for g in result.garments])
    edges = [mesh_edges(t.triangles) for t in result.garments]
    edge_group = np.concatenate([np.full(len(e), i, np.int32) for i, e in enumerate(edges)])
    all_edges = np.concatenate([e + o for e, o in zip(edges, offsets)])
    tris = np.concatenate([t.triangles + o for t, o in zip(result.garments, offsets)])
    tri_group = np.concatenate([np.full(len(t.triangles), i, np.int32) for i, t in enumerate(result.garments)])
    own = np.zeros((nf, len(names)), np.int32)
    other = np.zeros((nf, len(names)), np.int32)
    n_exact = 0
    if crossings:
        for f in range(nf):
            x = np.concatenate([t.positions[f] for t in result.garments])
            a, b, k = crossing_flags(x, all_edges, edge_group, tris, tri_group)
            own[f] = np.bincount(edge_group[a], minlength=len(names))
            other[f] = np.bincount(edge_group[b], minlength=len(names))
            n_exact += k
    out, warnings = [], []
    for i, (track, g) in enumerate(zip(result.garments, garments)):
        sel = g.kinds == STRETCH
        s = edge_strains(track.positions, g.springs[sel], g.rest_lengths[sel])
        mean = s.mean(axis=1) if s.shape[1] else np.zeros(nf)
        p99 = np.percentile(s, 99, axis=1) if s.shape[1] else np.zeros(nf)
        mx = s.max(axis=1) if s.shape[1] else np.zeros(nf)
        vs = vertex_strains(s, g.springs[sel], g.n_particles) if vertex_strain else None
        out.append(GarmentAudit(g.name, mean, p99, mx, vs, own[:, i].copy(), other[:, i].copy()))
        if mean.max(initial=0) > STRAIN_MEAN_LIMIT:
            f = int(np.argmax(mean))
            warnings.append(f"garment {g.name!r}: mean edge strain {100 * mean[f]:.1f} % at frame {f} "
                            f"(limit {100 * STRAIN_MEAN_LIMIT:.0f} %)")
        if p99.max(initial=0) > STRAIN_P99_LIMIT:
            f = int(np.argmax(p99))
            warnings.append(f"garment {g.name!r}: p99 edge strain {100 * p99[f]:.1f} % at frame {f} "
                            f"(limit {100 * STRAIN_P99_LIMIT:.0f} %)")
        if own[1:, i].any():
            f = 1 + int(np.argmax(own[1:, i]))
            warnings.append(f"garment {g.name!r}: {own[f, i]} edges cross its own triangles at frame {f}")
    between = other.sum(axis=1).astype(np.int32)
    if between[1:].any():
        f = 1 + int(np.argmax(between[1:]))
        warnings.append(f"{between[f]} cloth edges cross another garment's triangles at frame {f}")
    return ClothAudit(tuple(out), between, int(n_exact), tuple(warnings))
