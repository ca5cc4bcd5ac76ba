"""Untangling a sewn garment: the edges that pass through its own triangles, moved back out.

Sewing pulls the panels' seam edges together with the cloth collision off (its contacts would hold
the two sides of every seam a thickness apart), so where a stiff panel folds into a tube's closing
corner (a trouser leg's inseam at the hem) a few edges can end up through the garment's own
triangles; the simulation keeps the crossings it starts with, to the last frame.

Intersection contour minimisation (Volino & Magnenat-Thalmann 2006, "Resolving surface collisions
through intersection contour minimization"): where an edge E passes through a triangle of normal N,
the intersection contour runs on along each triangle i beside the edge (normal N_i) in the direction
R_i = N x N_i, turned to point into triangle i. Moving the edge by G = sum_i R_i - 2 (E.R_i)/(E.N) N,
and the triangle by -G, shortens the contour; where it shrinks to nothing the surfaces part. Each
round moves every vertex by the mean of its pairs' steps, each step `step` long (so the result does
not depend on the order of the pairs), until no edge crosses or `rounds` is spent; the round with
the fewest crossings is kept, and a garment without crossings is returned as it is.
"""
from __future__ import annotations

import numpy as np

from stages.geometry.mesh import mesh_edges


def crossing_pairs(x: np.ndarray, edges: np.ndarray, triangles: np.ndarray, flagged: np.ndarray) -> list:
    """[(edge index, triangle index)] for the edges in `flagged`: the triangles each passes through
    (triangles sharing a vertex with it excluded), by a direct segment-triangle test against every
    triangle (the crossings are few; `stages.sim.audit.crossing_flags` finds which edges cross)."""
    from stages.geometry.mesh import triangles_near_edges
    flagged = np.asarray(flagged, np.int64)
    if flagged.size == 0:
        return []
    nearby = triangles_near_edges(x, edges[flagged], triangles)
    out = []
    for e, near in zip(flagged, nearby):
        i, j = edges[e]
        near = np.sort(np.asarray(near, np.int64))
        tri = triangles[near]
        a, b, c = x[tri[:, 0]], x[tri[:, 1]], x[tri[:, 2]]
        e1, e2 = b - a, c - a
        d = x[j] - x[i]
        h = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, h)
        ok = np.abs(det) > 1e-18
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = x[i] - a
        u = inv * np.einsum("ij,ij->i", s, h)
        q = np.cross(s, e1)
        v = inv * (q @ d)
        t = inv * np.einsum("ij,ij->i", e2, q)
        hit = ok & (u > 0) & (v > 0) & (u + v < 1) & (t > 0) & (t < 1)
        hit &= ~np.any(tri == i, axis=1) & ~np.any(tri == j, axis=1)
        out.extend((int(e), int(k)) for k in near[hit])
    return out


def edge_faces(triangles: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """(E, 2) int64: the (at most two) triangles beside each edge, -1 where there is none."""
    n = int(triangles.max()) + 1 if triangles.size else 0
    key = edges[:, 0].astype(np.int64) * n + edges[:, 1]
    out = np.full((len(edges), 2), -1, np.int64)
    for k in range(3):
        a, b = triangles[:, k], triangles[:, (k + 1) % 3]
        code = np.minimum(a, b).astype(np.int64) * n + np.maximum(a, b)
        idx = np.searchsorted(key, code)
        for t, e in enumerate(idx):
            out[e, 0 if out[e, 0] < 0 else 1] = t
    return out


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """u x v of two 3-vectors (np.cross's overhead is most of the cost at this size)."""
    return np.array([u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]])


