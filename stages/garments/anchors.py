"""What each built-in garment kind is anchored on: the humanoid's parts (stages.rig.humanoid), or on a
four-legged character (stages.garments.quadruped) its trunk, where a cape becomes a blanket."""
from __future__ import annotations

from stages.errors import InputError

ANCHORS = {"tshirt": ("arm_l", "arm_r", "neck"), "shorts": ("leg_l", "leg_r"), "trousers": ("leg_l", "leg_r"),
           "cape": ("neck",), "short_skirt": ("hips",), "long_skirt": ("hips",)}
QUADRUPED_KINDS = ("cape",)   # a cape on four legs is a blanket over the back (quadruped.blanket)


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
