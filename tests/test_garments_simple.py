"""Garment contract and builder, simple garment generators: against brute-force references."""
import warnings

import numpy as np
import pytest

from stages.errors import InputError
from stages.garments.simple import rectangle_cloth, tube_skirt
from stages.garments.types import (BEND, STRETCH, attach_indices, attach_near, attach_top_loop, bind_pose,
                                   build_garment)
from stages.geometry.mesh import boundary_loops
from stages.sim.scenes import toy_character, toy_motion


def _reference_springs(tri):
    edges = set()
    for t in tri:
        for a, b in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0])):
            edges.add((min(a, b), max(a, b)))
    adj = {}
    for t in tri:
        for k in range(3):
            a, b, c = t[k], t[(k + 1) % 3], t[(k + 2) % 3]
            adj.setdefault((min(a, b), max(a, b)), []).append(c)
    bend = set()
    for e, opp in adj.items():
        if len(opp) == 2 and opp[0] != opp[1]:
            p = (min(opp), max(opp))
            if p not in edges:
                bend.add(p)
    return edges, bend


@pytest.mark.parametrize("mesh", [rectangle_cloth(1.0, 0.6, 7, 5), tube_skirt(0.2, 0.3, 0.4, 10, 4)])
def test_springs_and_masses_match_reference(mesh):
    x, tri = mesh
    g = build_garment("g", x, tri, density=0.3)
    edges, bend = _reference_springs(tri.tolist())
    got_e = {tuple(s) for s in g.springs[g.kinds == STRETCH].tolist()}
    got_b = {tuple(s) for s in g.springs[g.kinds == BEND].tolist()}
    assert got_e == edges and got_b == bend
    np.testing.assert_allclose(g.rest_lengths, np.linalg.norm(x[g.springs[:, 1]] - x[g.springs[:, 0]], axis=1))
    area = 0.5 * np.linalg.norm(np.cross(x[tri[:, 1]] - x[tri[:, 0]], x[tri[:, 2]] - x[tri[:, 0]]), axis=1).sum()
    assert np.isclose((1 / g.inverse_mass).sum(), 0.3 * area)


def test_generators_orientation_and_loops():
    x, tri = rectangle_cloth(2.0, 1.0, 5, 4, center=(0, 1, 0))
    n = np.cross(x[tri[:, 1]] - x[tri[:, 0]], x[tri[:, 2]] - x[tri[:, 0]])
    assert (n[:, 1] > 0).all() and x.shape == (20, 3) and tri.shape == (24, 3)
    x, tri = tube_skirt(0.2, 0.3, 0.5, 12, 6, center=(0, 1, 0))
    n = np.cross(x[tri[:, 1]] - x[tri[:, 0]], x[tri[:, 2]] - x[tri[:, 0]])
    radial = x[tri].mean(axis=1) * [1, 0, 1]
    assert (np.einsum("ij,ij->i", n, radial) > 0).all()
    loops = boundary_loops(tri)
    assert sorted(len(lp) for lp in loops) == [12, 12]
    top = max(loops, key=lambda lp: x[lp, 1].mean())
    assert np.allclose(x[top, 1], 1.0) and np.allclose(np.linalg.norm(x[top][:, [0, 2]], axis=1), 0.2)


def test_repairs_warn_and_bad_input_raises():
    x, tri = rectangle_cloth(1.0, 1.0, 3, 3)
    # a duplicate vertex used by one triangle, plus a zero-area triangle
    x2 = np.vstack([x, x[4]])
    tri2 = tri.copy()
    tri2[0] = np.where(tri2[0] == 4, 9, tri2[0])
    tri2 = np.vstack([tri2, [0, 0, 1]])
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        g = build_garment("g", x2, tri2)
    msgs = " ".join(str(m.message) for m in w)
    assert "welded" in msgs and "degenerate" in msgs
    assert g.n_particles == 9 and g.triangles.shape[0] == tri.shape[0]
    with pytest.raises(InputError, match="non-manifold"):
        build_garment("g", np.vstack([x, [[0, 1, 0]]]), np.vstack([tri, [tri[0, 0], tri[0, 1], 9]]))
    with pytest.raises(InputError, match="non-finite"):
        build_garment("g", np.where(np.arange(27).reshape(9, 3) == 4, np.nan, x), tri)
    with pytest.raises(InputError, match="out of range"):
        build_garment("g", x, tri + 100)


