"""Which joints of a rig are the humanoid's limbs, neck and head: by the joints' names read as tokens
(stages.rig.joint_names: any usual naming, Mixamo, Unreal, VRM, Rigify, Blender, MotionBuilder /
CMU, 3ds Max Biped, game engines, DAZ, Kenney), each name match checked against the skeleton's
shape, else by the shape alone (CesiumMan's `leg_joint_L_1`, any rig a user brings).

The wearer's left is +X in the rest pose (the character faces +Z, Y up), as every loader gives it.
Shape rules: a leg ends on the floor, below where it starts, its branch off the body on one side;
an arm is a branch off the spine on one side reaching far sideways and not down to the floor.

Garments anchor on these: sleeves on the upper arms, legs of trousers on the thighs, a collar
below the neck. A limb of fewer than 3 joints (Kenney's single `arm-left`) is recorded
(`HumanoidJoints.short`, with rest positions of its shoulder / elbow / wrist points taken from its
skin, `HumanoidJoints.points`) but is not a chain (`limb_chain` is None). The garments read every
limb, chain or short, through `limb` (a `Limb`: its three points, the joint each point moves with,
its joint set): trouser legs and sleeves are placed on a limb's points, a one-joint limb's three
carried by its only joint. A garment whose anchors cannot be found gets one error saying why, what
was looked for and the joints the rig has (`HumanoidJoints.require`).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from stages.errors import InputError
from stages.rig.joint_names import label, limb_ranks

# (upper, lower, end) of the left limb in a few usual namings, for messages and for an exact
# match (pipeline.inspect); the right one is the mirrored name. Detection reads any naming as tokens.
ARM_CHAINS = (("upperarm_l", "forearm_l", "hand_l"), ("LeftArm", "LeftForeArm", "LeftHand"),
              ("LeftShoulder", "LeftElbow", "LeftWrist"), ("leftUpperArm", "leftLowerArm", "leftHand"),
              ("L_UpperArm", "L_LowerArm", "L_Hand"))
LEG_CHAINS = (("thigh_l", "shin_l", "foot_l"), ("thigh_l", "calf_l", "foot_l"), ("LeftUpLeg", "LeftLeg", "LeftFoot"),
              ("LeftHip", "LeftKnee", "LeftAnkle"), ("leftUpperLeg", "leftLowerLeg", "leftFoot"),
              ("L_UpperLeg", "L_LowerLeg", "L_Foot"))
LIMB_PARTS = {"arm": ("clavicle", "shoulder", "upperarm", "lowerarm", "hand"),
              "leg": ("hip", "thigh", "leg", "shin", "foot")}


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
    size = _subtree_sizes(parents)
    path = [j]
    while True:
        kids = np.flatnonzero(parents == path[-1])
        if kids.size == 0:
            return path
        path.append(int(max(kids, key=lambda k: (size[k], -k))))


def _subtree_sizes(parents: np.ndarray) -> np.ndarray:
    size = np.ones(len(parents), int)
    for k in range(len(parents) - 1, 0, -1):
        size[parents[k]] += size[k]
    return size


def _ancestors(parents: np.ndarray, j: int) -> list:
    """j, its parent, ... up to the top joint."""
    out = []
    while j >= 0:
        out.append(int(j))
        j = int(parents[j])
    return out


def _rest_positions(character) -> np.ndarray:
    from stages.rig.transforms import forward_kinematics
    return forward_kinematics(character.parents, character.rest_local)[:, :3, 3]


class Body(NamedTuple):
    """The rest pose as detection reads it. w: (J, 3) joint positions; lo / hi: (J, 3) the lowest
    and highest coordinates of each joint and its dominant skin (every mesh of the character);
    sub_lo / sub_hi: the same over each joint's subtree; sub_skin: (J,) how many vertices the
    subtree's joints carry (dominant); y0 / height: the floor and the height of joints and skin
    together; x0: the root's x (the body's mid-plane)."""

    parents: np.ndarray
    root: int
    w: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    sub_lo: np.ndarray
    sub_hi: np.ndarray
    sub_skin: np.ndarray
    depth: np.ndarray
    dominant: np.ndarray
    y0: float
    height: float
    x0: float


def rest_body(character) -> Body:
    parents = np.asarray(character.parents)
    w = _rest_positions(character)
    v = np.asarray(character.vertices, np.float64)
    dom = character.skin_joints[np.arange(len(v)), np.argmax(character.skin_weights, axis=1)] if len(v) \
        else np.zeros(0, int)
    lo, hi = w.copy(), w.copy()
    np.minimum.at(lo, dom, v)
    np.maximum.at(hi, dom, v)
    sub_lo, sub_hi = lo.copy(), hi.copy()
    sub_skin = np.bincount(dom, minlength=len(parents))
    for k in range(len(parents) - 1, 0, -1):    # children after parents: fold each subtree upwards
        p = parents[k]
        sub_lo[p] = np.minimum(sub_lo[p], sub_lo[k])
        sub_hi[p] = np.maximum(sub_hi[p], sub_hi[k])
        sub_skin[p] += sub_skin[k]
    depth = np.zeros(len(parents), int)
    for k in range(1, len(parents)):
        depth[k] = depth[parents[k]] + 1
    y0, y1 = float(lo[:, 1].min()), float(hi[:, 1].max())
    root = int(character.root_joint)
    return Body(parents, root, w, lo, hi, sub_lo, sub_hi, sub_skin, depth, dom, y0, (y1 - y0) or 1.0,
                float(w[root, 0]))


def _crosses(b: Body, j: int, sign: float) -> bool:
    """Whether j's subtree (joints and skin) reaches clearly onto the other side of the mid-plane:
    then j is on the body's axis (spine, pelvis), not in a limb of side `sign`."""
    other = b.sub_lo[j, 0] if sign > 0 else b.sub_hi[j, 0]
    return sign * (other - b.x0) < -0.05 * b.height


