"""Hull stage: Qhull wrapper, degenerate-input policy, inflation (stages/hulls/hull.py)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from stages.checks import ContractError
from stages.errors import InputError
from stages.hulls.hull import convex_hull, face_normals, inflate_hull, mesh_volume
from stages.hulls.types import ConvexMesh


def cloud(seed: int, n: int, kind: str) -> np.ndarray:
    rng = np.random.default_rng(seed)
    if kind == "gauss":
        return rng.normal(size=(n, 3)) * rng.uniform(0.02, 0.3, size=3)
    if kind == "sphere":
        p = rng.normal(size=(n, 3))
        return 0.1 * p / np.linalg.norm(p, axis=1, keepdims=True)
    if kind == "grid":  # many coplanar / collinear points on the box faces
        g = np.linspace(-0.1, 0.1, 4)
        return np.stack(np.meshgrid(g, g * 0.5, g * 2), axis=-1).reshape(-1, 3)
    return rng.uniform(-0.1, 0.1, size=(n, 3))


def assert_is_hull_of(mesh: ConvexMesh, points: np.ndarray):
    diag = np.linalg.norm(np.ptp(points, axis=0))
    pl = mesh.planes
    assert np.isfinite(pl).all()
    # every input point behind every face plane (convex + contains them), outward orientation
    assert (points @ pl[:, :3].T - pl[:, 3]).max() <= 1e-12 * diag
    assert mesh_volume(mesh) > 0
    # hull vertices are input points (brute force nearest), each one used by a face
    d = np.linalg.norm(mesh.vertices[:, None] - points[None], axis=2).min(axis=1)
    assert d.max() == 0
    assert np.array_equal(np.unique(mesh.faces), np.arange(mesh.vertices.shape[0]))
    # closed 2-manifold: every directed edge once, and its reverse once
    e = np.concatenate([mesh.faces[:, [0, 1]], mesh.faces[:, [1, 2]], mesh.faces[:, [2, 0]]])
    assert len({tuple(x) for x in e}) == len(e)
    assert {tuple(x) for x in e} == {(b, a) for a, b in e}


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.integers(4, 200), st.sampled_from(["gauss", "sphere", "uniform", "grid"]))
def test_hull_is_the_convex_hull(seed, n, kind):
    pts = cloud(seed, n, kind)
    mesh = convex_hull(pts)
    assert_is_hull_of(mesh, pts)
    _, area2 = face_normals(mesh.vertices, mesh.faces)
    assert area2.min() > 0


def test_cube_volume_and_faces():
    g = np.array([[x, y, z] for x in (0, 1) for y in (0, 2) for z in (0, 3)], dtype=float)
    mesh = convex_hull(g)
    assert mesh.faces.shape[0] == 12
    assert mesh_volume(mesh) == pytest.approx(6.0)


@pytest.mark.parametrize("points, problem", [
    (np.zeros((3, 3)), "distinct"),
    (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]] * 5, dtype=float), "distinct"),          # duplicates
    (np.outer(np.arange(10.0), [1, 2, 3]), "collinear"),
    (np.c_[np.random.default_rng(1).uniform(size=(20, 2)), np.zeros(20)], "coplanar"),
    (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, np.nan]]), "non-finite"),
    (np.zeros((5, 2)), "shape"),
    ([["a", "b", "c"]] * 4, "numeric"),
])
def test_degenerate_input_is_a_clear_error(points, problem):
    with pytest.raises(InputError) as err:
        convex_hull(points, source="bone 'x'")
    assert problem in str(err.value) and "bone 'x'" in str(err.value)


def test_coplanar_slab_fallback():
    rng = np.random.default_rng(2)
    flat = np.c_[rng.uniform(size=(30, 2)), np.full(30, 0.5)]
    mesh = convex_hull(flat, flat_thickness=0.01)
    assert_is_hull_of(mesh, np.concatenate([flat + [0, 0, 0.01], flat - [0, 0, 0.01]]))
    assert np.ptp(mesh.vertices[:, 2]) == pytest.approx(0.02)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.integers(4, 120), st.sampled_from(["gauss", "sphere", "uniform", "grid"]),
       st.sampled_from([0.001, 0.005, 0.02]))
def test_inflation_moves_every_face_plane_out_by_delta(seed, n, kind, delta):
    pts = cloud(seed, n, kind)
    raw = convex_hull(pts)
    inflated = inflate_hull(raw, delta)
    pl = raw.planes
    # support of the inflated hull along each raw face normal reaches the raw plane + delta
    support = (inflated.vertices @ pl[:, :3].T).max(axis=0)
    assert (support - pl[:, 3] >= delta * (1 - 1e-9)).all()
    # and it contains the raw hull (hence the points)
    ipl = inflated.planes
    assert (pts @ ipl[:, :3].T - ipl[:, 3]).max() <= 1e-12
    # bounded: no vertex moved more than 1 / SHARP_DOT times delta
    d = np.linalg.norm(inflated.vertices[:, None] - raw.vertices[None], axis=2).min(axis=1)
    assert d.max() <= 4 * delta * (1 + 1e-9)


def test_inflated_cube_is_the_offset_cube():
    g = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
    inflated = inflate_hull(convex_hull(g), 0.1)
    assert mesh_volume(inflated) == pytest.approx(1.2 ** 3)


def test_inflation_of_a_needle_stays_bounded():
    # a very sharp tip: the scaled offset would be huge; the bevel keeps it at delta per face
    pts = np.array([[0, 0, 0], [0.01, 0, 0], [0, 0.01, 0], [0.003, 0.003, 1.0]])
    raw = convex_hull(pts)
    inflated = inflate_hull(raw, 0.01)
    assert np.abs(inflated.vertices[:, 2]).max() < 1.0 + 0.04
    pl = raw.planes
    assert ((inflated.vertices @ pl[:, :3].T).max(axis=0) - pl[:, 3] >= 0.01 * (1 - 1e-9)).all()


def test_inflate_rejects_negative_delta_and_zero_is_identity():
    mesh = convex_hull(cloud(0, 30, "gauss"))
    assert inflate_hull(mesh, 0.0) is mesh
    with pytest.raises(ContractError):
        inflate_hull(mesh, -0.1)
