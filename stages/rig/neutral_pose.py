"""A neutral bind pose for a humanoid skeleton: upright, legs straight and slightly apart, arms in
an A-pose, built from the skeleton itself.

Why: a skin generated around a captured pose keeps whatever touches in that pose fused for the
whole clip. In the CMU walk the hands rest on the hips at frame 0, so a skin bound there carries
a web of long triangles from arm to hip (edges up to 0.86 m, 34x the median). Bound with the
limbs apart, the skin only stretches where the body bends. Where the thighs still touch (the
crotch) `soften_seam` spreads the weights' jump from one thigh to the other over a few edges.

Limbs are found by the skeleton's shape, not its names: the spine is the path from the root to
the highest joint; the limbs are the chains hanging off it; legs reach down to the floor (the two
longest), arms branch off the spine above them (the two longest of the rest), each pair about
equally long and on opposite sides. Name hints ('head',
'leg', 'arm', ...) are a fallback when the shape alone is ambiguous (e.g. a hand is the highest
joint). Along a leg the thigh and shin are the two consecutive bones of largest total length;
along an arm the upper arm starts at the first joint clearly off the body's midline (the
clavicle, if any, stays as it was) and the forearm follows.

The pose starts from the BVH rest pose (all rotations zero: the skeleton's own proportions, flat
feet, hands in line with the forearms), turned upright, and re-aims only the spine, thighs,
shins, feet, upper arms and forearms; it faces the way the clip does at its first frame.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

ARM_ANGLE_DEG = 40.0  # arms from the body's side (A-pose); the procedural character uses 45
LEG_SPLAY_DEG = 3.0  # legs out from the vertical: feet ~20 cm apart, knees clear of each other
SHOULDER_OFF_MIDLINE = 0.065  # upper arm starts this far (fraction of height) off the midline

_HEAD = re.compile(r"(?i)head")
_LEG = re.compile(r"(?i)leg|thigh|femur|knee|shin|tibia|foot|ankle|toe")
_ARM = re.compile(r"(?i)arm|humerus|elbow|wrist|hand|radius|clavicle|collar|shoulder")


@dataclass(frozen=True)
class Humanoid:
    """Joint indices of a humanoid skeleton's parts.

    spine: root .. highest joint (head top), in order.
    legs, arms: two joint chains each, from the limb's first joint (a child of a spine joint) along
        its longest path to a leaf; legs[0] and arms[0] are on the same side of the body.
    thighs, shins: the joints owning each leg's two long bones (legs[k] order).
    found_by: 'shape' or 'names'.
    """

    spine: tuple[int, ...]
    legs: tuple[tuple[int, ...], tuple[int, ...]]
    arms: tuple[tuple[int, ...], tuple[int, ...]]
    thighs: tuple[int, int]
    shins: tuple[int, int]
    found_by: str


def _children(parents) -> list[list[int]]:
    out = [[] for _ in parents]
    for j, p in enumerate(parents):
        if p >= 0:
            out[p].append(j)
    return out


def subtree(parents, first: int) -> list[int]:
    """`first` and all joints below it (parents[j] < j: one pass in index order)."""
    inside = np.zeros(len(parents), bool)
    inside[first] = True
    for j in range(first + 1, len(parents)):
        inside[j] = parents[j] >= 0 and inside[parents[j]]
    return np.flatnonzero(inside).tolist()


def _path_lengths(parents, offsets) -> np.ndarray:
    """Longest path (sum of bone lengths) from each joint down to a leaf of its subtree."""
    bone = np.linalg.norm(offsets, axis=1)
    reach = np.zeros(len(parents))
    for j in range(len(parents) - 1, 0, -1):  # children come after their parents
        reach[parents[j]] = max(reach[parents[j]], reach[j] + bone[j])
    return reach


def _chain(first: int, children, reach, bone) -> tuple[int, ...]:
    """From `first` along the child with the longest path below it, to a leaf."""
    out = [first]
    while children[out[-1]]:
        out.append(max(children[out[-1]], key=lambda c: reach[c] + bone[c]))
    return tuple(out)


def _long_pair(chain, bone) -> tuple[int, int] | None:
    """Owners of the two consecutive non-zero bones of largest total length along `chain`."""
    owners = [chain[k] for k in range(len(chain) - 1) if bone[chain[k + 1]] > 1e-9]
    lengths = [bone[chain[chain.index(o) + 1]] for o in owners]
    if len(owners) < 2:
        return None
    k = max(range(len(owners) - 1), key=lambda i: lengths[i] + lengths[i + 1])
    return owners[k], owners[k + 1]


def find_humanoid(parents, offsets, positions, names=None, *, by_names: bool = False) -> Humanoid | None:
    """The skeleton's spine, legs and arms, or None when it does not look humanoid.

    parents: (J,) ints; offsets: (J, 3) bone vectors (lengths); positions: (J, 3) world joint
    positions of some pose, Y up (the shape is read there). by_names: take the head and the
    leg / arm split from joint names instead of heights (the fallback).
    """
    parents = np.asarray(parents)
    pos = np.asarray(positions, dtype=np.float64)
    bone = np.linalg.norm(np.asarray(offsets, dtype=np.float64), axis=1)
    bone[0] = 0.0
    children = _children(parents)
    reach = _path_lengths(parents, offsets)
    if len(parents) < 8:
        return None
    if by_names:
        heads = [j for j in range(len(parents)) if names is not None and _HEAD.search(str(names[j]))]
        if not heads:
            return None
        top = _chain(heads[0], children, reach, bone)[-1]
    else:
        top = int(np.argmax(pos[:, 1]))
    spine = [top]
    while parents[spine[-1]] >= 0:
        spine.append(int(parents[spine[-1]]))
    spine = spine[::-1]
    ylo, top_y = pos[:, 1].min(), pos[top, 1]
    extent = pos[:, 1].max() - ylo
    if extent <= 1e-6:
        return None
    limbs = []  # (index along the spine, chain, words say leg, words say arm)
    for i, s in enumerate(spine):
        for c in children[s]:
            if c in spine or reach[c] + bone[c] < 0.1 * extent:
                continue
            chain = _chain(c, children, reach, bone)
            text = " ".join(str(names[j]) for j in chain) if by_names else ""
            limbs.append((i, chain, bool(_LEG.search(text)), bool(_ARM.search(text))))
    # legs reach down to the floor (the lowest joints); arms branch off the spine above the legs
    if by_names:
        legs = [(i, ch) for i, ch, leg, _ in limbs if leg]
    else:
        legs = [(i, ch) for i, ch, _, _ in limbs if pos[list(ch), 1].min() < ylo + 0.15 * extent]
    legs = sorted(legs, key=lambda x: -reach[x[1][0]])[:2]
    if len(legs) < 2:
        return None
    hip = max(i for i, _ in legs)
    pelvis = spine[hip]
    rise = top_y - pos[pelvis, 1]
    arms = [ch for i, ch, leg, arm in limbs if i > hip and all(ch != c for _, c in legs)
            and ((arm and not leg) if by_names else pos[spine[i], 1] >= pos[pelvis, 1] + 0.25 * rise)]
    arms = sorted(arms, key=lambda ch: -reach[ch[0]])[:2]
    legs = [ch for _, ch in legs]
    if len(arms) < 2 or rise <= 1e-6:
        return None
    for a, b in (legs, arms):  # a pair of limbs: about as long as each other
        if min(reach[a[0]], reach[b[0]]) < 0.7 * max(reach[a[0]], reach[b[0]]):
            return None
    pairs = [_long_pair(ch, bone) for ch in legs]
    if any(p is None for p in pairs) or any(_long_pair(ch, bone) is None for ch in arms):
        return None
    # sides: the thighs' start joints define left-right; each arm goes with the leg on its side
    lateral = pos[pairs[0][0]] - pos[pairs[1][0]]
    lateral[1] = 0.0
    if np.linalg.norm(lateral) < 1e-6:
        return None
    side = [float(np.dot(pos[list(ch)].mean(axis=0) - pos[pelvis], lateral)) for ch in arms]
    if side[0] * side[1] >= 0:
        return None
    if side[0] < 0:
        arms = arms[::-1]
    return Humanoid(spine=tuple(int(j) for j in spine), legs=(legs[0], legs[1]), arms=(arms[0], arms[1]),
                    thighs=(pairs[0][0], pairs[1][0]), shins=(pairs[0][1], pairs[1][1]),
                    found_by="names" if by_names else "shape")


def _align(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation (3, 3) taking direction a to direction b."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis), float(np.dot(a, b))
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        perp = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        return Rotation.from_rotvec(np.pi * perp / np.linalg.norm(perp)).as_matrix()
    return Rotation.from_rotvec(axis / s * np.arctan2(s, c)).as_matrix()


def _frame(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Orthonormal columns (x', y, x' cross y) from y and a roughly perpendicular x."""
    y = y / np.linalg.norm(y)
    x = x - np.dot(x, y) * y
    x = x / np.linalg.norm(x)
    return np.stack([x, y, np.cross(x, y)], axis=1)


