"""GarmentCode sleeves: wrapped round the arm without shearing, and made as round as the character's arm."""
from __future__ import annotations

import math

import numpy as np
import pytest

from stages.garments.garmentcode import parse_pattern, panel_part
from stages.garments.garmentcode_place import GCBody, read_body, to_pattern
from stages.garments.garmentcode_sleeves import SLEEVE_EASE, arm_frame, fit_sleeves, upper_arm_girth
from stages.garments.garmentcode_wrap import wrap_ring, wrap_sleeves
from stages.garments.triangulate import triangulate_pattern
from tests.test_garmentcode import ASSETS, ASSETS_BODY, needs_assets

BODY = GCBody(height=1.72, waist_y=1.08, hips_y=0.86, bust_y=1.20, shoulder_y=1.46, waist=0.84, hips=1.03,
              bust=1.0, shoulder_half=0.18, arm_angle=math.radians(45), values={"arm_length": 54.0}, source="test")


def _sleeve_spec(width: float, length: float = 40.0, slant: float = 8.0) -> dict:
    """A left sleeve as GarmentCode lays one (cm): front and back halves in the frontal plane, each
    hanging `width` below the arm's line from the shoulder point down the 45 degree arm, the overarm
    and underarm seams joining them, the cuff slanted by `slant`."""
    loop = [[0, 0], [0, -width], [length - slant, -width], [length, 0]]   # counter-clockwise: faces +Z
    top = [BODY.shoulder_half * 100, (BODY.shoulder_y - 0.04) * 100]

    def panel(verts, z):
        n = len(verts)
        return {"translation": [top[0], top[1], z], "rotation": [0, 0, -45], "vertices": verts,
                "edges": [{"endpoints": [i, (i + 1) % n]} for i in range(n)]}
    panels = {"left_sleeve_f": panel(loop, 15), "left_sleeve_b": panel(loop[::-1], -12)}
    # front: e0 overarm end (shoulder, 0 -> 1 is the cap side), e1 underarm, e2 cuff, e3 overarm
    stitches = [[{"panel": "left_sleeve_f", "edge": 3}, {"panel": "left_sleeve_b", "edge": 0}],
                [{"panel": "left_sleeve_f", "edge": 1}, {"panel": "left_sleeve_b", "edge": 2}]]
    return {"pattern": {"panels": panels, "stitches": stitches},
            "properties": {"curvature_coords": "relative", "units_in_meter": 100}}


def _wrapped_strain(gc, body) -> np.ndarray:
    """|strain| of the arm panels' mesh edges wrapped round the body and the arms against the flat panels."""
    pattern, signs = to_pattern(gc, 0.02, "x")
    flat = triangulate_pattern(pattern)
    uvs = [fp.uv * [signs[p.name], 1.0] for p, fp in zip(gc.panels, flat.panels)]
    flat3 = [p.to_3d(uv) for p, uv in zip(gc.panels, uvs)]
    x = np.concatenate(wrap_sleeves(gc, wrap_ring(gc, flat3, body, uvs), body))
    arm = np.isin(flat.panel_of_triangle, [i for i, p in enumerate(gc.panels) if panel_part(p) == "arm"])
    tri = flat.triangles[arm]
    e = lambda p: np.linalg.norm(p[tri[:, [1, 2, 0]]] - p[tri], axis=2)
    return np.abs(e(x) / e(np.c_[flat.uv, np.zeros(len(flat.uv))]) - 1).ravel()


def test_a_sleeve_with_a_slanted_cuff_is_wrapped_round_the_arm_without_shearing():
    """Levels across the slanted cuff are cut short of the overarm seam; centred level by level they
    sheared the sleeve (p99 93 %); centred on one line, 23 %."""
    gc = parse_pattern(_sleeve_spec(24.0))
    strain = _wrapped_strain(gc, BODY)
    assert np.percentile(strain, 99) < 0.3          # before: 0.93; what is left is the slanted cuff's corner


def test_the_upper_arm_girth_of_a_sleeve_is_its_two_halves_widths():
    gc = parse_pattern(_sleeve_spec(24.0))
    assert upper_arm_girth(gc, BODY, 1.0) == pytest.approx(0.48, abs=0.005)
    assert upper_arm_girth(gc, BODY, -1.0) is None          # no right sleeve


