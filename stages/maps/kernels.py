"""Numba hull queries over the packed maps (paper A §2.3-2.4): the one home of the hull query, used
by the maps' tests and benchmark and inside the simulation's njit loops (stages/sim/body_collide.py).

The core, `hull_query`, takes the MapArrays fields one by one (plain arrays, in `QUERY_FIELDS`
order; `query_arrays(m)` unpacks them) and an OBB-local point, and returns the face it responded
on (the contact normal). Why plain arrays: numba increments / decrements (atomically) the reference
count of every array reached through a named tuple argument of a compiled call (~300 ns per query
with the 18-array MapArrays, more than the query itself); hull_query and its helpers are compiled
once with `_nrt=False` (no reference counting at all) and `forceinline=True`: LLVM inlines them into
each caller (numba's own inline="always" re-ran its front end at every call site: 8 s of the
collision kernels' compile for the same machine code, issue 19).

    hull_query(half, kind, n_theta, n_second, second_lo, second_hi, face_start, planes, cell_base,
               cell_start, cell_tris, loc_base, loc_x, loc_start, loc_y, loc_face, h, method, q0, q1, q2)
        -> (inside, x, y, z, face)   OBB-local point q of hull h; the response point (OBB-local) and
        the global face id it lies on when inside, else (False, q0, q1, q2, face) with face a
        separating face (q in front of its plane) or -1 (rejected by the OBB or an outline)

The MapArrays-level kernels take `m` = `MapSet.arrays` (the named tuple documented in
stages/maps/types.py), the hull index `h` and a bone-local point `p` ((3,) float64 array or row
view). Points come back as a tuple of three floats (bone-local, metres), which costs no allocation
inside a hot loop. They allocate nothing and are compiled with `_nrt=False` (no reference counting
of the 16 arrays they read from `m`: 2-3x the queries per second).

Signatures (stable; tests and the benchmark code against them):
    hull_inside(m, h, p) -> bool                        paper path: OBB, slab point location, 2 planes
    hull_response(m, h, p) -> (x, y, z)                  paper ray through the cell's triangle list
    hull_push_nearest_plane(m, h, p) -> (x, y, z)        baseline: out through the least-penetrated plane
    hull_inside_brute(m, h, p) -> bool                   behind every face plane
    hull_response_brute(m, h, p) -> (x, y, z)            the paper ray against every face
    hull_collide(m, h, p, method) -> (inside, x, y, z)   hull_query in bone-local coordinates (p itself
        if outside); method: METHOD_PAPER (0, default), METHOD_BRUTE (1), METHOD_NEAREST_PLANE (2)
Vectorised wrappers (tests, logging, benchmarks): inside_points, response_points, collide_points.

Response ray (paper A §2.4). Source s: the OBB centre (map sphere) or p's projection on the OBB long
axis (map cylinder); direction d = (p - s)/|p - s|. The response is where the ray LEAVES the hull:
for a convex hull that is s + t* d with t* = min over faces with n.d > 0 of (off - n.s) / (n.d).
Only the faces listed in p's cell are scanned: the exit face is hit by a ray of that cell, so it is
listed, and every other face facing along d gives a larger t, so the minimum is the same as over
all faces. This needs no barycentric test, so rays through edges and vertices are exact (two faces
give the same t up to rounding). With the source inside the hull (the usual case) the exit is the
paper's "nearest hit"; when the source is outside (a cylinder axis leaving a slanted hull end before
the OBB ends, or an OBB centre outside a very skewed hull) the ray from the source first ENTERS the
hull behind p; we take the exit beyond p (t* >= |p - s|), i.e. we always push outward along d.

Edge cases (documented behaviour):
- p at the ray source (|p - s| <= ZERO_DIR * longest half extent: sphere centre, or on the cylinder
  axis): no direction; fall back to the nearest-plane push.
- cylinder points whose axis projection is beyond the hull's ends (|q0| > half extent): such points
  are outside the OBB and so outside the hull; hull_collide returns them unchanged. hull_response
  clamps the axial cell index and, if no listed face faces along d, falls back to the nearest plane.
- points on the surface: inside (n.p <= off is inclusive) and their response is p itself (t* = |p - s|).
- hull_response / hull_push_nearest_plane are meant for points inside the hull (call hull_collide,
  or test hull_inside first); for outside points they return a finite point but not a meaningful one.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)
from stages.maps.types import KIND_CYLINDER, HullMap, MapSet


NUMBA_CACHE_DEPENDS = ("stages.maps.types",)     # KIND_CYLINDER is compiled in

METHOD_PAPER = 0
METHOD_BRUTE = 1
METHOD_NEAREST_PLANE = 2
ZERO_DIR = 1e-12          # relative to the hull's longest half extent
TWO_PI = 2.0 * math.pi
# the MapArrays fields hull_query takes, in its argument order
QUERY_FIELDS = ("half", "kind", "n_theta", "n_second", "second_lo", "second_hi", "face_start", "planes",
                "cell_base", "cell_start", "cell_tris", "loc_base", "loc_x", "loc_start", "loc_y", "loc_face")


@njit(cache=True, inline="always")
def query_arrays(m):
    """The MapArrays fields hull_query takes, in its order (unpack once, outside a hot loop)."""
    return (m.half, m.kind, m.n_theta, m.n_second, m.second_lo, m.second_hi, m.face_start, m.planes,
            m.cell_base, m.cell_start, m.cell_tris, m.loc_base, m.loc_x, m.loc_start, m.loc_y, m.loc_face)


# -- frames -------------------------------------------------------------------------------------
@njit(cache=True, _nrt=False, forceinline=True)
def _to_local(m, h, p):
    c = m.center[h]
    r = m.axes[h]
    dx = p[0] - c[0]
    dy = p[1] - c[1]
    dz = p[2] - c[2]
    return (r[0, 0] * dx + r[0, 1] * dy + r[0, 2] * dz,
            r[1, 0] * dx + r[1, 1] * dy + r[1, 2] * dz,
            r[2, 0] * dx + r[2, 1] * dy + r[2, 2] * dz)


@njit(cache=True, _nrt=False, forceinline=True)
def _to_bone(m, h, q0, q1, q2):
    c = m.center[h]
    r = m.axes[h]
    return (c[0] + r[0, 0] * q0 + r[1, 0] * q1 + r[2, 0] * q2,
            c[1] + r[0, 1] * q0 + r[1, 1] * q1 + r[2, 1] * q2,
            c[2] + r[0, 2] * q0 + r[1, 2] * q1 + r[2, 2] * q2)


@njit(cache=True, _nrt=False, forceinline=True)
def _plane_dist(planes, f, q0, q1, q2):
    return planes[f, 0] * q0 + planes[f, 1] * q1 + planes[f, 2] * q2 - planes[f, 3]


# -- inside ---------------------------------------------------------------------------------------
@njit(cache=True, _nrt=False, forceinline=True)
def _slab_locate(loc_base, loc_x, loc_start, loc_y, loc_face, k, x, y):
    """Face of planar mesh k (= 2h + side) containing (x, y); -1 outside the outline, -2 in a gap."""
    b0 = loc_base[k]
    b1 = loc_base[k + 1]
    xs = loc_x
    if x < xs[b0] or x > xs[b1 - 1]:
        return -1
    # last slab whose left boundary <= x; branch-free halving (a select, not a jump, per step:
    # random query points would mispredict a branchy binary search at every level)
    lo = b0
    n = b1 - 1 - b0
    while n > 1:
        half = n >> 1
        lo = lo + half if xs[lo + half] <= x else lo
        n -= half
    xl = xs[lo]
    f = (x - xl) / (xs[lo + 1] - xl)
    e0 = loc_start[lo]
    e1 = loc_start[lo + 1]
    if e1 <= e0:
        return -2
    ys = loc_y
    if ys[e0, 0] + f * (ys[e0, 1] - ys[e0, 0]) > y:
        return -1
    lo = e0
    n = e1 - e0
    while n > 1:                         # last entry whose lower edge is at or below y
        half = n >> 1
        k = lo + half
        lo = k if ys[k, 0] + f * (ys[k, 1] - ys[k, 0]) <= y else lo
        n -= half
    if y > ys[lo, 2] + f * (ys[lo, 3] - ys[lo, 2]):
        return -1 if lo == e1 - 1 else -2
    return loc_face[lo]


@njit(cache=True, _nrt=False)
def _locate(m, k, x, y):
    """_slab_locate over MapArrays (tests)."""
    return _slab_locate(m.loc_base, m.loc_x, m.loc_start, m.loc_y, m.loc_face, k, x, y)


@njit(cache=True, _nrt=False, forceinline=True)
def _inside_brute(planes, face_start, h, q0, q1, q2):
    for f in range(face_start[h], face_start[h + 1]):
        if _plane_dist(planes, f, q0, q1, q2) > 0.0:
            return False
    return True


@njit(cache=True, _nrt=False, forceinline=True)
def _inside_paper(half, face_start, planes, loc_base, loc_x, loc_start, loc_y, loc_face, h, q0, q1, q2):
    """(inside, face): OBB rejection, the upper and lower planar meshes' faces above / below q, their
    two planes. face: when outside, a face whose plane q is in front of (a separating plane: the
    simulation remembers it), -1 if rejected by the OBB or a planar mesh's outline."""
    if abs(q0) > half[h, 0] or abs(q1) > half[h, 1] or abs(q2) > half[h, 2]:
        return False, -1
    fu = _slab_locate(loc_base, loc_x, loc_start, loc_y, loc_face, 2 * h, q1, q2)
    if fu == -1:
        return False, -1
    fl = _slab_locate(loc_base, loc_x, loc_start, loc_y, loc_face, 2 * h + 1, q1, q2)
    if fl == -1:
        return False, -1
    if fu == -2 or fl == -2:             # a numerical gap in a planar mesh: answer exactly
        return _inside_brute(planes, face_start, h, q0, q1, q2), -1
    if _plane_dist(planes, fu, q0, q1, q2) > 0.0:
        return False, fu
    if _plane_dist(planes, fl, q0, q1, q2) > 0.0:
        return False, fl
    return True, -1


