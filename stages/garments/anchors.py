"""What each built-in garment kind is anchored on: the humanoid's parts (stages.rig.humanoid), or on a
four-legged character (stages.garments.quadruped) its trunk, where a cape becomes a blanket."""
from __future__ import annotations

from stages.errors import InputError

ANCHORS = {"tshirt": ("arm_l", "arm_r", "neck"), "shorts": ("leg_l", "leg_r"), "trousers": ("leg_l", "leg_r"),
           "cape": ("neck",), "short_skirt": ("hips",), "long_skirt": ("hips",)}
QUADRUPED_KINDS = ("cape",)   # a cape on four legs is a blanket over the back (quadruped.blanket)
# a GarmentCode pattern (or a GarmentCode body file) is graded and placed from a human's measurements:
# bust, waist and hips round the trunk, the arms, the legs, the neck (stages.garments.measurements)
HUMAN_PARTS = ("arm_l", "arm_r", "leg_l", "leg_r", "neck")


def require_anchors(kind: str, character, what: str, parts=None) -> None:
    """Raise one InputError naming `what` when the character lacks what `kind` is anchored on:
    ANCHORS on a humanoid; on a quadruped (stages.garments.quadruped) a cape needs its trunk
    (found with the front legs), and the kinds that need a biped are refused saying so."""
    from stages.garments.quadruped import front_legs
    from stages.rig.humanoid import humanoid_joints
    parts = parts or humanoid_joints(character)
    if front_legs(character, parts):
        if kind not in QUADRUPED_KINDS:
            raise InputError(what, f"{character.name!r} stands on four legs (its front legs reach the floor): "
                                   f"a {kind} needs a biped; a cape is dressed as a blanket over its back, and "
                                   f"mesh garments (type: mesh) fit any shape")
        return
    parts.require(ANCHORS.get(kind, ()), what)


def require_human(character, what: str, parts=None, subject: str = "a GarmentCode pattern is made") -> None:
    """Raise one InputError naming `what` unless the character is a biped with both arms, both legs
    and a neck (HUMAN_PARTS): what a GarmentCode pattern and a body file are measured on. Without
    them the measurements are the trunk of whatever the rig is (a bending cylinder measured a 6 m
    waist, and a dress placed on it ran 7 minutes in 5 GB before its timeout)."""
    from stages.garments.quadruped import front_legs
    from stages.rig.humanoid import humanoid_joints
    parts = parts or humanoid_joints(character)
    if front_legs(character, parts):
        raise InputError(what, f"{subject} for a human body, and {character.name!r} stands on "
                               f"four legs (its front legs reach the floor); a pattern cape is dressed as a blanket "
                               f"over its back (type: pattern, kind: cape), and mesh garments fit any shape")
    try:
        parts.require(HUMAN_PARTS, what)
    except InputError as err:
        raise InputError(what, f"{subject} for a human body (measured on its arms, legs and neck): {err.problem}; "
                               f"mesh garments (type: mesh) fit any shape") from None
