"""Map stage (paper A §2.3-2.4): build each hull's OBB, planar meshes, point location and map cells.

Choices
- OBB: eigenvectors of the covariance of the hull SURFACE (area-weighted triangles, Gottschalk et
  al. 1996's continuous formula), the robust variant: it does not depend on how densely a face is
  triangulated or on interior/duplicate points as the vertex covariance does. Extents and centre
  from the vertices' projections; axes sorted by half extent (row 0 longest), signs fixed so the
  largest component of axes 0 and 1 is positive, axes[2] = axes[0] x axes[1].
- Point location: a slab decomposition (Dobkin & Lipton) rather than Kirkpatrick's hierarchy. Both
  answer in O(log n); the slabs need O(n^2) storage in the worst case, which is nothing for hulls of
  ~100 faces, are simple to build exactly, and answer with two binary searches over flat arrays,
  a shorter and more predictable path in a numba kernel than walking a hierarchy of ~log n levels.
- Map kind: 'auto' picks the cylinder when half_extents[0] / half_extents[1] > ELONGATION_RATIO.
- Cell lists, exact and closed (each cell widened by CELL_MARGIN rad / CELL_MARGIN x extent so the
  query's floor() at a boundary can never miss): a face is listed iff it meets the cell's region,
  the union of the cell's rays. Cylinder: rays start on the axis segment of the cell's axial
  interval and run perpendicular to it inside the theta wedge, so the region is a wedge slab
  (4 half-spaces): clip the triangle, listed iff something is left. Sphere: the region is the cone
  {theta in wedge, phi in [phi0, phi1]} from the centre: clip the triangle by the wedge planes, then
  the phi range over the clipped polygon is an interval (continuous function on a convex set) whose
  ends are 0 / pi if the +/- axis ray pierces the triangle, else on the polygon's edges (endpoints,
  or the foot of the great-circle arc nearest / farthest from the pole).
"""
from __future__ import annotations

import math

import numpy as np
import trimesh
from scipy.spatial import ConvexHull
from scipy.spatial import QhullError

from stages.checks import ContractError
from stages.errors import InputError
from stages.hulls.types import ColliderSet, ConvexMesh
from stages.maps.types import HullMap, MapSet, SlabLocator

ELONGATION_RATIO = 1.5      # longest / second-longest half extent above which the map is a cylinder
CELL_MARGIN = 1e-9          # cell widening: radians, and a fraction of the axial extent
CONVEX_TOL = 1e-6           # allowed vertex violation of a face plane, fraction of the longest half extent
FLAT_TOL = 1e-12            # projected doubled area below FLAT_TOL * extent^2: the face is vertical, skipped


# -- OBB ------------------------------------------------------------------------------------------
def surface_obb(vertices: np.ndarray, faces: np.ndarray):
    """(center (3,), axes (3,3) rows, half_extents (3,)) from the area-weighted surface covariance."""
    if not np.isfinite(vertices).all():
        raise ContractError("build_hull_map: the hull has non-finite vertices")
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    total = area.sum()
    if not total > 0:
        raise ContractError("build_hull_map: the hull has zero surface area")
    cen = (a + b + c) / 3.0
    mean = (area[:, None] * cen).sum(0) / total
    # Gottschalk et al.: E[x x^T] over a triangle = (9 m m^T + a a^T + b b^T + c c^T) / 12
    second = np.einsum("t,ti,tj->ij", area, 9 * cen, cen) + sum(
        np.einsum("t,ti,tj->ij", area, p, p) for p in (a, b, c))
    cov = second / (12.0 * total) - np.outer(mean, mean)
    _, vec = np.linalg.eigh(cov)
    axes = vec.T.copy()
    proj = vertices @ axes.T
    lo, hi = proj.min(0), proj.max(0)
    order = np.argsort(-(hi - lo), kind="stable")
    axes, lo, hi = axes[order], lo[order], hi[order]
    for i in (0, 1):
        if axes[i][np.argmax(np.abs(axes[i]))] < 0:
            axes[i] = -axes[i]
            lo[i], hi[i] = -hi[i], -lo[i]
    axes[2] = np.cross(axes[0], axes[1])
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    proj = vertices @ axes.T
    lo, hi = proj.min(0), proj.max(0)
    center = ((lo + hi) / 2.0) @ axes
    # tied extents (a hull symmetric about its long axis: a tube) can swap order by rounding once
    # axes[2] is recomputed; the box grows by that rounding instead (HullMap wants them non-increasing)
    return center, axes, np.maximum.accumulate(((hi - lo) / 2.0)[::-1])[::-1]


