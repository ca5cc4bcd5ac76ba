"""Cloth drapes (paper B §5 scenes) with the simulation stage (stages.sim.simulate, obstacles collided
after every step)."""
from __future__ import annotations

import numpy as np

from stages.garments.simple import rectangle_cloth
from stages.garments.types import build_garment
from stages.obstacles import box_mesh, build_obstacle_set, make_obstacle, plane_mesh, sphere_mesh
from pipeline.benches.obstacles import table_scene
from stages.sim import SimParams, simulate

N = 30
SIZE = 1.6
# the former harness's step (1 step x 20 rounds per frame): the tests check the obstacle contacts
PARAMS = SimParams(substeps=1, iterations=20, tethers=False, damping=0.05, body_audit=False)


def _drop(oset, height: float, frames: int):
    """(x_prev, x, positions): a SIZE x SIZE cloth of N x N particles dropped from `height` on `oset`."""
    ch, motion, _, _ = table_scene(frames=frames)
    x, tri = rectangle_cloth(SIZE, SIZE, N, N, center=(0.0, height, 0.0))
    r = simulate(ch, motion, None, None, [build_garment("cloth", x, tri)], PARAMS, obstacles=oset)
    p = r.garments[0].positions.astype(np.float64)
    return p[-2], p[-1], p


def test_cloth_rests_on_a_table_with_overhang_hanging_and_corners_folding():
    h, top = 0.01, 0.75
    # a solid box table: point-only contacts cannot stop a cloth link cutting a slab edge thinner
    # than the particle spacing, so the drape test uses a block
    table = make_obstacle("table", box_mesh((0, top / 2, 0), (1.0, top, 1.0)), thickness=h, friction=0.5)
    x_prev, x, _ = _drop(build_obstacle_set([table]), 0.9, 150)
    inside_xz = (np.abs(x[:, 0]) < 0.5) & (np.abs(x[:, 2]) < 0.5)
    # nothing inside the table; what lies over it rests on the band (float32 positions)
    assert np.all(x[inside_xz, 1] >= top + h - 1e-5)
    assert np.all(x[inside_xz, 1] <= top + h + 1e-3)
    np.testing.assert_allclose(x[(np.abs(x[:, 0]) < 0.4) & (np.abs(x[:, 2]) < 0.4), 1], top + h, atol=1e-5)
    # the overhang hangs: every particle off the table is below its top, most of it well below
    off = ~inside_xz
    assert off.sum() > 0.4 * x.shape[0]
    assert np.all(x[off, 1] < top + h + 1e-5)
    assert np.median(x[off, 1]) < top - 0.1
    # at rest: displacement per frame under 1 mm
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
    d = np.einsum("pfk,fk->pf", points[:, None, :] - a[None], n)
    return (d < -depth).all(axis=1)


def test_cloth_rests_on_spheres_with_no_particle_inside():
    h = 0.01
    spheres = [((-0.35, 0.3, 0.0), 0.3), ((0.4, 0.25, 0.1), 0.25)]
    obs = [make_obstacle(f"ball{i}", sphere_mesh(c, r, 3), thickness=h, friction=0.6) for i, (c, r) in enumerate(spheres)]
    obs.append(make_obstacle("floor", plane_mesh((0, 0, 0), (0, 1, 0), (6, 6)), thickness=h, friction=0.6))
    x_prev, x, frames = _drop(build_obstacle_set(obs), 0.8, 120)
    for f, xf in enumerate(frames):
        for ob in obs[:2]:
            assert not inside_convex(xf, ob.vertices, ob.triangles, 0.0).any(), f"particle inside at frame {f}"
    # it rests on both tops and on the floor, not below it
    for c, r in spheres:
        near = np.linalg.norm(x[:, [0, 2]] - np.array([c[0], c[2]]), axis=1) < 0.05
        assert near.any()
        assert np.all(x[near, 1] > c[1] + r * 0.95)
    assert x[:, 1].min() >= h - 1e-5
    assert np.abs(x - x_prev).max() < 2e-3
