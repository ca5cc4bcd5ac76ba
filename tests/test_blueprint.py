"""What a recording opens on (issue 17): the embedded blueprint read back from the `.rrd`, the
colours, and cameras that hold every frame's body and garments."""
from __future__ import annotations

import numpy as np
import pytest
import rerun.blueprint.components as bpc

from pipeline import style
from pipeline.blueprint import (ASPECT_FULL, ASPECT_OVERVIEW, FOV_Y, Camera, front_three_quarter,
                                hull_points)
from pipeline.run import run_scene
from pipeline.scene import parse_scene_text
from tests.rrd_read import blueprint, blueprint_tabs, blueprint_views, entity_paths, rows

WALK = """
name: walk
character: {source: procedural, clip: walk}
frames: {count: 16}
colliders: {report_every: 0}
garments:
  - {type: pattern, name: skirt, kind: short_skirt, edge_length: 0.03}
"""
BARE = """
name: bare
character: {source: procedural, clip: walk}
frames: {count: 8}
colliders: {report_every: 0}
"""


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    out = tmp_path_factory.mktemp("bp") / "walk.rrd"
    run_scene(parse_scene_text(WALK, source="walk.yaml"), output=out, progress=False)
    return out


@pytest.fixture(scope="module")
def bare(tmp_path_factory):
    out = tmp_path_factory.mktemp("bp") / "bare.rrd"
    run_scene(parse_scene_text(BARE, source="bare.yaml"), output=out, progress=False)
    return out


def test_opens_on_the_frame_timeline_playing_in_a_loop_with_the_side_panels_collapsed(walk):
    bp = blueprint(walk)
    assert bp, "no blueprint stored in the recording"
    tp = bp["/time_panel"]
    assert tp["TimePanelBlueprint:timeline"] == "frame"
    assert tp["TimePanelBlueprint:play_state"] == bpc.PlayState.Playing.value
    assert tp["TimePanelBlueprint:loop_mode"] == bpc.LoopMode.All.value
    assert tp["TimePanelBlueprint:fps"] == pytest.approx(30.0, abs=0.01)
    assert tp["TimePanelBlueprint:state"] != bpc.PanelState.Hidden.value      # visible
    assert bp["/blueprint_panel"]["PanelBlueprint:state"] == bpc.PanelState.Collapsed.value
    assert bp["/selection_panel"]["PanelBlueprint:state"] == bpc.PanelState.Collapsed.value
    assert blueprint_tabs(bp)[None] == "overview"


def test_tabs_only_for_the_stages_that_ran(walk, bare):
    tabs = blueprint_tabs(blueprint(walk))
    assert [t for t in tabs if t] == ["overview", "rig", "colliders", "maps", "garments", "performance", "meta"]
    tabs = blueprint_tabs(blueprint(bare))      # no garments: no simulation, no sewing, no obstacles
    assert [t for t in tabs if t] == ["overview", "rig", "colliders", "maps", "meta"]
    views = blueprint_views(blueprint(bare))
    assert [views_named(views, i) for i in tabs["overview"]] == ["scene"]   # no empty plots


def views_named(views, view_id):
    return next(n for n, v in views.items() if v["id"] == view_id)


def test_overview_plots_read_cloth_quality_and_performance_has_its_own_tab(walk):
    bp = blueprint(walk)
    tabs, views = blueprint_tabs(bp), blueprint_views(bp)
    overview = {views_named(views, i) for i in tabs["overview"]}
    assert {"scene", "particles inside the body / a collider", "strain", "cloth intersections"} <= overview
    assert "step time (ms)" not in overview
    perf = {views_named(views, i) for i in tabs["performance"]}
    assert perf == {"step time (ms)", "contacts (particles per frame)"}
    # series another stage adds later show up by their paths
    assert "+ /sim/skirt/strain/**" in views["strain"]["contents"]
    assert "+ /sim/intersections/**" in views["cloth intersections"]["contents"]
    assert "+ /sim/penetrations/**" in views["particles inside the body / a collider"]["contents"]


def test_every_3d_view_has_a_fixed_camera(walk, bare):
    for path in (walk, bare):
        views = blueprint_views(blueprint(path))
        spatial = {n: v for n, v in views.items() if v["class"] == "3D"}
        assert len(spatial) >= 4
        for name, v in spatial.items():
            assert v["eye"] is not None, name
            pos, target = v["eye"]
            assert np.linalg.norm(pos - target) > 0.5, name


