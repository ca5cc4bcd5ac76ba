"""Convexity- and containment-preserving QEM simplification of a convex hull (paper A §2.2, fig. 3).

One step collapses a triangle t = (a, b, c) to one new vertex v: t and its three edge neighbours
disappear, every other face touching a, b or c is re-attached to v (the region's boundary cycle
w_0 .. w_k-1 becomes the fan (v, w_i, w_i+1)); faces -4, vertices -2.

Placing v (the heart of it). Every condition we need is *linear* in v, because "point p lies behind
the plane of the new face (v, w_i, w_i+1)" is the sign of the tetrahedron volume
((w_i - p) x (w_i+1 - p)) . (v - p), affine in v. So v is the solution of a small LP:
- (b) containment: a, b, c (and every point that must stay inside and is near the region) behind
  every new face. Since a, b, c were the only vertices dropped and the unchanged faces already had
  them behind, this makes the new hull contain the old one. (For a new face whose ring edge came
  from an old face (a, w_i, w_i+1), it says v is on or in front of that old face's plane, i.e. the
  removed volume is re-covered, as in Sander et al.'s progressive hulls.)
- (a) convexity: v behind every unchanged face touching the ring, and every ring vertex behind
  every new face, both by a margin `eps_convex` (strict convexity, so Qhull of the result finds
  the same faces);
- objective: the volume of the new mesh, linear in v (sum of the new faces' cone volumes), so v
  is the containing position that adds least volume.
The LP is solved by Seidel's algorithm in a numba kernel (3 unknowns, tens of rows; scipy's HiGHS
gives the same optimum, tested). Then everything is verified exactly on the candidate and the
collapse is rejected if anything fails: (c) every new face has positive area and height above
`min_height`; every vertex behind every new face plane and v behind every other face plane
(global convexity, tolerance `tol`); every `keep` point (the input hull's vertices, never the
previous step's) behind every new plane, so containment never drifts by accumulated tolerance.

Priority: the paper's quadric error (Garland-Heckbert, area-weighted face quadrics summed onto the
vertices, Q_v = Q_a + Q_b + Q_c) evaluated at the LP's v; or the added volume. Collapses run
cheapest first until the face count would drop below `min_triangles` or none is legal.
"""
from __future__ import annotations

import numpy as np

from stages.checks import ContractError
from stages.hulls import kernels
from stages.hulls.types import ConvexMesh

# Tolerances relative to the mesh's bounding-box diagonal L.
TOL_RELATIVE = 1e-9          # a point may be this far in front of a plane and count as behind
CONVEX_MARGIN_RELATIVE = 1e-7  # strictness of convexity asked of the LP
NEAR_RELATIVE = 1e-4         # keep points closer than this to a region's planes enter its LP
MIN_HEIGHT_RELATIVE = 1e-6   # smallest triangle height allowed (no slivers / degenerate faces)

# After a collapse only faces with a corner in the new vertex's 1-ring are re-costed (2 rings cost
# twice the time for no better result on CesiumMan); the winner is always re-evaluated, and when no
# candidate is left every face is re-evaluated once before stopping.
DIRTY_DEPTH = 1

PRIORITIES = {"qem": kernels.PRIO_QEM, "volume": kernels.PRIO_VOLUME}


def simplify_hull(mesh: ConvexMesh, min_triangles: int, *, priority: str = "qem",
                  keep: np.ndarray | None = None, max_offset: float | None = None) -> ConvexMesh:
    """Simplify a convex mesh by constrained triangle collapses down to >= min_triangles faces.

    mesh: a convex outward-oriented triangle mesh (e.g. from inflate_hull).
    min_triangles: floor of the face count (values below 4 mean 4: a tetrahedron).
    priority: 'qem' (paper) or 'volume' (least added volume first).
    keep: (p, 3) points that must stay inside (default: mesh's own vertices, i.e. the result
        contains the input hull).
    max_offset: optional error bound (m): new vertices stay behind every input face plane moved
        out by max_offset (linear rows of the same LP), so the result stays within about that
        distance of the input (more at sharp input vertices, where offset planes meet further out).
        None = no bound (the paper: only the face floor stops it).
    Returns a convex mesh with fewer or equal faces containing `keep` (to 1e-9 x bbox diagonal).
    """
    if priority not in PRIORITIES:
        raise ContractError(f"simplify_hull: priority must be one of {sorted(PRIORITIES)}, got {priority!r}")
    min_faces = max(int(min_triangles), 4)
    if mesh.faces.shape[0] - 4 < min_faces:
        return mesh
    verts = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
    diag = float(np.linalg.norm(np.ptp(verts, axis=0)))
    if keep is None:
        keep, keep_vertex = verts, np.arange(verts.shape[0])
    else:
        keep = np.ascontiguousarray(keep, dtype=np.float64)
        keep_vertex = np.full(keep.shape[0], -1, dtype=np.int64)
    bound = np.zeros((0, 4))
    if max_offset is not None:
        if not (np.isfinite(max_offset) and max_offset >= 0):
            raise ContractError(f"simplify_hull: max_offset must be a non-negative distance, got {max_offset}")
        bound = np.ascontiguousarray(mesh.planes)
        bound[:, 3] += max_offset
    out_v, valive, out_f, falive, _, _ = kernels.simplify_kernel(
        verts, mesh.faces.astype(np.int64), keep, keep_vertex, min_faces, TOL_RELATIVE * diag,
        CONVEX_MARGIN_RELATIVE * diag, NEAR_RELATIVE * diag, MIN_HEIGHT_RELATIVE * diag, PRIORITIES[priority],
        DIRTY_DEPTH, bound)
    faces = out_f[falive]
    used = np.flatnonzero(valive)
    remap = np.full(valive.shape[0], -1, dtype=np.int64)
    remap[used] = np.arange(used.size)
    return ConvexMesh(vertices=np.ascontiguousarray(out_v[used]), faces=remap[faces].astype(np.int32))
