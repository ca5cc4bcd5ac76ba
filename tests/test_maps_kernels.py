"""Hull queries (numba) against brute force: inside vs every half-space, response vs the ray against
every face, edge cases (source, axis ends, edges / vertices, surface), the nearest-plane baseline."""
from __future__ import annotations

import numpy as np
import pytest

from stages.maps import kernels as K
from stages.maps.build import build_hull_map
from stages.maps.types import MapSet
from tests.test_maps_reference import (map_rays, nearest_plane_reference, ray_exit_reference,
                                       sample_hulls, signed_distance)

N_POINTS = 100_000
SURFACE_TOL = 1e-9
HULLS = sample_hulls()


def _maps():
    out = {}
    for name, mesh in HULLS.items():
        for kind in ("sphere", "cylinder"):
            out[f"{name}-{kind}"] = build_hull_map(mesh, kind=kind)
    return out


MAPS = _maps()


def random_points(hm, n=N_POINTS, seed=0, grow=1.3):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-grow, grow, size=(n, 3)) * hm.half_extents
    return hm.to_bone(q)


def check_against_brute(hm, pts):
    sd = signed_distance(hm.planes, pts)
    clear = np.abs(sd) > SURFACE_TOL
    for method in (K.METHOD_PAPER, K.METHOD_BRUTE):
        ins = K.inside_points(hm, pts, method=method)
        bad = np.nonzero(clear & (ins != (sd <= 0)))[0]
        assert bad.size == 0, f"method {method}: {bad.size} disagreements, e.g. {pts[bad[:3]]}"
    inner = pts[sd < -SURFACE_TOL]
    src, dirs, start = map_rays(hm, inner)
    ref = ray_exit_reference(hm.mesh, src, dirs, start)
    assert np.isfinite(ref).all()
    for method in (K.METHOD_PAPER, K.METHOD_BRUTE):
        got = K.response_points(hm, inner, method=method)
        err = np.abs(got - ref).max()
        assert err <= 1e-9, f"method {method}: response off by {err}"
        assert np.abs(signed_distance(hm.planes, got)).max() <= 1e-12 * 10 + 1e-12
    hit, out = K.collide_points(hm, pts)
    np.testing.assert_array_equal(hit, K.inside_points(hm, pts))
    np.testing.assert_array_equal(out[~hit], pts[~hit])
    return inner.shape[0]


@pytest.mark.parametrize("key", sorted(MAPS))
def test_inside_and_response_agree_with_brute_force(key):
    hm = MAPS[key]
    n_inner = check_against_brute(hm, random_points(hm))
    assert n_inner > 1000


