"""Flat panel meshing with Shewchuk's Triangle (the `triangle` package).

Each panel's outline is resampled at the pattern's target edge length (both sides of a seam with
the same number of segments, so the sewn mesh matches), the interior is seeded with a hexagonal
lattice of that spacing, and Triangle builds the constrained Delaunay triangulation with switch 'Y'
(no Steiner points on the boundary segments: the boundary vertices stay exactly the resampled ones).
A few rounds of edge-length relaxation of the interior vertices (each followed by a fresh
triangulation) even out the band where the lattice meets the boundary.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import triangle as tr

from stages.checks import ContractError, check_array
from stages.errors import InputError
from stages.garments.patterns import Pattern, SeamSide


@dataclass(frozen=True)
class FlatPanel:
    """One meshed panel in pattern coordinates.

    name: panel name. uv: (N, 2) float64, metres, pattern (u, v) coordinates. triangles: (T, 3) int32,
    counter-clockwise in (u, v). n_boundary: the first n_boundary vertices are the outline, in
    outline order. edge_start: {edge name: index of its first boundary vertex} (an edge's boundary
    vertices run from its start to the next edge's start, wrapping).
    """

    name: str
    uv: np.ndarray
    triangles: np.ndarray
    n_boundary: int
    edge_start: dict

    def __post_init__(self):
        o = f"FlatPanel[{self.name!r}]"
        n = check_array(o, "uv", self.uv, (None, 2), np.float64).shape[0]
        t = check_array(o, "triangles", self.triangles, (None, 3), np.int32)
        if t.size and (t.min() < 0 or t.max() >= n):
            raise ContractError(f"{o}.triangles: index out of range")
        if not 3 <= self.n_boundary <= n:
            raise ContractError(f"{o}.n_boundary: expected 3..{n}, got {self.n_boundary}")

    def run_vertices(self, edge_ids: list[int], edge_names: list[str]) -> np.ndarray:
        """Boundary vertex indices of a run of consecutive edges, both ends included."""
        starts = [self.edge_start[edge_names[i]] for i in edge_ids]
        first = starts[0]
        nxt = (edge_ids[-1] + 1) % len(edge_names)
        last = self.edge_start[edge_names[nxt]]
        count = (last - first) % self.n_boundary
        if count == 0:
            count = self.n_boundary
        return (first + np.arange(count + 1)) % self.n_boundary

    @property
    def area(self) -> float:
        a, b, c = (self.uv[self.triangles[:, k]] for k in range(3))
        return float(0.5 * np.sum((b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0]))


@dataclass(frozen=True)
class FlatPattern:
    """All panels meshed, with the seam vertex pairs.

    panels: FlatPanel tuple (pattern order). offsets: (P+1,) int64, first global vertex of each
    panel (panels concatenated). seam_pairs: (K, 2) int32 global vertex indices to sew together.
    seam_index: (K,) int32, the seam each pair belongs to.
    """

    panels: tuple
    offsets: np.ndarray
    seam_pairs: np.ndarray
    seam_index: np.ndarray

    @property
    def uv(self) -> np.ndarray:
        return np.concatenate([p.uv for p in self.panels])

    @property
    def triangles(self) -> np.ndarray:
        return np.concatenate([p.triangles + o for p, o in zip(self.panels, self.offsets)]).astype(np.int32)

    @property
    def panel_of_vertex(self) -> np.ndarray:
        return np.repeat(np.arange(len(self.panels)), np.diff(self.offsets)).astype(np.int32)

    @property
    def panel_of_triangle(self) -> np.ndarray:
        return np.repeat(np.arange(len(self.panels)), [p.triangles.shape[0] for p in self.panels]).astype(np.int32)


def edge_counts(pattern: Pattern) -> dict:
    """{(panel, edge index): number of boundary segments}. Free edges: round(length / target);
    both runs of a seam: the same total, split over each run's edges by length."""
    L = pattern.edge_length
    counts = {}
    for p in pattern.panels:
        for i in range(len(p.edges)):
            counts[(p.name, i)] = max(1, int(round(p.edge_length(i) / L)))
    for s in pattern.seams:
        runs = [(side, pattern.edge_run(side)) for side in (s.a, s.b)]
        lens = [[pattern.panel(side.panel).edge_length(i) for i in ids] for side, ids in runs]
        total = max(max(len(ids) for _, ids in runs), int(round(0.5 * (sum(lens[0]) + sum(lens[1])) / L)))
        for (side, ids), ls in zip(runs, lens):
            for i, c in zip(ids, _split_count(total, ls)):
                counts[(side.panel, i)] = c
    return counts


def _split_count(total: int, lengths: list[float]) -> list[int]:
    """Split `total` segments over edges proportionally to length, each at least 1."""
    lengths = np.asarray(lengths, dtype=np.float64)
    c = np.maximum(1, np.floor(total * lengths / lengths.sum()).astype(int))
    while c.sum() < total:
        c[np.argmax(total * lengths / lengths.sum() - c)] += 1
    while c.sum() > total:
        c[np.argmax(np.where(c > 1, c - total * lengths / lengths.sum(), -np.inf))] -= 1
    return c.tolist()


def _segment_distance(p: np.ndarray, poly: np.ndarray, reach: float = np.inf) -> np.ndarray:
    """(N,) distance from points (N, 2) to the closed polyline `poly` (S, 2); with a finite `reach`,
    +inf for the points farther than reach from every segment (only the (point, segment) pairs
    whose midpoints are within reach + half the longest segment are measured: a big panel has
    thousands of points and outline segments)."""
    a, b = poly, np.roll(poly, -1, axis=0)
    ab = b - a
    if np.isfinite(reach):
        from scipy.spatial import cKDTree
        half = 0.5 * float(np.linalg.norm(ab, axis=1).max(initial=0.0))
        pairs = cKDTree(p).sparse_distance_matrix(cKDTree(0.5 * (a + b)), reach + half + 1e-12 * (1.0 + half),
                                                  output_type="ndarray")
        i, j = pairs["i"].astype(np.int64), pairs["j"].astype(np.int64)
        t = np.clip(np.einsum("nk,nk->n", p[i] - a[j], ab[j]) / np.einsum("nk,nk->n", ab[j], ab[j]), 0, 1)
        out = np.full(p.shape[0], np.inf)
        np.minimum.at(out, i, np.linalg.norm(p[i] - (a[j] + t[:, None] * ab[j]), axis=1))
        return out
    out = np.full(p.shape[0], np.inf)
    for k in range(0, a.shape[0], 256):  # chunks bound the (N, S) temporaries
        aa, bb = a[k:k + 256], ab[k:k + 256]
        t = np.clip(np.einsum("nsk,sk->ns", p[:, None] - aa[None], bb) / np.einsum("sk,sk->s", bb, bb), 0, 1)
        q = aa[None] + t[..., None] * bb[None]
        out = np.minimum(out, np.linalg.norm(p[:, None] - q, axis=2).min(axis=1))
    return out


MAX_PANEL_VERTICES = 100_000   # one panel's vertices at most (CesiumMan's and the built-in body's: under 1,000)
INSIDE_CHUNK = 4096   # points per even-odd test: its temporaries are (points, outline segments)


def _inside(poly: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Even-odd point-in-polygon test."""
    if p.shape[0] > INSIDE_CHUNK:
        return np.concatenate([_inside(poly, p[k:k + INSIDE_CHUNK]) for k in range(0, p.shape[0], INSIDE_CHUNK)])
    a, b = poly, np.roll(poly, -1, axis=0)
    x, y = p[:, :1], p[:, 1:]
    cross = (a[None, :, 1] > y) != (b[None, :, 1] > y)
    dy = np.where(b[:, 1] == a[:, 1], 1e-300, b[:, 1] - a[:, 1])
    xint = (b[None, :, 0] - a[None, :, 0]) * (y - a[None, :, 1]) / dy[None] + a[None, :, 0]
    return np.count_nonzero(cross & (x < xint), axis=1) % 2 == 1


def _cdt(points: np.ndarray, n_boundary: int, where: str):
    seg = np.stack([np.arange(n_boundary), (np.arange(n_boundary) + 1) % n_boundary], axis=1)
    try:
        out = tr.triangulate({"vertices": points, "segments": seg}, "pYQ")
    except Exception as exc:  # Triangle's own failures (should not happen for a valid outline)
        raise InputError(where, f"Triangle failed: {exc}") from None
    v, t = out.get("vertices"), out.get("triangles")
    if t is None or len(t) == 0 or v.shape[0] < points.shape[0] or not np.allclose(v[:points.shape[0]], points):
        raise InputError(where, "Triangle returned no triangles or moved input vertices "
                                "(duplicate boundary points? check the outline)")
    return np.asarray(t, dtype=np.int64)


def mesh_panel(pattern: Pattern, panel_index: int, counts: dict, relax_rounds: int = 10) -> FlatPanel:
    """Mesh one panel (see the module docstring)."""
    p = pattern.panels[panel_index]
    L = pattern.edge_length
    where = f"pattern {pattern.name!r} panel {p.name!r}"
    pieces, edge_start, k = [], {}, 0
    for i, e in enumerate(p.edges):
        n = counts[(p.name, i)]
        edge_start[e.name] = k
        pieces.append(p.sample_edge(i, n))
        k += n
    boundary = np.concatenate(pieces)
    nb = boundary.shape[0]
    d = np.linalg.norm(boundary - np.roll(boundary, -1, axis=0), axis=1)
    if d.min() < 1e-6 * L:
        raise InputError(where, "two consecutive outline points coincide (zero-length edge?)")
    # the vertex count grows with the panel's area over L^2 (a 9.55 m body's short skirt: 28,000)
    x, y = boundary[:, 0], boundary[:, 1]
    area = 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))
    estimate = nb + int(area / (L * L * np.sqrt(3) / 2))
    if estimate > MAX_PANEL_VERTICES:
        w, h_ = np.ptp(boundary, axis=0)
        raise InputError(where, f"about {estimate:,} vertices at edge length {L:g} m (a panel {w:.3g} x {h_:.3g} m), "
                                f"more than {MAX_PANEL_VERTICES:,}: a longer edge_length or a smaller garment")
    # interior: hexagonal lattice of spacing L, away from the outline
    lo, hi = boundary.min(axis=0), boundary.max(axis=0)
    h = L * np.sqrt(3) / 2
    rows = []
    for r, y in enumerate(np.arange(lo[1] + h / 2, hi[1], h)):
        xs = np.arange(lo[0] + (L / 2 if r % 2 else L / 4), hi[0], L)
        rows.append(np.stack([xs, np.full(xs.size, y)], axis=1))
    pts = np.concatenate(rows) if rows else np.zeros((0, 2))
    if pts.size:
        pts = pts[_inside(boundary, pts)]
    if pts.size:
        pts = pts[_segment_distance(pts, boundary, 0.5 * L) > 0.5 * L]
    v = np.concatenate([boundary, pts])
    t = _cdt(v, nb, where)
    for r in range(relax_rounds):
        e = _edges(t)
        dv = v[e[:, 1]] - v[e[:, 0]]
        ln = np.linalg.norm(dv, axis=1)
        f = ((ln - L) / np.maximum(ln, 1e-12))[:, None] * dv * 0.25
        move = np.zeros_like(v)
        np.add.at(move, e[:, 0], f)
        np.add.at(move, e[:, 1], -f)
        cand = v[nb:] + move[nb:]
        ok = _inside(boundary, cand) & (_segment_distance(cand, boundary, 0.25 * L) > 0.25 * L) if cand.size \
            else np.zeros(0, bool)
        v = v.copy()
        v[nb:][ok] = cand[ok]
        if r % 5 == 4 or r == relax_rounds - 1:
            t = _cdt(v, nb, where)
    used = np.unique(t)
    if used.size < v.shape[0]:   # interior points Triangle left outside the region
        keep = np.union1d(np.arange(nb), used)
        remap = np.full(v.shape[0], -1)
        remap[keep] = np.arange(keep.size)
        v, t = v[keep], remap[t]
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    signed = (b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0]
    t = np.where((signed < 0)[:, None], t[:, [0, 2, 1]], t)
    return FlatPanel(p.name, np.ascontiguousarray(v), np.ascontiguousarray(t, dtype=np.int32), nb, edge_start)


def _edges(t: np.ndarray) -> np.ndarray:
    e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    return np.unique(np.sort(e, axis=1), axis=0)


def triangulate_pattern(pattern: Pattern, relax_rounds: int = 10) -> FlatPattern:
    """Mesh every panel and pair the seam vertices."""
    counts = edge_counts(pattern)
    panels = tuple(mesh_panel(pattern, i, counts, relax_rounds) for i in range(len(pattern.panels)))
    offsets = np.concatenate([[0], np.cumsum([p.uv.shape[0] for p in panels])]).astype(np.int64)
    index = {p.name: i for i, p in enumerate(pattern.panels)}
    pairs, which = [], []
    for k, s in enumerate(pattern.seams):
        runs = []
        for side in (s.a, s.b):
            i = index[side.panel]
            names = [e.name for e in pattern.panels[i].edges]
            runs.append(panels[i].run_vertices(pattern.edge_run(side), names) + offsets[i])
        a, b = runs
        if s.reverse:
            b = b[::-1]
        if a.size != b.size:  # cannot happen: edge_counts gives both runs the same total
            raise ContractError(f"seam {k}: {a.size} vs {b.size} vertices")
        pairs.append(np.stack([a, b], axis=1))
        which.append(np.full(a.size, k))
    sp = np.concatenate(pairs).astype(np.int32) if pairs else np.zeros((0, 2), np.int32)
    si = np.concatenate(which).astype(np.int32) if which else np.zeros(0, np.int32)
    keep = sp[:, 0] != sp[:, 1]
    return FlatPattern(panels, offsets, np.ascontiguousarray(sp[keep]), np.ascontiguousarray(si[keep]))


def run_vertices(pattern: Pattern, flat: FlatPattern, side: SeamSide) -> np.ndarray:
    """Global vertex indices of an edge run (e.g. an attachment's edges)."""
    i = [p.name for p in pattern.panels].index(side.panel)
    names = [e.name for e in pattern.panels[i].edges]
    return flat.panels[i].run_vertices(pattern.edge_run(side), names) + flat.offsets[i]