def limb_points(b: Body, joints, skin_vertices: np.ndarray | None = None):
    """(3, 3) rest positions of a limb's upper, lower and end points: its joints for a chain of
    three; for a shorter limb, the end is where its skin reaches farthest along the limb (from the
    first joint towards the skin's centre) and the lower point halfway (or its second joint). None
    for a one-joint limb without skin."""
    joints = list(joints)
    if len(joints) >= 3:
        return b.w[joints[:3]].copy()
    u = b.w[joints[0]]
    pts = b.w[joints[1:]]
    if skin_vertices is not None and len(skin_vertices):
        pts = np.concatenate([pts, skin_vertices])
    if len(pts) == 0:
        return None
    d = pts.mean(axis=0) - u
    if np.linalg.norm(d) < 1e-9:
        return None
    d /= np.linalg.norm(d)
    e = u + d * float(((pts - u) @ d).max())
    mid = b.w[joints[1]] if len(joints) == 2 else (u + e) / 2
    return np.stack([u, mid, e])


def _shape_check(b: Body, kind: str, side: str, pts) -> str:
    """'' when the points (upper, lower, end) are shaped like the limb, else why not."""
    if pts is None:
        return "it has no skin to measure"
    sign = 1.0 if side == "l" else -1.0
    u, e = pts[0], pts[2]
    if sign * ((u[0] + e[0]) / 2 - b.x0) <= 0.01 * b.height:
        return f"it is not on the wearer's {'left (+X)' if side == 'l' else 'right (-X)'}"
    if kind == "arm" and pts[:, 1].min() <= b.y0 + 0.25 * b.height:
        return "it hangs down to the floor (a leg, not an arm)"
    if kind == "leg" and (e[1] >= b.y0 + 0.2 * b.height or e[1] >= u[1] - 0.15 * b.height):
        return "it does not go down to the floor"
    return ""


def _skin(character, b: Body, joints) -> np.ndarray:
    return np.asarray(character.vertices)[np.isin(b.dominant, list(joints))]