# -- response -------------------------------------------------------------------------------------
@njit(cache=True, _nrt=False, forceinline=True)
def _nearest_plane(planes, face_start, h, q0, q1, q2):
    """(signed distance, face) of the plane q is least behind (largest signed distance)."""
    best = -np.inf
    bf = face_start[h]
    for f in range(face_start[h], face_start[h + 1]):
        s = _plane_dist(planes, f, q0, q1, q2)
        if s > best:
            best = s
            bf = f
    return best, bf


@njit(cache=True, _nrt=False, forceinline=True)
def _cell_of(kind, n_theta, n_second, second_lo, second_hi, cell_base, h, q0, d0, d1, d2):
    """Global cell of a unit ray direction d (and axial coordinate q0 for the cylinder)."""
    nt = n_theta[h]
    ns = n_second[h]
    th = math.atan2(d2, d1)
    if th < 0.0:
        th += TWO_PI
    it = int(math.floor(th * nt / TWO_PI))
    if it >= nt:
        it = nt - 1
    if kind[h] == KIND_CYLINDER:
        v = q0
    else:
        v = math.atan2(math.sqrt(d1 * d1 + d2 * d2), d0)
    lo = second_lo[h]
    js = int(math.floor((v - lo) / (second_hi[h] - lo) * ns))
    if js < 0:
        js = 0
    elif js >= ns:
        js = ns - 1
    return cell_base[h] + it * ns + js


