"""Benchmark of the k-DOP obstacle collision on the table scene (a command, not a test).

    python -m stages.obstacles.bench

A 50 x 50 = 2,500-particle cloth (TEST HARNESS cloth, stages/obstacles/demo_cloth.py) dropped on a
table (top slab + 4 legs); timings over the steps after the cloth has reached the table.
"""
from __future__ import annotations

import time

import numpy as np

from stages.obstacles.demo_cloth import project_springs, square_cloth, verlet_integrate
from stages.obstacles.kdop import DEFAULT_K, refit_particle_tree
from stages.obstacles.kernels import candidate_pairs, motion_axis_order
from stages.obstacles.primitives import make_obstacle, table_mesh
from stages.obstacles.stage import ObstacleCollider, build_obstacle_set


def run_benchmark(k: int = DEFAULT_K, n_side: int = 50, steps: int = 120, warm_steps: int = 30,
                  dt: float = 1.0 / 30.0, iterations: int = 3) -> dict:
    """Returns a dict of figures (times in milliseconds, rates per second)."""
    table = make_obstacle("table", table_mesh((0, 0.75, 0), (1.0, 1.0), top_thickness=0.03),
                          thickness=0.01, friction=0.5)
    oset = build_obstacle_set([table], k=k)
    x0, springs, rest = square_cloth(n_side, 1.6, (0.0, 0.9, 0.0))
    coll = ObstacleCollider(oset, x0)
    n = x0.shape[0]
    w = np.ones(n)
    x = x0.copy()
    x_prev = x0.copy()
    g = (0.0, -9.81, 0.0)
    t_collide = t_step = 0.0
    exact_tree = []
    contacts = []
    for s in range(steps):
        t0 = time.perf_counter()
        verlet_integrate(x_prev, x, w, g[0], g[1], g[2], dt, 0.02)
        project_springs(x, w, springs, rest, iterations)
        t1 = time.perf_counter()
        before = coll.stats.copy()
        coll.collide(x_prev, x, w, s * dt, (s + 1) * dt)
        t2 = time.perf_counter()
        if s >= warm_steps:
            t_step += t2 - t0
            t_collide += t2 - t1
            exact_tree.append(int(coll.stats[1] - before[1]))
            contacts.append(coll.n_contacts)
    measured = steps - warm_steps
    # refit and traversal alone, on the final state (one pass), repeated for a stable figure
    c_min, c_max = coll.c_min, coll.c_max
    ct = coll.cloth_tree
    t = oset.tree
    x_next = x + (x - x_prev)
    reps = 200
    t0 = time.perf_counter()
    for _ in range(reps):
        refit_particle_tree(c_min, c_max, ct.children, ct.leaf_prim, t.directions, x, x_next)
    t_refit = (time.perf_counter() - t0) / reps
    stats = np.zeros(4, np.int64)
    order = motion_axis_order(t.directions, x, x_next)
    t0 = time.perf_counter()
    for _ in range(reps):
        pairs, m = candidate_pairs(c_min, c_max, ct.children, ct.leaf_prim, coll.o_min, coll.o_max,
                                   t.children, t.leaf_prim, t.tree_offsets, order, stats)
    t_trav = (time.perf_counter() - t0) / reps
    brute = n * oset.triangles.shape[0]  # every particle against every triangle, per pass
    per_step = float(np.mean(exact_tree))
    return {
        "k": k,
        "particles": n,
        "obstacle_triangles": int(oset.triangles.shape[0]),
        "passes": coll.passes,
        "steps_per_s_total": measured / t_step,
        "steps_per_s_collision_only": measured / t_collide,
        "collision_ms_per_step": 1e3 * t_collide / measured,
        "exact_tests_per_step_tree": per_step,
        "exact_tests_per_step_brute": brute * coll.passes,
        "reduction_factor": brute * coll.passes / max(per_step, 1.0),
        "contacts_per_step": float(np.mean(contacts)),
        "refit_ms": 1e3 * t_refit,
        "traversal_ms": 1e3 * t_trav,
        "node_pairs_per_traversal": int(stats[0] // reps),
        "candidate_pairs_per_traversal": int(m),
    }


def main() -> None:  # pragma: no cover - a command
    for k in (6, 14, 18, 26):
        r = run_benchmark(k=k)
        print(" ".join(f"{key}={val:.4g}" if isinstance(val, float) else f"{key}={val}" for key, val in r.items()))


if __name__ == "__main__":  # pragma: no cover
    main()
