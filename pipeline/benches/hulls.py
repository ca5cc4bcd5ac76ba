"""Hull-stage benchmark (not a test): the paper's 508-triangle example and the CesiumMan build time.

`run_benchmark()` returns a dict of figures; the lead's `python -m pipeline bench hulls` prints it.
"""
from __future__ import annotations

import time

import numpy as np


def paper_like_body() -> tuple[np.ndarray, np.ndarray]:
    """A closed 512-triangle body at the paper's scale (mean edge 0.084), deterministic.

    A trimesh capsule (16 x 16) with 57 % of its vertices dented inwards by 8 % (seeded), so that
    like the paper's 508-triangle model (hull: 224 faces) less than half its vertices are on the hull.
    """
    import trimesh

    m = trimesh.creation.capsule(height=0.6, radius=0.2, count=[16, 16])
    v = m.vertices.copy()
    rng = np.random.default_rng(508)
    dent = rng.uniform(size=v.shape[0]) < 0.57
    centre_axis = np.c_[np.zeros(len(v)), np.zeros(len(v)), np.clip(v[:, 2], -0.3, 0.3)]
    v[dent] = centre_axis[dent] + 0.92 * (v[dent] - centre_axis[dent])
    body = trimesh.Trimesh(v, m.faces, process=False)
    v *= 0.084 / body.edges_unique_length.mean()
    return v, np.asarray(m.faces, dtype=np.int32)


def _timed(fn, repeat: int):
    fn()  # warm (numba cache load / compile)
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return out, best


def run_benchmark(assets_dir=None, repeat: int = 3) -> dict:
    """Figures: paper example face counts; CesiumMan collider build time (warm, best of `repeat`)."""
    import trimesh

    from stages.hulls.fit import fit_colliders, fit_hull, fit_report_totals

    out: dict = {}
    v, f = paper_like_body()
    edges = trimesh.Trimesh(v, f, process=False).edges_unique_length
    for delta, floor, bound in ((0.005, 116, None), (0.005, 4, None), (0.005, 4, 0.02), (0.01, 4, 0.02)):
        (raw, inflated, simplified, rep), t = _timed(lambda: fit_hull(v, delta, floor, max_offset=bound), repeat)
        out[f"paper_body_delta{delta}_min{floor}_maxoffset{bound}"] = {
            "model_triangles": int(f.shape[0]), "mean_edge": float(edges.mean()),
            "faces_raw": rep.faces_raw, "faces_inflated": rep.faces_inflated,
            "faces_simplified": rep.faces_simplified, "excess_volume_m3": rep.excess_volume,
            "hausdorff_m": rep.hausdorff, "contains": rep.contains_region, "seconds": t}
    out["paper_reference"] = {"model_triangles": 508, "mean_edge": 0.084, "faces_raw": 224, "faces_simplified": 116,
                              "delta": 0.005}

    if assets_dir is None:
        from pipeline.assets import assets_dir as default_assets
        assets_dir = default_assets()
    path = assets_dir / "CesiumMan.glb"
    if path.is_file():
        from stages.rig.gltf import load_gltf
        from stages.rig.regions import split_regions

        ch = load_gltf(path)
        split = split_regions(ch)
        for delta in (0.01, 0.005):
            cs, t = _timed(lambda: fit_colliders(ch, split, delta=delta, min_triangles=40), repeat)
            tot = fit_report_totals(cs)
            tot["seconds_warm"] = t
            tot["per_hull"] = {h.name: [h.report.faces_raw, h.report.faces_inflated, h.report.faces_simplified]
                               for h in cs.hulls}
            out[f"cesium_man_delta{delta}_min40"] = tot
    else:
        out["cesium_man"] = f"skipped: {path} not found"
    return out


if __name__ == "__main__":  # pragma: no cover
    import json

    print(json.dumps(run_benchmark(), indent=1, default=str))
