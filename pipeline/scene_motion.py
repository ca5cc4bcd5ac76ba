"""The scene's motion as the stages get it: the clip times of its frames, the blend-in from the rest
pose, the poses the colliders are fitted over, and the simulation's sub-steps and speed limit for
how fast the clip moves the skin."""
from __future__ import annotations

import numpy as np

from pipeline.scene import Scene


def frame_times(scene: Scene, frames: int | None = None) -> np.ndarray:
    """Clip times of the frames to run: start + k * dt."""
    n = frames if frames is not None else scene["frames"]["count"]
    return scene["frames"]["start"] + scene["simulation"]["dt"] * np.arange(n, dtype=np.float64)


def blend_in_seconds(scene: Scene, character, dressed: bool | None = None) -> float:
    """The scene's blend-in: `frames.blend_in` when given, else (auto) sized by stages.rig.blend from
    how far the clip's pose at `frames.start` is from the rest pose, where garments are dressed; 0
    when nothing is dressed (dressed: None = the scene has garments)."""
    from stages.rig.blend import blend_seconds
    from stages.rig.skinning import pose_distance, sample_clip
    given = scene["frames"]["blend_in"]
    if given is not None:
        return float(given)
    clip = scene["character"]["clip"]
    dressed = bool(scene["garments"]) if dressed is None else dressed
    if clip == "rest" or not character.clips or not dressed:
        return 0.0
    first = sample_clip(character, character.clip(clip), np.array([scene["frames"]["start"]]))[0]
    height = float(np.ptp(character.vertices[:, 1])) if len(character.vertices) else 0.0
    return blend_seconds(pose_distance(character, character.rest_local, first), height)


def sample_scene_motion(scene: Scene, character, times: np.ndarray, dressed: bool | None = None):
    """The clip at `times`, after the blend-in (`blend_in_seconds`) from the rest pose."""
    from stages.rig.skinning import rest_motion, sample_motion
    clip = scene["character"]["clip"]
    if clip == "rest" or not character.clips:
        return rest_motion(character, len(times), scene["simulation"]["dt"])
    blend = int(round(blend_in_seconds(scene, character, dressed) / scene["simulation"]["dt"]))
    if blend and len(times) < 2:
        times = frame_times(scene, 2)[:2]
    return sample_motion(character, clip, times, blend_frames=blend)


def collider_poses(scene: Scene, character, motion) -> np.ndarray:
    """(F, J, 4, 4) joint transforms the region split is measured over: every frame the scene plays
    (blend-in included), plus, for `clip: rest`, the built-in range-of-motion sample. Poses the
    scene never plays (the rest of a long clip) would only widen the swept hulls."""
    from stages.rig.motion_range import range_of_motion
    if scene["character"]["clip"] == "rest" or not character.clips:
        return np.concatenate([motion.joint_world, range_of_motion(character)])
    return motion.joint_world


# a sub-step moves the skin at most this share of the body's height; a faster clip gets more sub-steps
STEP_TRAVEL = 0.01
MAX_SUBSTEPS = 100


def motion_substeps(scene: Scene, params, skinned: np.ndarray, height: float):
    """params with more sub-steps where the clip moves the skin far in a frame (a run, a kick, a
    jump) and `simulation.substeps` is left to the preset: enough that no sub-step moves the skin's
    fastest 1 % of vertices more than STEP_TRAVEL of the height (relative frame), rounded up to a
    whole number of cloth collision calls, at most MAX_SUBSTEPS. Returns (params, warning or None).
    A CMU walk 3x as fast: 50 sub-steps; p99 strain at the last frame 37 -> 6 %, 32 -> 0
    self-crossing edges."""
    from dataclasses import replace
    if scene["simulation"]["substeps"] is not None or len(skinned) < 2 or not height > 0:
        return params, None
    step = np.percentile(np.linalg.norm(np.diff(skinned, axis=0), axis=2), 99, axis=1)   # (F-1,) m
    f = int(np.argmax(step))
    need = int(np.ceil(step[f] / (STEP_TRAVEL * height)))
    if need <= params.substeps:
        return params, None
    k = params.contact_steps() if params.cloth_collision else 1
    n = min(MAX_SUBSTEPS, -(-need // k) * k)
    return replace(params, substeps=n), (
        f"simulation: {n} sub-steps a frame instead of {params.substeps}: the skin moves up to "
        f"{step[f] * 1000:.0f} mm ({100 * step[f] / height:.0f} % of its height) between frames {f} and {f + 1}"
        + (f"; {MAX_SUBSTEPS} is the most used, {need} would keep each under {100 * STEP_TRAVEL:.0f} %"
           if need > MAX_SUBSTEPS else ""))


def motion_speed_limit(scene: Scene, params, skinned: np.ndarray, root: np.ndarray, times: np.ndarray,
                       height: float):
    """params with `simulation.speed_limit`, or where it is null and the preset is not the paper's, the
    clip's: 3 times the fastest skin speed relative to the root (skinned (F, V, 3), root (F, 3) world
    m) plus twice the speed of a fall from the body's height. Cloth moves with the body or falls;
    much faster is cloth a collider threw (a Kenney chibi's skirt pressed between its arm and leg
    boxes: 117 m/s, diverged). A limit of twice the skin speed plus 1.5 falls (13.6 m/s on CesiumMan)
    capped its T-shirt's hem whipping off the forearm in 33 frames and raised the T-shirt's mean p99
    strain after the blend from 26 to 42 %."""
    from dataclasses import replace
    given = scene["simulation"]["speed_limit"]
    if given is not None:
        return replace(params, speed_limit=float(given))
    if scene["simulation"]["preset"] == "paper" or len(skinned) < 2 or not height > 0:
        return params
    rel = skinned - root[:, None, :]
    dt = np.maximum(np.diff(times), 1e-9)[:, None]
    skin_speed = float((np.linalg.norm(np.diff(rel, axis=0), axis=2) / dt).max())
    return replace(params, speed_limit=3.0 * skin_speed + 2.0 * float(np.sqrt(2.0 * 9.81 * height)))



def motion_floor(scene: Scene, params, skinned: np.ndarray, root: np.ndarray):
    """params with the scene's `simulation.floor` (SimParams.floor, world m): a number as it is; 'auto'
    under the character's feet: the colliders' inflation (`colliders.delta`, where the soles of the
    foot colliders are) under the lowest point its skin (skinned (F, V, 3) relative frame, root (F, 3))
    reaches over the clip (lowest_skin_point: y = 0, where every character is put, stages.rig, or
    where a foot dips under it), so that the floor does not press cloth up into a foot's collider
    standing on it (at the skin's lowest point, cloth a foot stepped on was held between the two and
    the sole's edges passed through it: CesiumMan's circle skirt, 19 -> 28 body edges through the cloth); none for 'none', with obstacles (the scene's environment:
    a `plane` obstacle is its floor) or the paper preset (paper A's figures had none)."""
    from dataclasses import replace
    given = scene["simulation"]["floor"]
    if given == "none" or given is None:
        return params
    if given != "auto":
        return replace(params, floor=float(given))
    if scene["simulation"]["preset"] == "paper" or scene["obstacles"] or len(skinned) == 0:
        return params
    return replace(params, floor=lowest_skin_point(skinned, root) - float(scene["colliders"]["delta"]))


def lowest_skin_point(skinned: np.ndarray, root: np.ndarray) -> float:
    """m: the lowest world height the skin (skinned (F, V, 3) relative frame, root (F, 3)) reaches."""
    return float((skinned[..., 1] + root[:len(skinned), None, 1]).min())
