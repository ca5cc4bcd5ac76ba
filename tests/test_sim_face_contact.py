"""The colliders against the cloth's triangles (stages.sim.face_collide, SimParams.face_contact): the
kernel against a plain-Python reference on spheres, and a thin rod swept through a coarse sheet
between its particles, which the particle collision alone lets through."""
import numpy as np
from hypothesis import given, settings, strategies as st

from stages.garments.simple import rectangle_cloth
from stages.garments.types import build_garment
from stages.hulls.types import ColliderSet, SphereCollider
from stages.maps.build import build_maps
from stages.sim import SimParams, simulate
from stages.sim.body_escape import PUSH_EPS
from stages.sim.collider_grid import build_grid
from stages.sim.collider_query import IGNORED
from stages.sim.face_collide import N_SAMPLES, collide_faces
from stages.sim.scenes import convex_mesh, hull_set, toy_character, toy_motion
from tests.test_sim_kernels import _collider_arrays

WEIGHTS = np.array([[1 / 3, 1 / 3, 1 / 3], [0.5, 0.5, 0.0], [0.0, 0.5, 0.5], [0.5, 0.0, 0.5]])


def _faces_ref(x, xp, inv_mass, tris, centres, radii, contact):
    """Plain reference of collide_faces for spheres on one static pose (start-of-step frame = now):
    triangles in order, samples in order; a sample inside exactly one sphere it is not ignored by,
    that was outside it at the step's start (from xp as the pass has left it) and whose push does not land in another sphere,
    moves the corners by d w_k m_k^-1 / sum w_j^2 m_j^-1 (d: out along the radius, PUSH_EPS beyond);
    xp moves along d by the corner's outward travel (inelastic). Returns (x, xp, pushes)."""
    x, xp = x.copy(), xp.copy()
    pushes = 0

    def inside(p, c):
        return np.linalg.norm(p - centres[c]) < radii[c] - 1e-9

    for t, (a, b, c3) in enumerate(tris):
        corners = (a, b, c3)
        for w in WEIGHTS:
            den = sum(w[k] ** 2 * inv_mass[v] for k, v in enumerate(corners))
            if den <= 0.0:
                continue
            s = sum(w[k] * x[v] for k, v in enumerate(corners))
            ok = [c for c in range(len(radii)) if all(contact[v, c] != IGNORED for v in corners)]
            holding = [c for c in ok if inside(s, c)]
            if len(holding) != 1:
                continue
            c = holding[0]
            o = sum(w[k] * xp[v] for k, v in enumerate(corners))
            if inside(o, c):
                continue
            u = s - centres[c]
            target = centres[c] + u / np.linalg.norm(u) * (radii[c] + PUSH_EPS)
            if any(inside(target, h) for h in range(len(radii)) if h != c and contact[a, h] != IGNORED):
                continue
            d = target - s
            dn = d / np.linalg.norm(d)
            for k, v in enumerate(corners):
                f = w[k] * inv_mass[v] / den
                if f <= 0.0:
                    continue
                new = x[v] + f * d
                vn = (new - xp[v]) @ dn
                if vn > 0.0:
                    xp[v] += vn * dn
                x[v] = new
            pushes += 1
    return x, xp, pushes


def _spheres(centres, radii):
    return ColliderSet(hulls=(), spheres=tuple(SphereCollider(j, f"s{j}", np.asarray(c, float), float(r),
                                                              np.zeros((0, 3)))
                                             for j, (c, r) in enumerate(zip(centres, radii))),
                       delta=0.0, min_triangles=4)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 100_000), st.integers(1, 3))
