"""`python -m pipeline matrix`: every built-in garment kind dressed on every character we have, as
a table a user reads (status, seam gap, body penetration, fit gap, hem above the floor, time).

Characters: the built-in one in three body shapes (default; tall and slim; short and heavy),
CesiumMan and the skin around the CMU 131_01 walk (read from GARMENT_ASSETS, default
../shared/assets; a missing asset is a skipped row). Each character's rig, colliders and maps are
built once, then each garment is built, sewn and simulated alone for `frames` frames, exactly as
`run` does (the same functions), without a recording.

A pair passes when: sewing converged (max seam gap <= the sewing tolerance), no particle inside a
collider after frame 0, <= 0.5 % of the particles inside the true body at every frame after frame 0,
the waistband / collar within 2 cm of the skin (median) after sewing, and every particle above the
floor at every frame. The body-mesh edges through the cloth (most in a frame after the blend-in,
pipeline.body_report) are reported, not judged: the corpus check (`--corpus`) judges them.
"""
from __future__ import annotations

import os
import re
import time
import warnings
from pathlib import Path

import numpy as np

KINDS = ("tshirt", "short_skirt", "long_skirt", "shorts", "trousers", "cape")


def _assets() -> Path:
    return Path(os.environ.get("GARMENT_ASSETS", Path(__file__).resolve().parents[1].parent / "shared" / "assets"))


def characters() -> dict:
    """name -> scene YAML of the character part (character + frames), without garments: written as a
    user writes them (no blend_in: the pipeline dresses on the rest pose and blends into the clip)."""
    a = _assets()
    walk = "frames: {count: %d}\n"
    return {
        "built-in": "character: {source: procedural, clip: walk}\n" + walk,
        "built-in tall slim": ("character: {source: procedural, clip: walk, body: {height: 1.95, chest: 0.85, "
                               "waist: 0.8, hips: 0.85, arms: 0.85, legs: 0.85}}\n" + walk),
        "built-in short heavy": ("character: {source: procedural, clip: walk, body: {height: 1.55, chest: 1.3, "
                                 "waist: 1.4, hips: 1.3, arms: 1.15, legs: 1.1}}\n" + walk),
        "CesiumMan": f"character: {{source: gltf, path: '{a / 'CesiumMan.glb'}', clip: 0}}\n" + walk,
        "CMU 131_01 (BVH)": (f"character: {{source: bvh, path: '{a / 'cmu_131_01_walk.bvh'}', clip: 0}}\n"
                             "frames: {start: 4.0, count: %d}\n"),
    }


def needed_asset(yaml_text: str) -> Path | None:
    for name in ("CesiumMan.glb", "cmu_131_01_walk.bvh"):
        if name in yaml_text:
            return _assets() / name
    return None


class Prepared:
    """One character's rig, motion, colliders and maps, built once for all its garments."""

    def __init__(self, scene):
        from pipeline.preflight import check_references
        from pipeline.run import load_character, split_and_fit
        from pipeline.scene_motion import frame_times, sample_scene_motion
        from stages.maps.build import build_maps
        from stages.rig.skinning import skin
        self.character = load_character(scene)
        check_references(scene, self.character)
        # the motion a scene with a garment plays (the blend-in from the rest pose, where it is dressed)
        self.motion = sample_scene_motion(scene, self.character, frame_times(scene), dressed=True)
        self.skinned = skin(self.character, self.motion)
        _, self.colliders = split_and_fit(scene, self.character, self.motion)
        m = scene["colliders"]["map"]
        self.maps = build_maps(self.colliders, kind=m["type"], n_theta=m["n_theta"], n_phi=m["n_phi"],
                               n_axial=m["n_axial"])


