"""Four-legged characters: which joints are the trunk, and the measurements a blanket is cut from.

A quadruped is read from the same detection as a humanoid (stages.rig.humanoid): both legs found
and both arms refused because the branch that would be an arm reaches the floor. Its hind legs are
the legs; its front legs are the branches off the body, outside the hind legs, that reach the floor
on either side; the trunk is the root's path up to the common ancestor of the front legs (the
withers), its skin the vertices whose dominant joint is on that path.

A cape on a quadruped is a blanket (stages.garments.library.blanket): two halves sewn along the
spine, laid over the back from the withers to the rump and pinned along the seam to the trunk's
bones; it drapes down the flanks while the garments settle before frame 0.
"""
from __future__ import annotations

import numpy as np

from stages.garments.patterns import Panel, Pattern, PatternAttachment, Placement, Seam, SeamSide, line

FLOOR_SHARE = 0.1   # a foot's skin comes within this share of the height of the floor (as the legs' rule)


def front_legs(character, parts=None) -> list:
    """Joint indices where each front leg leaves the body (empty for a character that is not a
    quadruped): branches off the trunk, outside the hind legs, whose skin reaches the floor, one on
    each side of the mid-plane."""
    from stages.rig.humanoid import _branch_start, humanoid_joints, rest_body, subtree
    parts = parts or humanoid_joints(character)
    if not (parts.leg_l and parts.leg_r) or parts.arm_l or parts.arm_r:
        return []
    why = " ".join(parts.why.get(p, "") for p in ("arm_l", "arm_r"))
    if "floor" not in why:
        return []
    b = rest_body(character)
    hind = set()
    for leg in (parts.leg_l, parts.leg_r):
        hind |= subtree(b.parents, leg[0])
    out = []
    for sign in (1.0, -1.0):
        feet = [j for j in range(len(b.parents)) if j not in hind and b.lo[j, 1] < b.y0 + FLOOR_SHARE * b.height
                and sign * (b.w[j, 0] - b.x0) > 0.01 * b.height]
        starts = {_branch_start(b, f, sign) for f in feet}
        starts = [s for s in starts if s != b.root and b.sub_skin[s] > 0]
        if not starts:
            return []
        out.append(min(starts, key=lambda s: (b.depth[s], s)))
    return out


def trunk_joints(character, parts=None) -> list:
    """The root's path up to the common ancestor of the front legs (root first); empty for a
    character that is not a quadruped."""
    from stages.rig.humanoid import _ancestors
    legs = front_legs(character, parts)
    if not legs:
        return []
    parents = np.asarray(character.parents)
    anc = [_ancestors(parents, int(parents[j])) for j in legs]   # each from its parent up to the root
    common = [j for j in anc[0] if j in anc[1]]
    withers = common[0]
    return _ancestors(parents, withers)[::-1]


def _need_keys(meas: dict, *keys: str) -> None:
    from stages.checks import ContractError
    missing = [k for k in keys if k not in meas]
    if missing:
        raise ContractError(f"blanket: measurements {', '.join(missing)} missing (not a quadruped?)")


def back_measurements(character, motion=None, parts=None) -> dict:
    """For a quadruped, from its trunk's skin at frame 0 of `motion` (relative frame; default: the
    rest pose), metres: back_x (the mid-plane), back_top_y / belly_y (highest and lowest trunk skin),
    back_rear_z / back_front_z (its extent along the body, facing +Z), back_half (half its width, 98th
    percentile), quadruped = 1. Empty for any other character (nothing skinned). parts: the
    character's humanoid_joints when the caller has them."""
    trunk = trunk_joints(character, parts)
    if not trunk:
        return {}
    if motion is None:
        v = np.asarray(character.vertices, np.float64)
    else:
        from stages.rig.skinning import skin
        v = skin(character, motion, frames=[0])[0]
    dom = character.skin_joints[np.arange(len(v)), np.argmax(character.skin_weights, axis=1)]
    t = v[np.isin(dom, trunk)]
    if len(t) < 4:
        return {}
    x0 = float(np.median(t[:, 0]))
    return {"quadruped": 1.0, "back_x": x0, "back_top_y": float(t[:, 1].max()), "belly_y": float(t[:, 1].min()),
            "back_rear_z": float(t[:, 2].min()), "back_front_z": float(t[:, 2].max()),
            "back_half": float(np.percentile(np.abs(t[:, 0] - x0), 98))}


def blanket(meas: dict, *, length: float | None = None, edge_length: float = 0.03, name: str = "cape") -> Pattern:
    """A quadruped's cape (stages.garments.quadruped): two halves sewn along the spine, laid flat over
    the back from the withers to the rump (length: default 90 % of the trunk's skin), each as wide as
    the arc from the spine over the flank to its widest (a quarter ellipse of the trunk's half width
    and half depth) plus a third of the trunk's depth below it; pinned along the spine seam to the
    nearest trunk bones, it drapes down the flanks while the garments settle before frame 0."""
    _need_keys(meas, "back_x", "back_top_y", "belly_y", "back_rear_z", "back_front_z", "back_half")
    a, b = meas["back_half"], 0.5 * (meas["back_top_y"] - meas["belly_y"])
    quarter = 0.25 * np.pi * (3 * (a + b) - np.sqrt((3 * a + b) * (a + 3 * b))) / 2   # Ramanujan
    half = quarter + (meas["back_top_y"] - meas["belly_y"]) / 3
    trunk = meas["back_front_z"] - meas["back_rear_z"]
    L = 0.9 * trunk if length is None else length
    z = 0.5 * (meas["back_front_z"] + meas["back_rear_z"])
    center = (meas["back_x"], meas["back_top_y"] + 0.03, z)
    on_back = Placement("plane", center=center, normal=(0.0, 1.0, 0.0))
    # plane axes (placement.place_panel): u along +X (the left flank), v along -Z (towards the rump)
    left = Panel("left", (line("front_l", (half, -L / 2)), line("side_l", (half, L / 2)),
                          line("rear_l", (0.0, L / 2)), line("spine_l", (0.0, -L / 2))), on_back)
    right = Panel("right", (line("front_r", (0.0, -L / 2)), line("spine_r", (0.0, L / 2)),
                            line("rear_r", (-half, L / 2)), line("side_r", (-half, -L / 2))), on_back)
    atts = (PatternAttachment("left", "spine_l", sewing=True), PatternAttachment("right", "spine_r", sewing=True))
    return Pattern(name, (left, right), (Seam(SeamSide("left", "spine_l"), SeamSide("right", "spine_r")),),
                   edge_length, atts)
