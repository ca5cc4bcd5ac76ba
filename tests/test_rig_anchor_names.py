"""Garment anchors found whatever the rig's naming (stages.rig.joint_names, stages.rig.humanoid):
every rig of the real assets and the built-in character renamed in memory to each usual naming
convention, and to meaningless names (shape only), gives the same joints as the original; name
matches that contradict the skeleton's shape are not taken; single-joint limbs (Kenney) are
recorded with a one-line reason."""
from __future__ import annotations

import dataclasses
import os

import numpy as np
import pytest

from pipeline.assets import ASSETS_ENV, assets_dir as _assets_dir
from stages.errors import InputError
from stages.rig.humanoid import humanoid_joints, limb_chain, structural_chain
from stages.rig.joint_names import label, tokens
from stages.rig.transforms import forward_kinematics
from stages.rig.types import Character

# Each rig's joints by role (the original's names); roles ending in _l / _r are sided.
ROLES = {
    "builtin": {"pelvis": "pelvis", "spine": "spine", "chest": "chest", "neck": "neck", "head": "head",
                **{f"{r}_{s}": f"{r}_{s}" for s in "lr" for r in ("clavicle", "upperarm", "forearm", "hand",
                                                                  "thigh", "shin", "foot")},
                "toes_l": "toes_l", "toes_r": "toes_r"},
    "CesiumMan": {"Skeleton_torso_joint_1": "pelvis", "Skeleton_torso_joint_2": "spine", "torso_joint_3": "chest",
                  "Skeleton_neck_joint_1": "neck", "Skeleton_neck_joint_2": "head",
                  "Skeleton_arm_joint_L__4_": "upperarm_l", "Skeleton_arm_joint_L__3_": "forearm_l",
                  "Skeleton_arm_joint_L__2_": "hand_l", "Skeleton_arm_joint_R": "upperarm_r",
                  "Skeleton_arm_joint_R__2_": "forearm_r", "Skeleton_arm_joint_R__3_": "hand_r",
                  **{f"leg_joint_{S}_{k}": f"{r}_{S.lower()}" for S in "LR"
                     for k, r in ((1, "thigh"), (2, "shin"), (3, "foot"), (5, "toes"))}},
    "cmu_131_01_walk": {"Hips": "pelvis", "lowerback": "spine", "Chest": "spine1", "Chest2": "chest",
                        "lowerneck": "neck", "Neck": "neck1", "Head": "head", "Head_end": "head_end",
                        **{f"{S[0]}HipJoint": f"hipjoint_{S[0].lower()}" for S in ("Left", "Right")},
                        **{f"{S}{n}": f"{r}_{S[0].lower()}" for S in ("Left", "Right") for n, r in
                           (("Hip", "thigh"), ("Knee", "shin"), ("Ankle", "foot"), ("Toe", "toes"),
                            ("Toe_end", "toes_end"), ("Collar", "clavicle"), ("Shoulder", "upperarm"),
                            ("Elbow", "forearm"), ("Wrist", "hand"))},
                        **{f"{c}{n}": f"{r}_{c.lower()}" for c in "LR" for n, r in
                           (("Fingers", "fingers"), ("Fingers_end", "fingers_end"), ("Thumb", "thumb"),
                            ("Thumb_end", "thumb_end"))},
                        "lhand": "palm_l", "rhand": "palm_r"},
    "kenney": {"root": "root", "leg-left": "leg_l", "leg-right": "leg_r", "torso": "chest", "arm-left": "arm_l",
               "arm-right": "arm_r", "head": "head"},
}

# naming conventions: (left word, right word), role -> name with {s} for the side word ('arm' and
# 'leg' are the single-joint limbs of the Kenney rig)
_MB = {"pelvis": "Hips", "spine": "Spine", "spine1": "Spine1", "chest": "Spine2", "neck": "Neck", "neck1": "Neck1",
       "head": "Head", "head_end": "HeadTop_End", "root": "Reference", "clavicle": "{s}Shoulder", "upperarm": "{s}Arm",
       "forearm": "{s}ForeArm", "hand": "{s}Hand", "palm": "{s}HandPalm", "fingers": "{s}HandIndex1",
       "fingers_end": "{s}HandIndex2", "thumb": "{s}HandThumb1", "thumb_end": "{s}HandThumb2",
       "hipjoint": "{s}HipJoint", "thigh": "{s}UpLeg", "shin": "{s}Leg", "foot": "{s}Foot", "toes": "{s}ToeBase",
       "toes_end": "{s}Toe_End", "arm": "{s}Arm", "leg": "{s}UpLeg"}
_RIGIFY = {"pelvis": "spine", "spine": "spine.001", "spine1": "spine.002", "chest": "spine.003", "neck": "spine.004",
           "neck1": "spine.005", "head": "spine.006", "head_end": "spine.007", "root": "root",
           "clavicle": "shoulder.{s}", "upperarm": "upper_arm.{s}", "forearm": "forearm.{s}", "hand": "hand.{s}",
           "palm": "palm.01.{s}", "fingers": "f_index.01.{s}", "fingers_end": "f_index.02.{s}",
           "thumb": "thumb.01.{s}", "thumb_end": "thumb.02.{s}", "hipjoint": "pelvis.{s}", "thigh": "thigh.{s}",
           "shin": "shin.{s}", "foot": "foot.{s}", "toes": "toe.{s}", "toes_end": "heel.02.{s}",
           "arm": "upper_arm.{s}", "leg": "thigh.{s}"}