def name_chain(b: Body, labels: list, kind: str, side: str):
    """The limb's joints by name (labels: `joint_names.label` of every joint): (upper, lower, end),
    or a shorter list for a limb named as one but of fewer than 3 joints (Kenney's `arm-left`),
    or None. The end is the topmost hand / foot joint (a skinned one first); upper, lower and end
    the topmost joints of their rank (joint_names.limb_ranks) on the path to it; an upper joint at
    its parent's place (CMU's `LHipJoint` on the hips) is passed over for the next one."""
    parents = b.parents
    named = [j for j, (s, p) in enumerate(labels) if s == side and p in LIMB_PARTS[kind]]
    if not named:
        return None
    end_part = "hand" if kind == "arm" else "foot"
    # deform joints first: a rig that also lists its control / mechanism copies (Rigify's ORG- and
    # MCH- beside DEF-) has the skin on one of them, and the garments split the skin by joint
    skinned = np.bincount(b.dominant, minlength=len(parents)) > 0
    ends = sorted((j for j in named if labels[j][1] == end_part), key=lambda j: (not skinned[j], b.depth[j], j))
    tips = ends or [max(named, key=lambda j: (b.depth[j], -j))]
    for tip in tips:
        path = _ancestors(parents, tip)[::-1]
        ranks = limb_ranks([labels[j][1] if labels[j][0] == side else "" for j in path], kind)
        ups = [i for i, r in enumerate(ranks) if r == 1]
        if not ups:
            continue
        moved = [i for i in ups if parents[path[i]] < 0
                 or np.linalg.norm(b.w[path[i]] - b.w[parents[path[i]]]) > 0.01 * b.height]
        iu = (moved or ups)[0]
        il = next((i for i in range(iu + 1, len(path)) if ranks[i] == 2), None)
        ie = next((i for i in range(iu + 1, len(path)) if ranks[i] == 3), None)
        if il is not None and ie is not None and il < ie:
            return [path[iu], path[il], path[ie]]
        limb = main_path(parents, path[iu])
        if len(limb) < 3:
            return limb
    return None


def _branch_start(b: Body, j: int, sign: float) -> int:
    """The topmost ancestor of j (j included) below the root whose subtree stays on j's side: where
    the limb leaves the body."""
    anc = _ancestors(b.parents, j)
    top = set(_ancestors(b.parents, b.root))
    start = j
    for a in anc[1:]:
        if a in top or _crosses(b, a, sign):
            break
        start = a
    return start


def shape_leg(b: Body, side: str):
    """A leg from the rest pose alone: from a foot (a joint on that side whose skin or itself
    reaches the floor) up to where its branch leaves the body (the shallowest such branch: a
    quadruped's hind legs, not its front legs), then down its main path. A leg chain starts at its
    first bone longer than 15 % of the leg (skips zero-length hip joints). Fewer than 3 joints: the
    short limb."""
    sign = 1.0 if side == "l" else -1.0
    top = set(_ancestors(b.parents, b.root))
    feet = [j for j in range(len(b.parents)) if j not in top and b.lo[j, 1] < b.y0 + 0.1 * b.height
            and sign * (b.w[j, 0] - b.x0) > 0.01 * b.height and not _crosses(b, j, sign)]
    best = None
    for f in feet:
        start = _branch_start(b, f, sign)
        if b.sub_skin[start] == 0:      # a helper without skin (Unreal's ik_foot_l at the ankle)
            continue
        key = (b.depth[start], b.lo[f, 1], -sign * b.w[f, 0], f)
        if best is None or key < best[0]:
            best = (key, start, f)
    if best is None:
        return None
    _, start, f = best
    down = _ancestors(b.parents, f)[::-1]
    path = down[down.index(start):] + main_path(b.parents, f)[1:]
    bone = np.linalg.norm(b.w[path[1:]] - b.w[path[:-1]], axis=1)
    long = np.flatnonzero(bone > 0.15 * bone.sum()) if bone.size else np.zeros(0, int)
    k = int(long[0]) if long.size else 0
    return path[k:k + 3]


