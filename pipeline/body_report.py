"""The body audit in a run (stages.sim.body_audit): where the body passes through the cloth between
its particles, measured after the simulation, logged and summarised.

Recording: per garment the series `sim/penetrations/body_edges/<garment>` (body-mesh edges through
the garment's triangles), `sim/penetrations/body_edges_self_overlap/<garment>` (of them, those where
the body meets itself) and `sim/penetrations/cloth_edges/<garment>` (the garment's edges through
body triangles), beside the particle count `sim/penetrations/body`; the markers
`sim/<garment>/body_cuts` (a point where each crossing edge meets the triangle, per frame; magenta,
orange where the body meets itself) shown in the scene view; `sim/body_audit` (the figures and the joints named). Summary: one line per garment
(worst frame after the blend-in, the joints nearest the crossings) beside the particles inside the
body, and a warning per garment with a body edge through it after the blend-in. Runs when
`simulation.body_audit` is on (the default), like the particle count.
"""
from __future__ import annotations

import time
import warnings

import numpy as np
import rerun as rr

CUT_COLOR = (255, 30, 200, 255)     # magenta: reads on the skin and on every fabric colour
OVERLAP_CUT_COLOR = (255, 150, 0, 255)  # orange: a cut where the body meets itself (no room for cloth)
OVERLAP_COLOR = (255, 150, 0)
CUT_RADIUS = 0.008
BODY_EDGES_COLOR = (220, 30, 160)
CLOTH_EDGES_COLOR = (120, 30, 200)


def blend_frames(scene, character) -> int:
    """Frames of the blend-in the scene's motion starts with (pipeline.scene_motion.sample_scene_motion)."""
    from pipeline.scene_motion import blend_in_seconds
    if scene["character"]["clip"] == "rest" or not character.clips:
        return 0
    return int(round(blend_in_seconds(scene, character) / scene["simulation"]["dt"]))


def body_audit(character, motion, skinned, result, first_frame: int):
    """The BodyCrossings of a SimResult against the skinned character (skinned: (F, V, 3) relative frame)."""
    from stages.sim.body_audit import BodyFrames, audit_body_crossings
    from dataclasses import replace
    f = result.n_frames     # a partial result: its frames only
    motion = replace(motion, times=motion.times[:f], joint_world=motion.joint_world[:f],
                     root_translation=motion.root_translation[:f])
    return audit_body_crossings(result, BodyFrames.of(character, motion, np.asarray(skinned)[:f]),
                                first_frame=first_frame)


def log_body_crossings(rec: rr.RecordingStream, audit, times: np.ndarray) -> None:
    from pipeline.logs import log_scalar_series, log_text, time_columns
    for g in audit.garments:
        log_scalar_series(rec, f"sim/penetrations/body_edges/{g.name}", g.body_edges, times,
                          name=f"{g.name}: body edges through the cloth", color=BODY_EDGES_COLOR)
        log_scalar_series(rec, f"sim/penetrations/cloth_edges/{g.name}", g.cloth_edges, times,
                          name=f"{g.name}: cloth edges through the body", color=CLOTH_EDGES_COLOR)
        log_scalar_series(rec, f"sim/penetrations/body_edges_self_overlap/{g.name}", g.body_edges_in_overlap(), times,
                          name=f"{g.name}: of them where the body meets itself", color=OVERLAP_COLOR)
        path = f"sim/{g.name}/body_cuts"
        rec.log(path, rr.Points3D.from_fields(radii=[CUT_RADIUS]), static=True)
        pts = np.concatenate(g.points).reshape(-1, 3).astype(np.float32)
        meets = np.concatenate([np.asarray(k, bool) for k in g.self_overlap]) if pts.size else np.zeros(0, bool)
        colors = np.where(meets[:, None], np.array(OVERLAP_CUT_COLOR, np.uint8), np.array(CUT_COLOR, np.uint8))
        rec.send_columns(path, indexes=time_columns(times),
                         columns=rr.Points3D.columns(positions=pts, colors=colors.astype(np.uint8)).partition(
                             np.array([len(p) for p in g.points])))
    lines = [f"- {k}: {v}" for k, v in audit.summary().items()]
    for g in audit.garments:
        total = g.joint_counts[audit.first_frame:].sum(axis=0)
        top = [j for j in np.argsort(-total, kind="stable")[:5] if total[j] > 0]
        if top:
            lines.append(f"- {g.name}: joints nearest the crossings (crossing edges summed over the frames from "
                         f"{audit.first_frame}): " + ", ".join(f"{audit.joint_names[j]} {int(total[j])}" for j in top))
    log_text(rec, "sim/body_audit", "\n".join(lines))


def audit_and_log(rec: rr.RecordingStream, scene, state: dict, announce=lambda name: None) -> None:
    """After the simulation of a run (pipeline.run.run_scene's `state`): the body audit into the
    recording, its lines into the summary's penetrations (after the particles inside the body), a
    stage time and the warnings; state['body_crossings'] = the BodyCrossings."""
    from pipeline.summary import StageReport
    result, summary = state.get("result"), state["summary"]
    if result is None or not result.garments or not result.n_frames or not scene["simulation"]["body_audit"]:
        return
    character = state["character"]
    announce("body audit")
    t0 = time.perf_counter()
    first = max(blend_frames(scene, character), 1)
    audit = body_audit(character, state["motion"], state["skinned"], result, first)
    seconds = time.perf_counter() - t0
    # sizes only: the summary's markdown leaves wall-clock figures out (the stage's seconds are in timings/)
    summary.stages.append(StageReport("body audit", seconds, {"frames": result.n_frames,
                                                              "exact_pairs": audit.exact_pairs}))
    state["body_crossings"] = audit
    log_body_crossings(rec, audit, result.times)
    pen = summary.penetrations
    after = next((k for k in pen if k.startswith("inside body")), None)
    items = list(pen.items())
    at = next((i + 1 for i, (k, _) in enumerate(items) if k == after), len(items))
    pen.clear()
    pen.update(dict(items[:at] + list(audit.summary().items()) + items[at:]))
    for w in audit.warnings:
        warnings.warn(w, stacklevel=1)


def body_edges_max(audit, in_overlap: bool = False) -> int:
    """The most body edges through the cloth (all garments) in a frame after the blend-in, away from
    where the body meets itself (or, in_overlap, where it does)."""
    return int(audit.body_edges_after(in_overlap).max(initial=0))
