"""Convex hulls (Qhull) and their inflation by a thickness delta (paper A §2.1-2.2).

Degenerate input policy (never a raw Qhull traceback):
- not an (n, 3) finite array or no points -> `InputError` naming the point set;
- fewer than 4 distinct points, collinear or coplanar points (extent across <= `FLAT_RELATIVE` x
  extent along) -> `InputError`, unless the caller passes `flat_thickness > 0`: then the documented
  fallback thickens the points (also those thinner than `THIN_RELATIVE`) by +-flat_thickness across them: coplanar -> a slab (copies along the
  plane's normal), collinear -> a square prism around the line, one distinct point -> a cube; the
  hull then has volume (`fit_colliders` uses delta). A robot's flat plate or a region of 1-3
  vertices gets a thin hull instead of a Qhull error.
- points far from the origin for their extent are hulled centred (Qhull's precision is relative to
  the largest coordinate); faces Qhull leaves degenerate are rebuilt with joggling ('QJ').
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from stages.checks import ContractError
from stages.errors import InputError
from stages.hulls.types import ConvexMesh

# Points whose smallest principal extent is below this fraction of the largest are called flat.
FLAT_RELATIVE = 1e-9
# With a flat_thickness, points this thin (across / along) are thickened too: Qhull hulls them, but
# the sliver faces round their rim left the inflated, simplified hull non-convex by up to 0.3 % of
# its size (random sets 1e-7 thick). Rigid regions are never this thin (regions.is_hull_ready: 1e-3).
THIN_RELATIVE = 1e-4
# Faces with twice-area below this fraction of extent^2 count as degenerate.
DEGENERATE_AREA = 1e-14
# Inflation: a vertex whose normal makes a dot product below this with an adjacent face normal is
# "sharp"; its offset is not scaled up (it would blow up) but split into one point per face.
SHARP_DOT = 0.25


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (m, 3) and twice-areas (m,) of triangles (zero normal for degenerate ones)."""
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    n = np.cross(b - a, c - a)
    area2 = np.linalg.norm(n, axis=1)
    safe = np.where(area2 > 0, area2, 1.0)
    return n / safe[:, None] * (area2 > 0)[:, None], area2