# -- planar meshes and point location -------------------------------------------------------------
def _edge_y(p0, p1, x):
    """y of segment p0-p1 at x, from its canonically ordered endpoints (bit-identical for both faces)."""
    if (p1[0], p1[1]) < (p0[0], p0[1]):
        p0, p1 = p1, p0
    return p0[1] + (p1[1] - p0[1]) * ((x - p0[0]) / (p1[0] - p0[0]))


def build_slab_locator(points: np.ndarray, tris: np.ndarray, face_ids: np.ndarray) -> SlabLocator:
    """Slab decomposition of a planar triangulation (points (n,2), CCW tris (k,3)) of a convex outline."""
    used = np.unique(tris)
    xs = np.unique(points[used, 0])
    tx = points[tris, 0]
    txmin, txmax = tx.min(1), tx.max(1)
    start, ys, fs = [0], [], []
    for j in range(xs.size - 1):
        xl, xr = xs[j], xs[j + 1]
        entries = []
        for t in np.nonzero((txmin <= xl) & (txmax >= xr))[0]:
            edges = []
            for u, v in ((0, 1), (1, 2), (2, 0)):
                p0, p1 = points[tris[t, u]], points[tris[t, v]]
                if min(p0[0], p1[0]) <= xl and max(p0[0], p1[0]) >= xr:
                    edges.append((_edge_y(p0, p1, xl), _edge_y(p0, p1, xr)))
            if len(edges) != 2:
                continue
            lo_e, hi_e = sorted(edges, key=lambda e: e[0] + e[1])
            entries.append((lo_e[0] + lo_e[1] + hi_e[0] + hi_e[1], lo_e + hi_e, face_ids[t]))
        entries.sort(key=lambda e: e[0])
        ys.extend(e[1] for e in entries)
        fs.extend(e[2] for e in entries)
        start.append(start[-1] + len(entries))
    return SlabLocator(x=xs.astype(np.float64), start=np.array(start, np.int32),
                       y=np.array(ys, np.float64).reshape(-1, 4), face=np.array(fs, np.int32))


def planar_meshes(local_vertices: np.ndarray, faces: np.ndarray, scale: float):
    """Upper / lower faces (CCW in the (q1, q2) plane) and their hull face ids."""
    p = local_vertices[:, 1:]
    a, b, c = (p[faces[:, i]] for i in range(3))
    area2 = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    tol = FLAT_TOL * scale * scale
    up = np.nonzero(area2 > tol)[0].astype(np.int32)
    low = np.nonzero(area2 < -tol)[0].astype(np.int32)
    return faces[up].astype(np.int32), up, faces[low][:, [0, 2, 1]].astype(np.int32), low


# -- map cells ------------------------------------------------------------------------------------
def _dot(a, b) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _clip(poly: list, n: tuple, off: float, tol: float) -> list:
    """Sutherland-Hodgman: keep the part of a convex polygon (list of 3-tuples) with n.x >= off - tol."""
    out = []
    k = len(poly)
    for i in range(k):
        p, q = poly[i], poly[(i + 1) % k]
        sp, sq = _dot(n, p) - off, _dot(n, q) - off
        if sp >= -tol:
            out.append(p)
        if (sp >= -tol) != (sq >= -tol):
            w = sp / (sp - sq)
            out.append((p[0] + (q[0] - p[0]) * w, p[1] + (q[1] - p[1]) * w, p[2] + (q[2] - p[2]) * w))
    return out


def _wedge_polys(tri: list, th0: float, th1: float, tol: float) -> list:
    """Parts of a triangle inside the closed theta wedge [th0, th1] around axis 0 (list of polygons)."""
    if th1 - th0 >= 2 * math.pi:
        return [tri]
    n0 = (0.0, -math.sin(th0), math.cos(th0))   # n0.x = r sin(theta - th0)
    n1 = (0.0, math.sin(th1), -math.cos(th1))   # n1.x = r sin(th1 - theta)
    if th1 - th0 <= math.pi:
        poly = _clip(_clip(tri, n0, 0.0, tol), n1, 0.0, tol)
        return [poly] if poly else []
    # wider than pi (n_theta <= 2): the wedge is the union of two half-spaces
    return [poly for poly in (_clip(tri, n0, 0.0, tol), _clip(tri, n1, 0.0, tol)) if poly]


def _phi(x) -> float:
    return math.atan2(math.hypot(x[1], x[2]), x[0])