def shape_arm(b: Body, side: str, legs: set):
    """An arm from the rest pose alone: the branch off the body's axis (its parent's subtree spans
    both sides, its own stays on this side; not in a leg) reaching farthest sideways, at least 10 %
    of the height (beyond the torso: arms hanging straight down reach about 14 %); the chain starts
    at the longest bone of its main path that leaves room for two more joints (the upper arm, not a
    clavicle)."""
    sign = 1.0 if side == "l" else -1.0
    parents = b.parents
    top = set(_ancestors(parents, b.root))
    reach = (b.sub_hi[:, 0] if sign > 0 else -b.sub_lo[:, 0]) - sign * b.x0
    best, most = None, 0.1 * b.height
    for j in range(len(parents)):
        p = parents[j]
        if j in top or j in legs or p < 0 or _crosses(b, j, sign) or not (_crosses(b, p, sign) or p in top):
            continue
        if b.sub_skin[j] == 0:          # a helper without skin (Unreal's ik_hand_l at the hand)
            continue
        if reach[j] > most:
            best, most = j, reach[j]
    if best is None:
        return None
    path = main_path(parents, best)
    if len(path) < 3:
        return path
    bone = np.linalg.norm(b.w[path[1:]] - b.w[path[:-1]], axis=1)
    k = int(np.argmax(bone[:len(path) - 2]))
    return path[k:k + 3]


def find_limbs(character, b: Body | None = None) -> dict:
    """part ('arm_l', ...) -> (joints or None, how: 'name' | 'shape' | 'missing', points (3, 3) or
    None, why: '' or why the part is missing). Legs first: the arms are looked for off the legs."""
    b = b or rest_body(character)
    labels = [label(n) for n in character.joint_names]
    out, legs = {}, set()
    for kind in ("leg", "arm"):
        for side in ("l", "r"):
            tried = []
            for how in ("name", "shape"):
                if how == "name":
                    joints = name_chain(b, labels, kind, side)
                else:
                    joints = shape_leg(b, side) if kind == "leg" else shape_arm(b, side, legs)
                if not joints:
                    continue
                pts = limb_points(b, joints, _skin(character, b, joints) if len(joints) < 3 else None)
                bad = _shape_check(b, kind, side, pts)
                if not bad:
                    break
                what = " > ".join(character.joint_names[j] for j in joints)
                tried.append(f"{'joints named as the' if how == 'name' else 'the branch'} {what}: {bad}")
                joints = None
            if joints:
                out[f"{kind}_{side}"] = (list(joints), how, pts, "")
                if kind == "leg":
                    legs |= subtree(b.parents, _branch_start(b, joints[0], 1.0 if side == "l" else -1.0))
            else:
                why = "; ".join(tried) or "no joint named as one, no branch shaped like one"
                out[f"{kind}_{side}"] = (None, "missing", None, why)
    return out


def limb_chain(character, kind: str, side: str):
    """Joint indices [upper, lower, end] of the arm or leg on `side` ('l' = the wearer's left, +X),
    found by name (any naming, checked against the shape) or by the skeleton's shape; None when
    neither finds one or the limb has fewer than 3 joints (`limb` gives any limb as the garments use it)."""
    joints = find_limbs(character)[f"{kind}_{side}"][0]
    return joints if joints is not None and len(joints) == 3 else None


def structural_chain(character, kind: str, side: str):
    """A limb chain [upper, lower, end] from the rest pose alone (names ignored), checked like a
    name match; None when none is found or it has fewer than 3 joints."""
    b = rest_body(character)
    legs = set()
    if kind == "arm":
        for s in ("l", "r"):
            ch = shape_leg(b, s)
            if ch and not _shape_check(b, "leg", s, limb_points(b, ch, _skin(character, b, ch))):
                legs |= subtree(b.parents, _branch_start(b, ch[0], 1.0 if s == "l" else -1.0))
    ch = shape_leg(b, side) if kind == "leg" else shape_arm(b, side, legs)
    if not ch or len(ch) < 3 or _shape_check(b, kind, side, limb_points(b, ch)):
        return None
    return ch