CONVENTIONS = {
    "mixamo": (("Left", "Right"), {k: "mixamorig:" + v for k, v in _MB.items()}),
    "motionbuilder": (("Left", "Right"), _MB),
    "character1": (("Left", "Right"), {k: "Character1_" + v for k, v in _MB.items()}),
    "unreal": (("l", "r"), {"pelvis": "pelvis", "spine": "spine_01", "spine1": "spine_02", "chest": "spine_03",
                            "neck": "neck_01", "neck1": "neck_02", "head": "head", "head_end": "head_end",
                            "root": "root", "clavicle": "clavicle_{s}", "upperarm": "upperarm_{s}",
                            "forearm": "lowerarm_{s}", "hand": "hand_{s}", "palm": "palm_{s}",
                            "fingers": "index_01_{s}", "fingers_end": "index_02_{s}", "thumb": "thumb_01_{s}",
                            "thumb_end": "thumb_02_{s}", "hipjoint": "hip_{s}", "thigh": "thigh_{s}",
                            "shin": "calf_{s}", "foot": "foot_{s}", "toes": "ball_{s}", "toes_end": "ball_end_{s}",
                            "arm": "upperarm_{s}", "leg": "thigh_{s}"}),
    "vrm": (("left", "right"), {"pelvis": "hips", "spine": "spine", "spine1": "chest", "chest": "upperChest",
                                "neck": "neck", "neck1": "neckUpper", "head": "head", "head_end": "headEnd",
                                "root": "root", "clavicle": "{s}Shoulder", "upperarm": "{s}UpperArm",
                                "forearm": "{s}LowerArm", "hand": "{s}Hand", "palm": "{s}HandPalm",
                                "fingers": "{s}IndexProximal", "fingers_end": "{s}IndexIntermediate",
                                "thumb": "{s}ThumbProximal", "thumb_end": "{s}ThumbIntermediate",
                                "hipjoint": "{s}HipJoint", "thigh": "{s}UpperLeg", "shin": "{s}LowerLeg",
                                "foot": "{s}Foot", "toes": "{s}Toes", "toes_end": "{s}ToesEnd",
                                "arm": "{s}UpperArm", "leg": "{s}UpperLeg"}),
    "vrm_bip": (("L", "R"), {"pelvis": "J_Bip_C_Hips", "spine": "J_Bip_C_Spine", "spine1": "J_Bip_C_Chest",
                             "chest": "J_Bip_C_UpperChest", "neck": "J_Bip_C_Neck", "neck1": "J_Adj_C_Neck2",
                             "head": "J_Bip_C_Head", "head_end": "J_Adj_C_HeadEnd", "root": "Root",
                             "clavicle": "J_Bip_{s}_Shoulder", "upperarm": "J_Bip_{s}_UpperArm",
                             "forearm": "J_Bip_{s}_LowerArm", "hand": "J_Bip_{s}_Hand", "palm": "J_Adj_{s}_Palm",
                             "fingers": "J_Bip_{s}_Index1", "fingers_end": "J_Bip_{s}_Index2",
                             "thumb": "J_Bip_{s}_Thumb1", "thumb_end": "J_Bip_{s}_Thumb2",
                             "hipjoint": "J_Adj_{s}_HipJoint", "thigh": "J_Bip_{s}_UpperLeg",
                             "shin": "J_Bip_{s}_LowerLeg", "foot": "J_Bip_{s}_Foot", "toes": "J_Bip_{s}_ToeBase",
                             "toes_end": "J_Adj_{s}_ToeEnd", "arm": "J_Bip_{s}_UpperArm",
                             "leg": "J_Bip_{s}_UpperLeg"}),
    "rigify_def": (("L", "R"), {k: "DEF-" + v for k, v in _RIGIFY.items()}),
    "rigify_org": (("L", "R"), {k: "ORG-" + v for k, v in _RIGIFY.items()}),
    "rigify_mch": (("L", "R"), {k: "MCH-" + v for k, v in _RIGIFY.items()}),
    "blender_metarig": (("L", "R"), _RIGIFY),
    "blender_generic": (("L", "R"), {"pelvis": "Hips", "spine": "Spine", "spine1": "Spine.001", "chest": "Chest",
                                     "neck": "Neck", "neck1": "Neck.001", "head": "Head", "head_end": "Head_end",
                                     "root": "Root", "clavicle": "Shoulder.{s}", "upperarm": "UpperArm.{s}",
                                     "forearm": "LowerArm.{s}", "hand": "Hand.{s}", "palm": "Palm.{s}",
                                     "fingers": "Index1.{s}", "fingers_end": "Index2.{s}", "thumb": "Thumb1.{s}",
                                     "thumb_end": "Thumb2.{s}", "hipjoint": "Hip.{s}", "thigh": "UpperLeg.{s}",
                                     "shin": "LowerLeg.{s}", "foot": "Foot.{s}", "toes": "Toe.{s}",
                                     "toes_end": "Toe_end.{s}", "arm": "UpperArm.{s}", "leg": "UpperLeg.{s}"}),
    "blender_generic_underscore": (("L", "R"), {
        "pelvis": "Pelvis", "spine": "Spine", "spine1": "Spine_1", "chest": "Chest", "neck": "Neck",
        "neck1": "Neck_1", "head": "Head", "head_end": "Head_End", "root": "Armature", "clavicle": "Clavicle_{s}",
        "upperarm": "Arm_{s}", "forearm": "ForeArm_{s}", "hand": "Hand_{s}", "palm": "Palm_{s}",
        "fingers": "Finger_1_{s}", "fingers_end": "Finger_2_{s}", "thumb": "Thumb_1_{s}", "thumb_end": "Thumb_2_{s}",
        "hipjoint": "Hip_{s}", "thigh": "Thigh_{s}", "shin": "Shin_{s}", "foot": "Foot_{s}", "toes": "Toes_{s}",
        "toes_end": "Toes_End_{s}", "arm": "Arm_{s}", "leg": "Leg_{s}"}),
    "cmu": (("Left", "Right"), {"pelvis": "Hips", "spine": "lowerback", "spine1": "Chest", "chest": "Chest2",
                                "neck": "lowerneck", "neck1": "Neck", "head": "Head", "head_end": "Head_end",
                                "root": "Reference", "clavicle": "{s}Collar", "upperarm": "{s}Shoulder",
                                "forearm": "{s}Elbow", "hand": "{s}Wrist", "palm": "{c}hand",
                                "fingers": "{C}Fingers", "fingers_end": "{C}Fingers_end", "thumb": "{C}Thumb",
                                "thumb_end": "{C}Thumb_end", "hipjoint": "{C}HipJoint", "thigh": "{s}Hip",
                                "shin": "{s}Knee", "foot": "{s}Ankle", "toes": "{s}Toe", "toes_end": "{s}Toe_end",
                                "arm": "{s}Shoulder", "leg": "{s}Hip"}),
    "biped": (("L", "R"), {"pelvis": "Bip01 Pelvis", "spine": "Bip01 Spine", "spine1": "Bip01 Spine1",
                           "chest": "Bip01 Spine2", "neck": "Bip01 Neck", "neck1": "Bip01 Neck1",
                           "head": "Bip01 Head", "head_end": "Bip01 HeadNub", "root": "Bip01",
                           "clavicle": "Bip01 {s} Clavicle", "upperarm": "Bip01 {s} UpperArm",
                           "forearm": "Bip01 {s} Forearm", "hand": "Bip01 {s} Hand", "palm": "Bip01 {s} Palm",
                           "fingers": "Bip01 {s} Finger1", "fingers_end": "Bip01 {s} Finger11",
                           "thumb": "Bip01 {s} Finger0", "thumb_end": "Bip01 {s} Finger01",
                           "hipjoint": "Bip01 {s} HipHelper", "thigh": "Bip01 {s} Thigh", "shin": "Bip01 {s} Calf",
                           "foot": "Bip01 {s} Foot", "toes": "Bip01 {s} Toe0", "toes_end": "Bip01 {s} Toe0Nub",
                           "arm": "Bip01 {s} UpperArm", "leg": "Bip01 {s} Thigh"}),
    "game_engine": (("Left", "Right"), {
        "pelvis": "b_Hip_{i}", "spine": "b_Spine01_{i}", "spine1": "b_Spine02_{i}", "chest": "b_Spine03_{i}",
        "neck": "b_Neck_{i}", "neck1": "b_Neck01_{i}", "head": "b_Head_{i}", "head_end": "b_HeadEnd_{i}",
        "root": "b_Root_{i}", "clavicle": "b_{s}Shoulder_{i}", "upperarm": "b_{s}UpperArm_{i}",
        "forearm": "b_{s}ForeArm_{i}", "hand": "b_{s}Hand_{i}", "palm": "b_{s}Palm_{i}",
        "fingers": "b_{s}Finger01_{i}", "fingers_end": "b_{s}Finger02_{i}", "thumb": "b_{s}Thumb01_{i}",
        "thumb_end": "b_{s}Thumb02_{i}", "hipjoint": "b_{s}Hip_{i}", "thigh": "b_{s}Leg01_{i}",
        "shin": "b_{s}Leg02_{i}", "foot": "b_{s}Foot01_{i}", "toes": "b_{s}Foot02_{i}", "toes_end": "b_{s}Toe_{i}",
        "arm": "b_{s}UpperArm_{i}", "leg": "b_{s}Leg01_{i}"}),
    "daz": (("l", "r"), {"pelvis": "hip", "spine": "abdomenLower", "spine1": "abdomenUpper", "chest": "chestUpper",
                         "neck": "neckLower", "neck1": "neckUpper", "head": "head", "head_end": "head_end",
                         "root": "Genesis8Male", "clavicle": "{s}Collar", "upperarm": "{s}ShldrBend",
                         "forearm": "{s}ForearmBend", "hand": "{s}Hand", "palm": "{s}Carpal1",
                         "fingers": "{s}Index1", "fingers_end": "{s}Index2", "thumb": "{s}Thumb1",
                         "thumb_end": "{s}Thumb2", "hipjoint": "{s}PelvisHelper", "thigh": "{s}ThighBend",
                         "shin": "{s}Shin", "foot": "{s}Foot", "toes": "{s}Toe", "toes_end": "{s}SmallToe1",
                         "arm": "{s}ShldrBend", "leg": "{s}ThighBend"}),
    "kenney": (("left", "right"), {"pelvis": "hips", "spine": "spine", "spine1": "spine-upper", "chest": "torso",
                                   "neck": "neck", "neck1": "neck-upper", "head": "head", "head_end": "head-end",
                                   "root": "root", "clavicle": "shoulder-{s}", "upperarm": "upperarm-{s}",
                                   "forearm": "forearm-{s}", "hand": "hand-{s}", "palm": "palm-{s}",
                                   "fingers": "finger-{s}", "fingers_end": "finger-end-{s}", "thumb": "thumb-{s}",
                                   "thumb_end": "thumb-end-{s}", "hipjoint": "hip-{s}", "thigh": "thigh-{s}",
                                   "shin": "shin-{s}", "foot": "foot-{s}", "toes": "toes-{s}",
                                   "toes_end": "toes-end-{s}", "arm": "arm-{s}", "leg": "leg-{s}"}),
}