def test_scene_camera_holds_every_frames_body_and_garment_from_a_front_three_quarter_view(walk):
    pos, target = blueprint_views(blueprint(walk))["scene"]["eye"]
    body = np.stack([v for _, v in rows(walk, "rig/mesh", "Mesh3D:vertex_positions")])
    cloth = np.stack([v for _, v in rows(walk, "sim/skirt/mesh", "Mesh3D:vertex_positions")])
    assert len(body) == len(cloth) > 16                  # the clip's 16 frames after the blend-in
    assert np.ptp(body[:, :, 2].mean(1)) > 0.3          # it walks: a camera on frame 0 alone would not do
    cam = Camera(pos, target)
    assert cam.sees(body, aspect=ASPECT_OVERVIEW) and cam.sees(cloth, aspect=ASPECT_OVERVIEW)
    # front three-quarter: the built-in character faces +Z; the camera is 25-65 degrees round from it
    d = (pos - target) * [1, 0, 1]
    angle = np.degrees(np.arccos(d[2] / np.linalg.norm(d)))
    assert 25 < angle < 65
    assert pos[1] > target[1]                            # a little above


def test_scene_camera_on_a_character_without_garments(bare):
    pos, target = blueprint_views(blueprint(bare))["scene"]["eye"]
    body = np.stack([v for _, v in rows(bare, "rig/mesh", "Mesh3D:vertex_positions")])
    assert Camera(pos, target).sees(body, aspect=ASPECT_FULL)


def test_body_is_skin_coloured_garments_in_fabric_colours_regions_only_in_the_rig_tab(walk):
    albedo = rows(walk, "rig/mesh", "Mesh3D:albedo_factor")
    assert len(albedo) == 1 and int(albedo[0][1].ravel()[0]) == rgba_u32(style.SKIN)
    assert not rows(walk, "rig/mesh", "Mesh3D:vertex_colors")
    cloth = rows(walk, "sim/skirt/mesh", "Mesh3D:albedo_factor")
    assert int(cloth[0][1].ravel()[0]) == rgba_u32(style.fabric(0))
    regions = rows(walk, "rig/regions", "Mesh3D:vertex_colors")
    assert len(np.unique(regions[0][1])) > 10                  # one colour per region
    labels = rows(walk, "rig/regions/labels", "Points3D:labels")
    assert {"pelvis", "head", "thigh_l"} <= {str(x) for x in labels[0][1]}
    pins = rows(walk, "sim/skirt/attached", "Points3D:positions")
    frames = len(rows(walk, "sim/skirt/mesh", "Mesh3D:vertex_positions"))
    assert len(pins) == frames and len(pins[0][1]) > 10        # pins shown every frame
    bp = blueprint(walk)
    views = blueprint_views(bp)
    assert "+ /sim/skirt/attached" in views["scene"]["contents"]
    assert not any("/rig/regions" in q for q in views["scene"]["contents"])
    assert any("/rig/regions" in q for n, v in views.items() if n.startswith("bind pose") for q in v["contents"])


def rgba_u32(c) -> int:
    r, g, b, a = c
    return (r << 24) | (g << 16) | (b << 8) | a


@pytest.mark.parametrize("seed", range(5))
def test_front_three_quarter_holds_a_random_clip_tightly(seed):
    rng = np.random.default_rng(seed)
    walk = rng.normal(size=3) * [2, 0, 2]
    frames = np.stack([rng.normal(size=(200, 3)) * [0.3, 0.8, 0.2] + [0, 0.9, 0] + t * walk
                       for t in np.linspace(0, 1, 30)])
    forward = rng.normal(size=3)
    for aspect in (0.8, 1.15, 1.9):
        cam = front_three_quarter(hull_points(frames), forward, aspect=aspect)
        assert cam.sees(frames, aspect=aspect)
        # tight: something reaches within 15 % of the edge of the picture
        x, y, depth = cam._project(frames.reshape(-1, 3))
        t = np.tan(FOV_Y / 2)
        assert max(np.max(np.abs(y) / depth) / t, np.max(np.abs(x) / depth) / (t * aspect)) > 0.85
