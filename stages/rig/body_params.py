"""The procedural humanoid's parameters (stages.rig.procedural) and the skin weights' influence count,
in a module of their own: the skin generator (stages.rig.capsule_skin) and the character builder
(stages.rig.procedural) both take them, and neither imports the other's caller."""
from __future__ import annotations

from dataclasses import dataclass

from stages.checks import ContractError, check_positive

INFLUENCES = 4  # K, influences per vertex


@dataclass(frozen=True)
class BodyParams:
    """Shape and resolution of the procedural humanoid.

    height: metres, floor to top of head (the generated mesh matches it exactly).
    chest, waist, hips, arms, legs: girth scale factors (1 = average adult), in [0.5, 2].
    arm_angle_deg: bind-pose arm angle below horizontal (45 = A-pose, 0 = T-pose), in [0, 75].
    target_triangles: wanted skin triangle count (met within about +-15 %).
    blend_radius: smooth-union fillet width as a fraction of height (armpits, crotch).
    keys_per_second: keyframe rate of the procedural clips.
    walk_speed: m/s, root speed of the walk clip; walk_period: s, one full gait cycle (two steps);
    walk_cycles: gait cycles in the walk clip (it translates, so it does not loop; see
        `stages.rig.procedural_motion.walk_clip`).
    """

    height: float = 1.75
    chest: float = 1.0
    waist: float = 1.0
    hips: float = 1.0
    arms: float = 1.0
    legs: float = 1.0
    arm_angle_deg: float = 45.0
    target_triangles: int = 4500
    blend_radius: float = 0.012
    keys_per_second: float = 30.0
    walk_speed: float = 1.2
    walk_period: float = 1.1
    walk_cycles: int = 4

    def __post_init__(self):
        o = "BodyParams"
        if not 0.5 <= self.height <= 2.5:
            raise ContractError(f"{o}.height: expected metres in [0.5, 2.5], got {self.height}")
        for name in ("chest", "waist", "hips", "arms", "legs"):
            v = getattr(self, name)
            if not 0.5 <= v <= 2.0:
                raise ContractError(f"{o}.{name}: expected a girth factor in [0.5, 2], got {v}")
        if not 0.0 <= self.arm_angle_deg <= 75.0:
            raise ContractError(f"{o}.arm_angle_deg: expected degrees in [0, 75], got {self.arm_angle_deg}")
        if not 500 <= self.target_triangles <= 200_000:
            raise ContractError(f"{o}.target_triangles: expected 500..200000, got {self.target_triangles}")
        if not 0.0 <= self.blend_radius <= 0.05:
            raise ContractError(f"{o}.blend_radius: expected a fraction of height in [0, 0.05], got {self.blend_radius}")
        for name in ("keys_per_second", "walk_period"):
            check_positive(o, name, getattr(self, name))
        check_positive(o, "walk_speed", self.walk_speed, strict=False)
        if int(self.walk_cycles) != self.walk_cycles or self.walk_cycles < 1:
            raise ContractError(f"{o}.walk_cycles: expected a positive integer, got {self.walk_cycles}")