def convention_names(rig: str, names, convention: str) -> tuple:
    """The rig's joint names in a naming convention ('scrambled': meaningless names)."""
    if convention == "scrambled":
        return tuple(f"x{(k * 7919) % 1000:03d}q{len(names) - k}" for k in range(len(names)))
    (left, right), table = CONVENTIONS[convention]
    out = []
    for i, n in enumerate(names):
        role = ROLES[rig][n]
        side = role[-1] if role[-2:] in ("_l", "_r") else ""
        base = role[:-2] if side else role
        s = left if side == "l" else right if side == "r" else ""
        out.append(table[base].format(s=s, i=f"{i:02d}", c=s[:1].lower(), C=s[:1].upper()))
    assert len(set(out)) == len(out), out
    return tuple(out)


def _renamed(character, names):
    return dataclasses.replace(character, joint_names=tuple(names))


def _parts(h):
    return (h.arm_l, h.arm_r, h.leg_l, h.leg_r, h.chest, h.neck, h.head, h.short)


FILES = {"CesiumMan": ("CesiumMan", "CesiumMan.glb"), "cmu_131_01_walk": ("cmu_131_01_walk", "cmu_131_01_walk.bvh"),
         "kenney_male_a": ("kenney", "kenney_mini_male_a.glb"), "kenney_female_b": ("kenney", "kenney_mini_female_b.glb")}
