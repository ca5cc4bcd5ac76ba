"""End to end: a scene through every stage into a recording, read back with the SDK's reader."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.run import load_character, run_scene
from pipeline.scene import load_scene, parse_scene_text
from pipeline.scene_motion import frame_times, sample_scene_motion
from tests.rrd_read import content, entity_paths, rows, timelines

REPO = Path(__file__).resolve().parent.parent
FRAMES = 6   # clip frames; a run also has the blend-in from the rest pose before them (summary.frames)


@pytest.fixture(scope="module")
def default_run(tmp_path_factory):
    scene = load_scene(REPO / "scenes" / "default.yaml")
    out = tmp_path_factory.mktemp("rec") / "default.rrd"
    summary = run_scene(scene, output=out, frames=FRAMES, progress=False)
    return scene, out, summary


def test_every_stage_is_logged(default_run):
    scene, out, summary = default_run
    assert summary.output == out and out.is_file()
    assert [s.name for s in summary.stages] == ["rig", "colliders", "coverage", "maps", "garments", "simulation",
                                                "cloth audit", "body audit"]
    assert "converged" in summary.stages[4].sizes["skirt sewing"]
    paths = entity_paths(out)
    for p in ["/rig/mesh", "/rig/skeleton", "/rig/joints", "/rig/regions", "/colliders/report", "/maps/report",
              "/sim/skirt/mesh", "/sim/penetrations/colliders", "/sim/penetrations/body", "/sim/penetrations/pinched",
              "/timings/step_ms",
              "/timings/stages", "/meta/scene", "/meta/provenance", "/meta/summary", "/sim/params", "/sim/skirt/strain",
              "/sim/intersections/skirt", "/sim/penetrations/body_edges/skirt", "/sim/skirt/body_cuts"]:
        assert p in paths, p
    hulls = {p.split("/")[3] for p in paths if p.startswith("/colliders/hulls/")}
    sizes = summary.stages[1].sizes
    assert sizes["split"] == "motion" and sizes["swept_hulls"] == 0 and sizes["spheres"] == 0 and sizes["balls"] > 0
    assert len(hulls) == sizes["rigid_hulls"]
    for bone in hulls:
        for part in ("raw", "inflated", "simplified", "region"):
            assert f"/colliders/hulls/{bone}/{part}" in paths
        assert f"/maps/{bone}/obb" in paths and f"/maps/{bone}/cells" in paths
    assert timelines(out) == {"frame", "sim_time", "sewing_iteration"}
    # the floor (simulation.floor: auto) under the character, under its lowest skin point, under the cloth
    floor = rows(out, "floor/mesh", "Mesh3D:vertex_positions", static=True)[0][1]
    assert np.ptp(floor[:, 1]) == 0 and abs(float(floor[0, 1])) < 0.05
    cloth = np.stack([v for _, v in rows(out, "sim/skirt/mesh", "Mesh3D:vertex_positions")])
    assert cloth[1:, :, 1].min() >= floor[0, 1]
    for part in ("flat", "placed", "sewing", "sewn", "sewing/gap_max", "report"):
        assert f"/garments/skirt/{part}" in paths


def test_per_frame_series_have_one_value_per_frame(default_run):
    _, out, summary = default_run
    for entity in ("sim/penetrations/colliders", "sim/penetrations/body", "sim/penetrations/pinched", "timings/step_ms"):
        got = rows(out, entity, "Scalars:scalars")
        assert [f for f, _ in got] == list(range(summary.frames)), entity
    pen = np.array([v[0] for _, v in rows(out, "sim/penetrations/colliders", "Scalars:scalars")])
    assert (pen[1:] == 0).all()          # nothing left inside a collider after the response
    cloth = rows(out, "sim/skirt/mesh", "Mesh3D:vertex_positions")
    assert [f for f, _ in cloth] == list(range(summary.frames))
    assert all(np.isfinite(v).all() for _, v in cloth)
    assert not np.allclose(cloth[0][1], cloth[-1][1])   # the cloth moved
    pinned = rows(out, "sim/skirt/attached", "Points3D:positions")
    assert [f for f, _ in pinned] == list(range(summary.frames))
    # the attached points are mesh vertices, the same ones every frame: the waistband ring
    idx = [np.flatnonzero((np.abs(cloth[f][1][:, None] - p[None]).max(axis=2) < 1e-7).any(axis=1))
           for f, p in pinned]
    assert all(len(i) == len(pinned[0][1]) > 0 for i in idx) and all(np.array_equal(i, idx[0]) for i in idx)
    colors = rows(out, "sim/skirt/attached", "Points3D:colors", static=True)
    assert len(colors) == 1 and len(colors[0][1]) == len(pinned[0][1])


def test_cloth_audit_series_are_logged_and_summarised(default_run):
    """sim/<garment>/strain: mean <= p99 <= max (%) per frame; sim/intersections/<garment>: a count
    per frame; the summary names both."""
    _, out, summary = default_run
    strain = rows(out, "sim/skirt/strain", "Scalars:scalars")
    assert [f for f, _ in strain] == list(range(summary.frames))
    s = np.array([v for _, v in strain])
    assert s.shape == (summary.frames, 3) and (s[:, 0] <= s[:, 1]).all() and (s[:, 1] <= s[:, 2]).all()
    assert s[-1, 0] < 2.0 and s[-1, 1] < 10.0                   # cloth, not rubber (percent)
    crossings = rows(out, "sim/intersections/skirt", "Scalars:scalars")
    assert [f for f, _ in crossings] == list(range(summary.frames))
    assert all(float(v[0]).is_integer() and v[0] >= 0 for _, v in crossings)
    assert any("strain" in k for k in summary.penetrations) and any("crossing" in k for k in summary.penetrations)


def test_skinned_mesh_in_the_recording_is_the_world_frame_skin(default_run):
    scene, out, summary = default_run
    from stages.rig.skinning import skin
    character = load_character(scene)
    motion = sample_scene_motion(scene, character, frame_times(scene, FRAMES))
    world = skin(character, motion) + motion.root_translation[:, None, :]
    got = rows(out, "rig/mesh", "Mesh3D:vertex_positions")
    assert len(got) == summary.frames
    np.testing.assert_allclose(got[-1][1], world[-1], atol=1e-5)
    assert np.linalg.norm(motion.root_translation[-1]) > 0.05   # the walk moves the root


def test_scene_yaml_and_summary_are_stored(default_run):
    scene, out, summary = default_run
    text = str(rows(out, "meta/scene", "TextDocument:text")[0][1])
    assert "kind: short_skirt" in text
    summary = str(rows(out, "meta/summary", "TextDocument:text")[0][1])
    assert "colliders" in summary and "simulation" in summary
    prov = str(rows(out, "meta/provenance", "TextDocument:text")[0][1])
    assert "rerun-sdk" in prov and "CC-BY 4.0" in prov


def test_same_scene_gives_the_same_recording(default_run, tmp_path):
    scene, out, summary = default_run
    again = tmp_path / "again.rrd"
    run_scene(scene, output=again, frames=FRAMES, progress=False)
    wall = ("/timings/step_ms", "/timings/stages", "/meta/summary")   # wall-clock measurements differ by nature
    a = [(e, b) for e, b in content(out) if e not in wall]
    b = [(e, b) for e, b in content(again) if e not in wall]
    assert len(a) == len(b) and all(ea == eb and ba.equals(bb) for (ea, ba), (eb, bb) in zip(a, b))


def test_failed_run_keeps_the_earlier_recording(default_run, tmp_path):
    scene, out, summary = default_run
    before = out.read_bytes()
    bad = parse_scene_text(scene.text.replace("clip: walk", "clip: nowhere"), source="bad.yaml")
    from pipeline.schema import SceneError
    with pytest.raises(SceneError, match="nowhere"):
        run_scene(bad, output=out, frames=2, progress=False)
    assert out.read_bytes() == before
    assert sorted(p.name for p in out.parent.iterdir()) == [out.name]


def test_skeleton_and_colliders_sit_inside_the_skinned_body(default_run):
    """Joints and hull regions logged in world must coincide with the skinned mesh of the frame."""
    scene, out, summary = default_run
    mesh = rows(out, "rig/mesh", "Mesh3D:vertex_positions")
    joints = rows(out, "rig/joints", "Points3D:positions")
    for f in (0, summary.frames - 1):
        lo, hi = mesh[f][1].min(0), mesh[f][1].max(0)
        j = joints[f][1]
        assert ((j >= lo - 0.02) & (j <= hi + 0.02)).all(), f
    # a hull's region points, moved by the logged per-frame transform, are skinned mesh vertices
    from pipeline.run import split_and_fit
    character = load_character(scene)
    split, _ = split_and_fit(scene, character, sample_scene_motion(scene, character, frame_times(scene, FRAMES)))
    bone = split.hull_bones[0]
    name = character.joint_names[bone]
    t = rows(out, f"colliders/hulls/{name}", "Transform3D:translation")
    r = rows(out, f"colliders/hulls/{name}", "Transform3D:mat3x3")
    region = rows(out, f"colliders/hulls/{name}/region", "Points3D:positions")[0][1]
    f = summary.frames - 1
    rot = np.asarray(r[f][1], dtype=np.float64).reshape(3, 3).T   # rerun stores column-major
    moved = region @ rot.T + np.asarray(t[f][1]).reshape(3)
    idx = split.rigid_vertices(bone)
    err = np.linalg.norm(moved - mesh[f][1][idx], axis=1)
    # "rigid" allows a vertex to move up to motion_tolerance * delta in its bone's frame
    tol = scene["colliders"]["motion_tolerance"] * scene["colliders"]["delta"]
    assert np.median(err) < 1e-4 and err.max() <= tol + 1e-9


def test_coverage_report_is_logged_per_sampled_frame(default_run):
    scene, out, summary = default_run
    report = str(rows(out, "colliders/report", "TextDocument:text")[0][1])
    assert "Coverage and excess" in report and "Hull fit" in report
    assert "_ball" in report                                 # the skinned balls are listed by name
    for key in ("coverage", "excess_p95", "excess_max", "shell", "skin_exposed"):
        got = rows(out, f"colliders/fit/{key}", "Scalars:scalars")
        assert [f for f, _ in got] == sorted({*range(0, summary.frames, 10), summary.frames - 1}), key   # every 10th and the last
    cov = np.array([v[0] for _, v in rows(out, "colliders/fit/coverage", "Scalars:scalars")])
    assert ((cov > 99.0) & (cov <= 100.0)).all()
    exposed = np.array([v[0] for _, v in rows(out, "colliders/fit/skin_exposed", "Scalars:scalars")])
    # % of the skin's points out of every collider: the built-in body's hull seams at bent knees and elbows
    assert ((exposed >= 0.0) & (exposed < 2.0)).all()
    assert summary.stages[2].sizes["skin_exposed"] == f"{exposed.max():.2f} %"
    assert "collider coverage" in summary.tables and "coverage" in summary.stages[2].sizes


def test_obstacle_scene_logs_obstacles_contacts_and_keeps_cloth_on_the_table(tmp_path):
    from pipeline.scene import parse_scene_text
    text = (REPO / "scenes" / "table_drape.yaml").read_text()
    assert "  body_audit: false\n" in text
    scene = parse_scene_text(text.replace("  body_audit: false\n", "  body_audit: false\n  strain_colors: true\n"),
                             base_dir=REPO / "scenes", default_name="table_drape")
    out = tmp_path / "table.rrd"
    run_scene(scene, output=out, frames=24, progress=False)
    # strain_colors: the cloth mesh carries per-vertex colours at every frame
    colors = rows(out, "sim/cloth/mesh", "Mesh3D:vertex_colors")
    assert [f for f, _ in colors] == list(range(24)) and len(colors[-1][1]) == 2500
    paths = entity_paths(out)
    assert {"/obstacles/table/mesh", "/obstacles/table/kdop", "/sim/contacts/obstacles",
            "/sim/contacts/obstacles/points", "/sim/cloth/mesh"} <= paths
    assert "/floor/mesh" not in paths                         # floor: auto is off with obstacles
    contacts = [int(v[0]) for _, v in rows(out, "sim/contacts/obstacles", "Scalars:scalars")]
    assert contacts[0] == 0 and max(contacts) > 500          # it fell, then touched the table
    cloth = rows(out, "sim/cloth/mesh", "Mesh3D:vertex_positions")[-1][1]
    o = scene["obstacles"][0]
    top = o["center"][1] + o["size"][1] / 2
    over = (np.abs(cloth[:, 0] - o["center"][0]) < o["size"][0] / 2 - 0.02) & \
           (np.abs(cloth[:, 2] - o["center"][2]) < o["size"][2] / 2 - 0.02)
    assert over.sum() > 500
    assert cloth[over, 1].min() > top - 1e-3                  # nothing fell through the top
    # the recording opens on the table and the cloth: an obstacles tab, a scene camera that holds them
    from pipeline.blueprint import ASPECT_OVERVIEW, Camera
    from tests.rrd_read import blueprint, blueprint_tabs, blueprint_views
    bp = blueprint(out)
    assert "obstacles" in blueprint_tabs(bp)
    pos, target = blueprint_views(bp)["scene"]["eye"]
    table = rows(out, "obstacles/table/mesh", "Mesh3D:vertex_positions")[0][1]
    falling = np.stack([v for _, v in rows(out, "sim/cloth/mesh", "Mesh3D:vertex_positions")])
    assert Camera(pos, target).sees(np.concatenate([table, falling.reshape(-1, 3)]), aspect=ASPECT_OVERVIEW)


def test_the_papers_colliders_still_run_and_are_reported_the_same_way(tmp_path):
    text = """
