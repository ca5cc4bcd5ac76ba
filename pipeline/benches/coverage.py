"""`python -m pipeline bench coverage`: collider coverage and excess per character, the paper's
colliders (weight split, joint spheres, unbounded simplification) beside swept flexible hulls
(`colliders.flexible: swept`) and the default ones (motion split, skinned balls for the flexible
regions, max_offset 5 mm), delta 1 cm, fitted over a 60-frame walk (2 s) and
measured at every 10th frame of it and the last, as a scene of that walk does.

Characters: the built-in one (walk), CesiumMan (its walk) and the skin generated around the CMU
BVH walk, read from GARMENT_ASSETS (default ../shared/assets beside the repository); a missing
asset is reported as skipped.
"""
from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

MODES = {
    "paper": dict(split="weights", flexible="sphere", max_offset=None),
    "swept": dict(split="motion", flexible="swept", max_offset=0.005),
    "default": dict(split="motion", flexible="balls", max_offset=0.005),
}


def _assets() -> Path:
    return Path(os.environ.get("GARMENT_ASSETS", Path(__file__).resolve().parents[2].parent / "shared" / "assets"))


def characters() -> dict:
    """name -> loader of (character, clip name, playback start in s)."""
    from stages.rig.bvh_character import load_bvh_character
    from stages.rig.gltf import load_gltf
    from stages.rig.procedural import procedural_character
    return {"built-in": lambda: (procedural_character(), "walk", 0.0),
            "CesiumMan": lambda: (load_gltf(_assets() / "CesiumMan.glb"), 0, 0.0),
            "CMU 131_01 (BVH skin)": lambda: (load_bvh_character(_assets() / "cmu_131_01_walk.bvh"), 0, 2.0)}


def measure(character, clip, start: float, mode: str, frames: int = 60, delta: float = 0.01) -> dict:
    from stages.coverage import measure_coverage
    from stages.hulls.fit import fit_character
    from stages.rig.skinning import sample_motion
    motion = sample_motion(character, clip, start + np.arange(frames) / 30.0)
    t0 = time.perf_counter()
    _, cs = fit_character(character, motion.joint_world, delta=delta, **MODES[mode])
    t1 = time.perf_counter()
    rep = measure_coverage(character, motion, cs)
    t = rep.totals()
    return {"colliders": len(cs.hulls) + len(cs.spheres), "hulls": len(cs.hulls), "spheres": len(cs.spheres),
            "faces": int(sum(h.simplified.faces.shape[0] for h in cs.hulls)),
            "coverage_min_pct": round(t["coverage_min"] * 100, 2), "excess_p95_cm": round(t["excess_p95"] * 100, 2),
            "excess_max_cm": round(t["excess_max"] * 100, 2), "shell_pct": round(t["shell_share"] * 100, 1),
            "skin_exposed_pct": round(t["skin_exposed"] * 100, 3),
            "fit_s": round(t1 - t0, 2), "measure_s": round(time.perf_counter() - t1, 2)}


def table(results: dict) -> str:
    rows = ["| character | colliders | count (hulls + spheres) | coverage min (%) | excess p95 / max (cm) | shell (% of body) "
            "| skin exposed, max (%) |", "| --- | --- | --- | ---: | --- | ---: | ---: |"]
    for name, per in results.items():
        for mode, r in per.items():
            if "skipped" in r:
                rows.append(f"| {name} | {mode} | skipped: {r['skipped']} | | | | |")
                continue
            rows.append(f"| {name} | {mode} | {r['colliders']} ({r['hulls']} + {r['spheres']}) | {r['coverage_min_pct']:.2f} | "
                        f"{r['excess_p95_cm']:.1f} / {r['excess_max_cm']:.1f} | {r['shell_pct']:.0f} | {r['skin_exposed_pct']:.3f} |")
    return "\n".join(rows)


def run_benchmark() -> dict:
    out = {}
    for name, load in characters().items():
        try:
            character, clip, start = load()
        except (OSError, ValueError) as err:
            out[name] = {m: {"skipped": str(err)} for m in MODES}
            continue
        out[name] = {m: measure(character, clip, start, m) for m in MODES}
    print(table(out), flush=True)
    return out
