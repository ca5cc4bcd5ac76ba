"""The cloth x cloth phase wired into the simulation (issue 15 part 2): scene keys, layers, the step
loop, crossings read back from a recording, and no cloth-contact compile when a scene does not use it."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pipeline.run import garment_layers, run_scene, sim_params
from pipeline.scene import parse_scene_text
from tests.rrd_read import rows

REPO = Path(__file__).resolve().parent.parent

# two small sheets falling on the static character's head; the first in the list is the outer one
# (`layer` says so, against the list order) and starts 1.5 cm above the other
LAYERED = """
name: layered
character: {source: procedural, clip: rest}
frames: {count: 16}
colliders: {report_every: 0}
garments:
  - {type: rectangle, name: top, width: 0.5, height: 0.5, resolution: [14, 14], center: [0.0, 1.875, 0.0], layer: 1}
  - {type: rectangle, name: under, width: 0.46, height: 0.46, resolution: [13, 13], center: [0.01, 1.86, 0.005], layer: 0}
simulation: {cloth_collision: on, body_audit: false}
"""


def test_scene_keys_layer_and_cloth_collision():
    s = parse_scene_text(LAYERED, source="s.yaml")
    assert garment_layers(s) == [1, 0]
    p = sim_params(s)
    assert p.cloth_collision and p.cloth_thickness == 0.003
    plain = parse_scene_text("garments: [{type: rectangle, name: a}, {type: rectangle, name: b}]", source="s.yaml")
    assert garment_layers(plain) == [0, 1]                     # earlier in the list = inner
    assert sim_params(plain).cloth_collision                   # on in the default preset
    assert not sim_params(parse_scene_text("simulation: {preset: paper}", source="s.yaml")).cloth_collision
    off = parse_scene_text("simulation: {cloth_collision: off}", source="s.yaml")
    assert sim_params(off).cloth_collision is False
    with pytest.raises(Exception, match="layer"):
        parse_scene_text("garments: [{type: rectangle, name: a, layer: -1}]", source="s.yaml")


@pytest.fixture(scope="module")
def layered_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("rec") / "layered.rrd"
    summary = run_scene(parse_scene_text(LAYERED, source=str(REPO / "scenes" / "layered.yaml")), output=out,
                        progress=False)
    return out, summary


def _series(path, entity):
    return np.array([float(np.ravel(v)[0]) for _, v in rows(path, entity, "Scalars:scalars")])


def test_layered_sheets_do_not_cross_and_keep_their_layers(layered_run):
    out, summary = layered_run
    # read back from the recording: crossings within each sheet and between them, per frame
    top, under, between = (_series(out, f"sim/intersections/{k}") for k in ("top", "under", "between"))
    assert top.size == under.size == between.size == 16
    assert top[1:].max() == 0 and under[1:].max() == 0 and between[1:].max() == 0
    assert summary.penetrations["cloth collision (layers; contacts / corrected / reverted / left over the run)"] \
        .startswith("on, thickness 3.0 mm (layers: top 1, under 0)")
    # the sheets landed on the head and the outer one is still on top of the inner one there
    pos = {k: [v.reshape(-1, 3) for _, v in rows(out, f"sim/{k}/mesh", "Mesh3D:vertex_positions")]
           for k in ("top", "under")}
    assert len(pos["top"]) == 16
    t, u = pos["top"][-1], pos["under"][-1]
    assert t[:, 1].max() < 1.85                                  # fell onto the head
    # above the crown the top sheet is over the under one: each top vertex within 8 cm of the crown
    # against the under sheet's surface straight below it (its triangle in the x-z plane)
    tri = np.asarray(rows(out, "sim/under/mesh", "Mesh3D:triangle_indices")[-1][1]).reshape(-1, 3)
    checked = 0
    for p in t[np.hypot(t[:, 0], t[:, 2]) < 0.08]:
        a, b, c = u[tri[:, 0]][:, ::2], u[tri[:, 1]][:, ::2], u[tri[:, 2]][:, ::2]
        den = (b[:, 1] - c[:, 1]) * (a[:, 0] - c[:, 0]) + (c[:, 0] - b[:, 0]) * (a[:, 1] - c[:, 1])
        l0 = ((b[:, 1] - c[:, 1]) * (p[0] - c[:, 0]) + (c[:, 0] - b[:, 0]) * (p[2] - c[:, 1])) / den
        l1 = ((c[:, 1] - a[:, 1]) * (p[0] - c[:, 0]) + (a[:, 0] - c[:, 0]) * (p[2] - c[:, 1])) / den
        inside = (l0 >= 0) & (l1 >= 0) & (l0 + l1 <= 1)
        for k in np.flatnonzero(inside):
            y = l0[k] * u[tri[k, 0], 1] + l1[k] * u[tri[k, 1], 1] + (1 - l0[k] - l1[k]) * u[tri[k, 2], 1]
            assert p[1] > y
            checked += 1
    assert checked >= 10


def test_simulate_layers_argument_sorts_sheets_that_start_the_wrong_way():
    """Two sheets on the head, the outer one (layer 1) starting 5 mm UNDER the inner one: sorted by
    the layers before frame 1, no crossing afterwards; the same without collision keeps the start order."""
    from pipeline.run import load_character, split_and_fit
    from pipeline.scene_motion import frame_times, sample_scene_motion
    from stages.garments.simple import rectangle_cloth
    from stages.garments.types import build_garment
    from stages.maps.build import build_maps
    from stages.sim import simulate
    from stages.sim.audit import audit_cloth
    from stages.sim.types import SimParams

    scene = parse_scene_text("character: {source: procedural, clip: rest}\nframes: {count: 8}", source="s.yaml")
    ch = load_character(scene)
    motion = sample_scene_motion(scene, ch, frame_times(scene))
    _, cs = split_and_fit(scene, ch, motion)
    maps = build_maps(cs)
    head_top = float(ch.vertices[:, 1].max())
    xa, ta = rectangle_cloth(0.4, 0.4, 12, 12, center=(0.0, head_top + 0.03, 0.0))
    xb, tb = rectangle_cloth(0.36, 0.36, 11, 11, center=(0.005, head_top + 0.035, 0.004))
    garments = [build_garment("a", xa, ta), build_garment("b", xb, tb)]
    p = SimParams(body_audit=False, cloth_collision=True)
    r = simulate(ch, motion, cs, maps, garments, p, layers=[1, 0])        # a outer, though it starts below
    a = audit_cloth(r, garments)
    assert a.crossings_between[1:].max() == 0
    assert all(g.crossings_self[1:].max() == 0 for g in a.garments)
    assert r.cloth_contact["layers"] == [1, 0] and r.cloth_contact["contacts"] > 0
    # the recorded frames' own share of the phase's cycles: the settling frames (garments sorted by
    # their layers before frame 1, a call every sub-step) are in the totals but not in "frames"
    fr, cc = r.cloth_contact["frames"], r.cloth_contact
    assert 0 < fr["cycles_detect"] < cc["cycles_detect"]
    assert 0 <= fr["cycles_build"] <= cc["cycles_build"] and fr["candidate_builds"] <= cc["candidate_builds"]
    assert r.timings["cloth"] > 0.0
    top_a = r.garments[0].positions[-1][:, 1].max()
    top_b = r.garments[1].positions[-1][:, 1].max()
    assert top_a > top_b                                                   # a ended outside (above) b
    r0 = simulate(ch, motion, cs, maps, garments, SimParams(body_audit=False))
    assert r0.cloth_contact == {} and r0.timings["cloth"] == 0.0
    assert r0.garments[0].positions[-1][:, 1].max() < r0.garments[1].positions[-1][:, 1].max()


def test_cloth_contact_kernels_not_compiled_when_off():
    code = """