def _axis_ray_hits(a, b, c, sign: float, tol: float) -> bool:
    """Does the ray from the origin along sign * axis 0 hit triangle abc (inclusive)?"""
    d = (sign, 0.0, 0.0)
    e1 = (b[0] - a[0], b[1] - a[1], b[2] - a[2])
    e2 = (c[0] - a[0], c[1] - a[1], c[2] - a[2])
    pv = _cross(d, e2)
    det = _dot(e1, pv)
    if abs(det) <= 1e-300:
        return False
    tv = (-a[0], -a[1], -a[2])
    u = _dot(tv, pv) / det
    qv = _cross(tv, e1)
    v = _dot(d, qv) / det
    t = _dot(e2, qv) / det
    return u >= -tol and v >= -tol and u + v <= 1 + tol and t >= -tol


def _cross(a, b) -> tuple:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _norm(a) -> float:
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


def _edge_phi_range(a, b):
    """Min and max of phi over the segment a-b (which does not pass through the origin).

    Plain floats on 3-tuples: called per face, wedge and edge, where numpy's per-call overhead
    was 80 % of the map build."""
    pa, pb = _phi(a), _phi(b)
    lo, hi = min(pa, pb), max(pa, pb)
    m = _cross(a, b)
    mn = _norm(m)
    if mn <= 1e-14 * _norm(a) * _norm(b):
        return lo, hi
    m = (m[0] / mn, m[1] / mn, m[2] / mn)
    f = (1.0 - m[0] * m[0], -m[0] * m[1], -m[0] * m[2])
    fn = _norm(f)
    if fn <= 1e-14:
        return lo, hi
    f = (f[0] / fn, f[1] / fn, f[2] / fn)
    for g, is_min in ((f, True), ((-f[0], -f[1], -f[2]), False)):
        if _dot(_cross(a, g), m) >= -1e-14 and _dot(_cross(g, b), m) >= -1e-14:
            if is_min:
                lo = min(lo, _phi(g))
            else:
                hi = max(hi, _phi(g))
    return lo, hi


def _origin_near_triangle(a, b, c, eps: float) -> bool:
    """Is the origin within eps of triangle abc? (the map sphere's centre on a face)"""
    n = np.cross(b - a, c - a)
    if abs(n @ a) > eps * np.linalg.norm(n):
        return False
    q = trimesh.triangles.closest_point(np.array([[a, b, c]]), np.zeros((1, 3)))[0]
    return bool(np.linalg.norm(q) <= eps)


def cell_lists(local_vertices: np.ndarray, faces: np.ndarray, kind: str, n_theta: int,
               n_second: int, second_lo: float, second_hi: float, scale: float):
    """CSR (cell_start, cell_tris) of the faces some ray of each closed cell can hit."""
    dth = 2 * math.pi / n_theta
    ds = (second_hi - second_lo) / n_second
    eps_len = CELL_MARGIN * scale
    tol = 1e-12 * scale
    tris = [[tuple(float(x) for x in local_vertices[i]) for i in f] for f in faces]
    lists = [[] for _ in range(n_theta * n_second)]
    if kind == "cylinder":
        umin = local_vertices[faces, 0].min(1)
        umax = local_vertices[faces, 0].max(1)
        e0, e0_neg = (1.0, 0.0, 0.0), (-1.0, 0.0, 0.0)
        for it in range(n_theta):
            th0, th1 = it * dth - CELL_MARGIN, (it + 1) * dth + CELL_MARGIN
            for t, tri in enumerate(tris):
                for poly in _wedge_polys(tri, th0, th1, tol):
                    for js in range(n_second):
                        z0 = second_lo + js * ds - eps_len
                        z1 = second_lo + (js + 1) * ds + eps_len
                        if umax[t] < z0 or umin[t] > z1:
                            continue
                        if _clip(_clip(poly, e0, z0, tol), e0_neg, -z1, tol):
                            lists[it * n_second + js].append(t)
    else:
        for t, tri in enumerate(tris):
            a, b, c = (np.array(v) for v in tri)
            if _origin_near_triangle(a, b, c, eps_len):
                for cell in lists:       # the centre is on this face: every ray touches it
                    cell.append(t)
                continue
            up = _axis_ray_hits(a, b, c, 1.0, 1e-9)
            down = _axis_ray_hits(a, b, c, -1.0, 1e-9)
            for it in range(n_theta):
                th0, th1 = it * dth - CELL_MARGIN, (it + 1) * dth + CELL_MARGIN
                lo, hi = math.inf, -math.inf
                for poly in _wedge_polys(tri, th0, th1, tol):
                    for i in range(len(poly)):
                        l, h = _edge_phi_range(poly[i], poly[(i + 1) % len(poly)])
                        lo, hi = min(lo, l), max(hi, h)
                    if up:
                        lo = 0.0
                    if down:
                        hi = math.pi
                if lo > hi:
                    continue
                for js in range(n_second):
                    p0 = second_lo + js * ds - CELL_MARGIN
                    p1 = second_lo + (js + 1) * ds + CELL_MARGIN
                    if lo <= p1 and hi >= p0:
                        lists[it * n_second + js].append(t)
    start = np.zeros(len(lists) + 1, np.int32)
    start[1:] = np.cumsum([len(c) for c in lists])
    tris_out = np.array([t for c in lists for t in sorted(set(c))], np.int32)
    return start, tris_out


