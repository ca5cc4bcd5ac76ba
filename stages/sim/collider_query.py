"""The inside test and response of one collider at a point, in its query frame: spheres (paper A
eq. 5-6) and hulls (the maps' query, stages.maps.kernels.hull_query, inlined). Shared by the collision
response (stages.sim.body_collide) and the escape from overlapping colliders (stages.sim.body_escape).
"""
from __future__ import annotations

import math

from numba import njit

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)
from stages.maps.kernels import METHOD_NEAREST_PLANE, hull_query
from stages.sim.collider_grid import KIND_SPHERE, apply12

# the hull query is inlined from stages.maps.kernels: its edits must invalidate this module's cache
NUMBA_CACHE_DEPENDS = ("stages.maps.kernels", "stages.maps.types", "stages.affine", "stages.sim.collider_grid")

TOUCH_EPS = 1e-9     # m: a response moving a particle less than this is a touch, not a penetration
IGNORED = -2147483648   # contact[i, c]: collider c never pushes particle i (its garment ignores c's joint)


# -- collider queries -----------------------------------------------------------------------------
# Hulls: stages.maps.kernels.hull_query over the MapArrays fields as plain arrays (unpacked once per
# kernel with query_arrays: a named tuple reached inside the loop would cost reference counting per
# query); the sphere test and the OBB rejection are written out in collide's loop, and only points
# inside an OBB reach the hull query.
@njit(cache=True, _nrt=False, forceinline=True)
def _sphere_hit(rad, q0, q1, q2):
    """(hit, r0, r1, r2, n0, n1, n2) of a sphere of radius rad at the origin of the query frame:
    paper eq. 5 (inside iff |q| < r) and eq. 6 (response r q / |q|), outward normal q / |q|."""
    d2 = q0 * q0 + q1 * q1 + q2 * q2
    if d2 >= rad * rad:
        return False, q0, q1, q2, 0.0, 0.0, 0.0
    d = math.sqrt(d2)
    if d < 1e-12:                     # at the centre: no direction, push up (deterministic)
        return True, 0.0, rad, 0.0, 0.0, 1.0, 0.0
    f = rad / d
    return True, f * q0, f * q1, f * q2, q0 / d, q1 / d, q2 / d


@njit(cache=True, _nrt=False)
def _collider_hit(c, col_kind, col_index, sph_radius, method,
                  half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes, cell_base,
                  cell_start, cell_tris, loc_base, loc_x, loc_start, loc_y, loc_face,
                  q0, q1, q2):
    """(hit, r0, r1, r2, n0, n1, n2): inside test, response point and outward unit contact normal
    of collider c, all in its query frame (the slow-path form of the test written out in collide)."""
    idx = col_index[c]
    if col_kind[c] == KIND_SPHERE:
        return _sphere_hit(sph_radius[idx], q0, q1, q2)
    if method != METHOD_NEAREST_PLANE and (abs(q0) > half[idx, 0] or abs(q1) > half[idx, 1] or abs(q2) > half[idx, 2]):
        return False, q0, q1, q2, 0.0, 0.0, 0.0
    hit, r0, r1, r2, face = hull_query(
        half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes, cell_base,
        cell_start, cell_tris, loc_base, loc_x, loc_start, loc_y, loc_face,
        idx, method, q0, q1, q2)
    if not hit:
        return False, q0, q1, q2, 0.0, 0.0, 0.0
    return True, r0, r1, r2, planes[face, 0], planes[face, 1], planes[face, 2]


@njit(cache=True, _nrt=False, forceinline=True)
def _penetrates(c, col_kind, col_index, sph_radius, method, tq, cw,
                half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes, cell_base,
                cell_start, cell_tris, loc_base, loc_x, loc_start, loc_y, loc_face,
                px, py, pz):
    """True if the world point is inside collider c with a real push (world sphere test first)."""
    dx = px - cw[c, 0]
    dy = py - cw[c, 1]
    dz = pz - cw[c, 2]
    if dx * dx + dy * dy + dz * dz >= cw[c, 4]:
        return False
    q0, q1, q2 = apply12(tq, c, px, py, pz)
    hit, r0, r1, r2, n0, n1, n2 = _collider_hit(
        c, col_kind, col_index, sph_radius, method,
        half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes, cell_base,
        cell_start, cell_tris, loc_base, loc_x, loc_start, loc_y, loc_face, q0, q1, q2)
    return hit and (r0 - q0) ** 2 + (r1 - q1) ** 2 + (r2 - q2) ** 2 >= TOUCH_EPS * TOUCH_EPS


@njit(cache=True, _nrt=False)
def _inside_any(col_kind, col_index, sph_radius, method, tq, cw, contact, i,
                half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes, cell_base,
                cell_start, cell_tris, loc_base, loc_x, loc_start, loc_y, loc_face,
                px, py, pz):
    """True if the world point is inside any collider particle i does not ignore (contact[i, c] !=
    IGNORED), with a real push."""
    for c in range(cw.shape[0]):
        if contact[i, c] != IGNORED and _penetrates(c, col_kind, col_index, sph_radius, method, tq, cw,
                                     half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes,
                                     cell_base, cell_start, cell_tris, loc_base, loc_x, loc_start, loc_y, loc_face,
                                     px, py, pz):
            return True
    return False