def test_cesium_man_hulls_agree_with_brute_force(assets_dir):
    from stages.hulls.hull import convex_hull, inflate_hull
    from stages.rig.gltf import load_gltf
    from stages.rig.regions import split_regions
    from stages.rig.transforms import transform_points
    ch = load_gltf(assets_dir / "CesiumMan.glb")
    split = split_regions(ch)
    assert split.hull_bones
    for b in split.hull_bones:
        pts = ch.vertices[split.rigid & (split.region_joint == b)]
        mesh = inflate_hull(convex_hull(transform_points(ch.inverse_bind[b], pts)), 0.005)
        hm = build_hull_map(mesh)
        check_against_brute(hm, random_points(hm, n=N_POINTS // 2, seed=b))


def test_mapset_indexes_hulls_independently():
    keys = ["round-sphere", "sheared-cylinder", "box-cylinder"]
    ms = MapSet.from_maps([MAPS[k] for k in keys])
    for h, k in enumerate(keys):
        pts = random_points(MAPS[k], n=5000, seed=h)
        np.testing.assert_array_equal(K.inside_points(ms, pts, h=h), K.inside_points(MAPS[k], pts))
        np.testing.assert_array_equal(K.response_points(ms, pts, h=h), K.response_points(MAPS[k], pts))


def test_point_at_the_ray_source_falls_back_to_nearest_plane():
    for key in ("round-sphere", "elongated116-cylinder", "box-sphere"):
        hm = MAPS[key]
        src = [hm.center, hm.to_bone([0.3 * hm.half_extents[0], 0, 0])] if hm.kind == "cylinder" else [hm.center]
        for p in src:
            p = np.asarray(p, float)
            assert signed_distance(hm.planes, p[None])[0] < 0
            got = np.array(K.response_points(hm, p[None])[0])
            np.testing.assert_allclose(got, nearest_plane_reference(hm.planes, p[None])[0], atol=1e-12)
            assert abs(signed_distance(hm.planes, got[None])[0]) < 1e-12


def test_cylinder_points_beyond_the_ends():
    hm = MAPS["sheared-cylinder"]
    rng = np.random.default_rng(3)
    q = rng.uniform(-1, 1, size=(2000, 3)) * hm.half_extents
    q[:, 0] = np.sign(q[:, 0]) * (hm.half_extents[0] * (1 + 1e-6 + rng.uniform(0, 0.5, 2000)))
    pts = hm.to_bone(q)
    hit, out = K.collide_points(hm, pts)
    assert not hit.any()
    np.testing.assert_array_equal(out, pts)
    assert np.isfinite(K.response_points(hm, pts)).all()


def test_sheared_hull_has_inside_points_whose_axis_source_is_outside():
    # the case where the paper's "nearest hit from the source" would be the entry point behind p
    hm = MAPS["sheared-cylinder"]
    pts = random_points(hm, n=20000, seed=5)
    inner = pts[signed_distance(hm.planes, pts) < -SURFACE_TOL]
    src, _, _ = map_rays(hm, inner)
    outside_src = signed_distance(hm.planes, src) > 1e-6
    assert outside_src.sum() > 20
    got = K.response_points(hm, inner[outside_src])
    s, d, start = map_rays(hm, inner[outside_src])
    t = np.einsum("ij,ij->i", got - s, d)
    assert (t >= start - 1e-12).all()          # pushed outward, beyond p


def test_rays_through_vertices_and_edges():
    for key in ("elongated116-cylinder", "round-sphere", "box-sphere", "cylinder-cylinder"):
        hm = MAPS[key]
        v = hm.mesh.vertices
        e = np.concatenate([hm.mesh.faces[:, [0, 1]], hm.mesh.faces[:, [1, 2]]])
        targets = np.concatenate([v, 0.5 * (v[e[:, 0]] + v[e[:, 1]])])
        src = hm.center[None] + np.zeros_like(targets)
        if hm.kind == "cylinder":
            src = hm.to_bone(hm.to_local(targets) * [1, 0, 0])
        inside_src = signed_distance(hm.planes, src) < -1e-9
        for lam in (0.25, 0.9):
            p = src + lam * (targets - src)
            got = K.response_points(hm, p[inside_src])
            np.testing.assert_allclose(got, targets[inside_src], atol=1e-12)


def test_points_on_the_surface_respond_with_themselves():
    rng = np.random.default_rng(11)
    for key in ("round-sphere", "elongated116-cylinder", "capsule-cylinder"):
        hm = MAPS[key]
        f = hm.mesh.faces[rng.integers(0, hm.mesh.faces.shape[0], 3000)]
        w = rng.dirichlet([1, 1, 1], 3000)
        p = np.einsum("nk,nkj->nj", w, hm.mesh.vertices[f])
        # (with the map source outside the hull, e.g. the cylinder axis beyond a tip, p may be on a
        # face the ray enters through; its exit is elsewhere)
        src, _, _ = map_rays(hm, p)
        src_in = signed_distance(hm.planes, src) < -1e-9
        assert src_in.mean() > 0.9
        got = K.response_points(hm, p[src_in])
        np.testing.assert_allclose(got, p[src_in], atol=1e-12)
        # on the surface counts as inside up to rounding: never a false "outside" deep in a face
        sd = signed_distance(hm.planes, p)
        ins = K.inside_points(hm, p)
        assert ins[sd <= -1e-15].all()


def test_nearest_plane_baseline_matches_reference():
    for key in ("round-sphere", "flatish-cylinder"):
        hm = MAPS[key]
        pts = random_points(hm, n=20000, seed=2)
        inner = pts[signed_distance(hm.planes, pts) < 0]
        got = K.response_points(hm, inner, method=K.METHOD_NEAREST_PLANE)
        np.testing.assert_allclose(got, nearest_plane_reference(hm.planes, inner), atol=1e-12)
        hit, out = K.collide_points(hm, pts, method=K.METHOD_NEAREST_PLANE)
        np.testing.assert_array_equal(hit, signed_distance(hm.planes, pts) <= 0)
        np.testing.assert_allclose(out[hit], got, atol=0)


def test_kernels_callable_from_user_njit_loops():
    from numba import njit

    @njit
    def count_and_resolve(m, h, pts, method):
        n = 0
        for i in range(pts.shape[0]):
            ins, x, y, z = K.hull_collide(m, h, pts[i], method)
            if ins:
                n += 1
                pts[i, 0] = x
                pts[i, 1] = y
                pts[i, 2] = z
        return n

    hm = MAPS["round-sphere"]
    ms = MapSet.from_maps([hm])
    pts = random_points(hm, n=3000, seed=9)
    n_in = int(K.inside_points(ms, pts).sum())
    resolved = pts.copy()
    assert count_and_resolve(ms.arrays, 0, resolved, K.METHOD_PAPER) == n_in
    assert signed_distance(hm.planes, resolved).min() > -1e-12


def test_query_arrays_follow_the_map_arrays_fields():
    """hull_query's array arguments are MapArrays' fields after the OBB frame, in field order."""
    from stages.maps.types import MapArrays
    assert K.QUERY_FIELDS == MapArrays._fields[2:]
    m = MapSet.from_maps([MAPS["round-sphere"]]).arrays
    got = K.query_arrays(m)
    assert len(got) == len(K.QUERY_FIELDS)
    for name, arr in zip(K.QUERY_FIELDS, got):
        np.testing.assert_array_equal(arr, getattr(m, name))
