"""The scene's `simulation.floor` (pipeline.scene_motion.motion_floor) and how far a garment slid off
the body (stages.garments.fit.garment_slide), the corpus's verdict on a garment that slid off."""
import numpy as np
import pytest

from pipeline.scene import parse_scene_text
from pipeline.scene_motion import motion_floor
from pipeline.schema import SceneError
from stages.garments.fit import garment_slide, slide_anchors
from stages.sim import SimParams


def _scene(extra: str = "", obstacles: bool = False):
    text = "character: {source: procedural, clip: walk}\n" + extra
    if obstacles:
        text += "obstacles:\n  - {type: plane, name: floor, point: [0, 0, 0], normal: [0, 1, 0], size: 4.0}\n"
    return parse_scene_text(text)


SKIN = np.array([[[0.0, 0.02, 0.0], [0.0, 1.7, 0.0]], [[0.0, -0.01, 0.0], [0.0, 1.7, 0.0]]])   # a foot dips
ROOT = np.array([[0.0, 0.0, 0.0], [0.0, 0.005, 0.0]])


def test_auto_is_the_lowest_skin_point_over_the_clip():
    assert _scene()["simulation"]["floor"] == "auto"
    p = motion_floor(_scene(), SimParams(), SKIN, ROOT)
    assert p.floor == pytest.approx(-0.005 - 0.01)          # under it by the colliders' inflation (delta)
    p = motion_floor(_scene("colliders: {delta: 0.02}\n"), SimParams(), SKIN, ROOT)
    assert p.floor == pytest.approx(-0.005 - 0.02)


@pytest.mark.parametrize("extra, obstacles, want", [
    ("simulation: {floor: none}\n", False, None),
    ("simulation: {floor: 0.25}\n", False, 0.25),
    ("simulation: {floor: -1}\n", False, -1.0),
    ("", True, None),                                        # obstacles: their plane is the floor
    ("simulation: {floor: 0.1}\n", True, 0.1),               # unless the scene asks for one
    ("simulation: {preset: paper}\n", False, None),          # paper A had no floor
])
def test_floor_keys(extra, obstacles, want):
    assert motion_floor(_scene(extra, obstacles), SimParams(), SKIN, ROOT).floor == want


@pytest.mark.parametrize("bad", ["banana", "true", "[0, 1]", "1e9"])
def test_a_bad_floor_is_named(bad):
    with pytest.raises(SceneError, match="simulation.floor"):
        _scene(f"simulation: {{floor: {bad}}}\n")


def test_slide_reads_how_far_the_anchors_left_their_skin():
    rng = np.random.default_rng(0)
    skin0 = rng.uniform(-0.2, 0.2, (200, 3)) + [0, 1.0, 0]
    move = np.array([0.0, 0.3, 0.5])          # the body walks forward and hops: the skin moves rigidly
    skin = np.stack([skin0, skin0 + move, skin0 + 2 * move])
    garment0 = skin0[:20] + [0.0, 0.0, 0.01]  # 1 cm off the skin
    worn = np.stack([garment0, garment0 + move, garment0 + 2 * move])
    np.testing.assert_allclose(garment_slide(skin, worn, np.arange(20)), 0.0, atol=1e-9)
    slid = worn.copy()
    slid[2, :, 1] -= 0.8                      # dropped 80 cm off where it was at the last frame
    assert garment_slide(skin, slid, np.arange(20))[2] > 0.5


def test_slide_anchors_are_the_fit_edges_else_the_top():
    x = np.stack([np.zeros(100), np.arange(100.0), np.zeros(100)], axis=1)
    assert list(slide_anchors(x, np.array([3, 4]))) == [3, 4]
    assert sorted(slide_anchors(x, np.zeros(0, np.int64))) == [95, 96, 97, 98, 99]
