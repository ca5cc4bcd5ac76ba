"""Scene files: every kind of bad input gets one message naming file, key path, value, expectation."""
from __future__ import annotations

import pytest

from pipeline.scene import SCENE_SPEC, load_scene, parse_scene_text
from pipeline.schema import SceneError


def error_of(text: str) -> str:
    with pytest.raises(SceneError) as e:
        parse_scene_text(text, source="s.yaml")
    return str(e.value)


def test_defaults_fill_every_section():
    s = parse_scene_text("{}", source="s.yaml", default_name="empty")
    assert s.name == "empty"
    assert s["character"]["source"] == "procedural"
    assert s["simulation"]["preset"] == "default" and s["simulation"]["iterations"] is None   # from the preset
    assert s["colliders"]["map"]["n_theta"] == 12
    assert s.output.as_posix() == "recordings/empty.rrd"
    assert set(s.settings) == set(SCENE_SPEC)


def paper_off_collision() -> bool:
    from pipeline.run import sim_params
    return sim_params(parse_scene_text("simulation: {preset: paper}", source="s.yaml")).cloth_collision


def test_simulation_preset_and_overrides():
    """simulation.preset picks the SimParams preset; keys the scene sets win over it."""
    from pipeline.run import sim_params
    from stages.sim.types import SimParams
    default = sim_params(parse_scene_text("{}", source="s.yaml"))
    # the default preset: the dataclass defaults with cloth collision on, a call every 5 sub-steps, settling
    assert default == SimParams(cloth_collision=True, cloth_contact_every=5, settle_frames=10)
    assert SimParams.preset("paper").limb_release == 0.0
    assert (default.substeps, default.iterations, default.tethers) == (20, 2, True)
    assert not paper_off_collision() and sim_params(parse_scene_text(
        "simulation: {cloth_collision: off}", source="s.yaml")).cloth_collision is False
    paper = sim_params(parse_scene_text("simulation: {preset: paper}", source="s.yaml"))
    assert (paper.substeps, paper.iterations, paper.tethers) == (1, 3, False)
    assert paper == SimParams.preset("paper")
    mixed = sim_params(parse_scene_text("simulation: {preset: paper, tethers: true, substeps: 2}", source="s.yaml"))
    assert (mixed.substeps, mixed.iterations, mixed.tethers) == (2, 3, True)
    assert "not one of default, paper" in error_of("simulation: {preset: fast}")
    # pinched cloth: held in the middle by default, the paper preset escapes (issue 6), a scene may choose
    assert (default.pinch, paper.pinch) == ("midpoint", "escape")
    assert sim_params(parse_scene_text("simulation: {pinch: limb}", source="s.yaml")).pinch == "limb"
    assert sim_params(parse_scene_text("simulation: {pinch: escape}", source="s.yaml")).pinch == "escape"
    assert sim_params(parse_scene_text("simulation: {preset: paper, pinch: midpoint}", source="s.yaml")).pinch == "midpoint"
    msg = error_of("simulation: {pinch: squeeze}")
    assert "simulation.pinch" in msg and "squeeze" in msg and "midpoint" in msg


def test_yaml_syntax_error_has_line_and_column():
    msg = error_of("simulation:\n  dt: [1, 2\n")
    assert msg.startswith("s.yaml:") and "YAML syntax error" in msg
    line = int(msg.split(":")[1])
    assert line >= 2


def test_unknown_key_suggests_nearest_and_points_at_the_key():
    msg = error_of("simulation:\n  itrations: 3\n")
    assert msg.startswith("s.yaml:2:3:")
    assert "simulation.itrations" in msg and "did you mean 'iterations'" in msg


def test_nested_key_path_in_list():
    msg = error_of("garments:\n  - {type: tube, name: a}\n  - type: rectangle\n    name: b\n    pin: {collider: 3}\n")
    assert "garments[1].pin.collider" in msg and "expected a string" in msg and "3" in msg