_LOADED: dict = {}


def load_rig(rig: str):
    """(role table, Character) of a rig: the built-in one, or a real asset loaded once; a missing
    asset skips the test naming it (a failure under GARMENT_REQUIRE_ASSETS=1)."""
    if rig not in _LOADED:
        if rig == "builtin":
            from stages.rig.procedural import procedural_character
            _LOADED[rig] = ("builtin", procedural_character())
        else:
            from stages.rig.bvh_character import load_bvh_character
            from stages.rig.gltf import load_gltf
            table, file = FILES[rig]
            path = _assets_dir() / file
            if not path.is_file():
                reason = f"real asset missing: {path}; set {ASSETS_ENV} to the assets' folder"
                if os.environ.get("GARMENT_REQUIRE_ASSETS") == "1":
                    pytest.fail(reason + " [GARMENT_REQUIRE_ASSETS=1]")
                pytest.skip(reason)
            _LOADED[rig] = (table, load_bvh_character(path) if file.endswith(".bvh") else load_gltf(path))
    return _LOADED[rig]


# what the originals give (joint indices): the built-in character, CesiumMan and the BVH as before
# token names; Kenney's limbs are single joints (short), its chest the torso, its neck the head
EXPECTED = {
    "builtin": ((6, 7, 8), (10, 11, 12), (13, 14, 15), (17, 18, 19), 2, 3, 4, {}),
    "CesiumMan": ((5, 6, 7), (8, 9, 10), (11, 12, 13), (15, 16, 17), 2, 3, 4, {}),
    "cmu_131_01_walk": ((21, 22, 23), (30, 31, 32), (2, 3, 4), (8, 9, 10), 15, 16, 17, {}),
    "kenney_male_a": (None, None, None, None, 3, 6, 6, {"leg_l": (1,), "leg_r": (2,), "arm_l": (4,), "arm_r": (5,)}),
    "kenney_female_b": (None, None, None, None, 3, 6, 6,
                        {"leg_l": (1,), "leg_r": (2,), "arm_l": (4,), "arm_r": (5,)}),
}


@pytest.mark.parametrize("rig", list(EXPECTED))
def test_originals(rig):
    _, c = load_rig(rig)
    assert _parts(humanoid_joints(c)) == EXPECTED[rig]


@pytest.mark.parametrize("convention", list(CONVENTIONS) + ["scrambled"])
@pytest.mark.parametrize("rig", list(EXPECTED))
def test_every_naming_finds_the_same_anchors(rig, convention):
    role_table, c = load_rig(rig)
    names = convention_names(role_table, c.joint_names, convention)
    h = humanoid_joints(_renamed(c, names))
    assert _parts(h) == EXPECTED[rig], names
    limbs = ("arm_l", "arm_r", "leg_l", "leg_r")
    assert {p: h.found[p] for p in limbs} == {p: "shape" if convention == "scrambled" else "name" for p in limbs}


