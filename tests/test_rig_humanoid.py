"""Humanoid parts (stages.rig.humanoid): the same joints found by every usual naming and by the
skeleton's shape alone; a garment whose anchors are missing gets one error listing the rig's joints."""
import dataclasses
import os

import numpy as np
import pytest

from stages.errors import InputError
from stages.rig.humanoid import humanoid_joints
from stages.rig.procedural import procedural_character

MIXAMO = {"pelvis": "Hips", "spine": "Spine", "chest": "Spine2", "neck": "Neck", "head": "Head",
          "clavicle_l": "LeftShoulder", "upperarm_l": "LeftArm", "forearm_l": "LeftForeArm", "hand_l": "LeftHand",
          "clavicle_r": "RightShoulder", "upperarm_r": "RightArm", "forearm_r": "RightForeArm", "hand_r": "RightHand",
          "thigh_l": "LeftUpLeg", "shin_l": "LeftLeg", "foot_l": "LeftFoot", "toes_l": "LeftToeBase",
          "thigh_r": "RightUpLeg", "shin_r": "RightLeg", "foot_r": "RightFoot", "toes_r": "RightToeBase"}
VRM = {"pelvis": "hips", "spine": "spine", "chest": "chest", "neck": "neck", "head": "head",
       "clavicle_l": "leftShoulder", "upperarm_l": "leftUpperArm", "forearm_l": "leftLowerArm", "hand_l": "leftHand",
       "clavicle_r": "rightShoulder", "upperarm_r": "rightUpperArm", "forearm_r": "rightLowerArm",
       "hand_r": "rightHand", "thigh_l": "leftUpperLeg", "shin_l": "leftLowerLeg", "foot_l": "leftFoot",
       "toes_l": "leftToes", "thigh_r": "rightUpperLeg", "shin_r": "rightLowerLeg", "foot_r": "rightFoot",
       "toes_r": "rightToes"}


@pytest.fixture(scope="module")
def builtin():
    return procedural_character()


def _renamed(character, names):
    return dataclasses.replace(character, joint_names=tuple(names))


def _parts(h):
    return (h.arm_l, h.arm_r, h.leg_l, h.leg_r, h.chest, h.neck, h.head)


def test_builtin_parts(builtin):
    h = humanoid_joints(builtin)
    n = builtin.joint_names
    assert [n[j] for j in h.arm_l] == ["upperarm_l", "forearm_l", "hand_l"]
    assert [n[j] for j in h.leg_r] == ["thigh_r", "shin_r", "foot_r"]
    assert (n[h.chest], n[h.neck], n[h.head]) == ("chest", "neck", "head")


@pytest.mark.parametrize("table,prefix", [(MIXAMO, "mixamorig:"), (MIXAMO, ""), (VRM, "")])
def test_usual_namings_find_the_same_joints(builtin, table, prefix):
    renamed = _renamed(builtin, [prefix + table[n] for n in builtin.joint_names])
    assert _parts(humanoid_joints(renamed)) == _parts(humanoid_joints(builtin))


def test_unknown_names_fall_back_to_the_skeleton_shape(builtin):
    renamed = _renamed(builtin, [f"j{k}" for k in range(builtin.n_joints)])
    assert _parts(humanoid_joints(renamed)) == _parts(humanoid_joints(builtin))


def test_real_rigs(assets_dir):
    from stages.rig.bvh_character import load_bvh_character
    from stages.rig.gltf import load_gltf
    cesium = load_gltf(assets_dir / "CesiumMan.glb")
    h = humanoid_joints(cesium)
    n = cesium.joint_names
    assert n[h.neck] == "Skeleton_neck_joint_1" and n[h.chest] == "torso_joint_3"
    assert n[h.leg_l[0]] == "leg_joint_L_1" and n[h.arm_r[0]] == "Skeleton_arm_joint_R"
    bvh = load_bvh_character(assets_dir / "cmu_131_01_walk.bvh")
    h = humanoid_joints(bvh)
    n = bvh.joint_names
    assert [n[j] for j in h.arm_l] == ["LeftShoulder", "LeftElbow", "LeftWrist"]
    assert (n[h.chest], n[h.neck]) == ("Chest2", "lowerneck")