def _positions(parents, offsets, world_rot=None) -> np.ndarray:
    """World joint positions from local offsets and world rotations (identity when None)."""
    pos = np.zeros_like(offsets)
    for j, p in enumerate(parents):
        pos[j] = offsets[j] if p < 0 else pos[p] + (offsets[j] if world_rot is None else world_rot[p] @ offsets[j])
    return pos


def _shoulder(chain, bone, pos, pelvis, lateral, height) -> int:
    """Owner of the upper-arm bone: the first joint owning a bone, with one more bone after it,
    that is clearly off the midline (a clavicle starts on it); else the two-longest-bones rule."""
    owners = [chain[k] for k in range(len(chain) - 1) if bone[chain[k + 1]] > 1e-9]
    for o in owners[:-1]:
        if abs(np.dot(pos[o] - pos[pelvis], lateral)) >= SHOULDER_OFF_MIDLINE * height:
            return o
    return _long_pair(chain, bone)[0]


def _bone_targets(body: Humanoid, parents, bone, rest_up, lat, arm_angle_deg, leg_splay_deg) -> dict:
    """{bone owner: (child at the bone's end, wanted world direction)} in the upright rest frame:
    spine up; thighs and shins down, splayed out; feet as in the rest pose (flat, forward); upper
    arms and forearms in one line, arm_angle_deg out from the body. Other bones keep their local
    rotation (pelvis, clavicles, hands)."""
    out = {}
    for a, b in zip(body.spine[1:-1], body.spine[2:]):
        out[a] = (b, np.array([0.0, 1.0, 0.0]))
    pelvis = parents[body.legs[0][0]]
    height = rest_up[:, 1].max() - rest_up[:, 1].min()
    for k in range(2):
        s = 1.0 if k == 0 else -1.0
        splay, angle = np.radians(leg_splay_deg), np.radians(arm_angle_deg)
        leg = np.array([0.0, -np.cos(splay), 0.0]) + s * np.sin(splay) * lat
        arm = np.array([0.0, -np.cos(angle), 0.0]) + s * np.sin(angle) * lat
        chain, after = body.legs[k], False
        for a, b in zip(chain[:-1], chain[1:]):
            if a in (body.thighs[k], body.shins[k]):
                out[a], after = (b, leg), a == body.shins[k]
            elif after and bone[b] > 1e-9:
                out[a] = (b, rest_up[b] - rest_up[a])
        chain = body.arms[k]
        upper = _shoulder(chain, bone, rest_up, pelvis, lat, height)
        owners = [chain[i] for i in range(len(chain) - 1) if bone[chain[i + 1]] > 1e-9]
        fore = owners[owners.index(upper) + 1]
        for a, b in zip(chain[:-1], chain[1:]):
            if a in (upper, fore):
                out[a] = (b, arm)
    return out