@pytest.mark.parametrize("text, key, expect", [
    ("simulation: {dt: -0.1}", "simulation.dt", "out of range"),
    ("simulation: {iterations: 2.5}", "simulation.iterations", "expected an integer"),
    ("simulation: {gravity: [0, -9.8]}", "simulation.gravity", "list of 3 numbers"),
    ("simulation: {damping: .nan}", "simulation.damping", "finite"),
    ("simulation: {body_audit: 3}", "simulation.body_audit", "true or false"),
    ("colliders: {map: {type: cone}}", "colliders.map.type", "not one of auto, sphere, cylinder"),
    ("character: {source: fbx}", "character.source", "not one of"),
    ("character: {source: gltf}", "character", "needs a 'path'"),
    ("character: {source: bvh, path: w.bvh, bind_pose: tpose}", "character.bind_pose", "not one of neutral, frame0, rest"),
    ("character: {source: gltf, path: m.glb, bind_pose: rest}", "character", "bind_pose applies to source 'bvh' only"),
    ("garments: [{name: x}]", "garments[0].type", "missing required key"),
    ("garments: [{type: tubr, name: x}]", "garments[0].type", "did you mean 'tube'"),
    ("garments: [{type: tube, name: x, pin: {}}]", "garments[0].pin", "at least one of"),
    ("obstacles: [{type: sphere, name: s}]", "obstacles[0].radius", "missing required key"),
    ("frames: 12", "frames", "expected a mapping"),
    ("garments: {type: tube}", "garments", "expected a list"),
])
def test_wrong_types_and_ranges(text, key, expect):
    msg = error_of(text)
    assert f": {key}:" in msg, msg
    assert expect in msg, msg


def test_bvh_bind_pose_key():
    assert parse_scene_text("character: {source: bvh, path: w.bvh}")["character"]["bind_pose"] is None  # neutral
    s = parse_scene_text("character: {source: bvh, path: w.bvh, bind_pose: frame0}")
    assert s["character"]["bind_pose"] == "frame0"


def test_duplicate_keys_are_refused():
    assert "duplicate key 'seed'" in error_of("seed: 1\nseed: 2\n")


def test_relative_paths_resolve_against_the_scene_folder(tmp_path):
    (tmp_path / "sub").mkdir()
    f = tmp_path / "sub" / "x.yaml"
    f.write_text("character: {source: bvh, path: ../walk.bvh}\noutput: out/x.rrd\n")
    s = load_scene(f)
    assert s["character"]["path"] == str(tmp_path / "sub" / ".." / "walk.bvh")
    assert s.output == tmp_path / "sub" / "out" / "x.rrd"


def test_missing_unreadable_and_folder_scene_files(tmp_path):
    with pytest.raises(SceneError, match="scene file not found"):
        load_scene(tmp_path / "nope.yaml")
    with pytest.raises(SceneError, match="is a folder"):
        load_scene(tmp_path)
    bad = tmp_path / "bin.yaml"
    bad.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(SceneError, match="cannot read scene file"):
        load_scene(bad)


def test_bad_scene_name():
    assert "name" in error_of("name: 'a b/c'")


def test_garments_and_obstacles_are_named_from_what_they_are():
    s = parse_scene_text("garments: [{type: pattern, kind: tshirt}, {type: pattern, kind: tshirt, name: tshirt_2}, "
                         "{type: pattern, kind: tshirt}, {type: garmentcode, path: /x/tee_specification.json}, "
                         "{type: mesh, path: 'my dress.obj'}, {type: rectangle}]\n"
                         "obstacles: [{type: sphere, radius: 1}, {type: sphere, radius: 2, name: sphere_2}, "
                         "{type: sphere, radius: 3}]", source="s.yaml")
    assert [g["name"] for g in s.settings["garments"]] == ["tshirt", "tshirt_2", "tshirt_3", "tee", "my_dress",
                                                           "rectangle"]
    assert [o["name"] for o in s.settings["obstacles"]] == ["sphere", "sphere_2", "sphere_3"]
    # a name given twice is still refused
    assert "already the name" in error_of("garments: [{type: rectangle, name: a}, {type: tube, name: a}]")


def test_a_pattern_kind_written_as_the_type_says_how_to_write_it():
    msg = error_of("garments: [{type: short_skirt}]")
    assert "garments[0].type" in msg and "write type: pattern, kind: short_skirt" in msg


def test_shipped_scenes_validate_against_the_schema():
    from pathlib import Path

    import yaml

    from pipeline.sweep import load_sweep
    scenes = sorted((Path(__file__).parent.parent / "scenes").glob("*.yaml"))
    assert scenes, "no scenes shipped"
    for p in scenes:
        data = yaml.safe_load(p.read_text())
        if isinstance(data, dict) and "base" in data:   # a sweep file (scenes/sweep_example.yaml)
            assert load_sweep(p, output="/tmp/unused").jobs
        else:
            load_scene(p)
