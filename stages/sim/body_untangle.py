"""Untangling the cloth from the body once a frame (SimParams.body_untangle).

The particles collide with the colliders, but a limb can still pass through the cloth between
them: on the worst frames of the real characters the crossed triangles are stretched across a limb,
their corners on the colliders about 1 cm off the skin, and the skin pokes through their flat
middle (a chord across a curved limb). After each frame's steps the body audit's crossings
(stages.sim.body_audit.frame_crossings: a body-mesh edge through a cloth triangle) are looked up on
the true skinned mesh, and each crossed triangle's free corners are moved out along the body's
outward normal at the crossing, far enough that the edge's outer end lies behind the triangle
(plus MARGIN): the cloth goes back to the side of the skin it belongs on (outside; the crossings
where the body meets itself, `in_self_overlap`, are left: no side is free there). A corner moves by
the largest of its triangles' pushes, at most one cloth edge length (median) per round, its previous
position with it (no velocity is added); up to ROUNDS rounds, until no free crossing is left.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stages.geometry.mesh import mesh_edges
from stages.sim.body_audit import frame_crossings, in_self_overlap

ROUNDS = 4          # rounds of look-up and push per frame
MARGIN = 0.002      # m beyond the body edge's outer end


@dataclass
class UntangleStats:
    """Over a run: free crossings found after the frames' steps, the corners moved, crossings left."""

    found: int = 0
    moved: int = 0
    left: int = 0


def untangle_pushes(x, tris, hits, points, normals, body, body_edges, inv_mass, cap) -> np.ndarray:
    """(N, 3) displacement per particle for the crossings `hits` ((k, 2): body edge, cloth triangle)
    at `points` with the body's outward `normals`: per crossing, depth = how far the body edge's
    outer end lies beyond the crossing point along the normal, plus MARGIN; each free corner of the
    triangle keeps the largest push of its triangles, capped at `cap` m."""
    d = np.zeros_like(x)
    size = np.zeros(x.shape[0])
    for (e, t), p, n in zip(hits, points, normals):
        u, v = body_edges[e]
        depth = max(float((body[u] - p) @ n), float((body[v] - p) @ n), 0.0) + MARGIN
        depth = min(depth, cap)
        for c in tris[t]:
            if inv_mass[c] > 0.0 and depth > size[c]:
                size[c] = depth
                d[c] = depth * n
    return d


class BodyUntangle:
    """The per-frame pass of one simulation: frame(f, x, xp, body) after frame f's steps."""

    def __init__(self, x0: np.ndarray, tris: np.ndarray, inv_mass: np.ndarray, body_tris: np.ndarray):
        """x0 (N, 3) the cloth as dressed (its median edge length caps a move); tris (T, 3) all garments'
        triangles; inv_mass (N,) 0: a particle that is never moved; body_tris the character's mesh."""
        self.tris = np.ascontiguousarray(tris, np.int32)
        self.edges = mesh_edges(self.tris)
        self.cap = float(np.median(np.linalg.norm(x0[self.edges[:, 1]] - x0[self.edges[:, 0]], axis=1)))
        self.free = np.asarray(inv_mass, np.float64)
        self.body_tris = np.ascontiguousarray(body_tris, np.int32)
        self.body_edges = mesh_edges(self.body_tris)
        self.stats = UntangleStats()

    def _free_hits(self, x, body, joints):
        hb, _, pts, _, normals, _ = frame_crossings(x, self.tris, self.edges, body, self.body_tris, self.body_edges,
                                                    joints)
        pts, normals = pts[:len(hb)].astype(np.float64), normals[:len(hb)].astype(np.float64)
        keep = ~in_self_overlap(body, self.body_tris, pts, normals)
        a, b, c = (body[self.body_tris[:, k]] for k in range(3))
        sign = 1.0 if np.einsum("ij,ij->", a, np.cross(b, c)) >= 0.0 else -1.0    # an inward-wound body
        return hb[keep], pts[keep], sign * normals[keep]

    def frame(self, x: np.ndarray, xp: np.ndarray, body: np.ndarray) -> None:
        """Move the cloth (x, xp: (N, 3) relative frame, in place) out of the body (V, 3) skinned at
        the same frame and in the same frame of reference."""
        body = np.asarray(body, np.float64)
        joints = np.zeros(body.shape[0], np.int32)
        moved = np.zeros(x.shape[0], bool)
        for r in range(ROUNDS):
            hits, pts, normals = self._free_hits(x, body, joints)
            if r == 0:
                self.stats.found += len(hits)
            if not len(hits):
                break
            d = untangle_pushes(x, self.tris, hits, pts, normals, body, self.body_edges, self.free, self.cap)
            x += d
            xp += d
            moved |= np.any(d != 0.0, axis=1)
        else:
            self.stats.left += len(self._free_hits(x, body, joints)[0])
        self.stats.moved += int(moved.sum())
