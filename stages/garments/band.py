"""The colliders of other bones that meet a garment's attached band (a waistband, a collar) during the
motion: those that swing through it, which it yields to, and the limbs that rest on it, which pass
through the garment.

A band follows its bones. Where the animation puts another bone's collider through it at some frames
(a hand swinging past the hip), the band's particles yield to that collider there (`swept_attachments`,
Garment.attach_joint). Where a limb the garment does not wrap lies on the band for most of the motion
(a chibi's arms hang over the waistband of its skirt: the arm's box is as wide as the hip is deep),
yielding drags the band along under the limb at every step: edges of the band 970 % long and the run
stopped as diverged in 13 of the 32 clips of a Kenney chibi with a skirt. Such a limb passes through the
garment instead (`resting_limbs`, Garment.passing_joints): the cloth hangs under it as if it were not
there, which the body audit counts as cloth inside the body. A limb the garment wraps (an upper arm in
a sleeve, a thigh in a skirt or a trouser leg) always collides, and so does a part of the trunk (a
bone whose colliders the band's vertical centre line runs through: CesiumMan's upper torso behind a
GarmentCode skirt's high waistband).
"""
from __future__ import annotations

import re

import numpy as np

REST_SHARE = 0.5          # a limb rests on a band when it holds it in this share of the frames or more
PINCH_GAP = 0.01          # m: two limbs' colliders this near leave no room for cloth between them (a sleeve
                          # stands 1 cm off its arm)
HOLD_REACH = 0.03         # m: cloth this near a limb's colliders is round that limb (a sleeve, a trouser leg)
WRAP_GAP = np.radians(150.0)   # a garment round a limb leaves no empty wedge wider than this round its
                               # axis (one below or beside the limb leaves 180 degrees or more)


def signed_distance(collider, p: np.ndarray) -> np.ndarray:
    """(...) signed distance (m) of bone-local points (..., 3) to a hull collider (largest plane
    distance: exact inside, a lower bound outside, near corners slightly more than the true
    distance) or a sphere collider."""
    if hasattr(collider, "simplified"):
        pl = collider.simplified.planes
        return (p @ pl[:, :3].T - pl[:, 3]).max(axis=-1)
    return np.linalg.norm(p - collider.center, axis=-1) - collider.radius


def collider_list(cs) -> list:
    """(bone, name, collider, pose index) of every hull, then every sphere (a skinned ball: the
    joint it is named by as the bone, the flexible region's joint of the first vertex it holds, which
    can differ from the joint that moves it most; its own frame as the pose index)."""
    return [(h.bone, h.name, h, h.bone) for h in cs.hulls] + [(s.joint, s.name, s, s.pose_index) for s in cs.spheres]


def band_contacts(bind, local: np.ndarray, joints: np.ndarray, depth: float, ignore=()):
    """Per collider of another bone that holds an attached particle deeper than `depth` (m) at some
    frame of bind.poses (stages.garments.types.BindPose): (bone, name, (M,) bool the particles it
    holds at some frame, (F,) bool the frames it holds any). local: (M, 3) bone-local positions,
    joints: (M,) the bones they follow. A particle's own bone's colliders move rigidly with it and are
    not tested, nor those of the joints in `ignore`."""
    out = []
    if bind.poses is None or bind.colliders is None or len(joints) == 0:
        return out
    m = bind.poses[:, joints]
    x = np.einsum("fmij,mj->fmi", m[..., :3, :3], local) + m[..., :3, 3]   # (F, M, 3) relative frame
    inv = np.linalg.inv(bind.frames_of_colliders())
    for bone, name, collider, frame in collider_list(bind.colliders):
        other = np.flatnonzero(joints != bone)
        if other.size == 0 or bone in ignore:
            continue
        w = inv[:, frame]
        p = np.einsum("fij,fmj->fmi", w[:, :3, :3], x[:, other]) + w[:, None, :3, 3]
        deep = signed_distance(collider, p) < -depth             # (F, M')
        if deep.any():
            held = np.zeros(len(joints), bool)
            held[other[deep.any(axis=0)]] = True
            out.append((int(bone), name, held, deep.any(axis=1)))
    return out


def _joint_name(name: str) -> str:
    # a bone's hull and sphere share its name; its skinned balls (<joint>_ball<k>) are named by their joint
    return re.sub(r"_ball\d+$", "", name)


def held_by(contacts: list, n: int, skip=()):
    """((n,) bool the attached particles some collider of `contacts` (band_contacts) holds, names of
    those colliders' joints), leaving out the colliders of the bones in `skip`."""
    hit = np.zeros(n, bool)
    names = []
    for bone, name, held, _ in contacts:
        if bone not in skip:
            hit |= held
            names.append(name)
    return hit, list(dict.fromkeys(_joint_name(n) for n in names))


