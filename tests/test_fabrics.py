"""Fabrics (issue 39, part 4): a garment's `material` and what it does to the cloth.

Each named fabric gives the figures the manual's table states; the garment's own keys win over the
material's; a GarmentCode simulator settings file maps onto the same scale; and the figures act in
the expected direction on a small drape: a stiffer fabric dropped on a ball stands out further, a
knit hangs lower, a heavier fabric falling through air drops farther.
"""
from __future__ import annotations

import dataclasses
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pipeline.scene import parse_scene_text
from pipeline.schema import SceneError
from stages.garments.fabrics import FABRICS, fabric_from_sim_props
from stages.garments.simple import rectangle_cloth
from stages.garments.types import attach_indices, bind_pose, build_garment
from stages.errors import InputError
from stages.maps.build import build_maps
from stages.sim.scenes import convex_mesh, fibonacci_points, hull_set, toy_character, toy_motion
from stages.sim.simulate import simulate
from stages.sim.types import SimParams

ROOT = Path(__file__).resolve().parents[1]


def manual_table() -> dict:
    """The fabrics table of docs/guide/garments.md: name -> (density, stretch, bend, friction, thickness m)."""
    rows = re.findall(r"^\| `(\w+)` \| ([\d.]+) \| ([\d.]+) \| ([\d.]+) \| ([\d.]+) \| ([\d.]+) \|$",
                      (ROOT / "docs/guide/garments.md").read_text(), re.M)
    return {r[0]: (*map(float, r[1:5]), float(r[5]) / 1000.0) for r in rows}


def test_every_fabric_gives_the_figures_the_manual_states():
    table = manual_table()
    assert set(table) == set(FABRICS) == {"cotton", "denim", "jersey", "silk", "wool", "leather"}
    for name, f in FABRICS.items():
        assert (f.density, f.stretch_stiffness, f.bend_stiffness, f.friction) == pytest.approx(table[name][:4])
        assert f.thickness == pytest.approx(table[name][4])


@pytest.mark.parametrize("kind", ["rectangle", "pattern", "garmentcode", "mesh"])
def test_a_material_sets_every_garment_kind(kind, tmp_path):
    extra = {"rectangle": "", "pattern": ", kind: tshirt", "garmentcode": ", path: x_specification.json",
             "mesh": ", path: x.obj"}[kind]
    s = parse_scene_text(f"garments:\n - {{type: {kind}, name: g, material: denim{extra}}}\n", base_dir=tmp_path)
    g = s["garments"][0]
    d = FABRICS["denim"]
    assert (g["density"], g["stretch_stiffness"], g["bend_stiffness"]) == (d.density, d.stretch_stiffness,
                                                                          d.bend_stiffness)


def test_the_garments_own_keys_override_the_material():
    s = parse_scene_text("garments:\n - {type: rectangle, name: a, material: silk, density: 0.5, "
                         "stretch_stiffness: 0.9}\n - {type: rectangle, name: b}\n")
    a, b = s["garments"]
    assert (a["density"], a["stretch_stiffness"], a["bend_stiffness"]) == (0.5, 0.9, FABRICS["silk"].bend_stiffness)
    assert (b["density"], b["stretch_stiffness"], b["bend_stiffness"]) == (0.2, None, None)


def test_garmentcode_settings_map_onto_the_same_scale(tmp_path):
    # GarmentCode's edge_ke 1 ("very soft"), 100 ("mid-softness"), 500 (minimal bending)
    assert fabric_from_sim_props({"garment_edge_ke": 100.0}, "f").bend_stiffness == pytest.approx(0.2)
    assert fabric_from_sim_props({"garment_edge_ke": 1.0}, "f").bend_stiffness == pytest.approx(0.02)
    assert fabric_from_sim_props({"garment_edge_ke": 500.0}, "f").bend_stiffness == pytest.approx(0.2 * 5 ** 0.5)
    f = fabric_from_sim_props({"garment_tri_ke": 5000.0, "fabric_friction": 0.3, "fabric_thickness": 0.1}, "f")
    assert (f.stretch_stiffness, f.friction, f.thickness) == pytest.approx((0.5, 0.3, 0.001))
    with pytest.raises(InputError, match="garment_edge_ke"):
        fabric_from_sim_props({"garment_edge_ke": "soft"}, "f")
    (tmp_path / "props.yaml").write_text("sim:\n  config:\n    material:\n      garment_edge_ke: 400.0\n")
    s = parse_scene_text("garments:\n - {type: rectangle, name: a, material: {file: props.yaml}}\n",
                         base_dir=tmp_path)
    g = s["garments"][0]
    assert (g["bend_stiffness"], g["stretch_stiffness"], g["density"]) == pytest.approx((0.4, 1.0, 0.2))