import numpy as np
from stages.garments.simple import rectangle_cloth
from stages.garments.types import build_garment
from stages.sim import simulate
from stages.sim.scenes import toy_character, toy_motion
from stages.sim.types import SimParams
from stages.sim import step
from stages.sim.cloth_contact import kernels as CK
x, t = rectangle_cloth(0.2, 0.2, 5, 5, center=(0.0, 1.0, 0.0))
ch = toy_character(np.zeros((0, 3)), np.zeros((0, 3), np.int32))
simulate(ch, toy_motion(3), None, None, [build_garment("c", x, t)], SimParams(body_audit=False, substeps=2))
print(len(CK.collide_cloth.signatures), len(step.cloth_phase.signatures), len(step.run_frames.signatures))
"""
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    n_cc, n_phase, n_frames = map(int, out.stdout.split()[-3:])
    assert (n_cc, n_phase) == (0, 0) and n_frames >= 1


def test_shipped_scenes_turn_cloth_collision_on_with_their_layers():
    from pipeline.scene import load_scene
    walk = load_scene(REPO / "scenes" / "walk_tshirt_skirt.yaml")
    assert garment_layers(walk) == [1, 0]                      # the T-shirt worn over the skirt
    assert sim_params(walk).cloth_collision
    tucked = load_scene(REPO / "scenes" / "walk_tshirt_tucked.yaml")
    assert garment_layers(tucked) == [0, 1]                    # the T-shirt tucked into the skirt
    assert sim_params(tucked).cloth_collision
    assert sim_params(load_scene(REPO / "scenes" / "long_skirt.yaml")).cloth_collision
    assert sim_params(load_scene(REPO / "scenes" / "default.yaml")).cloth_collision       # the default preset's
    assert not sim_params(load_scene(REPO / "scenes" / "drape.yaml")).settle_frames == 0