def neutral_pose(parents, offsets, names=None, heading_positions=None, *,
                 arm_angle_deg: float = ARM_ANGLE_DEG, leg_splay_deg: float = LEG_SPLAY_DEG):
    """Local joint rotations (J, 4) xyzw of the neutral pose, the body parts found, and a note.

    parents: (J,) ints, parents[j] < j; offsets: (J, 3) each joint's translation in its parent's
    frame (the bind translations). heading_positions: optional (J, 3) world joint positions of the
    clip's first frame: the pose is turned about Y to face the same way. names: for the fallback.
    Returns (rotations, body, note): rotations and body (a `Humanoid`) are None when the skeleton
    is not recognised as a humanoid, and note then says why (the caller binds elsewhere).
    """
    parents = np.asarray(parents)
    offsets = np.asarray(offsets, dtype=np.float64)
    rest = _positions(parents, offsets)
    body = find_humanoid(parents, offsets, rest, names)
    if body is None and heading_positions is not None:
        body = find_humanoid(parents, offsets, heading_positions, names)
    if body is None and names is not None:
        body = find_humanoid(parents, offsets, rest, names, by_names=True)
    if body is None:
        return None, None, ("no humanoid shape found (a spine from the root to the head, two legs "
                            "reaching the floor and two arms branching off the spine above them)")
    # upright: pelvis -> arm branch along +Y, the thighs' left-right axis horizontal
    up_rest = rest[parents[body.arms[0][0]]] - rest[parents[body.legs[0][0]]]
    lat_rest = rest[body.thighs[0]] - rest[body.thighs[1]]
    lat = np.array([lat_rest[0], 0.0, lat_rest[2]])
    if np.linalg.norm(up_rest) < 1e-9 or np.linalg.norm(np.cross(up_rest, lat_rest)) < 1e-9 or np.linalg.norm(lat) < 1e-9:
        return None, None, "the spine or the hips have no extent in the rest pose"
    lat /= np.linalg.norm(lat)
    upright = _frame(lat, np.array([0.0, 1.0, 0.0])) @ _frame(lat_rest, up_rest).T
    bone = np.linalg.norm(offsets, axis=1)
    targets = _bone_targets(body, parents, bone, rest @ upright.T, lat, arm_angle_deg, leg_splay_deg)

    world = np.empty((len(parents), 3, 3))
    for j, p in enumerate(parents):
        world[j] = upright if p < 0 else world[p]
        if j in targets and bone[targets[j][0]] > 1e-9:
            child, direction = targets[j]
            world[j] = _align(world[j] @ offsets[child], direction) @ world[j]
    if heading_positions is not None:  # turn about +Y so the thighs' axis is frame 0's
        now = _positions(parents, offsets, world)
        want = np.asarray(heading_positions, dtype=np.float64)
        a = now[body.thighs[0]] - now[body.thighs[1]]
        b = want[body.thighs[0]] - want[body.thighs[1]]
        if np.hypot(b[0], b[2]) > 1e-9:
            yaw = np.arctan2(a[2], a[0]) - np.arctan2(b[2], b[0])
            world = Rotation.from_rotvec([0.0, yaw, 0.0]).as_matrix() @ world
    local = world.copy()
    local[1:] = np.transpose(world[parents[1:]], (0, 2, 1)) @ world[1:]
    return Rotation.from_matrix(local).as_quat(), body, f"limbs found by {body.found_by}"


