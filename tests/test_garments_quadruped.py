"""Four-legged characters (stages.garments.quadruped): the trunk found from the legs, the biped kinds
refused in one line, a cape dressed as a blanket over the back that drapes down the flanks."""
from __future__ import annotations

import numpy as np
import pytest

from stages.errors import InputError
from stages.garments.anchors import require_anchors
from stages.garments.library import library_pattern, make_garment
from stages.garments.measurements import garment_measurements
from stages.garments.quadruped import back_measurements, front_legs, trunk_joints
from tests.test_rig_anchor_names import _quadruped, _renamed

TRUNK = ("b_Hip_00", "b_Spine01_01", "b_Spine02_02")


def _dog():
    """The anchor tests' dog-like stick rig, its trunk boxes widened to a 24 x 24 cm body."""
    q = _quadruped()
    v = q.vertices.copy()
    own = q.skin_joints[:, 0]
    for j in (q.joint_names.index(n) for n in TRUNK):
        sel = own == j
        c = v[sel].mean(axis=0)
        d = v[sel] - c
        v[sel] = c + d * np.array([4.0, 4.0, 1.0])     # 6 cm -> 24 cm across and deep
    from dataclasses import replace
    return replace(q, vertices=v, name="dog")


def test_front_legs_and_trunk_of_a_quadruped_by_name_and_by_shape():
    q = _quadruped()
    n = q.joint_names
    assert sorted(n[j] for j in front_legs(q)) == ["b_LeftUpperArm_09", "b_RightUpperArm_06"]
    assert [n[j] for j in trunk_joints(q)] == list(TRUNK)
    # meaningless names: the same joints, by the skeleton's shape
    s = _renamed(q, [f"j{k}" for k in range(q.n_joints)])
    assert sorted(front_legs(s)) == sorted(front_legs(q)) and trunk_joints(s) == trunk_joints(q)


def test_bipeds_have_no_front_legs():
    from stages.rig.procedural import BodyParams, procedural_character
    c = procedural_character(BodyParams())
    assert front_legs(c) == [] and trunk_joints(c) == [] and back_measurements(c) == {}


def test_back_measurements_are_the_trunks_skin():
    d = _dog()
    m = back_measurements(d)
    own = d.skin_joints[:, 0]
    t = d.vertices[np.isin(own, [d.joint_names.index(k) for k in TRUNK])]
    assert m["quadruped"] == 1.0
    assert m["back_top_y"] == pytest.approx(t[:, 1].max()) and m["belly_y"] == pytest.approx(t[:, 1].min())
    assert m["back_rear_z"] == pytest.approx(t[:, 2].min()) and m["back_front_z"] == pytest.approx(t[:, 2].max())
    assert m["back_half"] == pytest.approx(0.12, abs=0.01)


def test_biped_kinds_are_refused_on_four_legs_and_a_cape_is_not():
    q = _quadruped()
    require_anchors("cape", q, "garment 'cape'")
    for kind in ("tshirt", "short_skirt", "long_skirt", "shorts", "trousers"):
        with pytest.raises(InputError, match="stands on four legs .* needs a biped"):
            require_anchors(kind, q, f"garment {kind!r}")


def test_a_cape_on_a_dog_is_a_blanket_pinned_along_the_spine_that_drapes():
    from stages.hulls import fit_colliders
    from stages.maps.build import build_maps
    from stages.rig.regions import split_regions
    from stages.rig.skinning import rest_motion
    from stages.sim import SimParams, simulate
    d = _dog()
    m = rest_motion(d, 2, 1 / 30)
    cols = fit_colliders(d, split_regions(d, threshold=0.9), delta=0.01, min_triangles=40, max_offset=0.02)
    meas = garment_measurements(d, cols, m)
    pattern = library_pattern("cape", meas)
    assert [p.name for p in pattern.panels] == ["left", "right"]
    g, log, _ = make_garment(pattern, d, m, cols, build_maps(cols))
    assert log.converged
    pinned = {d.joint_names[j] for j in np.unique(g.attach_joint[g.attach_joint >= 0])}
    assert pinned and pinned <= set(TRUNK)                       # along the spine, to the trunk's bones
    spine = g.positions[g.attach_joint >= 0]
    assert np.ptp(spine[:, 0]) < 0.01                           # the seam runs along the mid-plane
    r = simulate(d, rest_motion(d, 20, 1 / 30), cols, build_maps(cols), [g], SimParams(settle_frames=20))
    x = r.garments[0].positions[-1]
    assert x[:, 1].min() < meas["back_top_y"] - 0.08            # the flanks hang down
    assert np.abs(x[:, 0] - meas["back_x"]).max() < meas["back_half"] + 0.1   # round the body, not spread out
    assert int(r.penetrations_colliders[-1]) == 0


@pytest.mark.assets
def test_a_garmentcode_pattern_on_four_legs_is_one_line(assets_dir):
    # made for a human body: validate said ok and a run would wrap a skirt round a dog
    from pipeline.dressing import build_garmentcode_garment
    from pipeline.scene import parse_scene_text
    from pipeline.schema import SceneError
    spec = assets_dir / "garmentcode" / "examples" / "flare_skirt_specification.json"
    scene = parse_scene_text(f"garments: [{{type: garmentcode, path: {spec}}}]", source="s.yaml")
    with pytest.raises(SceneError, match="made for a human body, and 'dog' stands on four legs"):
        build_garmentcode_garment(scene, 0, _dog(), None, None, None, place_only=True)