def test_attachments_bind_exactly_and_select():
    x, tri = tube_skirt(0.2, 0.3, 0.4, 8, 4, center=(0, 1, 0))
    ch = toy_character(np.zeros((3, 3)), np.array([[0, 1, 2]]))
    rot = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    mo = toy_motion(2)
    jw = mo.joint_world.copy()
    jw[0, 0, :3, :3] = rot
    jw[0, 0, :3, 3] = [0.1, 0.2, 0.3]
    mo = type(mo)(mo.clip_name, mo.times, jw, mo.root_translation)
    bind = bind_pose(ch, mo)
    g = build_garment("skirt", x, tri, attachments=[attach_top_loop("root")], bind=bind)
    top = np.flatnonzero(np.isclose(x[:, 1], 1.0))
    assert set(g.attached) == set(top)
    assert (g.inverse_mass[top] == 0).all() and (g.inverse_mass[g.attach_joint < 0] > 0).all()
    back = g.attach_local[top] @ jw[0, 0, :3, :3].T + jw[0, 0, :3, 3]
    np.testing.assert_allclose(back, x[top], atol=1e-12)
    g2 = build_garment("s", x, tri, attachments=[attach_indices([0, 1]), attach_near(0, 0.0001 + np.linalg.norm(x[5] - bind.joint_origins[0]))], bind=bind)
    assert {0, 1, 5} <= set(g2.attached)
    with pytest.raises(InputError):
        build_garment("s", x, tri, attachments=[attach_top_loop()])  # no bind pose


def test_trunk_bone_pins_a_waist_next_to_a_hand_to_the_trunk():
    """joint 'trunk': a particle next to a hand (a waistband beside a hanging arm) follows the
    nearest bone that is not on a limb; the nearest bone alone would be the hand's."""
    from stages.garments.types import TRUNK_BONE
    from stages.rig.procedural import procedural_character
    from stages.rig.skinning import sample_motion
    ch = procedural_character()
    mo = sample_motion(ch, "walk", np.arange(3) / 30.0)
    bind = bind_pose(ch, mo)
    hand, pelvis = ch.joint_names.index("hand_l"), ch.joint_names.index("pelvis")
    x = np.vstack([bind.joint_origins[hand] + [0.0, 0.0, 0.001], bind.joint_origins[pelvis] + [0.0, 0.0, 0.1],
                   bind.joint_origins[pelvis] + [0.0, -0.1, 0.1]])
    tri = np.array([[0, 1, 2]])
    nearest = build_garment("w", x, tri, attachments=[attach_indices([0, 1])], bind=bind)
    assert nearest.attach_joint[0] == hand
    g = build_garment("w", x, tri, attachments=[attach_indices([0, 1], TRUNK_BONE)], bind=bind)
    limbs = {j for j, n in enumerate(ch.joint_names) if n.split("_")[0] in ("upperarm", "forearm", "hand", "thigh",
                                                                           "shin", "foot", "toes")}
    assert bind.limb_joints == limbs
    assert g.attach_joint[0] not in limbs and g.attach_joint[1] == pelvis and g.attach_joint[2] == -1


def test_common_bone_pins_a_run_to_the_lowest_common_ancestor():
    """joint 'common': a run whose particles lie at the neck, a clavicle and an upper arm follows
    one bone, the chest (their common ancestor), instead of being torn between the three."""
    from stages.garments.types import COMMON_BONE
    from stages.rig.procedural import procedural_character
    from stages.rig.skinning import sample_motion
    ch = procedural_character()
    mo = sample_motion(ch, "walk", np.arange(3) / 30.0)
    bind = bind_pose(ch, mo)
    j = [ch.joint_names.index(n) for n in ("neck", "clavicle_l", "upperarm_l")]
    x = np.vstack([bind.joint_origins[j] + [0.0, 0.0, 0.001], bind.joint_origins[j[0]] + [0.0, -0.1, 0.05]])
    tri = np.array([[0, 1, 3], [1, 2, 3]])
    per_particle = build_garment("run", x, tri, attachments=[attach_indices([0, 1, 2])], bind=bind)
    assert len(set(per_particle.attach_joint[:3])) > 1          # the nearest bones differ
    g = build_garment("run", x, tri, attachments=[attach_indices([0, 1, 2], COMMON_BONE)], bind=bind)
    assert g.attach_joint[:3].tolist() == [ch.joint_names.index("chest")] * 3
    assert g.attach_joint[3] == -1