def swept_attachments(bind, local: np.ndarray, joints: np.ndarray, depth: float, ignore=()):
    """Attached particles that a collider of another bone holds deeper than `depth` (m) at some
    frame of bind.poses: ((M,) bool, names of those colliders' joints); see band_contacts."""
    return held_by(band_contacts(bind, local, joints, depth, ignore), len(joints))


def collider_points(bind, bone: int) -> np.ndarray:
    """(P, 3) points of bone's colliders (hull vertices, sphere poles) at frame 0, relative frame."""
    pts = [p[0] for _, _, p in _posed_vertices(bind, bone)]
    return np.concatenate(pts) if pts else np.zeros((0, 3))


def wraps(points: np.ndarray, limb: np.ndarray, origin: np.ndarray, toward) -> bool:
    """Whether a garment's points (N, 3) surround a limb: the points level with the limb (its points
    `limb` (P, 3), projected on its axis: from the joint at `origin` towards `toward` (3,), or the
    limb's main direction when None) leave no empty wedge wider than WRAP_GAP round that axis. Four
    points round a sleeve wrap the arm; a skirt below an arm held out does not."""
    if limb.shape[0] < 2:
        return True
    axis = None if toward is None else np.asarray(toward, np.float64) - origin
    if axis is None or np.linalg.norm(axis) < 0.25 * np.ptp(limb, axis=0).max():
        _, _, vt = np.linalg.svd(limb - limb.mean(axis=0), full_matrices=False)
        axis = vt[0]
    axis = axis / np.linalg.norm(axis)
    u = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    t_limb = (limb - origin) @ axis
    rel = np.asarray(points, np.float64) - origin
    t = rel @ axis
    level = rel[(t >= t_limb.min()) & (t <= t_limb.max())]
    if level.shape[0] == 0:
        return False
    angle = np.sort(np.arctan2(level @ v, level @ u))
    return bool(np.diff(np.concatenate([angle, angle[:1] + 2 * np.pi])).max() < WRAP_GAP)


def beside(limb: np.ndarray, centre: np.ndarray) -> bool:
    """Whether a bone's collider points (P, 3) lie beside the vertical line through centre (3,) (+y
    up): their centroid farther from it, horizontally, than any of them from the centroid. A limb
    hangs beside the body's line; the trunk's bones are round it."""
    if limb.shape[0] == 0:
        return False
    xz = limb[:, [0, 2]]
    mid = xz.mean(axis=0)
    return bool(np.linalg.norm(mid - np.asarray(centre)[[0, 2]]) > np.linalg.norm(xz - mid, axis=1).max())


def resting_limbs(bind, points: np.ndarray, local: np.ndarray, joints: np.ndarray, depth: float,
                  ignore=(), contacts: list | None = None) -> list[int]:
    """Joints (sorted) whose colliders rest on the garment's attached band: they hold one of its
    attached particles (local (M, 3) bone-local, joints (M,)) deeper than `depth` in REST_SHARE of
    bind.poses' frames or more, lie beside the band's vertical centre line at frame 0 (`beside`: a
    limb, not the trunk), and the garment (points (N, 3), frame 0) does not wrap them. Their
    colliders then pass through the garment (Garment.passing_joints). contacts: band_contacts of these
    arguments when already computed."""
    if contacts is None:
        contacts = band_contacts(bind, local, joints, depth, ignore)
    share: dict[int, np.ndarray] = {}
    for bone, _, _, frames in contacts:
        share[bone] = share.get(bone, np.zeros(frames.size, bool)) | frames
    parents = bind.parents
    band = np.einsum("mij,mj->mi", bind.joint_world[joints][:, :3, :3], local) + bind.joint_world[joints][:, :3, 3]
    centre = band.mean(axis=0) if band.shape[0] else np.zeros(3)
    out = []
    for bone, frames in share.items():
        if frames.mean() < REST_SHARE:
            continue
        limb = collider_points(bind, bone)
        children = np.flatnonzero(parents == bone) if parents is not None else []
        toward = bind.joint_origins[children].mean(axis=0) if len(children) else None
        if beside(limb, centre) and not wraps(points, limb, bind.joint_origins[bone], toward):
            out.append(bone)
    return sorted(out)


def _posed_vertices(bind, bone: int) -> list:
    """[(collider, pose index, (F, P, 3) its points (hull vertices, sphere poles) at every frame of
    bind.poses, relative frame)] of bone's colliders."""
    frames = bind.frames_of_colliders()
    out = []
    for b, _, c, frame in collider_list(bind.colliders):
        if b != bone:
            continue
        if hasattr(c, "simplified"):
            v = np.asarray(c.simplified.vertices, np.float64)
        else:
            v = np.asarray(c.center, np.float64) + float(c.radius) * np.vstack([np.eye(3), -np.eye(3)])
        m = frames[:, frame]
        out.append((c, frame, np.einsum("fij,pj->fpi", m[:, :3, :3], v) + m[:, None, :3, 3]))
    return out


