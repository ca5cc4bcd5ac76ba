"""Limbs that come against a limb the garment is worn round pass through it (stages.garments.band.
pinching_limbs): a chibi's block arm, in its T-shirt sleeve, sits 1.1 cm above its leg's top, and each
arm swing pressed the shirt's armpit between the two (edges torn past 500 %, the run stopped)."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from tests.test_garments_chibi import _bind, chibi  # noqa: F401  (chibi: the fixture)


def _tshirt(c, tmp_path, clip, start, count=2):
    from pipeline.dressing import build_scene_garments
    from stages.maps.build import build_maps
    scene, c, m, cols = _bind(c, tmp_path, "[{type: pattern, kind: tshirt}]", clip=clip, start=start)
    if count != 2:
        from pipeline.run import frame_times, split_and_fit
        from pipeline.scene_motion import sample_scene_motion
        scene["frames"]["count"] = count
        m = sample_scene_motion(scene, c, frame_times(scene, None))
        _, cols = split_and_fit(scene, c, m)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        (g,), _ = build_scene_garments(scene, c, m, cols, build_maps(cols), {})
    return scene, c, m, cols, g, [str(w.message) for w in caught]


def test_related_joints_are_one_chain():
    from stages.garments.band import _related
    parents = np.array([-1, 0, 1, 2, 0, 4], np.int32)      # root; 1-2-3 an arm; 4-5 a leg
    assert _related(parents, 1, 3) and _related(parents, 3, 1) and _related(parents, 0, 5)
    assert not _related(parents, 3, 5) and not _related(parents, 2, 4)


def test_the_legs_pass_through_a_tshirt_whose_sleeves_they_meet(chibi, tmp_path):
    # the sprint swings the arms down onto the legs' tops: the T-shirt's sleeves (round the arms) and
    # its hem (over the legs' tops) had no room between them; the legs now pass through the shirt
    names = list(chibi.joint_names)
    *_, g, said = _tshirt(chibi, tmp_path, "sprint", 0.2, count=30)
    assert {names[j] for j in g.passing_joints} >= {"leg-left", "leg-right"}
    assert not {names[j] for j in g.passing_joints} & {"arm-left", "arm-right", "torso"}   # worn round / the trunk
    assert any("come within 1 cm of those of arm-" in s and "pass through the garment" in s for s in said)


def test_the_legs_collide_where_the_arms_keep_off_them(chibi, tmp_path):
    # the static clip: the arms stay where the bind pose has them, above the legs' tops
    *_, g, said = _tshirt(chibi, tmp_path, "static", 0.04)
    assert g.passing_joints == ()
    assert not any("come within" in s for s in said)


@pytest.mark.parametrize("start", [0.0, 0.8])
def test_a_human_s_tshirt_lets_no_limb_through(assets_dir, tmp_path, start):
    # CesiumMan's walk: its upper arm's collider overlaps its thigh's by up to 2.9 cm, and from 0.8 s
    # the cloth round its right arm came within 1 cm of its left hand's: limbs with an elbow or a knee
    # bend away, and the shirt lets none of them through
    from stages.rig.gltf import load_gltf
    c = load_gltf(assets_dir / "CesiumMan.glb")
    *_, g, said = _tshirt(c, tmp_path, 0, start, count=30)
    assert g.passing_joints == () and not any("come within" in s for s in said)


def test_a_short_limb_has_one_or_two_joints():
    from stages.garments.band import _short_limb
    from stages.garments.types import BindPose
    # root 0; chibi-like arm 1 (one joint), leg 2-3 (two joints); a chain 4-5-6 with a finger 7
    parents = np.array([-1, 0, 0, 2, 0, 4, 5, 6], np.int32)
    n = len(parents)
    bind = BindPose(np.tile(np.eye(4), (n, 1, 1)), np.zeros((n, 3)), tuple(f"j{k}" for k in range(n)),
                    parents=parents, limb_joints=frozenset(range(1, n)))
    assert [_short_limb(bind, j) for j in range(1, n)] == [True, True, True, False, False, False, False]


def test_a_sprint_in_a_tshirt_is_simulated_to_its_end(tmp_path, assets_dir):
    # Kenney female sprint from 0.2 s: stopped at frame 23 (an edge 551 %, torn between arm-right and
    # leg-right); now simulated through, no edge past the divergence bound
    from pipeline.cloth_checks import check_blown_up
    from pipeline.dressing import build_scene_garments
    from pipeline.matrix import Prepared
    from pipeline.run import sim_params
    from pipeline.scene import load_scene
    from pipeline.scene_motion import motion_speed_limit, motion_substeps
    from stages.sim import simulate
    path = tmp_path / "s.yaml"
    path.write_text(f"character: {{source: gltf, path: {assets_dir / 'kenney_mini_female_b.glb'}, clip: sprint}}\n"
                    "frames: {start: 0.2, count: 30}\ngarments: [{type: pattern, kind: tshirt}]\n")
    scene = load_scene(path)
    p = Prepared(scene)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        garments, _ = build_scene_garments(scene, p.character, p.motion, p.colliders, p.maps)
        height = float(np.ptp(p.character.vertices[:, 1]))
        params, _ = motion_substeps(scene, sim_params(scene), p.skinned, height)
        params = motion_speed_limit(scene, params, p.skinned, p.motion.root_translation, p.motion.times, height)
        result = simulate(p.character, p.motion, p.colliders, p.maps, garments, params)
    body = p.skinned + p.motion.root_translation[:, None, :]
    assert check_blown_up(result, body, height, garments) is None
