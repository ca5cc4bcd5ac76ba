"""The colliders against the cloth's triangles, not only its particles (issue 38: limbs through cloth).

The particle collision (stages.sim.body_collide) keeps every particle outside the colliders, but a
triangle between particles can still cut a limb: cloth stretched across a forearm (on cesium_skirt at
frame 48 the crossed triangles' edges were 5.2 cm long against 2.5 cm at rest, their corners on the
colliders' surface ~1 cm off the skin, the skin 0.3 cm past the triangle), or a limb thinner than a
triangle passing between its corners. Here each triangle is sampled at its centre and its edges'
midpoints; a sample inside a collider moves the triangle's corners (the edge's two for an edge
midpoint) by the collider's push of the sample (the map's response, as the particles get), weighted by
their inverse masses so that the sample lands on the push's point (x_k += d w_k m_k^-1 / sum_j w_j^2
m_j^-1, w the sample's weights), inelastic along the push (body_escape._settle). Only a new contact
with one collider is pushed: a sample that was inside that collider at the step's start is a limb
through the triangle (pushing it out sideways hooks the cloth on the limb), and one inside two
colliders, or that the push would put into another, is in a pinch (SimParams.pinch decides there).
One serial pass over the triangles (they share corners: a fixed order gives the same result on every
run) after the particle collision of each step (three passes measured the same on the shipped scenes,
for three times the cost).
"""
from __future__ import annotations

from numba import njit

import stages.jit  # noqa: F401  (numba cache stamps follow NUMBA_CACHE_DEPENDS)
from stages.maps.kernels import query_arrays
from stages.sim.body_escape import PUSH_EPS, _settle
from stages.sim.collider_grid import apply12, grid_cell
from stages.sim.collider_query import IGNORED, TOUCH_EPS, _collider_hit, _penetrates

NUMBA_CACHE_DEPENDS = ("stages.maps.kernels", "stages.maps.types", "stages.affine", "stages.sim.collider_grid",
                       "stages.sim.collider_query", "stages.sim.body_escape")

N_SAMPLES = 4       # per triangle: its centre, then the midpoints of its edges (a, b), (b, c), (c, a)


@njit(cache=True, _nrt=False, forceinline=True)
def sample_weights(k):
    """(wa, wb, wc): barycentric weights of a triangle's sample k (see N_SAMPLES)."""
    if k == 0:
        return 1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0
    if k == 1:
        return 0.5, 0.5, 0.0
    if k == 2:
        return 0.0, 0.5, 0.5
    return 0.5, 0.0, 0.5


