"""What `run` prepares from a scene file before dressing, for tests that dress or place garments."""
from __future__ import annotations


def scene_parts(path):
    """(scene, character, motion, colliders) of the scene file at `path`."""
    from pipeline.run import frame_times, load_character, split_and_fit
    from pipeline.scene import load_scene
    from pipeline.scene_motion import sample_scene_motion
    scene = load_scene(path)
    character = load_character(scene)
    motion = sample_scene_motion(scene, character, frame_times(scene, None))
    _, colliders = split_and_fit(scene, character, motion)
    return scene, character, motion, colliders