def mesh_volume(mesh: ConvexMesh) -> float:
    """Enclosed volume (m^3) of a closed outward-oriented triangle mesh (divergence theorem)."""
    v = mesh.vertices - mesh.vertices.mean(axis=0)
    a, b, c = (v[mesh.faces[:, i]] for i in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def _check_points(points, source) -> np.ndarray:
    try:
        p = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise InputError(source, f"points are not numeric: {err}") from None
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(source, f"expected (n, 3) points, got shape {p.shape}")
    if not np.isfinite(p).all():
        raise InputError(source, f"non-finite coordinate in point {int(np.argwhere(~np.isfinite(p))[0, 0])}")
    return p


def _principal(unique: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(axes (3, 3) rows by descending spread, extents (3,) along them) of distinct points (n, 3)."""
    centred = unique - unique.mean(axis=0)
    # fewer than 3 rows: zero rows give the SVD its full 3 x 3 basis and change no singular value
    padded = np.concatenate([centred, np.zeros((max(0, 3 - centred.shape[0]), 3))])
    _, _, axes = np.linalg.svd(padded, full_matrices=False)
    return axes, np.ptp(centred @ axes.T, axis=0)


def _thickened(unique: np.ndarray, axes: np.ndarray, rank: int, t: float) -> np.ndarray:
    """The points copied to +-t along the axes across them (rank 2: the normal; 1: the two axes
    across the line; 0: all three): a slab, a square prism or a cube around them."""
    across = axes[rank:]
    signs = np.array(np.meshgrid(*[[1.0, -1.0]] * across.shape[0], indexing="ij")).reshape(across.shape[0], -1).T
    return np.concatenate([unique + t * (s @ across) for s in signs])


def convex_hull(points, *, source="points", flat_thickness: float = 0.0) -> ConvexMesh:
    """Convex hull of (n, 3) points with Qhull, outward-oriented, only hull vertices kept.

    source: names the point set in error messages (e.g. the bone). flat_thickness: see the module
    docstring (0 = degenerate input is an error). Vertices keep the input's frame and units.
    """
    p = _check_points(points, source)
    unique = np.unique(p, axis=0)
    if unique.shape[0] == 0:
        raise InputError(source, "no points to build a hull of")
    thick = flat_thickness > 0
    if unique.shape[0] < 4 and not thick:
        raise InputError(source, f"a hull needs >= 4 distinct points, got {unique.shape[0]}")
    axes, extent = _principal(unique)
    flat = (THIN_RELATIVE if thick else FLAT_RELATIVE) * extent[0]
    rank = 0 if not extent[0] > 0 else 1 if extent[1] <= flat else 2 if extent[2] <= flat else 3
    if rank == 1 and not thick:
        raise InputError(source, f"points are collinear (extent {extent[0]:.3g} x {extent[1]:.3g})")
    if rank == 2 and not thick:
        raise InputError(source, f"points are coplanar (thickness {extent[2]:.3g} over extent {extent[0]:.3g}); "
                                 "a hull needs volume")
    if rank < 3:
        unique = _thickened(unique, axes, rank, float(flat_thickness))
        extent = extent if rank == 2 else np.maximum(extent, 2.0 * flat_thickness)
    # far from the origin for its size: hull the centred points (Qhull's precision follows the coordinates)
    shift = unique.mean(axis=0) if np.abs(unique).max() > 1e3 * extent[0] else np.zeros(3)
    size = float(extent[0])
    # Qt triangulation of a facet with collinear boundary points leaves degenerate faces (and a sliver's
    # plane folds the mesh); joggling avoids them, but the joggled facets put back on the points can
    # fold too (a thin set: 0.3 % of its size); then a hull of the points moved out from their centroid
    # by 1-2e-8 of their size (it contains them), and last their bounding box
    for pts, options in ((unique, None), (unique, "QJ"), (_outward(unique, JITTER_RELATIVE * size), None)):
        mesh = _qhull_mesh(pts, shift, options)
        if mesh is not None and not _degenerate(mesh, size) and _convexity(mesh) <= CONVEX_RELATIVE * size:
            return mesh
    return _box(unique, axes, size)


CONVEX_RELATIVE = 5e-7   # a vertex this far (x size) in front of a face plane: the hull folds (maps: 1e-6 x half)
JITTER_RELATIVE = 1e-8   # how far (x size) the last fallback moves the points out


def _qhull_mesh(points: np.ndarray, shift: np.ndarray, options: str | None = None) -> ConvexMesh | None:
    """The hull's mesh on `points`, hulled at points - shift; None when Qhull refuses them."""
    try:
        return _mesh_from_qhull(points, ConvexHull(points - shift, qhull_options=options))
    except QhullError:
        return None


def _degenerate(mesh: ConvexMesh, size: float) -> bool:
    _, area2 = face_normals(mesh.vertices, mesh.faces)
    return bool((area2 <= DEGENERATE_AREA * size ** 2).any())


def _convexity(mesh: ConvexMesh) -> float:
    """Largest distance (m) of a vertex in front of a face plane (0 for a convex mesh)."""
    pl = mesh.planes
    return float(max((mesh.vertices @ pl[:, :3].T - pl[:, 3]).max(), 0.0))


def _box(points: np.ndarray, axes: np.ndarray, size: float) -> ConvexMesh:
    """The box around the points along `axes` (3, 3), grown by 1e-9 of their size and 1e-14 of their
    largest coordinate for rounding."""
    proj = points @ axes.T
    pad = 1e-9 * size + 1e-14 * float(np.abs(points).max())
    lo, hi = proj.min(axis=0) - pad, proj.max(axis=0) + pad
    corners = np.array(np.meshgrid(*zip(lo, hi), indexing="ij")).reshape(3, -1).T @ axes
    return _mesh_from_qhull(corners, ConvexHull(corners - corners.mean(axis=0)))


def _outward(points: np.ndarray, eps: float) -> np.ndarray:
    """Points moved away from their centroid by eps to 2 eps (seeded): no three stay collinear, and
    their hull contains the points (the centroid is inside it, each point between it and its move)."""
    d = points - points.mean(axis=0)
    r = np.linalg.norm(d, axis=1, keepdims=True)
    step = eps * (1.0 + np.random.default_rng(0).random((points.shape[0], 1)))
    return points + np.where(r > 0, step / np.where(r > 0, r, 1.0), 0.0) * d


def _mesh_from_qhull(points: np.ndarray, hull: ConvexHull) -> ConvexMesh:
    simplices = hull.simplices.astype(np.int64)
    tri = points[simplices]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    flip = np.einsum("ij,ij->i", n, hull.equations[:, :3]) < 0
    simplices[flip] = simplices[flip][:, [0, 2, 1]]
    return _reindexed(points, simplices)


def _reindexed(points: np.ndarray, faces: np.ndarray) -> ConvexMesh:
    used, inverse = np.unique(faces, return_inverse=True)
    return ConvexMesh(vertices=np.ascontiguousarray(points[used], dtype=np.float64),
                      faces=inverse.reshape(-1, 3).astype(np.int32))


def vertex_normals(mesh: ConvexMesh) -> np.ndarray:
    """(n, 3) unit angle-weighted vertex normals (degenerate faces ignored)."""
    v, f = mesh.vertices, mesh.faces
    fn, area2 = face_normals(v, f)
    acc = np.zeros_like(v)
    for i in range(3):
        e1 = v[f[:, (i + 1) % 3]] - v[f[:, i]]
        e2 = v[f[:, (i + 2) % 3]] - v[f[:, i]]
        cos = np.einsum("ij,ij->i", e1, e2) / np.maximum(np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1), 1e-300)
        angle = np.arccos(np.clip(cos, -1.0, 1.0))
        np.add.at(acc, f[:, i], fn * angle[:, None])
    norm = np.linalg.norm(acc, axis=1, keepdims=True)
    if (norm <= 0).any():
        raise ContractError("vertex_normals: a vertex has no non-degenerate face")
    return acc / norm


def inflate_hull(mesh: ConvexMesh, delta: float) -> ConvexMesh:
    """Hull of the vertices pushed out by delta along their angle-weighted normals, re-hulled.

    Pushing vertex v by delta along its normal n_v moves an adjacent face plane (normal n_f) out by
    only delta * (n_v . n_f) at v. So the offset is scaled to delta / min_f(n_v . n_f): every face
    plane adjacent to v then passes at distance >= delta behind the moved point, and the inflated
    hull reaches at least delta beyond every raw face plane (its support in each raw face normal is
    >= raw + delta). At a sharp vertex (min dot < SHARP_DOT) the scale would blow up, so instead v
    contributes v + delta n_f for each adjacent face plus v + delta n_v (a small bevel). In both
    cases the inflated hull contains the raw hull. delta = 0 returns the mesh unchanged.
    """
    if not (np.isfinite(delta) and delta >= 0):
        raise ContractError(f"inflate_hull: delta must be a non-negative thickness, got {delta}")
    if delta == 0:
        return mesh
    v, f = mesh.vertices, mesh.faces
    nv = vertex_normals(mesh)
    fn, area2 = face_normals(v, f)
    ok = area2 > 0
    corner_vertex = f[ok].ravel()
    corner_dot = np.einsum("ij,ij->i", nv[corner_vertex], np.repeat(fn[ok], 3, axis=0))
    min_dot = np.full(v.shape[0], np.inf)
    np.minimum.at(min_dot, corner_vertex, corner_dot)
    sharp = min_dot < SHARP_DOT
    scale = np.where(sharp, 1.0, 1.0 / np.where(sharp, 1.0, min_dot))
    moved = [v + (delta * scale)[:, None] * nv]
    sharp_corner = sharp[corner_vertex]
    if sharp_corner.any():
        moved.append(v[corner_vertex[sharp_corner]] + delta * np.repeat(fn[ok], 3, axis=0)[sharp_corner])
    return convex_hull(np.concatenate(moved), source="inflated hull")
