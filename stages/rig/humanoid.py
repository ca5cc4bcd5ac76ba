"""Which joints of a rig are the humanoid's limbs, neck and head: the usual namings first (the
built-in rig, Unreal-style, Mixamo with or without its `mixamorig:` prefix, CMU/BVH, VRM), the
skeleton's shape otherwise (CesiumMan's `leg_joint_L_1`, any rig a user brings).

Garments anchor on these: sleeves on the upper arms, legs of trousers on the thighs, a collar
below the neck. A garment whose anchors cannot be found gets one error listing what was looked for
and the joints the rig has (`HumanoidJoints.require`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from stages.errors import InputError

# (upper, lower, end) of the left limb; the right one is the mirrored name
ARM_CHAINS = (("upperarm_l", "forearm_l", "hand_l"), ("LeftArm", "LeftForeArm", "LeftHand"),
              ("LeftShoulder", "LeftElbow", "LeftWrist"), ("leftUpperArm", "leftLowerArm", "leftHand"),
              ("L_UpperArm", "L_LowerArm", "L_Hand"))
LEG_CHAINS = (("thigh_l", "shin_l", "foot_l"), ("thigh_l", "calf_l", "foot_l"), ("LeftUpLeg", "LeftLeg", "LeftFoot"),
              ("LeftHip", "LeftKnee", "LeftAnkle"), ("leftUpperLeg", "leftLowerLeg", "leftFoot"),
              ("L_UpperLeg", "L_LowerLeg", "L_Foot"))


def _bare(name: str) -> str:
    """A joint name without a namespace prefix (`mixamorig:LeftArm` -> `LeftArm`)."""
    return name.rsplit(":", 1)[-1]


def mirror_name(name: str) -> str:
    for a, b in (("_l", "_r"), ("Left", "Right"), ("_L", "_R"), ("left", "right"), ("L_", "R_")):
        if a in name:
            return name.replace(a, b)
    return name


def subtree(parents: np.ndarray, j: int) -> set:
    """j and every joint below it (parents listed before children)."""
    out = {j}
    for k in range(j + 1, len(parents)):
        if parents[k] in out:
            out.add(k)
    return out


def main_path(parents: np.ndarray, j: int) -> list:
    """j, then repeatedly the child with the largest subtree (first on ties)."""
    path = [j]
    while True:
        kids = np.flatnonzero(parents == path[-1])
        if kids.size == 0:
            return path
        path.append(int(max(kids, key=lambda k: (len(subtree(parents, int(k))), -k))))


def _rest_positions(character) -> np.ndarray:
    from stages.rig.transforms import forward_kinematics
    return forward_kinematics(character.parents, character.rest_local)[:, :3, 3]


def limb_chain(character, kind: str, side: str):
    """Joint indices (upper, lower, end) of the arm or leg on `side` ('l' = the wearer's left, +X),
    found by name (ARM_CHAINS / LEG_CHAINS, namespace prefixes ignored), else by the skeleton's
    shape (structural_chain); None when neither finds one."""
    bare = [_bare(n) for n in character.joint_names]
    for chain in (ARM_CHAINS if kind == "arm" else LEG_CHAINS):
        c = chain if side == "l" else tuple(mirror_name(n) for n in chain)
        if all(n in bare for n in c):
            return [bare.index(n) for n in c]
    return structural_chain(character, kind, side)


def structural_chain(character, kind: str, side: str):
    """A limb chain from the rest pose: legs are the root's children below it, arms the branches off
    the rest of the skeleton that reach furthest sideways (|x - root x| >= 15 % of the skeleton's
    height). A leg chain starts at its first joint with a bone longer than 15 % of the leg (skips
    zero-length hip joints); an arm chain at the joint of its path's longest bone (the upper arm,
    not a clavicle). Three joints needed."""
    parents = np.asarray(character.parents)
    w = _rest_positions(character)
    root = character.root_joint
    sign = 1.0 if side == "l" else -1.0
    down = _leg_roots(character, w)
    if kind == "leg":
        # a leg's side: where its subtree's lowest joint (the foot) is
        def foot_x(c):
            sub = sorted(subtree(parents, c))
            return sign * (w[sub[int(np.argmin(w[sub, 1]))], 0] - w[root, 0])
        starts = [c for c in down if foot_x(c) > 1e-3]
        best = max(starts, key=foot_x, default=None)
    else:
        legs = set().union(*[subtree(parents, c) for c in down]) if down else set()
        nkids = np.bincount(parents[parents >= 0], minlength=len(parents))
        height = float(np.ptp(w[:, 1])) or 1.0
        best, reach = None, 0.15 * height
        for j in range(len(parents)):
            if j == root or j in legs or parents[j] < 0 or nkids[parents[j]] < 2:
                continue
            r = max(sign * (w[k, 0] - w[root, 0]) for k in subtree(parents, j))
            if r >= reach:
                best, reach = j, r
    if best is None:
        return None
    path = main_path(parents, best)
    bone = np.linalg.norm(w[path[1:]] - w[path[:-1]], axis=1)
    if kind == "leg":
        long = np.flatnonzero(bone > 0.15 * bone.sum()) if bone.size else np.zeros(0, int)
        k = int(long[0]) if long.size else 0
        return path[k:k + 3] if len(path) >= k + 3 else None
    if len(path) < 3:
        return None
    k = int(np.argmax(bone[:len(path) - 2]))
    return path[k:k + 3]


def _leg_roots(character, w: np.ndarray) -> list:
    """Children of the root whose subtree reaches well below it (the legs)."""
    parents = np.asarray(character.parents)
    root = character.root_joint
    height = float(np.ptp(w[:, 1])) or 1.0
    out = []
    for c in np.flatnonzero(parents == root):
        sub = list(subtree(parents, int(c)))
        if w[sub, 1].min() < w[root, 1] - 0.2 * height:
            out.append(int(c))
    return out


@dataclass(frozen=True)
class HumanoidJoints:
    """Joint indices of a humanoid's parts (-1 / None: not found).

    root: the root joint. arm_l, arm_r, leg_l, leg_r: (upper, lower, end) joint indices or None.
    chest: the spine joint the arms branch from. neck: the spine joint right above it (its subtree
    is the neck and head). head: the neck's main child (or the neck itself on a one-joint neck).
    names: the rig's joint names (for messages).
    """

    root: int
    arm_l: tuple | None
    arm_r: tuple | None
    leg_l: tuple | None
    leg_r: tuple | None
    chest: int
    neck: int
    head: int
    names: tuple

    def limb(self, kind: str, side: str):
        return getattr(self, f"{kind}_{side}")

    def require(self, parts, what: str) -> None:
        """Raise one InputError naming `what` (e.g. "garment 'tshirt'") when a part is missing."""
        missing = [p for p in parts if (getattr(self, p) is None or getattr(self, p) == -1)]
        if not missing:
            return
        kinds = sorted({p.split("_")[0] for p in missing})
        looked = []
        for kind in kinds:
            if kind in ("arm", "leg"):
                chains = ARM_CHAINS if kind == "arm" else LEG_CHAINS
                looked.append(f"{kind}s named like " + ", ".join("/".join(c) for c in chains)
                              + " (right side mirrored) or found by the skeleton's shape")
            else:
                looked.append("the neck: the spine joint above where the arms branch off")
        raise InputError(what, f"cannot find the humanoid's {', '.join(missing)}; looked for {'; '.join(looked)}; "
                               f"the rig's joints: {', '.join(self.names)}")


def humanoid_joints(character) -> HumanoidJoints:
    """The character's limbs, chest, neck and head (see the module docstring)."""
    parents = np.asarray(character.parents)
    root = character.root_joint
    arms = {s: limb_chain(character, "arm", s) for s in ("l", "r")}
    legs = {s: limb_chain(character, "leg", s) for s in ("l", "r")}
    w = _rest_positions(character)
    leg_set = set().union(set(), *[subtree(parents, c) for c in _leg_roots(character, w)])
    for ch in legs.values():
        if ch is not None:
            leg_set |= subtree(parents, ch[0])
    # the spine: the root's main path upwards, not into a leg
    up = [int(c) for c in np.flatnonzero(parents == root) if int(c) not in leg_set]
    spine = [root]
    if up:
        spine += main_path(parents, max(up, key=lambda c: (len(subtree(parents, c)), -c)))
    chest, neck, head = -1, -1, -1
    arm_roots = [ch[0] for ch in arms.values() if ch is not None]
    if arm_roots:
        # the last spine joint that is an ancestor of every arm
        anc = [set(_ancestors(parents, a)) for a in arm_roots]
        common = [j for j in spine if all(j in s for s in anc)]
        if common:
            chest = common[-1]
            arm_side = set().union(*anc)
            # the neck: the chest's child off the arms, reaching highest
            kids = [int(c) for c in np.flatnonzero(parents == chest) if int(c) not in arm_side]
            if kids:
                neck = max(kids, key=lambda c: max(w[k, 1] for k in subtree(parents, c)))
                path = main_path(parents, neck)
                head = path[1] if len(path) > 1 else neck
    return HumanoidJoints(root, *(tuple(arms[s]) if arms[s] else None for s in ("l", "r")),
                          *(tuple(legs[s]) if legs[s] else None for s in ("l", "r")), chest, neck, head,
                          tuple(character.joint_names))


def _ancestors(parents: np.ndarray, j: int) -> list:
    out = []
    while j >= 0:
        out.append(int(j))
        j = int(parents[j])
    return out