def _nearest_approach(bind, a: list, b: list) -> tuple[float, int]:
    """(gap m, frame) where the colliders `a` and `b` (_posed_vertices) come nearest: the least
    signed distance of one's points to the other's collider over the frames (vertex tests: a lower
    bound on how deep they overlap, exact where a corner meets a face)."""
    inv = np.linalg.inv(bind.frames_of_colliders())
    best, at = np.inf, 0
    for first, second in ((a, b), (b, a)):
        for _, _, pts in first:
            for c, frame, _ in second:
                w = inv[:, frame]
                local = np.einsum("fij,fpj->fpi", w[:, :3, :3], pts) + w[:, None, :3, 3]
                d = signed_distance(c, local).min(axis=1)            # (F,)
                f = int(np.argmin(d))
                if d[f] < best:
                    best, at = float(d[f]), f
    return best, at


def _related(parents, a: int, b: int) -> bool:
    """Whether one joint is an ancestor of the other (one limb's chain: a hand and its upper arm)."""
    def chain(j):
        out = set()
        while j >= 0:
            out.add(int(j))
            j = int(parents[j])
        return out
    return a in chain(b) or b in chain(a)


def _short_limb(bind, joint: int) -> bool:
    """Whether a limb joint belongs to a limb of one or two joints (a chibi's block arm or leg), not to a
    chain with an elbow or knee (its top's subtree of limb joints: fewer than three)."""
    parents, limbs = bind.parents, bind.limb_joints
    top = joint
    while parents[top] >= 0 and int(parents[top]) in limbs:
        top = int(parents[top])
    sub, stack = 0, [top]
    while stack:
        j = stack.pop()
        sub += 1
        stack += [int(k) for k in np.flatnonzero(parents == j) if int(k) in limbs]
    return sub < 3


def pinching_limbs(bind, points: np.ndarray, gap: float = PINCH_GAP) -> list[tuple[int, int, int]]:
    """[(limb, wrapped limb, frame)] (sorted by limb): the limbs of one or two joints (bind.limb_joints,
    `_short_limb`: a chain's slim colliders, bending at the elbow, leave the cloth room) the garment
    (points (N, 3), frame 0) does not wrap (`wraps`, with its points within HOLD_REACH of the limb's
    colliders) but lies within `gap` of at frame 0, whose colliders come
    within `gap` of the collider of a limb it wraps (not on the same chain) at some frame of
    bind.poses; the frame where they come nearest. The cloth between the two has no room there: a
    chibi's block arm, in its sleeve, is 1.1 cm above its leg's top in the bind pose, and each arm
    swing presses the T-shirt's armpit between them (edges torn past 500 %, the run stopped, in 13 of
    the 32 clips of a Kenney mini). Such a limb passes through the garment (Garment.passing_joints)."""
    if bind.colliders is None or bind.poses is None or bind.parents is None or not bind.limb_joints:
        return []
    points = np.asarray(points, np.float64)
    parents = bind.parents
    posed, wrapped, near = {}, [], []
    for bone in sorted(j for j in bind.limb_joints if _short_limb(bind, j)):
        cols = _posed_vertices(bind, bone)
        if not cols:
            continue
        posed[bone] = cols
        limb = np.concatenate([p[0] for _, _, p in cols])
        d = np.min([signed_distance(c, bind.collider_to_local(frame, points)) for c, frame, _ in cols], axis=0)
        # the cloth near the limb round it: a T-shirt's hem, round the torso, encircles a chibi's leg
        # tops' axes but lies only in front of, beside and behind them
        if wraps(points[d < HOLD_REACH], limb, bind.joint_origins[bone], limb.mean(axis=0)):
            wrapped.append(bone)
        elif d.min() < gap:
            near.append(bone)
    out = []
    for bone in near:
        for w in wrapped:
            if _related(parents, bone, w):
                continue
            d, f = _nearest_approach(bind, posed[bone], posed[w])
            if d < gap:
                out.append((bone, w, f))
                break
    return out


def with_pinching_limbs(garment: str, bind, points: np.ndarray, passing: list, ignore=()) -> list:
    """`passing` (sorted joints) and the limbs `pinching_limbs` finds for the garment (points: frame 0)
    beyond it and `ignore`, with a warning naming them."""
    import warnings
    found = [(j, w, f) for j, w, f in pinching_limbs(bind, points) if j not in passing and j not in ignore]
    if not found:
        return passing
    names = bind.joint_names
    limbs = ", ".join(f"{names[j]} (at frame {f})" for j, _, f in found)
    worn = ", ".join(dict.fromkeys(names[w] for _, w, _ in found))
    warnings.warn(f"garment {garment!r}: the colliders of {limbs} come within {PINCH_GAP * 100:.0f} cm of those of "
                  f"{worn}, which it is worn round, and pass through the garment (no room for cloth between two "
                  f"limbs; the body audit counts the cloth inside them as inside the body)", stacklevel=3)
    return sorted(set(passing) | {j for j, _, _ in found})