@njit(cache=True, _nrt=False, forceinline=True)
def _response(half, kind, n_theta, n_second, second_lo, second_hi, face_start, planes, cell_base, cell_start,
              cell_tris, h, brute, q0, q1, q2):
    """(x, y, z, face): where the map ray through q (OBB-local) leaves the hull and the face it leaves
    through (brute: every face, else q's cell list); with no usable ray (q at the source, or no
    listed face facing along it) the nearest-plane push."""
    if kind[h] == KIND_CYLINDER:
        s0 = q0
        d0 = 0.0
    else:
        s0 = 0.0
        d0 = q0
    d1 = q1
    d2 = q2
    dn = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    tmin = np.inf
    ef = -1
    if dn > ZERO_DIR * half[h, 0]:
        d0 /= dn
        d1 /= dn
        d2 /= dn
        if brute:
            e0 = face_start[h]
            e1 = face_start[h + 1]
        else:
            c = _cell_of(kind, n_theta, n_second, second_lo, second_hi, cell_base, h, q0, d0, d1, d2)
            e0 = cell_start[c]
            e1 = cell_start[c + 1]
        for e in range(e0, e1):
            f = e if brute else cell_tris[e]
            nd = planes[f, 0] * d0 + planes[f, 1] * d1 + planes[f, 2] * d2
            if nd > 0.0:
                t = (planes[f, 3] - planes[f, 0] * s0) / nd
                if t < tmin:
                    tmin = t
                    ef = f
    if ef >= 0:
        return s0 + tmin * d0, tmin * d1, tmin * d2, ef
    best, bf = _nearest_plane(planes, face_start, h, q0, q1, q2)
    return q0 - best * planes[bf, 0], q1 - best * planes[bf, 1], q2 - best * planes[bf, 2], bf