@dataclass(frozen=True)
class HumanoidJoints:
    """Joint indices of a humanoid's parts (-1 / None: not found).

    root: the root joint. arm_l, arm_r, leg_l, leg_r: (upper, lower, end) joint indices or None.
    chest: the spine joint the arms branch from (the neck's parent where no arms are found). neck:
    the spine joint right above it (its subtree is the neck and head), or the topmost joint named
    as a neck where no arms are found. head: the neck's main child (or the neck itself on a
    one-joint neck). names: the rig's joint names (for messages).
    found: part -> 'name' | 'shape' | 'missing' (limbs and the neck). short: limb part -> its
    joints, for a limb of fewer than 3 joints (its chain is None). points: limb part -> (3, 3)
    rest positions (upper, lower, end; a short limb's from its skin). why: part -> one line saying
    why it is missing. A garment anchored on a limb takes a chain or a short limb alike (`require`;
    placed through `limb`).
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
    # details, not compared (points hold arrays) nor hashed: two results are equal by their joints
    found: dict = field(default_factory=dict, compare=False)
    short: dict = field(default_factory=dict, compare=False)
    points: dict = field(default_factory=dict, compare=False)
    why: dict = field(default_factory=dict, compare=False)

    def limb(self, kind: str, side: str):
        return getattr(self, f"{kind}_{side}")

    @property
    def hips(self) -> int:
        """The root where both legs are found (chains or legs of fewer joints: a skirt hangs from
        the hips over the legs, whatever their joints), else -1."""
        legs = all(self.limb("leg", s) or self.short.get(f"leg_{s}") for s in ("l", "r"))
        return self.root if legs else -1

    def _why(self, part: str) -> str:
        if part != "hips":
            return self.why.get(part, "")
        return "; ".join(f"leg_{s}: {self.why[f'leg_{s}']}" for s in ("l", "r")
                         if not (self.limb("leg", s) or self.short.get(f"leg_{s}")) and self.why.get(f"leg_{s}"))

    def require(self, parts, what: str) -> None:
        """Raise one InputError naming `what` (e.g. "garment 'tshirt'") when a part is missing (a limb
        of any number of joints is there)."""
        missing = [p for p in parts if (getattr(self, p) is None or getattr(self, p) == -1) and p not in self.short]
        if not missing:
            return
        # what was looked for
        kinds = sorted({"leg" if p == "hips" else p.split("_")[0] for p in missing})
        looked = []
        for kind in kinds:
            if kind in ("arm", "leg"):
                chains = ARM_CHAINS if kind == "arm" else LEG_CHAINS
                looked.append(f"{kind}s named in any usual way (" + ", ".join("/".join(c) for c in chains[1:3])
                              + ", ...; sides L/R/Left/Right) and shaped like one, or found by the shape")
            else:
                looked.append("the neck above where the arms branch off, or a joint named neck")
        # one reason per distinct text: "arm_l, arm_r: ..." (the line stays short enough to print whole)
        whys: dict = {}
        for p in missing:
            if self._why(p):
                whys.setdefault(self._why(p), []).append(p)
        why = "; ".join(f"{', '.join(ps)}: {w}" for w, ps in whys.items())
        raise InputError(what, f"cannot find the humanoid's {', '.join(missing)}" + (f" ({why})" if why else "")
                               + f"; the rig's joints: {', '.join(self.names)}"
                               + (f"; looked for {'; '.join(looked)}" if looked else "")
                               + "; a character without them can wear mesh garments (type: mesh)")


def humanoid_joints(character) -> HumanoidJoints:
    """The character's limbs, chest, neck and head (see the module docstring)."""
    b = rest_body(character)
    parents, root, w = b.parents, b.root, b.w
    limbs = find_limbs(character, b)
    leg_set, limb_set = set(), set()
    for part, (joints, *_rest) in limbs.items():
        if joints:
            sub = subtree(parents, _branch_start(b, joints[0], 1.0 if part.endswith("_l") else -1.0))
            limb_set |= sub
            if part.startswith("leg"):
                leg_set |= sub
    # the spine: the root's main path upwards, not into a leg
    size = _subtree_sizes(parents)
    up = [int(c) for c in np.flatnonzero(parents == root) if int(c) not in leg_set]
    spine = [root]
    if up:
        spine += main_path(parents, max(up, key=lambda c: (size[c], -c)))
    chest, neck, head = -1, -1, -1
    arm_roots = [limbs[p][0][0] for p in ("arm_l", "arm_r") if limbs[p][0]]
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
    neck_how = "shape" if neck >= 0 else "missing"
    if neck < 0:
        # no arms to find it by (a quadruped's front legs are not arms): the topmost joint named as a
        # neck, outside the limbs, going up
        named = [j for j, n in enumerate(character.joint_names) if label(n)[1] == "neck" and j not in limb_set
                 and j != root and b.sub_hi[j, 1] >= w[j, 1]]
        if named:
            neck, neck_how = min(named, key=lambda j: (b.depth[j], j)), "name"
            chest = chest if chest >= 0 else int(parents[neck])
    if neck >= 0:
        path = main_path(parents, neck)
        head = path[1] if len(path) > 1 else neck
    chains = {p: (tuple(j) if j is not None and len(j) == 3 else None) for p, (j, *_r) in limbs.items()}
    found = {p: v[1] for p, v in limbs.items()} | {"neck": neck_how}
    short = {p: tuple(v[0]) for p, v in limbs.items() if v[0] is not None and len(v[0]) < 3}
    points = {p: v[2] for p, v in limbs.items() if v[2] is not None}
    why = {p: v[3] for p, v in limbs.items() if v[3]}
    if neck < 0:
        why["neck"] = ("no arms branch off the spine and no joint is named neck" if not arm_roots
                       else "no joint above where the arms branch off")
    return HumanoidJoints(root, chains["arm_l"], chains["arm_r"], chains["leg_l"], chains["leg_r"], chest, neck, head,
                          tuple(character.joint_names), found, short, points, why)


