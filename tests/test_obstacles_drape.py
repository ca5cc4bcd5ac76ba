"""Cloth drapes (paper B §5 scenes) with the TEST HARNESS cloth of stages/obstacles/demo_cloth.py."""
from __future__ import annotations

import numpy as np

from stages.obstacles import (ObstacleCollider, box_mesh, build_obstacle_set, make_obstacle, plane_mesh,
                              sphere_mesh)
from stages.obstacles.demo_cloth import drop_cloth, square_cloth

N = 30
SIZE = 1.6


def test_cloth_rests_on_a_table_with_overhang_hanging_and_corners_folding():
    h, top = 0.01, 0.75
    # a solid box table: point-only contacts cannot stop a cloth link cutting a slab edge thinner
    # than the particle spacing (see the report), so the drape test uses a block
    table = make_obstacle("table", box_mesh((0, top / 2, 0), (1.0, top, 1.0)), thickness=h, friction=0.5)
    x0, springs, rest = square_cloth(N, SIZE, (0.0, 0.9, 0.0))
    coll = ObstacleCollider(build_obstacle_set([table]), x0)
    x_prev, x = drop_cloth(coll, x0, springs, rest, 150, iterations=20, damping=0.05)
    inside_xz = (np.abs(x[:, 0]) < 0.5) & (np.abs(x[:, 2]) < 0.5)
    # nothing inside the table; what lies over it rests on the band
    assert np.all(x[inside_xz, 1] >= top + h - 1e-6)
    assert np.all(x[inside_xz, 1] <= top + h + 1e-3)
    np.testing.assert_allclose(x[(np.abs(x[:, 0]) < 0.4) & (np.abs(x[:, 2]) < 0.4), 1], top + h, atol=1e-6)
    # the overhang hangs: every particle off the table is below its top, most of it well below
    off = ~inside_xz
    assert off.sum() > 0.4 * x.shape[0]
    assert np.all(x[off, 1] < top + h + 1e-6)
    assert np.median(x[off, 1]) < top - 0.1
    # at rest: displacement per step under 1 mm
    assert np.abs(x - x_prev).max() < 1e-3
    # corners fold down lower than the middle of each hanging side
    g = x.reshape(N, N, 3)
    corners = [g[0, 0, 1], g[0, -1, 1], g[-1, 0, 1], g[-1, -1, 1]]
    mids = [g[0, N // 2, 1], g[-1, N // 2, 1], g[N // 2, 0, 1], g[N // 2, -1, 1]]
    assert max(corners) < min(mids)


def inside_convex(points, v, f, depth):
    """True where a point is more than `depth` behind every face plane of a convex mesh."""
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    d = (points[:, None, :] - a[None]) @ np.ones(3) * 0 + np.einsum("pfk,fk->pf", points[:, None, :] - a[None], n)
    return (d < -depth).all(axis=1)


def test_cloth_rests_on_spheres_with_no_particle_inside():
    h = 0.01
    spheres = [((-0.35, 0.3, 0.0), 0.3), ((0.4, 0.25, 0.1), 0.25)]
    obs = [make_obstacle(f"ball{i}", sphere_mesh(c, r, 3), thickness=h, friction=0.6) for i, (c, r) in enumerate(spheres)]
    obs.append(make_obstacle("floor", plane_mesh((0, 0, 0), (0, 1, 0), (6, 6)), thickness=h, friction=0.6))
    oset = build_obstacle_set(obs)
    x0, springs, rest = square_cloth(N, SIZE, (0.0, 0.8, 0.0))
    coll = ObstacleCollider(oset, x0)
    worst = [0.0]

    def check(step, x_prev, x, n):
        for ob in obs[:2]:
            assert not inside_convex(x, ob.vertices, ob.triangles, 0.0).any(), f"particle inside at step {step}"
    x_prev, x = drop_cloth(coll, x0, springs, rest, 120, iterations=20, damping=0.05, on_step=check)
    # it rests on both tops and on the floor, not below it
    for c, r in spheres:
        near = np.linalg.norm(x[:, [0, 2]] - np.array([c[0], c[2]]), axis=1) < 0.05
        assert near.any()
        assert np.all(x[near, 1] > c[1] + r * 0.95)
    assert x[:, 1].min() >= h - 1e-6
    assert np.abs(x - x_prev).max() < 2e-3