def test_garmentcodes_own_settings_files_are_read():
    props = Path("/work/shared/assets/garmentcode/sim_props")
    if not props.is_dir():
        pytest.skip("GarmentCode assets not present")
    want = {"default_sim_props.yaml": 0.02, "mid_bending.yaml": 0.2, "minimal_bending.yaml": 0.2 * 5 ** 0.5}
    for name, bend in want.items():
        s = parse_scene_text(f"garments:\n - {{type: rectangle, name: a, material: {{file: {props / name}}}}}\n")
        assert s["garments"][0]["bend_stiffness"] == pytest.approx(bend), name


@pytest.mark.parametrize("material, problem", [("denimm", "denimm"), ("{file: missing.yaml}", "not found"),
                                               ("{path: x.yaml}", "expected one of")])
def test_a_bad_material_is_one_line_naming_the_key(material, problem, tmp_path):
    scene = tmp_path / "bad.yaml"
    scene.write_text(f"garments:\n - {{type: rectangle, name: a, material: {material}}}\n")
    r = subprocess.run([sys.executable, "-m", "pipeline", "validate", str(scene)], capture_output=True, text=True,
                       cwd=ROOT)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "garments[0].material" in lines[0] and problem in lines[0], r.stderr


def test_a_material_file_without_a_material_section_is_refused(tmp_path):
    (tmp_path / "props.yaml").write_text("sim:\n  config:\n    max_sim_steps: 10\n")
    with pytest.raises(SceneError, match="no material section"):
        parse_scene_text("garments:\n - {type: rectangle, name: a, material: {file: props.yaml}}\n",
                         base_dir=tmp_path)


# -- the drape ---------------------------------------------------------------------------------------
def _drop(garment, frames: int, params: SimParams):
    mesh = convex_mesh(fibonacci_points(40, (0.02, 0.02, 0.02), (0.0, -3.0, 0.0)))   # out of the way
    cs = hull_set(mesh)
    ch, mo = toy_character(mesh.vertices, mesh.faces), toy_motion(frames)
    return ch, mo, cs, simulate(ch, mo, cs, build_maps(cs), [garment], params).garments[0].positions


def _over_a_ball(stretch: float | None, bend: float | None):
    """A 40 cm square dropped onto a ball of 8 cm radius for 1.5 s: the mean distance of its border
    from the ball's vertical axis (how far the hem stands out) and its lowest point, m."""
    x, tri = rectangle_cloth(0.4, 0.4, 17, 17, center=(0.0, 1.0, 0.0))
    mesh = convex_mesh(fibonacci_points(200, (0.08, 0.08, 0.08), (0.0, 0.9, 0.0)))
    cs = hull_set(mesh)
    g = dataclasses.replace(build_garment("c", x, tri), stretch_stiffness=stretch, bend_stiffness=bend)
    pos = simulate(toy_character(mesh.vertices, mesh.faces), toy_motion(45), cs, build_maps(cs), [g],
                   SimParams(body_audit=False)).garments[0].positions[-1]
    border = (np.abs(x[:, 0]) > 0.199) | (np.abs(x[:, 2]) > 0.199)
    return float(np.hypot(pos[border, 0], pos[border, 2]).mean()), float(pos[:, 1].min())


def test_a_stiffer_fabric_stands_out_further():
    # measured: hem 10.8 (silk), 13.9 (cotton), 16.0 (denim) cm from the axis
    silk, cotton, denim = (_over_a_ball(None, FABRICS[m].bend_stiffness)[0] for m in ("silk", "cotton", "denim"))
    assert silk + 0.01 < cotton < denim - 0.01, (silk, cotton, denim)
    # a garment without its own stiffness takes the simulation's (0.2, cotton's)
    assert _over_a_ball(None, None)[0] == pytest.approx(cotton, abs=1e-6)


def test_a_knit_hangs_lower_than_a_woven():
    # jersey's stretch 0.5 against cotton's 1.0, the same bend: measured lowest points 74.2 / 76.5 cm
    jersey = _over_a_ball(FABRICS["jersey"].stretch_stiffness, 0.2)[1]
    cotton = _over_a_ball(FABRICS["cotton"].stretch_stiffness, 0.2)[1]
    assert jersey < cotton - 0.01, (jersey, cotton)


def test_a_heavier_fabric_falls_faster_through_air():
    x, tri = rectangle_cloth(0.3, 0.3, 9, 9, center=(0.0, 1.0, 0.0))
    drops = {}
    for m in ("silk", "denim"):
        g = build_garment(m, x, tri, density=FABRICS[m].density)
        pos = _drop(g, 10, SimParams(body_audit=False))[3]
        drops[m] = float(1.0 - pos[-1][:, 1].mean())
    # falling flat, the air's drag holds the light silk back more than the denim
    assert drops["denim"] > drops["silk"] * 1.05, drops