# -- the stage ------------------------------------------------------------------------------------
def build_hull_map(mesh: ConvexMesh, *, kind: str = "auto", n_theta: int = 12, n_phi: int = 6,
                   n_axial: int = 8) -> HullMap:
    """All query structures of one hull (bone-local in, bone-local out).

    kind: 'auto' (cylinder iff half_extents[0] / half_extents[1] > ELONGATION_RATIO), 'sphere' or
    'cylinder'. n_theta: theta intervals (paper: step pi/6 -> 12); n_phi: the sphere's phi
    intervals; n_axial: the cylinder's axial intervals (paper: 8).
    """
    if kind not in ("auto", "sphere", "cylinder"):
        raise ContractError(f"build_hull_map.kind: expected 'auto', 'sphere' or 'cylinder', got {kind!r}")
    for name, v in (("n_theta", n_theta), ("n_phi", n_phi), ("n_axial", n_axial)):
        if int(v) != v or v < 1:
            raise ContractError(f"build_hull_map.{name}: expected a positive integer, got {v}")
    vertices, faces = mesh.vertices, mesh.faces
    center, axes, half = surface_obb(vertices, faces)
    scale = float(half[0])
    if not half[2] > 1e-9 * scale:
        raise ContractError(f"build_hull_map: the hull is flat (OBB half extents {half})")
    planes = mesh.planes
    if not np.isfinite(planes).all():
        raise ContractError("build_hull_map: the hull has degenerate (zero-area) faces")
    viol = float((vertices @ planes[:, :3].T - planes[:, 3]).max())
    if viol > CONVEX_TOL * scale:
        raise ContractError(f"build_hull_map: the mesh is not convex (a vertex is {viol:.3g} m outside a face plane)")
    local = (vertices - center) @ axes.T
    up, up_ids, low, low_ids = planar_meshes(local, faces, scale)
    planar = np.ascontiguousarray(local[:, 1:])
    try:
        outline = ConvexHull(planar[np.unique(faces)]).vertices
    except QhullError as err:
        raise ContractError(f"build_hull_map: the hull's outline is degenerate ({str(err).splitlines()[0]})") from None
    outline = np.unique(faces)[outline].astype(np.int32)
    if kind == "auto":
        kind = "cylinder" if half[0] > ELONGATION_RATIO * half[1] else "sphere"
    if kind == "cylinder":
        n_second, lo, hi = int(n_axial), -float(half[0]), float(half[0])
    else:
        n_second, lo, hi = int(n_phi), 0.0, math.pi
    cell_start, cell_tris = cell_lists(local, faces, kind, int(n_theta), n_second, lo, hi, scale)
    return HullMap(
        mesh=mesh, kind=kind, center=center, axes=axes, half_extents=half, planes=planes,
        planar_vertices=planar, upper_faces=up, upper_face_ids=up_ids, lower_faces=low,
        lower_face_ids=low_ids, outline=outline,
        upper_locator=build_slab_locator(planar, up, up_ids),
        lower_locator=build_slab_locator(planar, low, low_ids),
        n_theta=int(n_theta), n_second=n_second, second_lo=lo, second_hi=hi,
        cell_start=cell_start, cell_tris=cell_tris)


def build_maps(colliders: ColliderSet, **params) -> MapSet:
    """One HullMap per hull collider (its `simplified` mesh), packed for the kernels.

    params: build_hull_map's keywords, or `kinds={bone_name: 'sphere'|'cylinder'}` to override the
    automatic choice per hull.
    """
    kinds = params.pop("kinds", None) or {}
    maps = []
    for h in colliders.hulls:
        try:
            maps.append(build_hull_map(h.simplified, kind=kinds.get(h.name, params.get("kind", "auto")),
                                       **{k: v for k, v in params.items() if k != "kind"}))
        except (ContractError, InputError) as err:   # one line naming the collider, not a bare contract
            raise InputError(f"map of collider {h.name!r} (joint {h.bone})", str(err)) from None
    maps = tuple(maps)
    return MapSet.from_maps(maps, bones=[h.bone for h in colliders.hulls], names=[h.name for h in colliders.hulls])