def contour_gradient(x: np.ndarray, triangles: np.ndarray, edge: np.ndarray, beside: np.ndarray,
                     t: int) -> np.ndarray:
    """(3,) G for edge (i, j) through triangle t (see the module): moving the edge by G and the
    triangle by -G shortens their intersection contour."""
    a, b, c = x[triangles[t]]
    n = _cross(b - a, c - a)
    n /= max(np.linalg.norm(n), 1e-300)
    i, j = int(edge[0]), int(edge[1])
    e = x[j] - x[i]
    en = e @ n
    g = np.zeros(3)
    if abs(en) < 1e-18:
        return g
    for f in beside:
        if f < 0:
            continue
        tri = triangles[f]
        p, q, r = x[tri]
        ni = _cross(q - p, r - p)
        ni /= max(np.linalg.norm(ni), 1e-300)
        rv = _cross(n, ni)
        norm = np.linalg.norm(rv)
        if norm < 1e-12:
            continue
        rv /= norm
        k = int(np.flatnonzero(tri == i)[0])
        flipped = tri[(k + 1) % 3] != j        # the edge runs j -> i in this triangle's winding
        side = ((n @ ni) * (ni @ e) - (n @ e)) * (-1.0 if flipped else 1.0)
        if side < 0:
            rv = -rv
        g += rv - 2.0 * (e @ rv) / en * n
    return g


def untangle(x: np.ndarray, triangles: np.ndarray, *, step: float = 5e-4, rounds: int = 200,
             max_move: float | None = None) -> tuple[np.ndarray, int, int]:
    """(positions, crossing edges left, crossing edges before) of a mesh whose edges pass through
    its own triangles (see the module). step: m a pair moves its vertices per round. max_move: m,
    the most any vertex may move in total (default: the mesh's median edge length): a tangle too
    large for this local repair is left as found rather than torn."""
    from stages.sim.audit import crossing_flags
    x0 = np.asarray(x, np.float64)
    tris = np.ascontiguousarray(triangles, np.int32)
    edges = mesh_edges(tris)
    zeros_e, zeros_t = np.zeros(len(edges), np.int32), np.zeros(len(tris), np.int32)

    def flagged_of(y):
        own, _, _ = crossing_flags(y, edges, zeros_e, tris, zeros_t)
        return np.flatnonzero(own)

    flagged = flagged_of(x0)
    before = int(flagged.size)
    if before == 0:
        return x0, 0, 0
    if max_move is None:
        max_move = float(np.median(np.linalg.norm(x0[edges[:, 1]] - x0[edges[:, 0]], axis=1)))
    beside = edge_faces(tris, edges)
    y = x0.copy()
    best, best_n = x0, before
    for _ in range(rounds):
        move = np.zeros_like(y)
        count = np.zeros(len(y))
        for e, t in crossing_pairs(y, edges, tris, flagged):
            g = contour_gradient(y, tris, edges[e], beside[e], t)
            norm = np.linalg.norm(g)
            if norm < 1e-12:
                continue
            d = step * g / norm
            for k in edges[e]:
                move[k] += d
                count[k] += 1
            for k in tris[t]:
                move[k] -= d
                count[k] += 1
        touched = count > 0
        if not touched.any():
            break
        y[touched] += move[touched] / count[touched, None]
        total = np.linalg.norm(y - x0, axis=1)
        over = total > max_move
        if over.any():   # a vertex never goes farther than max_move from where it was
            y[over] = x0[over] + (y[over] - x0[over]) * (max_move / total[over])[:, None]
        flagged = flagged_of(y)
        if flagged.size < best_n:
            best, best_n = y.copy(), int(flagged.size)
        if flagged.size == 0:
            break
    return best, best_n, before


def untangle_sewn(positions: np.ndarray, triangles: np.ndarray, log):
    """(positions, log) of a sewn garment (merged mesh) after `untangle`, the sewing log (SewingLog)
    with a note saying how many crossing edges were moved back out when there were any."""
    from dataclasses import replace
    pos, left, tangled = untangle(positions, triangles)
    if tangled:
        log = replace(log, notes=log.notes + (f"untangled: {tangled - left} of {tangled} edges through the "
                                              f"garment's own triangles moved back out",))
    return pos, log
