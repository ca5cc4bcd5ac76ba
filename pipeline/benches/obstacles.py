"""Benchmark of the k-DOP obstacle collision on the table scene (a command, not a test).

    python -m pipeline.benches.obstacles

A 50 x 50 = 2,500-particle cloth dropped on a table (top slab + 4 legs) by the simulation stage
(stages.sim.simulate: its step, then the obstacle collision after every step). Reported: the stage's
own phase times, obstacle contacts, and the tree refit and traversal alone on the final state.
"""
from __future__ import annotations

import time

import numpy as np

from stages.geometry.kdop import DEFAULT_K, refit_particle_tree
from stages.obstacles.kernels import candidate_pairs, motion_axis_order
from stages.obstacles.primitives import make_obstacle, table_mesh
from stages.obstacles.stage import ObstacleCollider, build_obstacle_set


def table_scene(k: int = DEFAULT_K, n_side: int = 50, frames: int = 60):
    """(character, motion, garments, obstacle set): a static one-joint character without colliders,
    an n_side x n_side 1.6 m cloth 15 cm above a 1 m table."""
    from stages.garments.simple import rectangle_cloth
    from stages.garments.types import build_garment
    from stages.sim.scenes import toy_character, toy_motion

    table = make_obstacle("table", table_mesh((0, 0.75, 0), (1.0, 1.0), top_thickness=0.03),
                          thickness=0.01, friction=0.5)
    oset = build_obstacle_set([table], k=k)
    x, tri = rectangle_cloth(1.6, 1.6, n_side, n_side, center=(0.0, 0.9, 0.0))
    # the character is a 1 cm tetrahedron under the table: no colliders, no body audit
    tet = np.array([[0, 0, 0], [0.01, 0, 0], [0, 0.01, 0], [0, 0, 0.01]], np.float64)
    ch = toy_character(tet, np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], np.int32), name="no_body")
    return ch, toy_motion(frames), [build_garment("cloth", x, tri)], oset


def run_benchmark(k: int = DEFAULT_K, n_side: int = 50, frames: int = 60, params=None) -> dict:
    """Returns a dict of figures (times in milliseconds, rates per second). params: SimParams (the
    defaults without the body audit when None)."""
    from stages.sim import SimParams, simulate

    ch, motion, garments, oset = table_scene(k, n_side, frames)
    params = params or SimParams(body_audit=False)
    simulate(ch, motion, None, None, garments, params, obstacles=oset)        # compile / warm
    t0 = time.perf_counter()
    r = simulate(ch, motion, None, None, garments, params, obstacles=oset)
    wall = time.perf_counter() - t0
    tm = r.timings
    steps = max(r.steps, 1)
    # refit and traversal alone, on the final state (one pass), repeated for a stable figure
    x_prev = r.garments[0].positions[-2].astype(np.float64)
    x = r.garments[0].positions[-1].astype(np.float64)
    coll = ObstacleCollider(oset, x)
    ct, t = coll.cloth_tree, oset.tree
    x_next = x + (x - x_prev)
    reps = 200
    t1 = time.perf_counter()
    for _ in range(reps):
        refit_particle_tree(coll.c_min, coll.c_max, ct.children, ct.leaf_prim, t.directions, x, x_next)
    t_refit = (time.perf_counter() - t1) / reps
    stats = np.zeros(4, np.int64)
    order = motion_axis_order(t.directions, x, x_next)
    t1 = time.perf_counter()
    for _ in range(reps):
        pairs, m = candidate_pairs(coll.c_min, coll.c_max, ct.children, ct.leaf_prim, coll.o_min, coll.o_max,
                                   t.children, t.leaf_prim, t.tree_offsets, order, stats)
    t_trav = (time.perf_counter() - t1) / reps
    n = x.shape[0]
    return {
        "k": k,
        "particles": n,
        "obstacle_triangles": int(oset.triangles.shape[0]),
        "frames": r.n_frames,
        "steps": r.steps,
        "substeps": params.substeps,
        "steps_per_s_total": steps / max(wall - tm.get("setup", 0.0), 1e-12),
        "obstacle_ms_per_step": 1e3 * tm["obstacles"] / steps,
        "cloth_ms_per_step": 1e3 * (tm["integrate"] + tm["constraints"] + tm["collisions"]) / steps,
        "contacts_per_frame_last_10": float(np.mean(r.contacts_obstacles[-10:])),
        "refit_ms": 1e3 * t_refit,
        "traversal_ms": 1e3 * t_trav,
        "node_pairs_per_traversal": int(stats[0] // reps),
        "candidate_pairs_per_traversal": int(m),
        "brute_pairs_per_pass": n * int(oset.triangles.shape[0]),
    }


def main() -> None:  # pragma: no cover - a command
    for k in (6, 14, 18, 26):
        r = run_benchmark(k=k)
        print(" ".join(f"{key}={val:.4g}" if isinstance(val, float) else f"{key}={val}" for key, val in r.items()))


if __name__ == "__main__":  # pragma: no cover
    main()