@njit(cache=True, _nrt=False, forceinline=True)
def hull_query(half, kind, n_theta, n_second, second_lo, second_hi, face_start, planes, cell_base, cell_start,
               cell_tris, loc_base, loc_x, loc_start, loc_y, loc_face, h, method, q0, q1, q2):
    """(inside, x, y, z, face) of hull h for an OBB-local point q: the response point (OBB-local) and
    the global face it lies on (its plane's normal is the contact normal), or (False, q, face) outside
    with face a face whose plane q is in front of (-1 when the OBB or an outline rejected q).
    METHOD_PAPER: OBB, slab point location, two planes; the map ray through q's cell list.
    METHOD_BRUTE: every plane; the ray against every face. METHOD_NEAREST_PLANE: every plane; push
    to the least penetrated one."""
    if method == METHOD_PAPER:
        inside, sep = _inside_paper(half, face_start, planes, loc_base, loc_x, loc_start, loc_y, loc_face, h,
                                    q0, q1, q2)
        if not inside:
            return False, q0, q1, q2, sep
    else:
        best, bf = _nearest_plane(planes, face_start, h, q0, q1, q2)
        if best > 0.0:
            return False, q0, q1, q2, bf
        if method == METHOD_NEAREST_PLANE:
            return True, q0 - best * planes[bf, 0], q1 - best * planes[bf, 1], q2 - best * planes[bf, 2], bf
    r0, r1, r2, face = _response(half, kind, n_theta, n_second, second_lo, second_hi, face_start, planes,
                                 cell_base, cell_start, cell_tris, h, method != METHOD_PAPER, q0, q1, q2)
    return True, r0, r1, r2, face


# -- MapArrays-level kernels (bone-local points) ----------------------------------------------------
@njit(cache=True, _nrt=False)
def hull_inside(m, h, p):
    """Paper path: OBB rejection, point location in the upper and lower planar meshes, two planes."""
    q0, q1, q2 = _to_local(m, h, p)
    return _inside_paper(m.half, m.face_start, m.planes, m.loc_base, m.loc_x, m.loc_start, m.loc_y, m.loc_face,
                         h, q0, q1, q2)[0]


@njit(cache=True, _nrt=False)
def hull_inside_brute(m, h, p):
    """Inside iff behind (or on) every face plane."""
    q0, q1, q2 = _to_local(m, h, p)
    return _inside_brute(m.planes, m.face_start, h, q0, q1, q2)


@njit(cache=True, _nrt=False, forceinline=True)
def _response_bone(m, h, p, brute):
    q0, q1, q2 = _to_local(m, h, p)
    r0, r1, r2, _ = _response(m.half, m.kind, m.n_theta, m.n_second, m.second_lo, m.second_hi, m.face_start,
                              m.planes, m.cell_base, m.cell_start, m.cell_tris, h, brute, q0, q1, q2)
    return _to_bone(m, h, r0, r1, r2)


