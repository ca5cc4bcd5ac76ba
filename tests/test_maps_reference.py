"""Independent numpy references for the map tests (brute force over every face), the test hulls,
and checks of the references themselves on hand-computed cases."""
from __future__ import annotations

import numpy as np
import trimesh

from stages.hulls.hull import convex_hull
from stages.hulls.types import ConvexMesh

BARY_TOL = 1e-10


def hull_of(points, rng=None, rotate=True, offset=(0.0, 0.0, 0.0)) -> ConvexMesh:
    p = np.asarray(points, float)
    if rotate:
        rng = rng or np.random.default_rng(0)
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        p = p @ q.T
    return convex_hull(p + np.asarray(offset))


def ellipsoid_hull(seed: int, radii, n: int = 60) -> ConvexMesh:
    """n points on an ellipsoid surface (all extreme: 2n - 4 faces), rotated and shifted."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return hull_of(d * radii, rng, offset=rng.normal(size=3) * 0.3)


def sample_hulls() -> dict:
    """Named test hulls: random ellipsoids (round, elongated, 116 faces), trimesh primitives, and a
    sheared box whose long axis leaves the hull through its slanted ends before the OBB ends."""
    rng = np.random.default_rng(7)
    box = trimesh.creation.box(extents=(2.0, 0.4, 0.4)).vertices
    sheared = box + np.outer(box[:, 1], [2.5, 0, 0])
    return {
        "round": ellipsoid_hull(1, (0.12, 0.1, 0.09), 40),
        "elongated116": ellipsoid_hull(2, (0.3, 0.1, 0.08), 60),
        "flatish": ellipsoid_hull(3, (0.2, 0.15, 0.04), 80),
        "box": hull_of(trimesh.creation.box(extents=(0.3, 0.2, 0.1)).vertices, rng),
        "cylinder": hull_of(trimesh.creation.cylinder(radius=0.05, height=0.3, sections=16).vertices, rng),
        "capsule": hull_of(trimesh.creation.capsule(radius=0.04, height=0.2, count=[8, 8]).vertices, rng),
        "icosphere": hull_of(trimesh.creation.icosphere(subdivisions=1, radius=0.1).vertices, rng),
        "sheared": hull_of(sheared * 0.1, rng),
    }


def signed_distance(planes: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Max over faces of n.p - d: <= 0 inside (brute-force half-spaces)."""
    return (pts @ planes[:, :3].T - planes[:, 3]).max(axis=1)


def map_rays(hm, pts):
    """(sources, unit directions, |p - s|) of the map rays through bone-local points."""
    q = hm.to_local(pts)
    s = np.zeros_like(q)
    if hm.kind == "cylinder":
        s[:, 0] = q[:, 0]
    d = q - s
    n = np.linalg.norm(d, axis=1)
    return hm.to_bone(s), (d / n[:, None]) @ hm.axes, n


def ray_hits(mesh: ConvexMesh, src, dirs, tol=BARY_TOL):
    """Moller-Trumbore of every ray against every face: (t (N, m), hit (N, m)) with barycentric tolerance."""
    a, b, c = (mesh.vertices[mesh.faces[:, i]] for i in range(3))
    e1, e2 = b - a, c - a
    pv = np.cross(dirs[:, None, :], e2[None])
    det = np.einsum("fk,nfk->nf", e1, pv)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / det
        tv = src[:, None, :] - a[None]
        u = np.einsum("nfk,nfk->nf", tv, pv) * inv
        qv = np.cross(tv, e1[None])
        v = np.einsum("nk,nfk->nf", dirs, qv) * inv
        t = np.einsum("fk,nfk->nf", e2, qv) * inv
        hit = (np.abs(det) > 1e-300) & (u >= -tol) & (v >= -tol) & (u + v <= 1 + tol)
    return t, hit


def ray_exit_reference(mesh: ConvexMesh, src, dirs, start, chunk: int = 4000):
    """Nearest hit at or beyond p (t >= |p - s| - tiny) of the ray against every face."""
    out = np.full((src.shape[0], 3), np.nan)
    for i in range(0, src.shape[0], chunk):
        sl = slice(i, i + chunk)
        t, hit = ray_hits(mesh, src[sl], dirs[sl])
        t = np.where(hit & (t >= start[sl, None] * (1 - 1e-12) - 1e-15), t, np.inf)
        tm = t.min(axis=1)
        out[sl] = src[sl] + tm[:, None] * dirs[sl]
    return out


def nearest_plane_reference(planes, pts):
    sd = pts @ planes[:, :3].T - planes[:, 3]
    f = np.argmax(sd, axis=1)
    return pts - sd[np.arange(len(pts)), f][:, None] * planes[f, :3]


# -- the references on hand-computed cases --------------------------------------------------------
def unit_cube() -> ConvexMesh:
    return hull_of(trimesh.creation.box(extents=(2.0, 2.0, 2.0)).vertices, rotate=False)


def test_reference_ray_exit_on_a_cube():
    cube = unit_cube()
    src = np.zeros((3, 3))
    dirs = np.array([[1.0, 0, 0], [0, 0, -1.0], [1.0, 1.0, 0]])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    got = ray_exit_reference(cube, src, dirs, np.zeros(3))
    np.testing.assert_allclose(got, [[1, 0, 0], [0, 0, -1], [1, 1, 0]], atol=1e-15)


def test_reference_exit_beyond_p_from_an_outside_source():
    cube = unit_cube()
    # source outside at x = -3: the ray enters at x = -1 and leaves at x = +1; p at x = 0 (start 3)
    got = ray_exit_reference(cube, np.array([[-3.0, 0.2, 0.1]]), np.array([[1.0, 0, 0]]), np.array([3.0]))
    np.testing.assert_allclose(got, [[1.0, 0.2, 0.1]], atol=1e-15)


def test_reference_signed_distance_and_nearest_plane():
    cube = unit_cube()
    p = np.array([[0.5, 0.2, 0.0], [2.0, 0.0, 0.0]])
    np.testing.assert_allclose(signed_distance(cube.planes, p), [-0.5, 1.0], atol=1e-15)
    np.testing.assert_allclose(nearest_plane_reference(cube.planes, p[:1]), [[1.0, 0.2, 0.0]], atol=1e-15)


def test_test_hulls_are_valid():
    for name, m in sample_hulls().items():
        sd = signed_distance(m.planes, m.vertices)
        assert sd.max() < 1e-12, name
    assert sample_hulls()["elongated116"].faces.shape[0] == 116