def test_missing_anchor_lists_what_was_looked_for_and_the_joints():
    from stages.sim.scenes import toy_character, fibonacci_points
    from scipy.spatial import ConvexHull
    pts = fibonacci_points(64, radii=(0.2, 0.5, 0.2), center=(0.0, 0.5, 0.0))
    blob = toy_character(pts, ConvexHull(pts).simplices, name="blob")
    h = humanoid_joints(blob)
    with pytest.raises(InputError) as e:
        h.require(("arm_l", "arm_r", "neck"), "garment 'tshirt'")
    msg = str(e.value)
    assert "garment 'tshirt'" in msg and "arm_l" in msg and "LeftArm" in msg and "joints: root" in msg
    h.require((), "garment 'skirt'")    # nothing needed, nothing raised


def test_a_garment_on_a_rig_without_its_anchors_is_one_error_line(assets_dir, tmp_path):
    """validate (and run) on a rig with no arms: exit 2, one line naming the scene file, the garment,
    the character and the rig's joints."""
    from tests.test_cli import cli
    scene = tmp_path / "shirt_on_a_tube.yaml"
    scene.write_text(f"character: {{source: gltf, path: '{assets_dir / 'RiggedSimple.glb'}', clip: 0}}\n"
                     "frames: {count: 5}\ngarments:\n  - {type: pattern, name: top, kind: tshirt}\n")
    r = cli("validate", str(scene))
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr
    for fragment in (str(scene), "garments[0] ('top', kind tshirt)", "'RiggedSimple'", "arm_l", "Root.001"):
        assert fragment in lines[0]


def test_how_each_part_was_found_and_its_points(builtin):
    """found says name / shape / missing; points are the chain joints' rest positions."""
    from stages.rig.transforms import forward_kinematics
    h = humanoid_joints(builtin)
    assert h.found == {"arm_l": "name", "arm_r": "name", "leg_l": "name", "leg_r": "name", "neck": "shape"}
    w = forward_kinematics(builtin.parents, builtin.rest_local)[:, :3, 3]
    for part in ("arm_l", "arm_r", "leg_l", "leg_r"):
        assert np.allclose(h.points[part], w[list(getattr(h, part))])
    assert h.short == {} and h.why == {}
    s = humanoid_joints(_renamed(builtin, [f"j{k}" for k in range(builtin.n_joints)]))
    assert set(s.found.values()) == {"shape"}


def test_real_rigs_scrambled_names_give_the_same_parts(assets_dir):
    """CesiumMan (by shape already) and the BVH (by name) with meaningless joint names: the shape
    alone finds the same joints (the BVH's arms start past the collar, its legs past LHipJoint)."""
    from stages.rig.bvh_character import load_bvh_character
    from stages.rig.gltf import load_gltf
    for c in (load_gltf(assets_dir / "CesiumMan.glb"), load_bvh_character(assets_dir / "cmu_131_01_walk.bvh")):
        s = _renamed(c, [f"j{k}" for k in range(c.n_joints)])
        assert _parts(humanoid_joints(s)) == _parts(humanoid_joints(c))


def test_a_tshirt_on_single_joint_arms_validates(tmp_path):
    """validate a T-shirt on Kenney's 7-joint rig: its one-joint arms are arms (exit 0; it was
    refused with "a sleeve needs shoulder, elbow and wrist joints")."""
    from pipeline.assets import assets_dir
    from tests.test_cli import cli
    kenney = assets_dir() / "kenney_mini_male_a.glb"
    if not kenney.is_file():
        reason = f"real asset missing: {kenney}"
        if os.environ.get("GARMENT_REQUIRE_ASSETS") == "1":
            pytest.fail(reason + " [GARMENT_REQUIRE_ASSETS=1]")
        pytest.skip(reason)
    scene = tmp_path / "shirt_on_kenney.yaml"
    scene.write_text(f"character: {{source: gltf, path: '{kenney}', clip: 0}}\n"
                     "frames: {count: 5}\ngarments:\n  - {type: pattern, name: top, kind: tshirt}\n")
    r = cli("validate", str(scene))
    assert r.returncode == 0, r.stderr