def test_collide_faces_matches_the_plain_reference_on_spheres(seed, n_spheres):
    """Random triangles among one to three spheres (some overlapping, some ignored by some particles,
    some particles pinned): the kernel's positions, previous positions and push count equal the
    reference's."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-0.2, 0.2, (n_spheres, 3))
    radii = rng.uniform(0.08, 0.2, n_spheres)
    n = 60
    start = rng.uniform(-0.4, 0.4, (n, 3))             # the step's start (xp), then moved a little
    x = start + rng.normal(0.0, 0.03, (n, 3))
    tris = np.array([rng.choice(n, 3, replace=False) for _ in range(50)], np.int32)
    inv_mass = np.where(rng.random(n) < 0.1, 0.0, rng.uniform(0.5, 2.0, n))
    contact = np.where(rng.random((n, n_spheres)) < 0.1, IGNORED, -1).astype(np.int32)
    col = _collider_arrays(_spheres(centres, radii), None, np.tile(np.eye(4), (n_spheres, 1, 1)))
    build_grid(col.m, 0, col.kind, col.index, col.sph_radius, col.tq, col.fq, col.cw, col.grid_start,
               col.grid_items, col.grid_runs, col.grid_box, col.grid_dims)
    xk, xpk, corr = x.copy(), start.copy(), np.zeros(n, np.uint8)
    pushes = collide_faces(xk, xpk, inv_mass, tris, col.m, 0, col.kind, col.index, col.sph_radius, col.tq, col.tq0,
                           col.fq, col.cw, col.grid_start, col.grid_items, col.grid_box, col.grid_dims, contact, corr)
    xr, xpr, pr = _faces_ref(x, start, inv_mass, tris, centres, radii, contact)
    assert pushes == pr
    np.testing.assert_allclose(xk, xr, atol=1e-12)
    np.testing.assert_allclose(xpk, xpr, atol=1e-12)
    moved = np.any(xk != x, axis=1)
    assert np.array_equal(corr.astype(bool), moved) and not moved[inv_mass == 0].any()


def test_a_pushed_sample_lands_on_the_sphere():
    """One triangle whose centre alone is inside a sphere (its corners around it, outside): the push
    moves all three corners by the centre's depth, so the centre lands PUSH_EPS outside (by hand)."""
    col = _collider_arrays(_spheres([[0.0, 0.0, 0.0]], [0.1]), None, np.eye(4)[None])
    build_grid(col.m, 0, col.kind, col.index, col.sph_radius, col.tq, col.fq, col.cw, col.grid_start,
               col.grid_items, col.grid_runs, col.grid_box, col.grid_dims)
    ang = np.array([0.0, 2.0, 4.0]) * np.pi / 3
    x = np.column_stack([0.2 * np.cos(ang), np.full(3, 0.09), 0.2 * np.sin(ang)])   # centre (0, 0.09, 0)
    start = x + [0.0, 0.05, 0.0]                                                      # it came from above
    xk, xpk, corr = x.copy(), start.copy(), np.zeros(3, np.uint8)
    pushes = collide_faces(xk, xpk, np.ones(3), np.array([[0, 1, 2]], np.int32), col.m, 0, col.kind, col.index,
                           col.sph_radius, col.tq, col.tq0, col.fq, col.cw, col.grid_start, col.grid_items,
                           col.grid_box, col.grid_dims, np.full((3, 1), -1, np.int32), corr)
    assert pushes == 1 and N_SAMPLES == 4      # the edge midpoints (0.1 from the axis, 0.09 up) are outside
    np.testing.assert_allclose(xk - x, [[0.0, 0.01 + PUSH_EPS, 0.0]] * 3, atol=1e-12)
    np.testing.assert_allclose(xk.mean(axis=0), [0.0, 0.1 + PUSH_EPS, 0.0], atol=1e-12)


def _rod_sweep(face_contact: bool, half_thickness: float):
    """A 60 cm rod (a box hull, square section 2 * half_thickness) lifted 12 cm (accelerating from rest)
    into a free 40 x 40 cm sheet of 10 x 10 particles 4.4 cm apart, lying across the rod between two
    rows of particles; no gravity, world-space inertia: the sheet stays where it is until something
    pushes it. Returns the sheet's last frame (world) and the rod's lift."""
    h = half_thickness
    box = np.array([[sx * 0.3, sy * h, sz * h] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    mesh = convex_mesh(box)
    cs = hull_set(mesh)
    x, tri = rectangle_cloth(0.4, 0.4, 10, 10, center=(0.0, 0.03, 0.0))
    nf = 30
    lift = np.zeros((nf, 3))
    lift[:, 1] = 0.12 * np.linspace(0.0, 1.0, nf) ** 2
    r = simulate(toy_character(mesh.vertices, mesh.faces), toy_motion(nf, root_translation=lift), cs,
                 build_maps(cs), [build_garment("sheet", x, tri)],
                 SimParams(friction=1.0, face_contact=face_contact, gravity=(0.0, 0.0, 0.0), inertia_scale=1.0))
    return r.garments[0].positions[-1].astype(np.float64), tri, lift[-1, 1]


def _crossings_up(p, tri, origin):
    """How many sheet triangles the ray from origin straight up (+y) passes through (Moller-Trumbore)."""
    n = 0
    d = np.array([0.0, 1.0, 0.0])
    for a, b, c in p[tri]:
        e1, e2 = b - a, c - a
        pv = np.cross(d, e2)
        det = e1 @ pv
        if abs(det) < 1e-15:
            continue
        tv = origin - a
        u = (tv @ pv) / det
        qv = np.cross(tv, e1)
        v = (d @ qv) / det
        n += (u >= 0) and (v >= 0) and (u + v <= 1) and ((e2 @ qv) / det > 0)
    return n


def test_a_thin_rod_swept_between_the_particles_carries_the_sheet():
    """The rod (1 cm and 1.6 cm thick) is thinner than the 4.4 cm between the sheet's rows: the
    particles alone let it through (the sheet ends below its bottom: a ray up from there meets no
    cloth); with face contact the sheet ends on it (the ray meets the sheet once at three places
    along the rod)."""
    for h in (0.005, 0.008):
        for faces, want in ((False, 0), (True, 1)):
            p, tri, top = _rod_sweep(faces, h)
            got = [_crossings_up(p, tri, np.array([px, top - h, 0.0])) for px in (-0.1, 0.0, 0.1)]
            assert got == [want] * 3, (h, faces, got)
