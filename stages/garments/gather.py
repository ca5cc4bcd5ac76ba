"""Gathered edges: a panel edge longer than what it is sewn or hugged to takes up its extra length in
the cloth behind it.

GarmentCode gathers the longer side of a stitch into the shorter (a puff sleeve into its armhole, a
skirt tier into the one above, a bodice into a waistband: 20 of 32 sampled designs have a stitch
1.25x or more, up to 1.99x). A seam's two sides are sampled with the same number of vertices
(triangulate.edge_counts), so the longer side has longer boundary segments, and seam springs that pull
the pairs together stall against the panel's own springs (the sampled tee's armholes, 37.6 vs
22.2 cm, stayed 16-26 mm open). So the longer side's panel gets rest lengths in which that edge is as
long as the other side.

The rest lengths come from a per-triangle linear map of the flat panel, not from moved points: each
triangle is compressed along the gathered edge's direction (at its nearest point) by the seam's
ratio at the edge, easing back to 1 `band` metres into the panel (smoothstep), and left as cut
across it. Real gathers fold the cloth along the edge and do not shear it; moving the panel's points
along the edge towards its middle (the previous rest shape) slanted every edge across the band near
the ends of the gathered edge, up to 2.15x its length (the sampled jumpsuit: 1,194 edges longer
than cut), and two gathered edges meeting in line (a waistband's front halves) pulled their shared
corner both ways: the jumpsuit's front-centre stayed 13 mm open on the CMU walk. Each triangle
stays a triangle (the image of one under a linear map), so masses (Heron) and bend springs (hinges
unfolded flat) stay defined.
"""
from __future__ import annotations

import numpy as np

# m: the width of cloth behind a gathered edge that takes up its extra length. Over the extra length
# when wider (a 40 cm edge sewn to 25 cm, held flat: 3.7 mm open over 8 cm, 2.5 over 15 cm) the
# sampled tee's 1.7x sleeve caps pulled it off the CMU walk's shoulders while sewing (its top 9 cm
# under them)
GATHER_BAND = 0.08
PARALLEL = 0.7       # |cos| from which two gathered edges near a triangle count as one direction (not compressed twice)


def gathered_rest(triangles: np.ndarray, uv: np.ndarray, pairs: np.ndarray, seam_index: np.ndarray,
                  panel_of_vertex: np.ndarray, min_ratio: float = 1.01,
                  band: float = GATHER_BAND) -> tuple[np.ndarray, dict]:
    """Triangle rest lengths (T, 3) (edge k joins vertex k and k+1 mod 3) of the flat panels `uv`
    (N, 2) with the longer side of every unequal seam gathered onto the shorter (gathered_lengths),
    and {seam: long / short length ratio} of the gathered seams. Sides within `min_ratio` of each
    other keep their lengths (the merged edge's rest is their mean)."""
    runs, ratios = [], {}
    for s in np.unique(seam_index) if pairs.size else ():
        p = pairs[seam_index == s]
        if len(p) < 2:
            continue
        seg = [np.linalg.norm(np.diff(uv[p[:, k]], axis=0), axis=1) for k in (0, 1)]
        la, lb = float(seg[0].sum()), float(seg[1].sum())
        if max(la, lb) < min_ratio * min(la, lb):
            continue
        ratios[int(s)] = max(la, lb) / min(la, lb)
        runs.append((p[:, 0 if la > lb else 1], 1.0 / ratios[int(s)]))
    return gathered_lengths(triangles, uv, panel_of_vertex, runs, band), ratios