def soften_seam(triangles, skin_joints, skin_weights, group_a, group_b, *, rings: int = 3,
                iterations: int = 12):
    """Skin weights (joints, weights) with the seam between two joint groups smoothed over the mesh.

    Why: where the thighs touch (the crotch) the generated weights jump from one thigh to the other
    within a centimetre, so one edge takes the whole separation when the legs split (kneeling in
    the CMU walk: 6.8x the median edge). Averaging the weights of the vertices within `rings`
    edges of the seam with their neighbours spreads that over several edges. group_a, group_b:
    joint indices (e.g. each leg's subtree); a vertex belongs to the group of its heaviest joint.
    Returns (joints (V, K) int32, weights (V, K)), K as given, rows summing to 1.
    """
    from scipy.sparse import coo_matrix

    sj = np.asarray(skin_joints)
    sw = np.asarray(skin_weights, dtype=np.float64)
    nv, k = sj.shape
    nj = max(int(sj.max()) + 1, max(list(group_a) + list(group_b)) + 1)
    tri = np.asarray(triangles)
    e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    adj = coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(nv, nv)).tocsr()
    adj.data[:] = 1.0
    dominant = sj[np.arange(nv), np.argmax(sw, axis=1)]
    group = np.where(np.isin(dominant, list(group_a)), 0, np.where(np.isin(dominant, list(group_b)), 1, -1))
    cross = (group[e[:, 0]] >= 0) & (group[e[:, 1]] >= 0) & (group[e[:, 0]] != group[e[:, 1]])
    region = np.zeros(nv, bool)
    region[e[cross].ravel()] = True
    if not region.any():
        return sj.copy(), sw.copy()
    for _ in range(rings):
        region |= (adj @ region.astype(np.float64)) > 0
    w = np.zeros((nv, nj))
    np.add.at(w, (np.repeat(np.arange(nv), k), sj.ravel()), sw.ravel())
    degree = np.asarray(adj.sum(axis=1)).ravel()
    for _ in range(iterations):
        w[region] = ((w + adj @ w) / (1.0 + degree)[:, None])[region]
    order = np.argsort(-w, axis=1, kind="stable")[:, :k]
    top = np.take_along_axis(w, order, axis=1)
    top /= top.sum(axis=1, keepdims=True)
    order = np.where(top > 0, order, order[:, :1])
    return order.astype(np.int32), top
