"""Continuous particle-triangle contacts and response (paper B §3.2, §4), against a plain-numpy
reference and on small physical scenarios."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from stages.obstacles import (ObstacleCollider, ObstacleMotion, box_mesh, build_obstacle_set, make_obstacle,
                              plane_mesh, sphere_mesh, table_mesh)

DT = 1.0 / 30.0
G = np.array([0.0, -9.81, 0.0])


def reference_collide(x_prev, x, inv_mass, v, f, h, mu, e):
    """Single-pass reference for static obstacles, straight from the documented rule."""
    x_prev = x_prev.copy()
    x = x.copy()
    hits = {}
    for p in range(x.shape[0]):
        if inv_mass[p] == 0:
            continue
        best = None
        for t_id, (ia, ib, ic) in enumerate(f):
            a, b, c = v[ia], v[ib], v[ic]
            n = np.cross(b - a, c - a)
            n /= np.linalg.norm(n)
            d0 = n @ (x_prev[p] - a)
            d1 = n @ (x[p] - a)
            if not (d1 < h - 1e-10 and d0 >= -0.5 * h):
                continue
            t = (d0 - h) / (d0 - d1) if d0 > h else 0.0
            ts = [t] + ([d0 / (d0 - d1)] if (d1 < 0 < d0) else [])
            area = np.cross(b - a, c - a) @ n

            def inside(tt):
                q = x_prev[p] + tt * (x[p] - x_prev[p])
                q = q - (n @ (q - a)) * n
                l0 = np.cross(c - b, q - b) @ n / area
                l1 = np.cross(a - c, q - c) @ n / area
                return min(l0, l1, 1 - l0 - l1) >= -1e-9

            if not any(inside(tt) for tt in ts):
                continue
            key = (t, -d0, t_id)
            if best is None or key < best[0]:
                best = (key, n, a)
        if best is None:
            continue
        (t, _, t_id), n, a = best
        vel = x[p] - x_prev[p]
        vn = vel @ n
        vt = vel - vn * n
        push = max(h - n @ (x[p] - a), 0.0)
        keep = max(0.0, 1 - mu * push / np.linalg.norm(vt)) if np.linalg.norm(vt) > 0 else 1.0
        new_x = x[p] + push * n - (1 - keep) * vt
        new_v = keep * vt + (-e * vn if vn < 0 else vn) * n
        x[p] = new_x
        x_prev[p] = new_x - new_v
        hits[p] = t_id
    return x_prev, x, hits


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n_part=st.integers(1, 60), k=st.sampled_from([6, 14, 18, 26]))
def test_kernel_matches_reference_on_random_configurations(seed, n_part, k):
    rng = np.random.default_rng(seed)
    # a bumpy triangulated patch plus a sphere: particles rain through both
    u = np.linspace(-1, 1, 6)
    gx, gz = np.meshgrid(u, u, indexing="ij")
    gy = 0.1 * rng.normal(size=gx.shape)
    pv = np.column_stack([gx.ravel(), gy.ravel(), gz.ravel()])
    idx = np.arange(36).reshape(6, 6)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    pf = np.concatenate([np.column_stack([a, d, c]), np.column_stack([a, c, b])]).astype(np.int32)
    h, mu, e = 0.02, float(rng.uniform(0, 1)), float(rng.uniform(0, 1))
    obs = [make_obstacle("patch", (pv, pf), thickness=h, friction=mu, restitution=e),
           make_obstacle("ball", sphere_mesh((0.3, 0.6, -0.2), 0.25, 1), thickness=h, friction=mu, restitution=e)]
    oset = build_obstacle_set(obs, k=k)
    x_prev = rng.uniform(-1.1, 1.1, (n_part, 3)) * [1, 0.6, 1] + [0, 0.5, 0]
    x = x_prev + rng.normal(0, 0.3, (n_part, 3)) + [0, -0.3, 0]
    inv_mass = (rng.uniform(size=n_part) > 0.1).astype(np.float64)
    ref_prev, ref_x, hits = reference_collide(x_prev, x, inv_mass, oset.vertices, oset.triangles, h, mu, e)
    coll = ObstacleCollider(oset, x_prev, passes=1)
    got_prev, got_x = x_prev.copy(), x.copy()
    n = coll.collide(got_prev, got_x, inv_mass)
    c = coll.contacts()
    assert n == len(hits)
    assert dict(zip(c["particle"].tolist(), c["triangle"].tolist())) == hits
    np.testing.assert_allclose(got_x, ref_x, atol=1e-9)
    np.testing.assert_allclose(got_prev, ref_prev, atol=1e-9)


def run_particle(coll, x0, v0, steps, t0=0.0):
    x_prev = np.array([x0], dtype=np.float64)
    x = x_prev + np.array([v0]) * DT
    w = np.ones(1)
    path = []
    for s in range(steps):
        coll.collide(x_prev, x, w, t0 + s * DT, t0 + (s + 1) * DT)
        path.append(x[0].copy())
        nxt = 2 * x - x_prev + G * DT * DT
        x_prev, x = x, nxt
    return np.array(path)


def test_no_tunnelling_through_a_1mm_table_top_at_5_m_per_s():
    h = 0.002
    table = make_obstacle("table", table_mesh((0, 0.75, 0), (1.0, 1.0), top_thickness=0.001), thickness=h)
    coll = ObstacleCollider(build_obstacle_set([table]), np.zeros((1, 3)))
    # 5 m/s * dt = 17 cm per step, 170x the top's thickness
    path = run_particle(coll, (0.1, 0.9, -0.2), (0.0, -5.0, 0.0), 60)
    assert path[:, 1].min() >= 0.75 + h - 1e-9
    np.testing.assert_allclose(path[-10:, 1], 0.75 + h, atol=1e-9)


def test_two_sided_plane_keeps_particles_on_their_side():
    h = 0.005
    plane = make_obstacle("wall", plane_mesh((0, 0, 0), (0, 1, 0), (4, 4)), thickness=h)
    coll = ObstacleCollider(build_obstacle_set([plane]), np.zeros((1, 3)))
    above = run_particle(coll, (0.2, 0.5, 0.1), (0.0, -3.0, 0.0), 40)
    assert above[:, 1].min() >= h - 1e-9
    global G
    g_saved = G
    try:
        G = -g_saved  # "gravity" upwards: from below the plane
        below = run_particle(coll, (0.2, -0.5, 0.1), (0.0, 3.0, 0.0), 40)
    finally:
        G = g_saved
    assert below[:, 1].max() <= -h + 1e-9


@pytest.mark.parametrize("mu", [0.0, 0.4])
def test_friction_slows_a_sliding_particle(mu):
    h = 0.005
    floor = make_obstacle("floor", plane_mesh((0, 0, 0), (0, 1, 0), (40, 40)), thickness=h, friction=mu)
    coll = ObstacleCollider(build_obstacle_set([floor]), np.zeros((1, 3)))
    path = run_particle(coll, (0.0, h, 0.0), (2.0, 0.0, 0.0), 30)
    speed = np.abs(np.diff(path[:, 0])) / DT
    np.testing.assert_allclose(path[:, 1], h, atol=1e-9)
    if mu == 0.0:
        np.testing.assert_allclose(speed, 2.0, rtol=1e-9)
    else:
        # Coulomb: each step after the first (no gravity push yet) loses mu * g * dt of speed
        expected = np.maximum(2.0 - mu * 9.81 * DT * np.arange(1, 30), 0.0)
        np.testing.assert_allclose(speed, expected, atol=1e-9)


def test_restitution_bounces_back():
    h = 0.005
    floor = make_obstacle("floor", plane_mesh((0, 0, 0), (0, 1, 0), (4, 4)), thickness=h, restitution=0.5)
    coll = ObstacleCollider(build_obstacle_set([floor]), np.zeros((1, 3)))
    path = run_particle(coll, (0.0, 0.3, 0.0), (0.0, -4.0, 0.0), 12)
    first = int(np.argmax(np.isclose(path[:, 1], h)))
    assert path[first + 1, 1] > h  # it leaves the surface again
    assert path[:, 1].min() >= h - 1e-9


def test_moving_platform_lifts_a_resting_particle():
    h = 0.005
    motion = ObstacleMotion.from_velocity(linear=(0.0, 0.5, 0.0), duration=3.0)
    lift = make_obstacle("lift", box_mesh((0, -0.05, 0), (1, 0.1, 1)), thickness=h, motion=motion)
    coll = ObstacleCollider(build_obstacle_set([lift]), np.zeros((1, 3)))
    path = run_particle(coll, (0.0, h + 1e-4, 0.0), (0.0, 0.0, 0.0), 45)
    top = 0.5 * DT * np.arange(1, 46) + h
    assert np.all(path[:, 1] >= top - 1e-9)
    assert path[-1, 1] == pytest.approx(top[-1], abs=0.02)


def test_pinned_particles_are_never_moved():
    floor = make_obstacle("floor", plane_mesh((0, 0, 0), (0, 1, 0), (4, 4)), thickness=0.01)
    coll = ObstacleCollider(build_obstacle_set([floor]), np.zeros((2, 3)))
    x_prev = np.array([[0.0, 0.5, 0.0], [0.3, 0.5, 0.0]])
    x = np.array([[0.0, -0.5, 0.0], [0.3, -0.5, 0.0]])
    w = np.array([0.0, 1.0])
    coll.collide(x_prev, x, w)
    assert x[0, 1] == -0.5 and x[1, 1] == pytest.approx(0.01)
