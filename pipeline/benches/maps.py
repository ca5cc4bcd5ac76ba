"""Benchmark of the hull queries: queries per second of (a) the paper's path (slab point location +
cell ray), (b) brute force (every half-space + the ray against every face), (c) the nearest-plane
baseline, on 10^6 points around each hull. `python -m pipeline.benches.maps` prints the dict.

Hulls: CesiumMan's colliders (region split -> Qhull hull -> inflate 5 mm -> simplify to >= 116
faces, bone-local) when the rig and hull stages and the asset are available, else random 116-face
hulls (60 points on random ellipsoids); the result says which.
"""
from __future__ import annotations

import time

import numpy as np

from stages.maps import kernels as K
from stages.maps.build import build_hull_map
from stages.maps.types import MapSet


def _cesium_meshes(path):
    from stages.hulls.hull import convex_hull, inflate_hull
    from stages.hulls.simplify import simplify_hull
    from stages.rig.gltf import load_gltf
    from stages.rig.regions import split_regions
    from stages.rig.transforms import transform_points
    ch = load_gltf(path)
    split = split_regions(ch)
    out = []
    for b in split.hull_bones:
        pts = transform_points(ch.inverse_bind[b], ch.vertices[split.rigid & (split.region_joint == b)])
        out.append((ch.joint_names[b], simplify_hull(inflate_hull(convex_hull(pts), 0.005), 116)))
    return out


def _random_meshes(n: int = 6):
    from stages.hulls.hull import convex_hull
    rng = np.random.default_rng(0)
    out = []
    for i in range(n):
        d = rng.normal(size=(60, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        radii = np.sort(rng.uniform(0.03, 0.2, 3))[::-1]
        out.append((f"random{i}", convex_hull(d * radii)))
    return out


def _rate(fn, *args, repeats: int = 3) -> float:
    fn(*args)  # compile / warm
    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        fn(*args)
        best = min(best, time.perf_counter() - t)
    return best


def run_benchmark(n_points: int = 1_000_000, assets_dir=None, seed: int = 0) -> dict:
    """Queries per second per method (inside test, response on inside points, collide on all)."""
    source = "random 116-face hulls (CesiumMan colliders unavailable)"
    meshes = None
    try:
        from pipeline.assets import assets_dir as default_assets
        path = (assets_dir or default_assets()) / "CesiumMan.glb"
        if path.is_file():
            meshes = _cesium_meshes(path)
            source = "CesiumMan colliders (inflated 5 mm, simplified to >= 116 faces)"
    except ImportError:
        pass
    meshes = meshes or _random_meshes()
    maps = MapSet.from_maps([build_hull_map(m) for _, m in meshes], names=[n for n, _ in meshes])
    m = maps.arrays
    rng = np.random.default_rng(seed)
    per_hull = n_points // len(meshes)
    hulls = []
    totals = {"paper": [0.0, 0.0, 0.0], "brute": [0.0, 0.0, 0.0], "nearest_plane": [0.0, 0.0, 0.0]}
    n_inside_total = 0
    for h, hm in enumerate(maps.maps):
        pts = hm.to_bone(rng.uniform(-1.2, 1.2, size=(per_hull, 3)) * hm.half_extents)
        ins = np.empty(per_hull, np.bool_)
        hit = np.empty(per_hull, np.bool_)
        out = np.empty_like(pts)
        K._inside_many(m, h, pts, K.METHOD_PAPER, ins)
        inner = np.ascontiguousarray(pts[ins])
        out_in = np.empty_like(inner)
        n_inside_total += inner.shape[0]
        row = {"name": maps.names[h], "kind": hm.kind, "faces": int(hm.mesh.faces.shape[0]), **hm.cell_stats,
               "inside_fraction": float(ins.mean())}
        for label, method in (("paper", K.METHOD_PAPER), ("brute", K.METHOD_BRUTE), ("nearest_plane", K.METHOD_NEAREST_PLANE)):
            t_in = _rate(K._inside_many, m, h, pts, min(method, K.METHOD_BRUTE), ins)
            t_resp = _rate(K._response_many, m, h, inner, method, out_in)
            t_col = _rate(K._collide_many, m, h, pts, method, hit, out)
            for i, t in enumerate((t_in, t_resp, t_col)):
                totals[label][i] += t
            row[label] = {"inside_qps": per_hull / t_in, "response_qps": inner.shape[0] / max(t_resp, 1e-12),
                          "collide_qps": per_hull / t_col}
        hulls.append(row)
    n_all = per_hull * len(meshes)
    summary = {label: {"inside_qps": n_all / t[0], "response_qps": n_inside_total / t[1], "collide_qps": n_all / t[2]}
               for label, t in totals.items()}
    faster = max(("paper", "brute"), key=lambda k: summary[k]["collide_qps"])
    return {"source": source, "points": n_all, "inside_points": n_inside_total, "hulls": hulls,
            "summary": summary, "faster_of_paper_and_brute": faster,
            "note": "collide = inside test + response for inside points (what the simulation calls); "
                    "inside for nearest_plane uses the brute half-space test"}


if __name__ == "__main__":
    import json
    print(json.dumps(run_benchmark(), indent=1, default=float))