@pytest.mark.parametrize("name, side, part", [
    ("mixamorig:LeftArm", "l", "upperarm"), ("mixamorig:LeftShoulder", "l", "shoulder"),
    ("upperarm_l", "l", "upperarm"), ("lowerarm_r", "r", "lowerarm"), ("leftUpperArm", "l", "upperarm"),
    ("J_Bip_L_UpperArm", "l", "upperarm"), ("DEF-upper_arm.L.001", "l", "upperarm"), ("ORG-forearm.R", "r", "lowerarm"),
    ("MCH-hand.L", "l", "hand"), ("UpperArm.L", "l", "upperarm"), ("Arm_L", "l", "upperarm"),
    ("LowerArm.R", "r", "lowerarm"), ("LeftForeArm", "l", "lowerarm"), ("LeftUpLeg", "l", "thigh"),
    ("LeftLeg", "l", "leg"), ("Bip01 L Forearm", "l", "lowerarm"), ("Bip01 R Calf", "r", "shin"),
    ("Bip01 Neck", "", "neck"), ("b_LeftUpperArm_09", "l", "upperarm"), ("b_Neck_04", "", "neck"),
    ("b_LeftLeg01_15", "l", "leg"), ("Character1_LeftArm", "l", "upperarm"), ("lShldrBend", "l", "shoulder"),
    ("rForearmBend", "r", "lowerarm"), ("lThighBend", "l", "thigh"), ("lShin", "l", "shin"),
    ("arm-left", "l", "upperarm"), ("leg-right", "r", "leg"), ("LHipJoint", "l", "hip"), ("lhand", "l", "hand"),
    ("LeftHandIndex1", "l", "hand"), ("Hips", "", "pelvis"), ("Armature", "", ""), ("leg_joint_L_1", "l", "leg"),
    ("Skeleton_arm_joint_R__2_", "r", "upperarm"), ("torso_joint_3", "", "spine"), ("j12", "", ""),
    ("Arm_Left_Lower", "l", "lowerarm"), ("J_Bip_C_Hips", "", "pelvis"), ("rThighTwist", "r", "thigh"),
])
def test_labels(name, side, part):
    assert label(name) == (side, part), tokens(name)


