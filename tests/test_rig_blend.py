"""The blend from the rest pose into a running clip (stages.rig.blend, sample_motion's blend_frames)
and the scene's automatic blend length (pipeline.scene_motion.blend_in_seconds)."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings, strategies as st

from stages.rig.blend import (BLEND_MAX_S, BLEND_MIN_S, blend_schedule, blend_seconds, smootherstep,
                              smootherstep_tail)
from stages.rig.skinning import sample_motion
from stages.rig.transforms import forward_kinematics
from tests.test_rig_skinning import make_character, make_clip


def _world(motion) -> np.ndarray:
    """(F, J, 3) joint positions in world (root translation put back)."""
    return motion.joint_world[..., :3, 3] + motion.root_translation[:, None, :]


def test_smootherstep_and_its_tail_against_quadrature():
    u = np.linspace(0.0, 1.0, 2001)
    s = smootherstep(u)
    assert s[0] == 0.0 and s[-1] == 1.0 and (np.diff(s) >= 0).all()
    # the tail is the integral of smootherstep from u to 1 (trapezoid rule, 2000 intervals)
    steps = (s[1:] + s[:-1]) / 2 * np.diff(u)
    tail = np.concatenate([np.cumsum(steps[::-1])[::-1], [0.0]])
    np.testing.assert_allclose(smootherstep_tail(u), tail, atol=1e-6)


@given(st.integers(2, 80), st.floats(0.005, 0.1), st.floats(0.0, 10.0))
@settings(max_examples=60, deadline=None)
def test_blend_schedule_reaches_the_start_at_full_speed(n, dt, start):
    w, t = blend_schedule(n, dt, start)
    assert w[0] == 0.0 and (np.diff(w) > 0).all() and w[-1] < 1.0
    assert (np.diff(t) >= 0).all() and t[-1] < start
    assert abs(t[0] - (start - n * dt / 2)) < 1e-9                    # half the blend's time of clip played
    # the next frame (u = 1) is the start itself; the clip time's step there is a whole dt
    assert abs((start - t[-1]) - dt) < 0.02 * dt + 1e-12 or n < 8


def test_blend_ends_moving_with_the_clip_and_starts_at_rest():
    """Frame 0 is the rest pose; the joints' velocity at the end of the blend equals the clip's
    (the old blend to a frozen pose arrived at rest and then jumped to the clip's speed)."""
    clip = make_clip(7, 4, loop=True)
    c = make_character(7, n_joints=4, clips=[clip])
    dt = 1 / 60
    times = 0.3 + dt * np.arange(10)
    plain = sample_motion(c, 0, times)
    blended = sample_motion(c, 0, times, blend_frames=30)
    assert blended.n_frames == 40
    rest = forward_kinematics(c.parents, c.rest_local)
    np.testing.assert_allclose(_world(blended)[0], rest[:, :3, 3], atol=1e-9)
    # after the blend the clip itself (relative frames differ by the root's offset at frame 0)
    a, b = _world(blended)[30:], _world(plain)
    np.testing.assert_allclose(a - a[0], b - b[0], atol=1e-9)
    np.testing.assert_allclose(blended.joint_world[30:, :, :3, :3], plain.joint_world[:, :, :3, :3], atol=1e-9)
    v_in = _world(blended)[30] - _world(blended)[29]        # the last blend step
    v_clip = _world(plain)[1] - _world(plain)[0]            # the clip's first step
    speed = np.abs(v_clip).max()
    assert speed > 1e-3
    assert np.abs(v_in - v_clip).max() < 0.15 * speed
    # and it starts from rest: the first step is tiny next to the clip's
    assert np.abs(_world(blended)[1] - _world(blended)[0]).max() < 0.05 * speed


def test_blend_seconds_grows_with_the_distance_and_is_bounded():
    assert blend_seconds(0.0, 1.7) == 0.0 and blend_seconds(0.005, 1.7) == 0.0   # the rest pose: no blend
    got = [blend_seconds(d, 1.7) for d in (0.02, 0.2, 0.5, 0.8, 3.0)]
    assert got == sorted(got) and got[0] == BLEND_MIN_S and got[-1] == BLEND_MAX_S
    assert blend_seconds(0.4, 1.7) > blend_seconds(0.4, 3.4)     # a bigger body: the same reach is less
    assert blend_seconds(float("nan"), 1.7) == 0.0


def test_a_scene_blends_in_by_itself_and_blend_in_overrides():
    """frames.blend_in null (the default) sizes the blend from the rest pose to the clip's first pose;
    a given value wins; no garments or clip: rest need none."""
    from pipeline.run import load_character
    from pipeline.scene_motion import blend_in_seconds, frame_times, sample_scene_motion
    from pipeline.scene import parse_scene_text
    base = "character: {source: procedural, clip: walk}\nframes: {start: 0.5, count: 4%s}\n"
    dressed = "garments: [{type: pattern, name: s, kind: short_skirt}]\n"
    auto = parse_scene_text(base % "" + dressed, source="s.yaml")
    character = load_character(auto)
    seconds = blend_in_seconds(auto, character)
    assert BLEND_MIN_S <= seconds <= BLEND_MAX_S
    motion = sample_scene_motion(auto, character, frame_times(auto))
    assert motion.n_frames == 4 + round(seconds / auto["simulation"]["dt"])
    rest = forward_kinematics(character.parents, character.rest_local)[:, :3, 3]
    np.testing.assert_allclose(_world(motion)[0], rest, atol=1e-9)         # dressed on the rest pose
    assert blend_in_seconds(parse_scene_text(base % ", blend_in: 0.25" + dressed, source="s.yaml"), character) == 0.25
    assert blend_in_seconds(parse_scene_text(base % ", blend_in: 0" + dressed, source="s.yaml"), character) == 0.0
    assert blend_in_seconds(parse_scene_text(base % "", source="s.yaml"), character) == 0.0
    rest_scene = parse_scene_text("character: {source: procedural, clip: rest}\n" + dressed, source="s.yaml")
    assert blend_in_seconds(rest_scene, character) == 0.0


def test_fast_clips_get_more_substeps_and_a_warning_naming_the_frame():
    """pipeline.scene_motion.motion_substeps: sub-steps such that no sub-step moves the skin's fastest 1 % of
    vertices more than STEP_TRAVEL of the height; a scene's own `substeps` wins; capped."""
    from pipeline.run import sim_params
    from pipeline.scene_motion import MAX_SUBSTEPS, STEP_TRAVEL, motion_substeps
    from pipeline.scene import parse_scene_text
    scene = parse_scene_text("{}", source="s.yaml")
    params = sim_params(scene)
    height = 1.5
    rng = np.random.default_rng(0)
    skin0 = rng.normal(0, 0.2, (500, 3))
    slow = np.stack([skin0 + [0.0, 0.0, 0.01 * f] for f in range(6)])                 # 1 cm a frame
    same, note = motion_substeps(scene, params, slow, height)
    assert same == params and note is None
    fast = slow.copy()
    fast[4:] += [0.0, 0.0, 0.6]                                                        # 60 cm between frames 3 and 4
    got, note = motion_substeps(scene, params, fast, height)
    per_step = 0.61 / got.substeps
    assert per_step <= STEP_TRAVEL * height < 0.61 / (got.substeps - params.contact_steps())
    assert got.substeps % params.contact_steps() == 0 and got.substeps > params.substeps
    assert "between frames 3 and 4" in note and "610 mm" in note and f"{got.substeps} sub-steps" in note
    huge = slow.copy()
    huge[4:] += [0.0, 0.0, 30.0]
    capped, note = motion_substeps(scene, params, huge, height)
    assert capped.substeps == MAX_SUBSTEPS and "is the most used" in note
    own = parse_scene_text("simulation: {substeps: 20}", source="s.yaml")
    assert motion_substeps(own, sim_params(own), fast, height) == (sim_params(own), None)