def limb_joint_sets(character, parts: HumanoidJoints | None = None) -> dict:
    """part ('arm_l', 'arm_r', 'leg_l', 'leg_r') -> the set of joints whose skin is that limb: the
    subtree of its upper joint, for a chain and for a limb of fewer joints alike (a chibi's one-joint
    arm is still an arm: its skin is not the torso's). Empty where none is found. parts: the
    character's humanoid_joints when the caller has them (not found again)."""
    parts = parts or humanoid_joints(character)
    out = {}
    for part in ("arm_l", "arm_r", "leg_l", "leg_r"):
        found = limb(character, part[:3], part[-1], parts)
        out[part] = set(found.joint_set) if found else set()
    return out


@dataclass(frozen=True)
class Limb:
    """An arm or leg as the garments use it, a chain of three joints or a shorter limb alike.

    joints: its joints (a chain's upper, lower, end; a short limb's one or two). follow: the joint
    each of its points (upper, lower, end) moves with: a chain's own joints; a one-joint limb's only
    joint for all three (no elbow to bend: a sleeve follows its only bone); a two-joint limb's first
    for the upper point, its second for the lower and end points. rest: (3, 3) the points' rest
    positions (HumanoidJoints.points: a short limb's measured on its skin). joint_set: the joints
    whose skin is the limb (limb_joint_sets)."""

    joints: tuple
    follow: tuple
    rest: np.ndarray = field(compare=False)
    joint_set: frozenset

    @property
    def is_chain(self) -> bool:
        return len(self.joints) >= 3

    def points(self, character, joint_world: np.ndarray) -> np.ndarray:
        """(3, 3) the points in a pose (joint_world (J, 4, 4)): a chain's joint origins; a short
        limb's each carried from its rest place by the joint it follows, as its skin is (inverse bind)."""
        jw = np.asarray(joint_world)
        if self.is_chain:
            return jw[list(self.joints[:3]), :3, 3]
        out = np.empty((3, 3))
        for k, j in enumerate(self.follow):
            m = jw[j] @ np.asarray(character.inverse_bind[j], np.float64)
            out[k] = m[:3, :3] @ self.rest[k] + m[:3, 3]
        return out


def limb(character, kind: str, side: str, parts: HumanoidJoints | None = None) -> Limb | None:
    """The arm or leg on `side` ('l': the wearer's left) as a Limb, a chain or a limb of one or two
    joints alike; None where none is found. parts: the character's humanoid_joints when the caller
    has them (not found again)."""
    parts = parts or humanoid_joints(character)
    part = f"{kind}_{side}"
    joints = parts.limb(kind, side) or parts.short.get(part)
    if not joints or part not in parts.points:
        return None
    joints = tuple(int(j) for j in joints)
    follow = joints[:3] if len(joints) >= 3 else (joints[0], joints[-1], joints[-1])
    return Limb(joints, follow, np.asarray(parts.points[part], np.float64),
                frozenset(subtree(np.asarray(character.parents), joints[0])))