def gathered_lengths(triangles: np.ndarray, uv: np.ndarray, panel_of_vertex: np.ndarray, runs,
                     band: float = GATHER_BAND) -> np.ndarray:
    """Triangle rest lengths (T, 3) of the flat mesh `uv` (N, 2+) with every run gathered: `runs` is a
    sequence of (vertex run (k,) int in order along an edge, scale in (0, 1]): the edge's rest
    length becomes scale x its cut length.

    A triangle of a run's panel whose centroid lies within `band` of the run is compressed along the
    run's direction at its nearest point by f = scale at the edge (the first half edge length: the
    row of triangles on it) to 1 at `band`, smoothstep between. Where several runs reach a triangle,
    the strongest compression acts along its direction, and the strongest of those at least
    PARALLEL away from it along its own (a corner of two gathered edges); runs in line with one
    already applied (two halves of one gathered edge) are not applied again."""
    tri = np.asarray(triangles, np.int64)
    x = np.asarray(uv, np.float64)[:, :2]
    e = x[tri[:, [1, 2, 0]]] - x[tri]                              # (T, 3, 2) edge vectors
    rest = np.linalg.norm(e, axis=2)
    runs = [(np.asarray(r, np.int64), float(s)) for r, s in runs if len(r) >= 2 and s < 1.0]
    if not runs:
        return rest
    if not all(0.0 < s for _, s in runs):
        raise ValueError("gathered_lengths: scales must be in (0, 1]")
    lead = 0.5 * float(np.median(rest))
    pot = np.asarray(panel_of_vertex)[tri[:, 0]]
    c = x[tri].mean(axis=1)
    f = np.ones((len(runs), len(tri)))
    t = np.zeros((len(runs), len(tri), 2))
    reach = max(band - lead, 1e-9)
    for k, (run, scale) in enumerate(runs):
        on = np.flatnonzero(pot == panel_of_vertex[run[0]])
        d, tk = _nearest_on_polyline(x[run], c[on])
        w = np.clip((d - lead) / reach, 0.0, 1.0)
        f[k, on] = scale + (1.0 - scale) * w * w * (3.0 - 2.0 * w)
        t[k, on] = tk
    order = np.argsort(f, axis=0, kind="stable")                 # (R, T): strongest first
    cols = np.arange(len(tri))
    f1, t1 = f[order[0], cols], t[order[0], cols]
    # the second direction: the strongest run not in line with the first
    f2, t2 = np.ones(len(tri)), np.zeros((len(tri), 2))
    for r in range(1, len(runs)):
        fk, tk = f[order[r], cols], t[order[r], cols]
        take = (f2 == 1.0) & (fk < 1.0) & (np.abs(np.einsum("tk,tk->t", tk, t1)) < PARALLEL)
        f2[take], t2[take] = fk[take], tk[take]
    for fk, tk in ((f1, t1), (f2, t2)):                         # e <- e - (1 - f) (t . e) t
        along = np.einsum("tsk,tk->ts", e, tk)
        e = e - ((1.0 - fk)[:, None] * along)[..., None] * tk[:, None, :]
    return np.linalg.norm(e, axis=2)


def _nearest_on_polyline(poly: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(distance (M,), unit direction (M, 2) of the segment) of the nearest point on the polyline
    `poly` (S+1, 2) to each point q (M, 2)."""
    a, ab = poly[:-1], np.diff(poly, axis=0)
    L2 = np.maximum(np.einsum("sk,sk->s", ab, ab), 1e-18)
    u = np.clip(np.einsum("msk,sk->ms", q[:, None, :] - a[None], ab) / L2, 0.0, 1.0)
    d = np.linalg.norm(q[:, None, :] - (a[None] + u[..., None] * ab[None]), axis=2)
    j = np.argmin(d, axis=1)
    return d[np.arange(len(q)), j], ab[j] / np.sqrt(L2[j])[:, None]


def ease(x: np.ndarray, edge: np.ndarray, verts: np.ndarray, scale: float, band: float) -> None:
    """Draw the points `verts` of x (in place) along the polyline x[edge] towards its middle: by
    `scale` on it, by 1 (not at all) `band` away from it, smoothly between. A flat rest shape (a
    fan) for an edge drawn towards a point (hug.gather_below: a cape's top onto the neck); seams are
    gathered by gathered_lengths, which does not shear the cloth."""
    poly = x[edge].copy()
    a, b = poly[:-1], poly[1:]
    ab = b - a
    L = np.linalg.norm(ab, axis=1)
    s0 = np.concatenate([[0.0], np.cumsum(L)])
    q = x[verts]
    t = np.clip(np.einsum("nsk,sk->ns", q[:, None, :] - a[None], ab) / np.maximum(L * L, 1e-18), 0.0, 1.0)
    foot = a[None] + t[..., None] * ab[None]
    d = np.linalg.norm(q[:, None, :] - foot, axis=2)
    j = np.argmin(d, axis=1)
    k = np.arange(len(verts))
    dist, arc = d[k, j], s0[j] + t[k, j] * L[j]
    w = np.clip(dist / band, 0.0, 1.0)
    f = scale + (1.0 - scale) * w * w * (3.0 - 2.0 * w)      # smoothstep from scale to 1
    new_arc = s0[-1] / 2 + (arc - s0[-1] / 2) * f

    def at(sv):
        i = np.clip(np.searchsorted(s0, sv, side="right") - 1, 0, len(L) - 1)
        return a[i] + ((sv - s0[i]) / np.maximum(L[i], 1e-18))[:, None] * ab[i]
    near = dist < band
    x[verts[near]] = q[near] + at(new_arc[near]) - at(arc[near])
