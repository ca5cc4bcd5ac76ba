"""The T-shirt on arms whose root fills the torso's side (Kenney's one-joint block arms): the open-top
cut (stages.garments.tshirt_open), sewn round the arms' roots under the head."""
from __future__ import annotations

import numpy as np
import pytest

from stages.garments.library import library_pattern
from stages.garments.measurements import garment_measurements
from stages.garments.tshirt_open import _rounded_box
from tests.test_garments_chibi import _bind, _largest_angle_gap, chibi  # noqa: F401  (chibi: the fixture)


def _edge(pattern, panel: str, edge: str) -> float:
    p = next(p for p in pattern.panels if p.name == panel)
    return p.edge_length([e.name for e in p.edges].index(edge))


def test_rounded_box_lengths_match_a_dense_outline():
    # the superellipse |y/b|^4 + |z/c|^4 = 1 traced independently: its upper half by z, dense
    b, c = 0.09, 0.12
    z = np.linspace(-c, c, 200001)
    y = b * (1.0 - np.abs(z / c) ** 4) ** 0.25
    half = float(np.hypot(np.diff(z), np.diff(y)).sum())
    girth, above = _rounded_box(b, c, 0.0)
    assert girth == pytest.approx(2 * half, rel=2e-3) and above == pytest.approx(half, rel=2e-3)
    assert _rounded_box(b, c, b)[1] == 0.0 and _rounded_box(b, c, -b)[1] == pytest.approx(girth)
    high = y > 0.5 * b
    part = float(np.hypot(np.diff(z[high]), np.diff(y[high])).sum())
    assert _rounded_box(b, c, 0.5 * b)[1] == pytest.approx(part, rel=5e-3)


def test_the_open_top_cut_on_one_joint_arms(chibi):
    # the regular cut's armpit fell 5 cm below the hem on a Kenney mini ("the outline intersects
    # itself"); the open-top cut: the neckline under the head, each armhole as long as the part of
    # the sleeve's end sewn to it, the sleeve open over the arm's top
    from stages.garments.anchors import require_anchors
    require_anchors("tshirt", chibi, "garment 'tshirt'")      # was refused: "a sleeve needs shoulder, ..."
    m = garment_measurements(chibi)
    p = library_pattern("tshirt", m)
    assert [x.name for x in p.panels] == ["front", "back", "sleeve_l", "sleeve_r"]
    for side, other in (("l", "r"), ("r", "l")):
        s = f"sleeve_{side}"
        assert _edge(p, s, "cap_front") == pytest.approx(_edge(p, "front", f"armhole_{side}"), rel=0.01)
        assert _edge(p, s, "cap_back") == pytest.approx(_edge(p, "back", f"armhole_{other}"), rel=0.01)
        # open over the arm's top: no edge there; the sleeve as wide as the two parts sewn to the armholes
        assert "cap_top" not in {e.name for x in p.panels if x.name == s for e in x.edges}
        assert _edge(p, s, "cuff") == pytest.approx(_edge(p, s, "cap_front") + _edge(p, s, "cap_back"), rel=1e-6)
    front = next(x for x in p.panels if x.name == "front")
    top = max(max(pt[1] for pt in e.points) for e in front.edges) + front.placement.shift
    assert top <= m["neck_low"] + 1e-9


def test_regular_bodies_keep_the_regular_cut(assets_dir):
    from stages.rig.bvh_character import load_bvh_character
    from stages.rig.gltf import load_gltf
    from stages.rig.procedural import procedural_character
    for c in (procedural_character(), load_gltf(assets_dir / "CesiumMan.glb"),
              load_bvh_character(assets_dir / "cmu_131_01_walk.bvh")):
        p = library_pattern("tshirt", garment_measurements(c))
        names = {e.name for x in p.panels for e in x.edges}
        assert "shoulder_l" in names and "cap_top" not in names


def test_a_tshirt_is_sewn_round_one_joint_arms(chibi, tmp_path):
    import warnings

    from pipeline.dressing import build_scene_garments
    from stages.maps.build import build_maps
    from stages.rig.humanoid import limb
    scene, c, m, cols = _bind(chibi, tmp_path, "[{type: pattern, kind: tshirt}]")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        (g,), builds = build_scene_garments(scene, c, m, cols, build_maps(cols), {})
    log, build = builds["tshirt"]
    assert log.converged and build.worst_seam()[1] < 0.004
    meas = garment_measurements(c, cols, m)
    for side, sign in (("l", 1.0), ("r", -1.0)):
        arm = limb(c, "arm", side)
        u, mid, _ = arm.points(c, m.joint_world[0])
        # round the arm just beyond the torso's side: cloth in front of, under and behind its axis,
        # none over its top, under the head (a closed sleeve's top there was pressed into the head's
        # collider when the arm rose: edges torn past 500 % on the melee and shoot clips)
        x = sign * (g.positions[:, 0] - m.joint_world[0][c.root_joint, 0, 3])
        ring = g.positions[(x > meas["torso_side"]) & (x < meas["torso_side"] + 0.04)]
        assert len(ring) >= 8 and _largest_angle_gap(ring, u, mid - u) < 200.0
        assert not (ring[:, 1] > meas["arm_root_hi"]).any()
        rel = ring - u
        assert (rel[:, 2] > 0.5 * (meas["arm_root_front"] - meas["arm_root_back"]) - 0.02).any()    # in front
        assert (rel[:, 2] < -0.5 * (meas["arm_root_front"] - meas["arm_root_back"]) + 0.02).any()   # behind
    from stages.garments.placement import bind_geometry, inside_body
    skinned, _, _ = bind_geometry(c, m)
    assert inside_body(c, skinned, g.positions).mean() <= 0.005