name: paper_colliders
character: {source: procedural, clip: walk}
frames: {count: 11}
colliders: {split: weights, flexible: sphere, max_offset: null, report_every: 5}
"""
    scene = parse_scene_text(text, source="paper.yaml")
    out = tmp_path / "paper.rrd"
    summary = run_scene(scene, output=out, progress=False)
    sizes = summary.stages[1].sizes
    assert sizes["split"] == "weights" and sizes["swept_hulls"] == 0 and sizes["spheres"] > 0
    paths = entity_paths(out)
    assert any(p.startswith("/colliders/spheres/") for p in paths)
    got = rows(out, "colliders/fit/excess_p95", "Scalars:scalars")
    assert [f for f, _ in got] == [0, 5, 10]
    report = str(rows(out, "colliders/report", "TextDocument:text")[-1][1])
    assert "| sphere |" in report                             # spheres listed per collider
    # the paper's spheres stand farther off the skin than the default colliders (README table)
    assert max(v[0] for _, v in got) > 3.0


def test_skinned_balls_are_logged_where_the_skin_moves_them(default_run):
    """The default colliders' balls: the recording's ball centres are the BallSet's centres skinned
    at every frame (plus the root translation), and no particle ends inside a collider."""
    from pipeline.run import split_and_fit
    scene, out, summary = default_run
    assert "inside colliders (max / mean per frame, frame 0 excluded): 0 /" in summary.text()
    character = load_character(scene)
    motion = sample_scene_motion(scene, character, frame_times(scene, FRAMES))
    _, colliders = split_and_fit(scene, character, motion)
    assert colliders.balls.radius.size == summary.stages[1].sizes["balls"]
    want = colliders.balls.centers(character.inverse_bind, motion.joint_world) + motion.root_translation[:, None]
    got = rows(out, "colliders/balls", "Ellipsoids3D:centers")
    assert [f for f, _ in got] == list(range(summary.frames))
    for f, c in got:
        assert np.allclose(np.asarray(c).reshape(-1, 3), want[f], atol=1e-5)


def test_swept_hulls_run_hold_the_cloth_and_are_logged(tmp_path):
    """colliders.flexible: swept (the default until balls) through the whole pipeline: swept hulls
    are logged by name with their stages, and no particle ends inside a collider."""
    scene = parse_scene_text((REPO / "scenes" / "default.yaml").read_text().replace(
        "  delta: 0.01\n", "  delta: 0.01\n  flexible: swept\n"), source="swept.yaml")
    out = tmp_path / "swept.rrd"
    summary = run_scene(scene, output=out, frames=FRAMES, progress=False)
    sizes = summary.stages[1].sizes
    assert sizes["swept_hulls"] > 0 and sizes["spheres"] == 0 and "balls" not in sizes
    assert "inside colliders (max / mean per frame, frame 0 excluded): 0 /" in summary.text()
    paths = entity_paths(out)
    hulls = {p.split("/")[3] for p in paths if p.startswith("/colliders/hulls/")}
    assert len(hulls) == sizes["rigid_hulls"] + sizes["swept_hulls"]
    assert any("_flex" in h for h in hulls) and "/colliders/balls" not in paths
    for h in hulls:
        assert f"/colliders/hulls/{h}/simplified" in paths
    assert "_flex" in str(rows(out, "colliders/report", "TextDocument:text")[0][1])


def test_the_speed_limit_comes_from_the_clip_and_is_reported_where_it_acted():
    from types import SimpleNamespace

    from pipeline.cloth_checks import speed_limit_note
    from pipeline.run import sim_params
    from pipeline.scene_motion import motion_speed_limit
    scene = parse_scene_text("name: s\ncharacter: {source: procedural}\n")
    times = np.arange(4) / 30.0
    skinned = np.zeros((4, 2, 3))
    skinned[:, 1, 0] = [0.0, 0.1, 0.2, 0.3]                 # a vertex moving 3 m/s relative to the root
    root = np.zeros((4, 3))
    root[:, 2] = np.arange(4) * 0.5                           # root motion (15 m/s) does not count
    skinned += root[:, None, :]
    p = motion_speed_limit(scene, sim_params(scene), skinned, root, times, 1.8)
    assert p.speed_limit == pytest.approx(3 * 3.0 + 2 * np.sqrt(2 * 9.81 * 1.8))
    paper = parse_scene_text("name: s\ncharacter: {source: procedural}\nsimulation: {preset: paper}\n")
    assert motion_speed_limit(paper, sim_params(paper), skinned, root, times, 1.8).speed_limit == 0.0
    given = parse_scene_text("name: s\ncharacter: {source: procedural}\nsimulation: {speed_limit: 4}\n")
    assert motion_speed_limit(given, sim_params(given), skinned, root, times, 1.8).speed_limit == 4.0
    quiet = SimpleNamespace(speed_limited=np.array([0, 0, 0], np.int32), params=p)
    assert speed_limit_note(quiet) is None
    hit = SimpleNamespace(speed_limited=np.array([5, 0, 3, 7, 0], np.int32), params=p)
    note = speed_limit_note(hit)      # frame 0 (the initial state) is not counted
    assert "2 frame(s)" in note and "frame 3 (7 particles)" in note