def run_pair(prepared: Prepared, scene) -> dict:
    """Dress, sew and simulate the scene's one garment on a prepared character; the pair's figures."""
    from pipeline.run import ignored_colliders, sim_params
    from pipeline.scene_motion import motion_floor, motion_speed_limit, motion_substeps
    from pipeline.dressing import build_scene_garments, garment_fits
    from stages.garments.fit import BODY_SHARE_MAX, FIT_GAP_MAX
    from stages.sim import simulate
    from pipeline.schema import SceneError
    from stages.checks import ContractError
    from stages.errors import InputError
    from stages.sim import SimulationDiverged
    p = prepared
    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            garments, builds = build_scene_garments(scene, p.character, p.motion, p.colliders, p.maps)
            height = float(np.ptp(p.character.vertices[:, 1]))
            params, note = motion_substeps(scene, sim_params(scene), p.skinned, height)
            params = motion_speed_limit(scene, params, p.skinned, p.motion.root_translation, p.motion.times, height)
            params = motion_floor(scene, params, p.skinned, p.motion.root_translation)
            if note:
                warnings.warn(note, stacklevel=1)
            result = simulate(p.character, p.motion, p.colliders, p.maps, garments, params,
                              ignore_colliders=ignored_colliders(scene, p.character))
        except (SceneError, InputError, ContractError, SimulationDiverged) as err:   # what `run` exits 2 on
            # the scene and garment are the row: keep what went wrong
            return {"status": "error: " + re.sub(r"^.*? on '[^']*': ", "", str(err)), "message": str(err),
                    "seconds": time.perf_counter() - t0}
    g = garments[0]
    log, build = builds[g.name]
    fit = garment_fits(p.character, p.motion, p.skinned, garments, builds, result)[0]
    tol = scene["garments"][0]["sewing"]["tolerance"]
    crossings = None
    if params.body_audit:
        from pipeline.body_report import blend_frames, body_audit, body_edges_max
        audit = body_audit(p.character, p.motion, p.skinned, result, max(blend_frames(scene, p.character), 1))
        crossings = body_edges_max(audit)
    r = {"status": "ok", "seam_gap_mm": float(log.gap_max[-1] * 1000), "sewn": bool(log.gap_max[-1] <= tol),
         "body_edges": crossings,
         "in_colliders": int(result.penetrations_colliders[1:].max(initial=0)),
         "in_body_pct": float(np.nanmax(fit.body_share[1:], initial=0.0) * 100),
         "fit_gap_cm": fit.fit_gap_median * 100, "floor_cm": float(fit.floor_clearance.min() * 100),
         "particles": int(g.n_particles), "seconds": time.perf_counter() - t0,
         "warnings": [str(w.message) for w in caught]}
    failed = []
    if not r["sewn"]:
        failed.append(f"seam gap {r['seam_gap_mm']:.1f} mm")
    if r["in_colliders"]:
        failed.append(f"{r['in_colliders']} in colliders")
    if r["in_body_pct"] > BODY_SHARE_MAX * 100:
        failed.append(f"{r['in_body_pct']:.2f} % in body")
    if np.isfinite(r["fit_gap_cm"]) and abs(r["fit_gap_cm"]) > FIT_GAP_MAX * 100:
        failed.append(f"fit gap {r['fit_gap_cm']:.1f} cm")
    if r["floor_cm"] < 0:
        failed.append(f"{-r['floor_cm']:.1f} cm below floor")
    if failed:
        r["status"] = "FAIL: " + ", ".join(failed)
    return r


def run_matrix(frames: int = 30, characters_: list[str] | None = None, kinds: list[str] | None = None,
               echo=print) -> dict:
    """{character: {kind: figures}}; an error a user would see (exit 2) is a row's status."""
    from pipeline.scene import parse_scene_text
    from pipeline.schema import SceneError
    for flag, asked, known in (("--character", characters_, list(characters())), ("--garment", kinds, KINDS)):
        for n in asked or ():
            if n not in known:   # an empty table and exit 0 would say every pair passed
                raise SceneError(f"{flag}: {n!r} is not in the matrix; expected one of: "
                                 + ", ".join(repr(k) for k in known))
    out: dict = {}
    for name, text in characters().items():
        if characters_ and name not in characters_:
            continue
        out[name] = {}
        need = needed_asset(text)
        if need is not None and not need.is_file():
            out[name] = {k: {"status": f"skipped: {need} not found"} for k in (kinds or KINDS)}
            continue
        base = text % frames + "colliders: {report_every: 0}\n"
        t0 = time.perf_counter()
        prepared = Prepared(parse_scene_text(base, source=f"matrix:{name}"))
        echo(f"{name}: rig, colliders, maps {time.perf_counter() - t0:.1f} s")
        for kind in kinds or KINDS:
            scene = parse_scene_text(base + f"garments: [{{type: pattern, name: {kind}, kind: {kind}}}]\n",
                                     source=f"matrix:{name}:{kind}")
            r = run_pair(prepared, scene)
            out[name][kind] = r
            echo(f"  {kind:<12} {row_figures(r)}")
    return out


def row_figures(r: dict) -> str:
    if "seam_gap_mm" not in r:
        return r["status"]
    return (f"{r['status']:<8} seam {r['seam_gap_mm']:.1f} mm, colliders {r['in_colliders']}, body {r['in_body_pct']:.2f} %, "
            f"body edges through cloth {_count(r.get('body_edges'))}, "
            f"fit {r['fit_gap_cm']:.1f} cm, floor {r['floor_cm']:.0f} cm, {r['seconds']:.1f} s")


def _count(v) -> str:
    return "-" if v is None else str(v)


def table(results: dict) -> str:
    rows = ["| character | garment | status | seam gap (mm) | in colliders | in body (%) | body edges through cloth | "
            "fit gap (cm) | above floor (cm) | time (s) |",
            "| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for name, per in results.items():
        for kind, r in per.items():
            if "seam_gap_mm" not in r:
                rows.append(f"| {name} | {kind} | {r['status']} | | | | | | | |")
                continue
            rows.append(f"| {name} | {kind} | {r['status']} | {r['seam_gap_mm']:.1f} | {r['in_colliders']} | "
                        f"{r['in_body_pct']:.2f} | {_count(r.get('body_edges'))} | {r['fit_gap_cm']:.1f} | {r['floor_cm']:.0f} | {r['seconds']:.1f} |")
    return "\n".join(rows)
