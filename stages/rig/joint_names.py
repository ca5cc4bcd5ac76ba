"""Joint names read as tokens: which side and which body part a joint's name says, whatever the
rig's naming convention (Mixamo `mixamorig:LeftArm`, Unreal `upperarm_l`, VRM `leftUpperArm` /
`J_Bip_L_UpperArm`, Rigify `DEF-upper_arm.L`, Blender `UpperArm.L` / `Arm_L`, MotionBuilder / CMU
`LeftForeArm` / `LeftElbow`, 3ds Max `Bip01 L Forearm`, game engines `b_LeftUpperArm_09` /
`Character1_LeftArm`, DAZ `lShldrBend`, Kenney `arm-left`).

A name is split into lower-case tokens (namespace dropped, split at `_ . - : |` and spaces, at
case changes and at digits); prefixes (`DEF`, `Bip01`, `b`, `J_Bip`, `Character1`, ...) and any
word not listed here are ignored. `label(name)` gives (side, part): side 'l', 'r' or '' and part one
of PARTS or ''. Which joint of a limb is its upper / lower / end joint is decided along the skeleton
(`limb_ranks`): 'shoulder' is the upper arm only where no upper-arm joint exists (CMU), 'leg' the
shin below a thigh (Mixamo `LeftUpLeg > LeftLeg`) and the thigh otherwise (Kenney `leg-left`).
"""
from __future__ import annotations

import re

# camel-case pieces: "LHipJoint" -> L Hip Joint, "lShldrBend" -> l Shldr Bend, "leftUpperArm" -> left Upper Arm
_CAMEL = re.compile(r"[A-Z]+(?=[A-Z][a-z])|[A-Z]?[a-z]+|[A-Z]+")
_SPLIT = re.compile(r"[\s_.\-:|]+|\d+")

SIDES = {"l": "l", "left": "l", "r": "r", "right": "r"}
# part words; two-word parts ('upper arm') are joined first (COMPOUNDS)
PARTS = {
    "clavicle": "clavicle", "collar": "clavicle", "collarbone": "clavicle", "clav": "clavicle",
    "shoulder": "shoulder", "shldr": "shoulder",
    "upperarm": "upperarm", "uparm": "upperarm", "arm": "upperarm", "humerus": "upperarm",
    "forearm": "lowerarm", "lowerarm": "lowerarm", "lowarm": "lowerarm", "elbow": "lowerarm",
    "hand": "hand", "wrist": "hand",
    "hip": "hip",
    "thigh": "thigh", "upleg": "thigh", "upperleg": "thigh", "femur": "thigh",
    "leg": "leg",
    "shin": "shin", "calf": "shin", "knee": "shin", "lowerleg": "shin", "lowleg": "shin", "tibia": "shin",
    "foot": "foot", "ankle": "foot",
    "neck": "neck", "head": "head",
    "spine": "spine", "chest": "spine", "torso": "spine", "abdomen": "spine", "back": "spine",
    "pelvis": "pelvis", "hips": "pelvis",
}
COMPOUNDS = {("upper", "arm"): "upperarm", ("up", "arm"): "upperarm", ("fore", "arm"): "forearm",
             ("lower", "arm"): "lowerarm", ("low", "arm"): "lowerarm", ("up", "leg"): "upleg",
             ("upper", "leg"): "upperleg", ("lower", "leg"): "lowerleg", ("low", "leg"): "lowleg",
             ("collar", "bone"): "collarbone"}
# leading words that say nothing about the part, dropped (`DEF-`, `Bip01`, `b_`, `J_Bip_C_`,
# `Character1_`; any other word not in SIDES / PARTS is ignored too)
PREFIXES = ("mixamorig", "def", "org", "mch", "bip", "b", "j", "character", "bone", "bn", "jnt", "joint",
            "skeleton", "c")

# which part words make each rank of a limb: 0 before the limb (clavicle), 1 upper, 2 lower, 3 end
ARM_RANKS = {"clavicle": 0, "upperarm": 1, "lowerarm": 2, "hand": 3}
LEG_RANKS = {"thigh": 1, "shin": 2, "foot": 3}


def tokens(name: str) -> list:
    """Lower-case words of a joint name: namespace, leading prefixes (PREFIXES) and digits dropped,
    two-word parts joined (`upper_arm`, `ForeArm`, also apart: `Arm_Left_Lower`)."""
    name = name.rsplit(":", 1)[-1].rsplit("|", 1)[-1]
    words = []
    for piece in _SPLIT.split(name):
        words += [w.lower() for w in _CAMEL.findall(piece)]
    while words[1:] and words[0] in PREFIXES:
        words = words[1:]
    out = []
    for w in words:
        if out and (out[-1], w) in COMPOUNDS:
            out[-1] = COMPOUNDS[(out[-1], w)]
            continue
        # a side glued to a lower-case part (CMU `lhand`, `leftarm`)
        for s in ("left", "right", "l", "r"):
            if w.startswith(s) and w[len(s):] in PARTS:
                out.append(s)
                w = w[len(s):]
                break
        out.append(w)
    # a modifier apart from its limb word (`Arm_Left_Lower`, `Leg_R_Upper`)
    for base in ("arm", "leg"):
        mods = [m for m in ("upper", "up", "lower", "low", "fore") if m in out and (m, base) in COMPOUNDS]
        if base in out and mods:
            out[out.index(base)] = COMPOUNDS[(mods[0], base)]
            out.remove(mods[0])
    return out


def label(name: str) -> tuple:
    """(side, part) a joint name says: side 'l' / 'r' / '', part a PARTS value or '' (the last
    part word wins: `LeftHandIndex1` is a hand joint, `HeadTop_End` a head joint)."""
    side, part = "", ""
    for w in tokens(name):
        if w in SIDES and not side:
            side = SIDES[w]
        elif w in PARTS:
            part = PARTS[w]
    return side, part


def limb_ranks(path_labels: list, kind: str) -> list:
    """Rank of each joint on a root-to-tip path (labels from `label`, already of the limb's side):
    0 clavicle / hip helper, 1 upper, 2 lower, 3 end, -1 not a limb part. Ambiguous words are
    resolved along the path: 'shoulder' is the clavicle when an upper-arm joint is on the path
    (Mixamo `LeftShoulder > LeftArm`) and the upper arm otherwise (CMU `LeftShoulder > LeftElbow`);
    a sided 'hip' the same against a thigh (CMU `LeftHip > LeftKnee`); 'leg' is the shin below a
    thigh and the thigh otherwise."""
    parts = list(path_labels)
    if kind == "arm":
        has_upper = "upperarm" in parts
        return [1 if p == "shoulder" and not has_upper else 0 if p == "shoulder" else ARM_RANKS.get(p, -1)
                for p in parts]
    has_thigh = any(p in ("thigh", "leg") for p in parts)
    out, seen_thigh = [], False
    for p in parts:
        if p == "hip":
            r = 0 if has_thigh else 1
        elif p == "leg":
            r = 2 if seen_thigh else 1
        else:
            r = LEG_RANKS.get(p, -1)
        seen_thigh |= r == 1
        out.append(r)
    return out