def test_a_sleeve_narrower_than_the_arm_is_widened_across_it_and_keeps_its_length():
    gc = parse_pattern(_sleeve_spec(16.0))                  # 32 cm round
    need = 0.40
    fitted, widened = fit_sleeves(gc, BODY, need)
    assert set(widened) == {1.0} and widened[1.0] == pytest.approx((need + SLEEVE_EASE) / 0.32, rel=0.02)
    assert upper_arm_girth(fitted, BODY, 1.0) == pytest.approx(need + SLEEVE_EASE, abs=0.005)
    F, c = arm_frame(BODY, 1.0)
    for p, q in zip(gc.panels, fitted.panels):
        a, b = (p.to_3d(p.vertices) - c) @ F.T, (q.to_3d(q.vertices) - c) @ F.T
        np.testing.assert_allclose(b[:, 1:], a[:, 1:], atol=1e-9)     # along the arm and depth: kept
        np.testing.assert_allclose(b[:, 0], a[:, 0] * widened[1.0], atol=1e-9)
    same, none = fit_sleeves(gc, BODY, 0.32 - SLEEVE_EASE)
    assert none == {} and same.panels == gc.panels


@needs_assets
@pytest.mark.parametrize("name, p99", [("examples/shirt_mean", 0.25), ("sampled/tee_s1100/tee_s1100", 0.7),
                                       ("sampled/hoodie_s1092/hoodie_s1092", 0.7)])
def test_shipped_sleeves_are_wrapped_close_to_their_flat_lengths(name, p99):
    """Before: p99 1.20 (shirt), 0.97 (tee), 0.92 (hoodie); now 0.2, 0.5, 0.4; the tee's and the hoodie's caps are
    wider than their sleeves and a ring round the arm cannot keep all of them."""
    from stages.garments.garmentcode import read_pattern
    spec = ASSETS / f"{name}_specification.json"
    beside = spec.parent / "body_measurements.yaml"
    gc = read_pattern(spec)
    strain = _wrapped_strain(gc, read_body(beside if beside.is_file() else ASSETS_BODY))
    assert np.percentile(strain, 99) < p99


def test_junction_pairs_join_every_two_vertices_a_junction_merges():
    """Against brute force: the merge groups are unchanged, every two members of a group of three or
    more are paired once, groups of two keep their one pair."""
    from stages.garments.garmentcode_place import junction_pairs
    from stages.garments.sewing import merge_pairs
    rng = np.random.default_rng(3)
    for _ in range(20):
        n = 30
        pairs = np.unique(np.sort(rng.integers(0, n, (rng.integers(5, 25), 2)), axis=1), axis=0)
        pairs = pairs[pairs[:, 0] != pairs[:, 1]]
        out = junction_pairs(pairs)
        assert len(np.unique(np.sort(out, axis=1), axis=0)) == len(out)
        g0, g1 = merge_pairs(n, pairs), merge_pairs(n, out)
        assert (g0[:, None] == g0[None]).tolist() == (g1[:, None] == g1[None]).tolist()
        paired = {tuple(p) for p in np.sort(out, axis=1).tolist()}
        for gid in np.unique(g0[pairs.ravel()]):
            mem = np.flatnonzero(g0 == gid)
            want = {(int(a), int(b)) for i, a in enumerate(mem) for b in mem[i + 1:]}
            assert want <= paired
    assert junction_pairs(np.zeros((0, 2), np.int64)).shape == (0, 2)


@needs_assets
@pytest.mark.parametrize("name", ["hoody_mean", "standing_lapel_fix"])
def test_a_front_v_where_four_panels_meet_is_sewn_on_the_cmu_walk(tmp_path, name):
    """The hood's (collars') corners and the two front halves meet at the V: sewn corner to corner
    only, the hood's corner stayed 13.3 mm off (collars: 6.6 mm) and the sewing failed."""
    from pipeline.assets import assets_dir
    from pipeline.dressing import build_garmentcode_garment
    from stages.maps.build import build_maps
    from tests.scene_setup import scene_parts
    p = tmp_path / "scene.yaml"
    p.write_text(f"character: {{source: bvh, path: {assets_dir() / 'cmu_131_01_walk.bvh'}}}\n"
                 f"frames: {{start: 3.313, count: 2}}\n"
                 f"garments: [{{type: garmentcode, path: {ASSETS / 'examples' / (name + '_specification.json')}}}]\n")
    scene, c, m, cols = scene_parts(p)
    _, log, build = build_garmentcode_garment(scene, 0, c, m, cols, build_maps(cols))
    assert log.converged and build.worst_seam()[1] < 0.005
