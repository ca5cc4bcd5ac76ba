"""The procedural humanoid: skin topology, weights, skeleton, clips, measurements."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from stages.checks import ContractError
from stages.rig.capsule_skin import guess_radii, skin_skeleton
from stages.rig.procedural import (
    BodyParams,
    _girth,
    body_measurements,
    humanoid_skeleton,
    procedural_character,
)
from stages.rig.transforms import forward_kinematics, trs_to_matrix

# bones that must get a hull (paper A: 14 hulls; here 17 incl. neck, hands and feet)
HULL_BONES = ("pelvis", "spine", "chest", "neck", "head", "upperarm_l", "forearm_l", "hand_l",
              "upperarm_r", "forearm_r", "hand_r", "thigh_l", "shin_l", "foot_l", "thigh_r",
              "shin_r", "foot_r")


@pytest.fixture(scope="module")
def character():
    return procedural_character()


def assert_closed_manifold(vertices, triangles):
    mesh = trimesh.Trimesh(vertices, triangles, process=False)
    assert mesh.is_watertight
    assert mesh.is_winding_consistent
    assert mesh.volume > 0  # outward orientation
    assert len(mesh.split(only_watertight=False)) == 1
    # every triangle has positive area and no vertex is unused
    assert np.all(mesh.area_faces > 0)
    assert np.unique(triangles).size == len(vertices)


def assert_weights_valid(skin_joints, skin_weights, n_joints):
    assert skin_joints.shape == skin_weights.shape and skin_joints.shape[1] == 4
    assert skin_joints.dtype == np.int32 and skin_weights.dtype == np.float64
    assert np.all(skin_weights >= 0)
    np.testing.assert_allclose(skin_weights.sum(axis=1), 1.0, atol=1e-9)
    assert skin_joints.min() >= 0 and skin_joints.max() < n_joints


def test_skin_is_closed_manifold_in_range(character):
    assert_closed_manifold(character.vertices, character.triangles)
    assert 3000 <= len(character.triangles) <= 6000


def test_weights_sum_to_one_and_are_non_negative(character):
    assert_weights_valid(character.skin_joints, character.skin_weights, character.n_joints)


def test_every_hull_bone_has_a_solid_rigid_region(character):
    dom_joint = character.skin_joints[np.arange(len(character.vertices)), np.argmax(character.skin_weights, axis=1)]
    dom_weight = character.skin_weights.max(axis=1)
    nv = len(character.vertices)
    for name in HULL_BONES:
        j = character.joint_names.index(name)
        pts = character.vertices[(dom_joint == j) & (dom_weight >= 0.9)]
        assert 20 <= len(pts) <= 0.2 * nv, (name, len(pts))
        # non-coplanar: the third principal extent is a real thickness
        sv = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False)
        assert sv[2] / np.sqrt(len(pts)) > 0.004, (name, sv)
    # blended vertices exist around joints too
    assert 0.1 * nv < np.sum(dom_weight < 0.9) < 0.6 * nv


def test_skeleton_shape(character):
    names, parents, local = humanoid_skeleton()
    assert 18 <= len(names) <= 24 and len(set(names)) == len(names)
    assert parents[0] == -1 and np.all(parents[1:] < np.arange(1, len(names)))
    assert local.shape == (len(names), 4, 4)
    np.testing.assert_array_equal(character.parents, parents)
    world = forward_kinematics(character.parents, character.rest_local)
    pos = dict(zip(character.joint_names, world[:, :3, 3]))
    # facing +Z, left at +X, A-pose: hands below shoulders and outside them
    assert pos["hand_l"][0] > pos["upperarm_l"][0] > 0 > pos["upperarm_r"][0] > pos["hand_r"][0]
    assert pos["hand_l"][1] < pos["upperarm_l"][1] - 0.2
    assert pos["toes_l"][2] > pos["foot_l"][2]
    assert pos["head"][1] > pos["neck"][1] > pos["chest"][1] > pos["spine"][1] > pos["pelvis"][1]
    # inverse bind really inverts the bind-pose globals
    np.testing.assert_allclose(character.inverse_bind @ world, np.broadcast_to(np.eye(4), world.shape), atol=1e-12)


@pytest.mark.parametrize("height", [1.75, 1.5])
def test_stands_on_ground_with_given_height(height, character):
    c = character if height == 1.75 else procedural_character(BodyParams(height=height), motions=())
    y = c.vertices[:, 1]
    assert abs(y.min()) < 1e-9
    assert abs(y.max() - height) <= 0.03 * height


def test_measurements_scale_with_params(character):
    base = body_measurements(character)
    # plausible adult sizes for 1.75 m
    assert 0.8 < base["chest"] < 1.1 and 0.65 < base["waist"] < 0.95 and 0.85 < base["hips"] < 1.15
    assert base["waist"] < base["chest"] and base["waist"] < base["hips"]
    assert 0.5 < base["arm_length"] < 0.65 and 0.75 < base["leg_length"] < 0.95
    wide = body_measurements(procedural_character(BodyParams(chest=1.3, waist=1.2, hips=1.15), motions=()))
    assert wide["chest"] > 1.15 * base["chest"]
    assert wide["waist"] > 1.1 * base["waist"]
    assert wide["hips"] > 1.05 * base["hips"]
    small = body_measurements(procedural_character(BodyParams(height=1.5), motions=()))
    s = 1.5 / 1.75
    for key in ("chest", "waist", "hips", "arm_length", "leg_length"):
        assert small[key] == pytest.approx(base[key] * s, rel=0.05), key


def test_girth_of_a_cylinder_is_its_circumference():
    cyl = trimesh.creation.cylinder(radius=0.12, height=1.0, sections=64)
    cyl.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))  # axis Z -> Y
    got = _girth(np.asarray(cyl.vertices, float), np.asarray(cyl.faces), 0.1, np.zeros(2))
    # inscribed 64-gon perimeter
    assert got == pytest.approx(2 * 64 * 0.12 * np.sin(np.pi / 64), rel=1e-9)


def test_girth_of_a_loop_flattened_onto_a_line_is_twice_its_length():
    """A plate standing edge-on to the cut (every crossing point on one line in xz): Qhull refuses
    it (QH6154 on the Kenney characters); the tape goes round it, twice its width."""
    plate = trimesh.creation.box(extents=(0.3, 1.0, 1e-12))      # zero thickness in z
    got = _girth(np.asarray(plate.vertices, float), np.asarray(plate.faces), 0.1, np.zeros(2))
    assert got == pytest.approx(0.6, rel=1e-9)


def test_torso_tapes_follow_the_skeleton_where_adult_proportions_miss_it(character):
    """The built-in body keeps its proportional tapes (72 / 62 / 53 % of the height); a body whose
    arms and legs start far lower in its height (a chibi: a head half its height) gets them between
    its leg and arm joints instead of across its head."""
    from stages.rig.procedural import SHOULDER_SHARE, SLICE_SHARES, _torso_slices
    world = forward_kinematics(character.parents, character.rest_local)[:, :3, 3]
    y0, h = float(character.vertices[:, 1].min()), float(np.ptp(character.vertices[:, 1]))
    assert _torso_slices(character, world, y0, h) == {k: y0 + f * h for k, f in SLICE_SHARES.items()}
    m = body_measurements(character)
    assert (m["chest_y"], m["hips_y"]) == (y0 + 0.72 * h, y0 + 0.53 * h)
    # the same skeleton and skin in a mesh twice as tall (a big head above it): the tapes stay on the torso
    tall = np.concatenate([character.vertices, [[0.0, y0 + 2 * h, 0.0]]])
    from dataclasses import replace
    chibi = replace(character, vertices=tall,
                    skin_joints=np.concatenate([character.skin_joints, character.skin_joints[:1]]),
                    skin_weights=np.concatenate([character.skin_weights, character.skin_weights[:1]]),
                    primitive_ids=np.concatenate([character.primitive_ids, character.primitive_ids[:1]]))
    got = _torso_slices(chibi, world, y0, 2 * h)
    hip = np.mean([world[character.joint_names.index(n), 1] for n in ("thigh_l", "thigh_r")])
    shoulder = np.mean([world[character.joint_names.index(n), 1] for n in ("upperarm_l", "upperarm_r")])
    assert got["hips"] == pytest.approx(hip) and hip < got["waist"] < got["chest"] < shoulder
    share = (got["chest"] - hip) / (shoulder - hip)
    assert share == pytest.approx((SLICE_SHARES["chest"] - SLICE_SHARES["hips"]) / (SHOULDER_SHARE - SLICE_SHARES["hips"]))


def _fk(character, clip):
    return forward_kinematics(character.parents, trs_to_matrix(clip.translations, clip.rotations, clip.scales))


def test_walk_root_advances_and_does_not_loop(character):
    walk = character.clip("walk")
    assert not walk.loop
    root = _fk(character, walk)[:, character.root_joint, :3, 3]
    assert np.all(np.diff(root[:, 2]) > 0)
    speed = (root[-1, 2] - root[0, 2]) / walk.duration
    assert speed == pytest.approx(1.2, rel=1e-6)
    bob = root[:, 1].max() - root[:, 1].min()
    assert 0.01 < bob < 0.08
    assert np.allclose(root[:, 0], 0.0)
    # legs swing in opposite phase, arms opposite to legs
    j = {n: i for i, n in enumerate(character.joint_names)}
    world = _fk(character, walk)
    foot_dz = world[:, j["foot_l"], 2, 3] - world[:, j["foot_r"], 2, 3]
    hand_dz = world[:, j["hand_l"], 2, 3] - world[:, j["hand_r"], 2, 3]
    assert foot_dz.max() > 0.3 and foot_dz.min() < -0.3
    assert np.corrcoef(foot_dz, hand_dz)[0, 1] < -0.8


def test_other_clips(character):
    assert [c.name for c in character.clips] == ["rest", "walk", "arm_raise", "turn"]
    j = {n: i for i, n in enumerate(character.joint_names)}
    rest_world = forward_kinematics(character.parents, character.rest_local)
    raise_world = _fk(character, character.clip("arm_raise"))
    assert raise_world[:, j["hand_l"], 1, 3].max() > rest_world[j["head"], 1, 3]
    np.testing.assert_allclose(raise_world[-1], rest_world, atol=1e-9)  # loops back to rest
    turn = _fk(character, character.clip("turn"))
    root = turn[:, 0, :3, 3]
    np.testing.assert_allclose(root, np.broadcast_to(rest_world[0, :3, 3], root.shape), atol=1e-12)
    facing = turn[:, 0, :3, 2]  # pelvis +Z axis in world
    half = len(facing) // 2
    assert facing[half] @ np.array([0, 0, 1.0]) < -0.99  # half-way: facing backwards
    np.testing.assert_allclose(turn[-1], rest_world, atol=1e-9)
    rest = _fk(character, character.clip("rest"))
    np.testing.assert_allclose(rest[0], rest_world, atol=1e-12)


def test_generation_is_deterministic(character):
    again = procedural_character()
    for field in ("vertices", "triangles", "skin_joints", "skin_weights", "rest_local", "inverse_bind"):
        np.testing.assert_array_equal(getattr(again, field), getattr(character, field))
    for a, b in zip(again.clips, character.clips):
        np.testing.assert_array_equal(a.rotations, b.rotations)
        np.testing.assert_array_equal(a.translations, b.translations)


@settings(max_examples=5, deadline=None)
@given(
    height=st.floats(1.2, 2.1),
    chest=st.floats(0.8, 1.4),
    waist=st.floats(0.8, 1.5),
    hips=st.floats(0.8, 1.4),
    arms=st.floats(0.8, 1.4),
    legs=st.floats(0.8, 1.4),
)
def test_any_body_is_a_valid_closed_skin(height, chest, waist, hips, arms, legs):
    p = BodyParams(height=height, chest=chest, waist=waist, hips=hips, arms=arms, legs=legs)
    c = procedural_character(p, motions=())
    assert_closed_manifold(c.vertices, c.triangles)
    assert 3000 <= len(c.triangles) <= 6000
    assert_weights_valid(c.skin_joints, c.skin_weights, c.n_joints)


def test_two_bone_chain_weights_match_hand_computation():
    """Straight vertical chain a -> b -> end site: rigid far from the joint, smoothstep across it
    (50/50 on the joint plane)."""
    names = ("a", "b")
    parents = np.array([-1, 0])
    pos = np.array([[0.0, 0.0, 0.0], [0.0, 0.5, 0.0]])
    v, f, sj, sw = skin_skeleton(names, parents, pos, BodyParams(target_triangles=3000),
                                 radii=np.full(2, 0.06), end_sites={1: np.array([0.0, 1.0, 0.0])})
    assert_closed_manifold(v, f)
    assert_weights_valid(sj, sw, 2)
    w = np.zeros((len(v), 2))
    np.add.at(w, (np.repeat(np.arange(len(v)), 4), sj.ravel()), sw.ravel())
    # joint b: band half-width = min(0.5 * 0.06, 0.25 * 0.5) = 0.03, plane normal +Y
    y = v[:, 1] - 0.5
    np.testing.assert_allclose(w[y < -0.03, 0], 1.0, atol=1e-12)
    np.testing.assert_allclose(w[y > 0.03, 1], 1.0, atol=1e-12)
    band = np.abs(y) < 0.03
    assert band.sum() > 10
    u = (y[band] + 0.03) / 0.06
    np.testing.assert_allclose(w[band, 1], u * u * (3 - 2 * u), atol=1e-9)
    # the surface reaches the end site and the root's cap
    assert v[:, 1].max() == pytest.approx(1.0, abs=0.01)
    assert v[:, 1].min() == pytest.approx(-0.06, abs=0.01)


def test_odd_skeleton_with_guessed_radii():
    """A bent chain with a branch, a zero-length bone ('dup') and no radii or end sites."""
    names = ("root", "mid", "dup", "tip", "side")
    parents = np.array([-1, 0, 1, 2, 0])
    pos = np.array([[0, 0, 0], [0.3, 0.2, 0], [0.3, 0.2, 0], [0.5, 0.5, 0.1], [-0.2, 0.1, 0.0]], float)
    v, f, sj, sw = skin_skeleton(names, parents, pos, BodyParams(target_triangles=3000))
    assert_closed_manifold(v, f)
    assert_weights_valid(sj, sw, 5)
    assert 2000 < len(f) < 4500


def test_guessed_radii_dress_a_humanoid_skeleton():
    """The humanoid template path of guess_radii (as the BVH importer uses it)."""
    names, parents, local = humanoid_skeleton()
    pos = forward_kinematics(parents, local)[:, :3, 3]
    radii = guess_radii(parents, pos)
    j = {n: i for i, n in enumerate(names)}
    assert radii[j["chest"], 0] > 2 * radii[j["forearm_l"], 0]
    assert radii[j["thigh_l"], 0] > radii[j["shin_l"], 0] > radii[j["toes_l"], 0]
    v, f, sj, sw = skin_skeleton(names, parents, pos, BodyParams())
    assert_closed_manifold(v, f)
    assert_weights_valid(sj, sw, len(names))


def test_bad_input_raises_contract_error():
    with pytest.raises(ContractError):
        BodyParams(height=-1.0)
    with pytest.raises(ContractError):
        BodyParams(chest=5.0)
    with pytest.raises(ContractError):
        skin_skeleton(("a", "b"), np.array([-1, 0]), np.array([[0, 0, 0], [0, np.nan, 0]]))
    with pytest.raises(ContractError):
        skin_skeleton(("a", "b"), np.array([1, -1]), np.zeros((2, 3)))
    with pytest.raises(ContractError):  # every bone has zero length
        skin_skeleton(("a", "b", "c"), np.array([-1, 0, 1]), np.zeros((3, 3)), radii=np.full(3, 0.05),
                      end_sites={2: np.zeros(3)})
    with pytest.raises(ContractError):
        procedural_character(motions=("moonwalk",))