@njit(cache=True, _nrt=False)
def hull_response(m, h, p):
    """Paper ray from the map source through p, scanning only p's cell list (see module doc)."""
    return _response_bone(m, h, p, False)


@njit(cache=True, _nrt=False)
def hull_response_brute(m, h, p):
    """The same ray against every face of the hull."""
    return _response_bone(m, h, p, True)


@njit(cache=True, _nrt=False)
def hull_push_nearest_plane(m, h, p):
    """Baseline (NvCloth-style convex response): project p on the plane it penetrates least."""
    q0, q1, q2 = _to_local(m, h, p)
    best, bf = _nearest_plane(m.planes, m.face_start, h, q0, q1, q2)
    pl = m.planes[bf]
    return _to_bone(m, h, q0 - best * pl[0], q1 - best * pl[1], q2 - best * pl[2])


@njit(cache=True, _nrt=False)
def hull_collide(m, h, p, method):
    """(inside, x, y, z): hull_query's response point (bone-local) if p is inside the hull, else p."""
    q0, q1, q2 = _to_local(m, h, p)
    inside, r0, r1, r2, _ = hull_query(m.half, m.kind, m.n_theta, m.n_second, m.second_lo, m.second_hi,
                                       m.face_start, m.planes, m.cell_base, m.cell_start, m.cell_tris, m.loc_base,
                                       m.loc_x, m.loc_start, m.loc_y, m.loc_face, h, method, q0, q1, q2)
    if not inside:
        return False, p[0], p[1], p[2]
    x, y, z = _to_bone(m, h, r0, r1, r2)
    return True, x, y, z


# -- vectorised wrappers ----------------------------------------------------------------------------
@njit(cache=True, _nrt=False)
def _inside_many(m, h, pts, method, out):
    for i in range(pts.shape[0]):
        if method == METHOD_PAPER:
            out[i] = hull_inside(m, h, pts[i])
        else:
            out[i] = hull_inside_brute(m, h, pts[i])


@njit(cache=True, _nrt=False)
def _response_many(m, h, pts, method, out):
    for i in range(pts.shape[0]):
        if method == METHOD_PAPER:
            r = hull_response(m, h, pts[i])
        elif method == METHOD_BRUTE:
            r = hull_response_brute(m, h, pts[i])
        else:
            r = hull_push_nearest_plane(m, h, pts[i])
        out[i, 0] = r[0]
        out[i, 1] = r[1]
        out[i, 2] = r[2]


@njit(cache=True, _nrt=False)
def _collide_many(m, h, pts, method, hit, out):
    for i in range(pts.shape[0]):
        ins, x, y, z = hull_collide(m, h, pts[i], method)
        hit[i] = ins
        out[i, 0] = x
        out[i, 1] = y
        out[i, 2] = z


def _arrays(maps):
    if isinstance(maps, HullMap):
        maps = MapSet.from_maps((maps,))
    return maps.arrays


def _points(pts) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(pts, dtype=np.float64).reshape(-1, 3))


def inside_points(maps, pts, h: int = 0, method: int = METHOD_PAPER) -> np.ndarray:
    """(N,) bool: which bone-local points are inside hull h. `maps`: MapSet or a single HullMap."""
    pts = _points(pts)
    out = np.empty(pts.shape[0], dtype=np.bool_)
    _inside_many(_arrays(maps), h, pts, method, out)
    return out


def response_points(maps, pts, h: int = 0, method: int = METHOD_PAPER) -> np.ndarray:
    """(N, 3) response points (bone-local) of hull h; method 2 = the nearest-plane push."""
    pts = _points(pts)
    out = np.empty_like(pts)
    _response_many(_arrays(maps), h, pts, method, out)
    return out


def collide_points(maps, pts, h: int = 0, method: int = METHOD_PAPER):
    """((N,) bool inside, (N, 3) resolved points): hull_collide on every point."""
    pts = _points(pts)
    hit = np.empty(pts.shape[0], dtype=np.bool_)
    out = np.empty_like(pts)
    _collide_many(_arrays(maps), h, pts, method, hit, out)
    return hit, out