@njit(cache=True, _nrt=False)
def collide_faces(x, xp, inv_mass, tris, m, method, col_kind, col_index, sph_radius, tq, tq0, fq, cw,
                  grid_start, grid_items, grid_box, grid_dims, contact, corrected):
    """Push every triangle whose samples lie inside a collider out of it (module docstring).

    x, xp (N, 3) current / previous positions (relative frame), moved in place; tris (T, 3) int32;
    the collider arrays as stages.sim.body_collide.collide's; contact[i, c] == IGNORED: particle i's
    garment ignores collider c (a triangle is pushed by c only if none of its corners ignores it).
    tq0: the colliders' query frames at the step's start (a sample's start point, from xp as the pass
    has left it, is tested there). Per sample, the colliders of its grid cell are tested; a sample held
    by exactly one is pushed as the module docstring says. corrected[i] |= 1 for every particle moved.
    Returns the number of pushes."""
    (half, mkind, n_theta, n_second, second_lo, second_hi, face_start, planes, cell_base, cell_start, cell_tris,
     loc_base, loc_x, loc_start, loc_y, loc_face) = query_arrays(m)
    pushes = 0
    for t in range(tris.shape[0]):
        a = tris[t, 0]
        b = tris[t, 1]
        c3 = tris[t, 2]
        if inv_mass[a] <= 0.0 and inv_mass[b] <= 0.0 and inv_mass[c3] <= 0.0:
            continue
        for k in range(N_SAMPLES):
            wa, wb, wc = sample_weights(k)
            den = wa * wa * inv_mass[a] + wb * wb * inv_mass[b] + wc * wc * inv_mass[c3]
            if den <= 0.0:
                continue
            sx = wa * x[a, 0] + wb * x[b, 0] + wc * x[c3, 0]
            sy = wa * x[a, 1] + wb * x[b, 1] + wc * x[c3, 1]
            sz = wa * x[a, 2] + wb * x[b, 2] + wc * x[c3, 2]
            # the one collider holding the sample (none, or several: a pinch, left to the particles)
            bb = grid_cell(grid_box, grid_dims, sx, sy, sz)
            if bb < 0:
                continue
            held = -1
            for j in range(grid_start[bb], grid_start[bb + 1]):
                c = grid_items[j]
                if contact[a, c] == IGNORED or contact[b, c] == IGNORED or contact[c3, c] == IGNORED:
                    continue
                if _penetrates(c, col_kind, col_index, sph_radius, method, tq, cw, half, mkind, n_theta, n_second,
                               second_lo, second_hi, face_start, planes, cell_base, cell_start, cell_tris, loc_base,
                               loc_x, loc_start, loc_y, loc_face, sx, sy, sz):
                    held = c if held == -1 else -2
            if held < 0:
                continue
            c = held
            q0, q1, q2 = apply12(tq, c, sx, sy, sz)
            hit, r0, r1, r2, n0, n1, n2 = _collider_hit(
                c, col_kind, col_index, sph_radius, method, half, mkind, n_theta, n_second, second_lo,
                second_hi, face_start, planes, cell_base, cell_start, cell_tris, loc_base, loc_x, loc_start,
                loc_y, loc_face, q0, q1, q2)
            if not hit:
                continue
            u0 = r0 - q0
            u1 = r1 - q1
            u2 = r2 - q2
            un = (u0 * u0 + u1 * u1 + u2 * u2) ** 0.5
            if un < TOUCH_EPS:
                continue
            e = 1.0 + PUSH_EPS / un        # strictly outside, as the particles' push
            wx, wy, wz = apply12(fq, c, q0 + e * u0, q1 + e * u1, q2 + e * u2)
            # new contacts only: a sample that was inside c already at the start of the step (its
            # start point, from xp, in c's frame then) is a limb through the triangle, not cloth lying
            # on it: pushing it out would hook the triangle on the limb
            ox = wa * xp[a, 0] + wb * xp[b, 0] + wc * xp[c3, 0]
            oy = wa * xp[a, 1] + wb * xp[b, 1] + wc * xp[c3, 1]
            oz = wa * xp[a, 2] + wb * xp[b, 2] + wc * xp[c3, 2]
            o0, o1, o2 = apply12(tq0, c, ox, oy, oz)
            was, s0, s1, s2, m0, m1, m2 = _collider_hit(
                c, col_kind, col_index, sph_radius, method, half, mkind, n_theta, n_second, second_lo,
                second_hi, face_start, planes, cell_base, cell_start, cell_tris, loc_base, loc_x, loc_start,
                loc_y, loc_face, o0, o1, o2)
            if was and (s0 - o0) ** 2 + (s1 - o1) ** 2 + (s2 - o2) ** 2 >= TOUCH_EPS * TOUCH_EPS:
                continue
            # not into another collider (a pinch: the particles' rule decides)
            bb = grid_cell(grid_box, grid_dims, wx, wy, wz)
            into = False
            if bb >= 0:         # outside the grid: outside every collider
                for j in range(grid_start[bb], grid_start[bb + 1]):
                    h = grid_items[j]
                    if h != c and contact[a, h] != IGNORED and _penetrates(
                            h, col_kind, col_index, sph_radius, method, tq, cw, half, mkind, n_theta, n_second,
                            second_lo, second_hi, face_start, planes, cell_base, cell_start, cell_tris, loc_base,
                            loc_x, loc_start, loc_y, loc_face, wx, wy, wz):
                        into = True
                        break
            if into:
                continue
            ddx = wx - sx
            ddy = wy - sy
            ddz = wz - sz
            for v, w in ((a, wa), (b, wb), (c3, wc)):
                f = w * inv_mass[v] / den
                if f <= 0.0:
                    continue
                px = x[v, 0]
                py = x[v, 1]
                pz = x[v, 2]
                nx = px + f * ddx
                ny = py + f * ddy
                nz = pz + f * ddz
                _settle(xp, v, px, py, pz, nx, ny, nz)
                x[v, 0] = nx
                x[v, 1] = ny
                x[v, 2] = nz
                corrected[v] |= 1
            pushes += 1
    return pushes