def _stick(names, parents, positions, name="stick", skinless=()):
    """A character of one box per bone (around the segment from a joint to its children's mean),
    skinned rigidly to that joint (none for the joints in `skinless`); rest frames are translations."""
    parents = np.asarray(parents, np.int32)
    p = np.asarray(positions, float)
    rest = np.tile(np.eye(4), (len(p), 1, 1))
    rest[:, :3, 3] = p - np.where(parents[:, None] >= 0, p[parents], 0.0)
    verts, tris, owner = [], [], []
    box = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    faces = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                      [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    for j in range(len(p)):
        if j in skinless:
            continue
        kids = np.flatnonzero(parents == j)
        a, b = p[j], (p[kids].mean(axis=0) if kids.size else p[j])
        lo, hi = np.minimum(a, b) - 0.03, np.maximum(a, b) + 0.03
        tris.append(faces + len(owner))
        verts.append((lo + hi) / 2 + box * (hi - lo) / 2)
        owner += [j] * 8
    v = np.concatenate(verts)
    inv = np.linalg.inv(forward_kinematics(parents, rest))
    return Character(name=name, vertices=v, triangles=np.concatenate(tris).astype(np.int32),
                     primitive_ids=np.zeros(len(v), np.int32), joint_names=tuple(names), parents=parents,
                     rest_local=rest, inverse_bind=inv, skin_joints=np.array(owner, np.int32)[:, None],
                     skin_weights=np.ones((len(v), 1)))


def _quadruped(names=None):
    """A dog-like rig (hips root, facing +Z): front legs named as arms, hind legs as legs."""
    rig = [("b_Hip_00", -1, (0, 0.6, -0.4)), ("b_Spine01_01", 0, (0, 0.62, 0.0)), ("b_Spine02_02", 1, (0, 0.64, 0.35)),
           ("b_Neck_04", 2, (0, 0.75, 0.5)), ("b_Head_05", 3, (0, 0.95, 0.6)),
           ("b_LeftUpperArm_09", 2, (0.12, 0.55, 0.35)), ("b_LeftForeArm_10", 5, (0.12, 0.3, 0.37)),
           ("b_LeftHand_11", 6, (0.12, 0.05, 0.38)), ("b_RightUpperArm_06", 2, (-0.12, 0.55, 0.35)),
           ("b_RightForeArm_07", 8, (-0.12, 0.3, 0.37)), ("b_RightHand_08", 9, (-0.12, 0.05, 0.38)),
           ("b_LeftLeg01_15", 0, (0.12, 0.55, -0.4)), ("b_LeftLeg02_16", 11, (0.12, 0.3, -0.45)),
           ("b_LeftFoot01_17", 12, (0.12, 0.05, -0.42)), ("b_RightLeg01_19", 0, (-0.12, 0.55, -0.4)),
           ("b_RightLeg02_20", 14, (-0.12, 0.3, -0.45)), ("b_RightFoot01_21", 15, (-0.12, 0.05, -0.42)),
           ("b_Tail01_22", 0, (0, 0.62, -0.6))]
    return _stick(names or [r[0] for r in rig], [r[1] for r in rig], [r[2] for r in rig], "quadruped")


def test_quadruped_neck_found_by_name_front_legs_not_arms():
    """The reported refusal ('no neck' on `b_Neck_04`): the front legs named as arms reach the
    floor, so they are not arms; the neck is then the joint named neck, the chest its parent."""
    q = _quadruped()
    h = humanoid_joints(q)
    n = q.joint_names
    assert h.arm_l is None and h.arm_r is None and "floor" in h.why["arm_l"] and "b_LeftUpperArm_09" in h.why["arm_l"]
    assert [n[j] for j in h.leg_l] == ["b_LeftLeg01_15", "b_LeftLeg02_16", "b_LeftFoot01_17"]
    assert [n[j] for j in h.leg_r] == ["b_RightLeg01_19", "b_RightLeg02_20", "b_RightFoot01_21"]
    assert (n[h.neck], n[h.head], n[h.chest], h.found["neck"]) == ("b_Neck_04", "b_Head_05", "b_Spine02_02", "name")
    h.require(("neck",), "garment 'cape'")         # a cape can be dressed
    with pytest.raises(InputError, match="hangs down to the floor"):
        h.require(("arm_l", "arm_r", "neck"), "garment 'tshirt'")
    # meaningless names: the hind legs by shape (the branches nearest the root), no neck to find
    s = humanoid_joints(_renamed(q, [f"j{k}" for k in range(q.n_joints)]))
    assert (s.leg_l, s.leg_r, s.arm_l, s.neck) == (h.leg_l, h.leg_r, None, -1)


def _robot(names):
    """Root at the chest; arms hanging from it reach below the root; legs under a pelvis below."""
    rig = [(-1, (0, 1.3, 0)), (0, (0, 1.0, 0)), (1, (0, 0.9, 0)),
           (2, (0.1, 0.9, 0)), (3, (0.1, 0.5, 0)), (4, (0.1, 0.08, 0)), (5, (0.1, 0.02, 0.12)),
           (2, (-0.1, 0.9, 0)), (7, (-0.1, 0.5, 0)), (8, (-0.1, 0.08, 0)), (9, (-0.1, 0.02, 0.12)),
           (0, (0.22, 1.3, 0)), (11, (0.24, 1.0, 0)), (12, (0.26, 0.7, 0)), (13, (0.26, 0.6, 0)),
           (0, (-0.22, 1.3, 0)), (15, (-0.24, 1.0, 0)), (16, (-0.26, 0.7, 0)), (17, (-0.26, 0.6, 0)),
           (0, (0, 1.45, 0)), (19, (0, 1.6, 0))]
    return _stick(names, [r[0] for r in rig], [r[1] for r in rig], "robot")


def test_robot_arm_is_never_a_leg():
    """Rooted at the chest with arms hanging below the root: the legs are the chains down to the
    floor, the arms the chains off the root; the neck the root's child between them. (The reported
    failure: the shape rule before token names took the arms for the legs here and found no arms.)"""
    r = _robot([f"j{k}" for k in range(21)])
    h = humanoid_joints(r)
    assert (h.leg_l, h.leg_r, h.arm_l, h.arm_r) == ((3, 4, 5), (7, 8, 9), (11, 12, 13), (15, 16, 17))
    assert (h.chest, h.neck, h.head) == (0, 19, 20)
    assert structural_chain(r, "leg", "r") == [7, 8, 9]


def test_name_matches_against_the_shape_are_not_taken():
    """Arms named as legs (they do not reach the floor), legs named as arms (they do), left and
    right swapped (the 'left' limbs on -X): the names are passed over, the shape finds the limbs."""
    _, c = load_rig("builtin")
    want = EXPECTED["builtin"]

    def renamed(mapping):    # part word -> new part word, or None: a meaningless name
        out = []
        for k, x in enumerate(c.joint_names):
            part, _, side = x.partition("_")
            out.append(x if part not in mapping else f"bone{k}" if mapping[part] is None else f"{mapping[part]}_{side}")
        return _renamed(c, out)

    arms_as_legs = {"upperarm": "thigh", "forearm": "shin", "hand": "foot", "thigh": None, "shin": None, "foot": None}
    h = humanoid_joints(renamed(arms_as_legs))
    assert _parts(h) == want and (h.found["leg_l"], h.found["arm_l"]) == ("shape", "shape")
    legs_as_arms = {"thigh": "upperarm", "shin": "forearm", "foot": "hand", "upperarm": None, "forearm": None,
                    "hand": None}
    h = humanoid_joints(renamed(legs_as_arms))
    assert _parts(h) == want and (h.found["arm_r"], h.found["leg_r"]) == ("shape", "shape")
    mirrored = [x[:-2] + {"_l": "_r", "_r": "_l"}[x[-2:]] if x[-2:] in ("_l", "_r") else x for x in c.joint_names]
    h = humanoid_joints(_renamed(c, mirrored))
    assert _parts(h) == want and (h.found["arm_l"], h.found["leg_r"]) == ("shape", "shape")


def test_kenney_single_joint_limbs():
    """Kenney's limbs are one joint each: no (upper, lower, end) chain, but limbs all the same, with
    shoulder / elbow / wrist points measured on the skin (the arm's end at the hand, 0.384 m out;
    the leg's at the floor): a T-shirt's anchors are there."""
    _, c = load_rig("kenney_male_a")
    h = humanoid_joints(c)
    assert limb_chain(c, "arm", "l") is None and structural_chain(c, "leg", "l") is None
    assert h.short["arm_l"] == (c.joint_names.index("arm-left"),) and "arm_l" not in h.why
    u, m, e = h.points["arm_l"]
    assert np.allclose(u, [0.1, 0.288, -0.017], atol=2e-3) and e[0] == pytest.approx(0.384, abs=0.01)
    assert np.allclose(m, (u + e) / 2)
    assert h.points["leg_r"][2][1] == pytest.approx(0.0, abs=0.02) and h.points["leg_r"][2][0] < 0
    h.require(("arm_l", "arm_r", "neck"), "garment 'tshirt'")
    h.require(("neck",), "garment 'cape'")


@pytest.mark.parametrize("rig", ["kenney_male_a", "kenney_female_b"])
def test_several_skins_detection_does_not_depend_on_which(rig):
    """Kenney has a body and a head mesh: their order swapped, or the body's skin alone, gives the
    same anchors (and the same short limbs)."""
    _, c = load_rig(rig)
    assert np.unique(c.primitive_ids).size == 2
    want = _parts(humanoid_joints(c))
    order = np.argsort(-c.primitive_ids, kind="stable")        # head mesh first
    back = np.argsort(order)
    swapped = dataclasses.replace(c, vertices=c.vertices[order], triangles=back[c.triangles].astype(np.int32),
                                  primitive_ids=c.primitive_ids[order], skin_joints=c.skin_joints[order],
                                  skin_weights=c.skin_weights[order])
    assert _parts(humanoid_joints(swapped)) == want
    keep = np.flatnonzero(c.primitive_ids == 0)
    new = np.full(len(c.vertices), -1)
    new[keep] = np.arange(keep.size)
    tris = new[c.triangles]
    body = dataclasses.replace(c, vertices=c.vertices[keep], triangles=tris[(tris >= 0).all(axis=1)].astype(np.int32),
                               primitive_ids=c.primitive_ids[keep], skin_joints=c.skin_joints[keep],
                               skin_weights=c.skin_weights[keep])
    assert _parts(humanoid_joints(body)) == want


def _human(left_arm, left_leg, spine=("pelvis", "spine", "chest", "neck", "head"), on_path=True):
    """A T-posed stick human (1.7 m): the spine's joints, then each side's arm and leg chains named
    by `left_arm` / `left_leg` (a name per point: clavicle, shoulder, mid upper arm, elbow, mid
    forearm, wrist / hip, mid thigh, knee, ankle, toe; None: no joint there) and mirrored with
    mirror(); on_path False hangs the mid joints off the chain (twist bones beside it)."""
    arm_pts = [(0.03, 1.45, 0), (0.18, 1.45, 0), (0.31, 1.45, 0), (0.45, 1.45, 0), (0.57, 1.45, 0), (0.7, 1.45, 0)]
    leg_pts = [(0.1, 0.95, 0), (0.1, 0.72, 0), (0.1, 0.5, 0), (0.1, 0.08, 0), (0.1, 0.02, 0.12)]
    spine_pts = [(0, 1.0, 0), (0, 1.15, 0), (0, 1.3, 0), (0, 1.5, 0), (0, 1.6, 0)]
    names, parents, pos = list(spine), [-1, 0, 1, 2, 3], list(spine_pts)
    for side, sign in (("l", 1.0), ("r", -1.0)):
        for chain, pts, attach, mid in ((left_arm, arm_pts, 2, {2, 4}), (left_leg, leg_pts, 0, {1})):
            prev = attach
            for k, (n, p) in enumerate(zip(chain, pts)):
                if n is None:
                    continue
                names.append(n if side == "l" else mirror(n))
                pos.append((sign * p[0], p[1], p[2]))
                parents.append(prev)
                if on_path or k not in mid:
                    prev = len(names) - 1
    return _stick(names, parents, pos, "human")


def mirror(name):
    for a, b in ((".L", ".R"), ("_l", "_r"), ("Left", "Right")):
        if a in name:
            return name.replace(a, b)
    return "r" + name[1:] if name[0] == "l" else name


@pytest.mark.parametrize("arm, leg, on_path, want_arm, want_leg", [
    # DAZ: bend and twist joints on the chain; the collar is not the upper arm
    (("lCollar", "lShldrBend", "lShldrTwist", "lForearmBend", "lForearmTwist", "lHand"),
     ("lThighBend", "lThighTwist", "lShin", "lFoot", "lToe"), True,
     ("lShldrBend", "lForearmBend", "lHand"), ("lThighBend", "lShin", "lFoot")),
    # Rigify: segments (.001) on the chain, 'shoulder' is the clavicle
    (("DEF-shoulder.L", "DEF-upper_arm.L", "DEF-upper_arm.L.001", "DEF-forearm.L", "DEF-forearm.L.001", "DEF-hand.L"),
     ("DEF-thigh.L", "DEF-thigh.L.001", "DEF-shin.L", "DEF-foot.L", "DEF-toe.L"), True,
     ("DEF-upper_arm.L", "DEF-forearm.L", "DEF-hand.L"), ("DEF-thigh.L", "DEF-shin.L", "DEF-foot.L")),
    # Unreal: twist bones beside the chain
    (("clavicle_l", "upperarm_l", "upperarm_twist_01_l", "lowerarm_l", "lowerarm_twist_01_l", "hand_l"),
     ("thigh_l", "thigh_twist_01_l", "calf_l", "foot_l", "ball_l"), False,
     ("upperarm_l", "lowerarm_l", "hand_l"), ("thigh_l", "calf_l", "foot_l")),
    # MotionBuilder without a clavicle joint: 'LeftShoulder' absent, LeftArm is the upper arm
    ((None, "LeftArm", None, "LeftForeArm", None, "LeftHand"),
     ("LeftUpLeg", None, "LeftLeg", "LeftFoot", "LeftToeBase"), True, ("LeftArm", "LeftForeArm", "LeftHand"), ("LeftUpLeg", "LeftLeg", "LeftFoot")),
])
def test_in_between_joints_and_clavicles(arm, leg, on_path, want_arm, want_leg):
    c = _human(arm, leg, on_path=on_path)
    h = humanoid_joints(c)
    n = c.joint_names
    assert tuple(n[j] for j in h.arm_l) == want_arm and tuple(n[j] for j in h.leg_l) == want_leg
    assert tuple(n[j] for j in h.arm_r) == tuple(mirror(x) for x in want_arm)
    assert tuple(n[j] for j in h.leg_r) == tuple(mirror(x) for x in want_leg)
    assert (n[h.chest], n[h.neck], n[h.head]) == ("chest", "neck", "head")
    assert all(h.found[p] == "name" for p in ("arm_l", "arm_r", "leg_l", "leg_r"))


def test_deform_joints_before_their_unskinned_copies():
    """Rigify's ORG- copies (no skin, a shorter chain: no .001 segments) beside the DEF- chain
    that carries the skin: the DEF- joints are the anchors (the garments split the skin by joint)."""
    c = _human(("DEF-shoulder.L", "DEF-upper_arm.L", "DEF-upper_arm.L.001", "DEF-forearm.L", "DEF-forearm.L.001",
                "DEF-hand.L"), ("DEF-thigh.L", "DEF-thigh.L.001", "DEF-shin.L", "DEF-foot.L", "DEF-toe.L"))
    w = forward_kinematics(c.parents, c.rest_local)[:, :3, 3]
    names, parents, pos = list(c.joint_names), list(c.parents), list(w)
    for part in ("shoulder", "upper_arm", "forearm", "hand"):
        for side in "LR":       # each ORG joint under the previous one of its side, the first under the chest
            prev = {"shoulder": "chest", "upper_arm": f"ORG-shoulder.{side}", "forearm": f"ORG-upper_arm.{side}",
                    "hand": f"ORG-forearm.{side}"}[part]
            pos.append(w[names.index(f"DEF-{part}.{side}")])
            parents.append(names.index(prev))
            names.append(f"ORG-{part}.{side}")
    org = {k for k, n in enumerate(names) if n.startswith("ORG-")}
    rig = _stick(names, parents, pos, "rigify", skinless=org)
    h = humanoid_joints(rig)
    n = rig.joint_names
    assert [n[j] for j in h.arm_l] == ["DEF-upper_arm.L", "DEF-forearm.L", "DEF-hand.L"]
    assert [n[j] for j in h.arm_r] == ["DEF-upper_arm.R", "DEF-forearm.R", "DEF-hand.R"]


def test_arms_hanging_straight_down_found_by_shape():
    """Meaningless names, arms straight down beside the body (hands at the hips): still arms."""
    names, parents = ["pelvis", "spine", "chest", "neck", "head"], [-1, 0, 1, 2, 3]
    pos = [(0, 1.0, 0), (0, 1.15, 0), (0, 1.3, 0), (0, 1.5, 0), (0, 1.6, 0)]
    for s in (1, -1):
        b = len(names)
        parents += [2, b, b + 1, b + 2, 0, b + 4, b + 5, b + 6]
        pos += [(s * 0.03, 1.45, 0), (s * 0.18, 1.45, 0), (s * 0.2, 1.15, 0), (s * 0.21, 0.88, 0),
                (s * 0.1, 0.95, 0), (s * 0.1, 0.5, 0), (s * 0.1, 0.08, 0), (s * 0.1, 0.02, 0.12)]
        names += [f"x{b + k}" for k in range(8)]
    h = humanoid_joints(_stick(names, parents, pos))
    assert (h.arm_l, h.arm_r, h.leg_l, h.leg_r) == ((6, 7, 8), (14, 15, 16), (9, 10, 11), (17, 18, 19))
    assert (h.chest, h.neck, h.head) == (2, 3, 4) and h.found["neck"] == "shape"


@pytest.mark.parametrize("scrambled", [False, True])
def test_unskinned_ik_helpers_are_not_limbs(scrambled):
    """Unreal's ik_hand_l / ik_foot_l (no skin, at the hand and the foot; here a little beyond
    them): neither by name nor by shape are they the limb's end."""
    c = _human(("clavicle_l", "upperarm_l", None, "lowerarm_l", None, "hand_l"),
               ("thigh_l", None, "calf_l", "foot_l", "ball_l"))
    w = forward_kinematics(c.parents, c.rest_local)[:, :3, 3]
    names, parents, pos = list(c.joint_names), list(c.parents), list(w)
    helpers = [("ik_hand_root", 0, (0, 0, 0)), ("ik_hand_gun", -1, (0.75, 1.45, 0)), ("ik_hand_l", -1, (0.76, 1.45, 0)),
               ("ik_hand_r", -2, (-0.76, 1.45, 0)), ("ik_foot_l", 0, (0.1, -0.02, 0.05)),
               ("ik_foot_r", 0, (-0.1, -0.02, 0.05))]
    for n, p, x in helpers:
        parents.append(p if p == 0 else len(names) + p)
        names.append(n)
        pos.append(np.array(x, float))
    skinless = set(range(c.n_joints, len(names)))
    rig = _stick(names if not scrambled else [f"q{k}" for k in range(len(names))], parents, pos, "ik",
                 skinless=skinless)
    h = humanoid_joints(rig)
    n = names
    assert [n[j] for j in h.arm_l] == ["upperarm_l", "lowerarm_l", "hand_l"]
    assert [n[j] for j in h.arm_r] == ["upperarm_r", "lowerarm_r", "hand_r"]
    assert [n[j] for j in h.leg_l] == ["thigh_l", "calf_l", "foot_l"]
    assert [n[j] for j in h.leg_r] == ["thigh_r", "calf_r", "foot_r"]
