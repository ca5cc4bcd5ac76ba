"""Body measurements a built-in pattern is sized from: `garment_measurements` (girths and heights of
the body, sizes from the skeleton) and `clearance_measurements` (what a garment must clear: the
body and its colliders at the bind pose, and the loop a hugged waistband makes).
"""
from __future__ import annotations

import numpy as np


def garment_measurements(character, colliders=None, motion=None, *, clearance: float = 0.008,
                         under: np.ndarray | None = None) -> dict:
    """body_measurements plus, from the skeleton at rest (metres, world): shoulder_y (upper-arm
    joint height), shoulder_half (|x| of the upper-arm joint from the root), neck_y (neck-base
    joint height or 0.82 height), arm_girth (upper-arm circumference estimate), floor_y.

    With `colliders` (and the motion whose frame 0 is the bind pose; default: the rest pose) it
    adds the clearance the cloth actually needs around the colliders AND the body (see
    clearance_measurements); the patterns then size themselves to clear them. under: (K, 3) points
    of the garments worn under this one (relative frame at frame 0), cleared as the body is.
    """
    from stages.rig.humanoid import humanoid_joints, limb
    from stages.rig.procedural import body_measurements
    from stages.rig.transforms import forward_kinematics
    m = dict(body_measurements(character))
    rest = forward_kinematics(character.parents, character.rest_local)
    w = rest[:, :3, 3]
    h = m["height"]
    y0 = float(character.vertices[:, 1].min())
    root = w[character.root_joint]
    parts = humanoid_joints(character)
    # each limb's upper / lower / end points (stages.rig.humanoid.Limb), a chain's joints or a short
    # limb's measured on its skin (a chibi's one-joint arm: shoulder, halfway, hand)
    arm = limb(character, "arm", "l", parts)
    if arm is not None:
        top, low = arm.rest[0], arm.rest[1]
        m["shoulder_y"] = float(top[1])
        m["shoulder_half"] = float(abs(top[0] - root[0]))
        dom = character.skin_joints[np.arange(len(character.vertices)), np.argmax(character.skin_weights, axis=1)]
        v = character.vertices[dom == arm.follow[0]]
        if len(v) >= 4:
            d = low - top
            d /= np.linalg.norm(d)
            rel = v - top
            r = np.linalg.norm(rel - np.outer(rel @ d, d), axis=1)
            m["arm_girth"] = float(2 * np.pi * np.percentile(r, 90))
    for side in ("l", "r"):
        leg = limb(character, "leg", side, parts)
        if leg is not None:
            hip, knee, ankle = leg.points(character, rest if motion is None else motion.joint_world[0])
            d = hip - knee
            m[f"hip_joint_y_{side}"] = float(hip[1])
            m[f"thigh_up_y_{side}"] = float(d[1] / np.linalg.norm(d))
            m[f"thigh_len_{side}"] = float(np.linalg.norm(d))
            m[f"shin_len_{side}"] = float(np.linalg.norm(ankle - knee))
    m.setdefault("shoulder_y", y0 + 0.81 * h)
    m.setdefault("shoulder_half", 0.105 * h)
    m.setdefault("arm_girth", 0.21 * h)
    neck = parts.neck
    m["neck_y"] = float(w[neck, 1]) if neck >= 0 else y0 + 0.82 * h
    m["floor_y"] = y0
    m.update(clearance_measurements(character, colliders, motion, clearance=clearance, under=under))
    from stages.garments.quadruped import back_measurements
    m.update(back_measurements(character, motion, parts))   # a quadruped's trunk, where a blanket is laid
    return m


def _slab_girth(points_xz: np.ndarray) -> float:
    from scipy.spatial import ConvexHull, QhullError
    if points_xz.shape[0] < 3:
        return 0.0
    try:
        return float(ConvexHull(points_xz).area)    # 2D: 'area' is the perimeter
    except QhullError:
        return 0.0


def clearance_measurements(character, colliders=None, motion=None, *, clearance: float = 0.015,
                           under: np.ndarray | None = None) -> dict:
    """What a garment must clear (metres, world at frame 0 of `motion`, default the rest pose), from
    the skinned body plus the collider surfaces when given, each plus `clearance`:

    clear_chest / clear_waist / clear_hips: perimeter of the torso's slab (6 cm thick; hips: with
        the thighs) at those heights, + 2 pi clearance. clear_skirt: the largest such perimeter of
        hips + legs from the hips down to 10 cm below the crotch.
    neck_half: half-width of the neck (its body part and collider) below neck_y + 6 cm.
    shoulder_top: highest point of the shoulders (torso and upper arms, without neck and head)
        between the neck and the upper-arm joint.
    torso_depth: largest |z - root z| of the upper torso between chest_y and shoulder_top.
    arm_radius: 90th percentile of the upper arm's skin distance from its axis over the middle 70 %
        of the bone, plus the colliders' delta. arm_angle: the upper arm's angle below horizontal, rad.
    thigh_radius: the same for the thigh. crotch_y: lowest point where a leg (or its collider)
        reaches the body's mid-plane. band_top (with colliders): length of the loop a band at
        skirt_top makes once hugged onto the colliders and the body (hug.hug).
    under: (K, 3) points of garments worn under it (relative frame at frame 0): in the slab girths
        (clear_chest / clear_waist / clear_hips) as part of the body, each with the body part of its
        nearest skin vertex: a T-shirt worn over shorts is cut to go round them (pushed out over
        them at dressing, a hem cut to the body alone was stretched: BVH walk, T-shirt over shorts,
        p99 53 % at the last frame, 56 edges through the shorts; cut to clear them, 32 %, 10). Not in
        the other measures: a waistband is hugged over what is tucked under it (make_garment), and
        shorts cut round a T-shirt's tail were too wide to sew on the BVH walk.
    """
    from stages.rig.humanoid import humanoid_joints, limb, limb_joint_sets, subtree
    from stages.garments.placement import (_cross_sections, bind_geometry, body_axis, collider_points,
                                           frame_poses0, part_joints, triangle_grid_points)
    from stages.rig.skinning import rest_motion
    if motion is None:
        motion = rest_motion(character, 1, 1.0 / 30.0)
    skinned, origins, dominant = bind_geometry(character, motion)
    pts = [skinned]
    owner = [dominant]
    for j, p in collider_points(colliders, frame_poses0(colliders, character, motion)):
        pts.append(p)
        owner.append(np.full(len(p), j))
    pts, owner = np.concatenate(pts), np.concatenate(owner)
    root = origins[character.root_joint]
    parents = np.asarray(character.parents)
    torso = np.isin(owner, list(part_joints(character, "torso", origins)))
    hips = np.isin(owner, list(part_joints(character, "hips", origins)))
    parts = humanoid_joints(character)
    limbs = limb_joint_sets(character, parts)
    leg_joints = limbs["leg_l"] | limbs["leg_r"]
    arm_joints = limbs["arm_l"] | limbs["arm_r"]
    # each limb as a Limb: a chain or a shorter one (a chibi's single joint); each arm's upper joint
    limbs_of = {(k, s): limb(character, k, s, parts) for k in ("arm", "leg") for s in ("l", "r")}
    arm_upper = [limbs_of["arm", s].follow[0] for s in ("l", "r") if limbs_of["arm", s] is not None]
    neck_j = parts.neck
    headneck = subtree(parents, neck_j) if neck_j >= 0 else set()
    neckpts = np.isin(owner, list(headneck))
    legs = np.isin(owner, list(leg_joints))
    out = {}
    b = body_measurements_cached(character)
    c2 = 2 * np.pi * clearance
    rel = pts - root

    slab_pts, slab_owner = pts, owner
    if under is not None and len(under):
        from scipy.spatial import cKDTree
        under = np.asarray(under, np.float64).reshape(-1, 3)
        slab_pts = np.concatenate([pts, under])
        slab_owner = np.concatenate([owner, dominant[cKDTree(skinned).query(under)[1]]])

    def slab(joints, y, half=0.03):
        m = np.isin(slab_owner, list(joints)) & (np.abs(slab_pts[:, 1] - y) <= half)
        return _slab_girth(slab_pts[m][:, [0, 2]] - root[[0, 2]])

    torso_j = set(part_joints(character, "torso", origins)) - set(headneck)
    out["clear_chest"] = slab(torso_j, b["chest_y"]) + c2
    out["clear_waist"] = slab(torso_j, b["waist_y"]) + c2
    out["clear_hips"] = slab(set(part_joints(character, "hips", origins)) | leg_joints, b["hips_y"]) + c2
    m = owner == neck_j if neck_j >= 0 else np.zeros(len(pts), bool)
    out["neck_half"] = (float(np.abs(rel[m, 0]).max()) if m.any() else 0.035 * b["height"]) + clearance
    # the neck as a box in the sagittal plane: a neckline must stay below or in front of / behind it
    out["neck_low"] = (float(pts[m, 1].min()) if m.any() else b["chest_y"] + 0.1 * b["height"]) - clearance
    out["neck_front"] = (float(rel[m, 2].max()) if m.any() else 0.03 * b["height"]) + clearance
    out["neck_back"] = (float(rel[m, 2].min()) if m.any() else -0.03 * b["height"]) - clearance
    upper = (torso | np.isin(owner, arm_upper)) & ~neckpts & ~legs
    if arm_upper:
        sh = float(np.mean([abs(origins[a, 0] - root[0]) for a in arm_upper]))
    else:
        sh = 0.105 * b["height"]
    # beside the neck (and its colliders) out to the shoulder joint, or 5 cm beyond the neck where
    # the shoulder joint sits inside the neck's width (CesiumMan)
    m = upper & (np.abs(rel[:, 0]) >= out["neck_half"] - clearance) & (np.abs(rel[:, 0]) <= max(sh + 0.02, out["neck_half"] + 0.05))
    out["shoulder_top"] = (float(pts[m, 1].max()) if m.any() else b["chest_y"] + 0.12 * b["height"]) + clearance
    m = torso & ~neckpts & (pts[:, 1] >= b["chest_y"]) & (pts[:, 1] <= out["shoulder_top"])
    out["torso_depth"] = (float(np.abs(rel[m, 2]).max()) if m.any() else 0.07 * b["height"]) + clearance
    for key, kind in (("arm", "arm"), ("thigh", "leg")):
        found = limbs_of[kind, "l"]
        if found is None:
            continue
        ch = found.follow
        o, e = found.points(character, motion.joint_world[0])[:2]
        d = e - o
        L = float(np.linalg.norm(d))
        d /= L
        if kind == "arm":
            # the skin of the upper arm's middle (its root blends into the shoulder and armpit, and a
            # swept shoulder collider can reach far from the arm over a big range of motion), plus
            # the collider inflation
            r = skinned[dominant == ch[0]] - o
            t = r @ d
            keep = (t >= 0.15 * L) & (t <= 0.85 * L)
            rad = np.linalg.norm(r[keep] - np.outer(t[keep], d), axis=1)
            rad = np.percentile(rad, 90) + (colliders.delta if colliders is not None else 0.0) if rad.size else None
        else:
            mm = owner == ch[0]
            r = pts[mm] - o
            t = r @ d
            keep = (t >= -0.05) & (t <= 0.7 * L)
            rad = np.linalg.norm(r[keep] - np.outer(t[keep], d), axis=1)
            rad = float(rad.max()) if rad.size else None
        out[f"{key}_radius"] = (0.03 * b["height"] if rad is None else float(rad)) + clearance
        if kind == "arm":
            out["arm_angle"] = float(np.arcsin(np.clip(-d[1], -1.0, 1.0)))
            # on the skin's surface (a box arm of a low-poly toon has few vertices near its root)
            tri = np.asarray(character.triangles)
            owner_t = dominant[tri[:, 0]]
            torso_skin = set(part_joints(character, "torso", origins)) - headneck - leg_joints
            out.update(_arm_root(triangle_grid_points(skinned, tri[owner_t == ch[0]]),
                                 triangle_grid_points(skinned, tri[np.isin(owner_t, list(torso_skin))]), root,
                                 clearance))
    # crotch: going down the mid-plane from the hips, the first height where the line across the
    # body (front to back, 15 cm each way) is outside the body and every collider
    ys = b["hips_y"] - np.arange(0.0, 0.3 * b["height"], 0.005)
    zs = np.arange(-0.15, 0.151, 0.01)
    line = np.stack(np.broadcast_arrays(root[0], ys[:, None], root[2] + zs[None, :]), axis=-1).reshape(-1, 3)
    from stages.garments.placement import inside_body
    from stages.garments.types import bind_pose
    blocked = inside_body(character, skinned, line, colliders, bind_pose(character, motion, colliders)
                          if colliders is not None else None).reshape(ys.size, zs.size).any(axis=1)
    free = np.flatnonzero(~blocked)
    out["crotch_y"] = (float(ys[free[0]]) if free.size else b["hips_y"] - 0.05 * b["height"]) - clearance
    arms = np.isin(owner, list(arm_joints))
    trunk = (torso | hips | legs) & ~neckpts & ~arms
    # skirt_top: the waist, or lower where the upper arms' colliders (CesiumMan's shoulder spheres)
    # come down beside the torso: a waistband there would be pushed about by them
    reach = out["clear_waist"] / (2 * np.pi) + clearance
    upper_arms = np.isin(owner, arm_upper) & (np.hypot(rel[:, 0], rel[:, 2]) <= reach)
    top = b["waist_y"]
    if upper_arms.any():
        top = min(top, float(pts[upper_arms, 1].min()) - clearance)
    out["skirt_top"] = max(top, b["hips_y"] - 0.02)
    # what a skirt must go around from its top to 10 cm below the crotch (thighs, hips, the
    # flexible spheres between the pelvis and the spine), and trousers' seat down to the crotch:
    # the girths of the cross-sections the 'hips' placement wraps panels on (offset = clearance),
    # so that a panel this wide is placed without stretch
    ys = np.arange(max(out["crotch_y"] - 0.10, b["hips_y"] - 0.2 * b["height"]), out["skirt_top"] + 0.005, 0.01)
    ab = _cross_sections(pts[trunk], body_axis(character, "hips", motion.joint_world[0]), ys, clearance, True)
    girth = np.array([_ellipse_perimeter(a, b_) for a, b_ in ab])
    out["clear_top"] = float(girth[-1])
    out["clear_skirt"] = float(girth.max())
    out["clear_seat"] = float(girth[ys >= out["crotch_y"]].max(initial=girth[-1]))
    # band_top: the length of the loop a waistband makes hugged (hug.hug, as make_garment
    # does) onto the body and colliders at skirt_top: what a snug waistband is cut to
    if colliders is not None:
        from stages.garments.hug import hug
        ang = np.linspace(0.0, 2 * np.pi, 73)[:-1]
        axis = np.array([root[0], out["skirt_top"], root[2]])
        # from the ellipse the 'hips' placement wraps the band on at skirt_top
        ring = axis + np.stack([ab[-1, 0] * np.sin(ang), np.zeros_like(ang), ab[-1, 1] * np.cos(ang)], axis=1)
        ring = hug(ring, np.broadcast_to(axis, ring.shape), character, skinned,
                   bind_pose(character, motion, colliders))
        out["band_top"] = float(np.linalg.norm(ring - np.roll(ring, 1, axis=0), axis=1).sum())
    # leg tubes: the thigh below the crotch (its hull and the knee sphere) and the shin
    for key, k in (("thigh_low_radius", 0), ("shin_radius", 1)):
        found = limbs_of["leg", "l"]
        if found is None:
            continue
        ch = found.follow
        o, e = found.points(character, motion.joint_world[0])[k:k + 2]
        d = (e - o) / np.linalg.norm(e - o)
        mm = np.isin(owner, [ch[k], ch[k + 1]] if k == 0 else [ch[k]])
        r = pts[mm] - o
        t = r @ d
        keep = (pts[mm, 1] <= out["crotch_y"]) & (t <= np.linalg.norm(e - o) + (0.0 if k == 0 else -0.03))
        rad = np.linalg.norm(r[keep] - np.outer(t[keep], d), axis=1)
        out[key] = (float(rad.max()) if rad.size else 0.05 * b["height"]) + clearance
    return out


ARM_ROOT_SLICE = 0.05   # m beyond the torso's side where the left arm's root is measured


def _arm_root(arm: np.ndarray, torso: np.ndarray, root: np.ndarray, clearance: float) -> dict:
    """The left arm's root beside the torso (points at rest, world; on the skin's surface): torso_side,
    the torso's half-width (|x| from the root) at the arm's height; torso_band, the girth of the torso
    there (the perimeter of its hull, from above); arm_root_lo / arm_root_hi, the lowest / highest point of
    the arm's skin within ARM_ROOT_SLICE beyond that side; arm_root_front / arm_root_back, its largest
    and smallest z from the root; each plus `clearance`. Empty where the arm has no skin there."""
    if not len(arm) or not len(torso):
        return {}
    band = torso[(torso[:, 1] >= arm[:, 1].min()) & (torso[:, 1] <= arm[:, 1].max())]
    side = float((band[:, 0] - root[0]).max()) if len(band) else float((torso[:, 0] - root[0]).max())
    x = arm[:, 0] - root[0]
    near = arm[(x >= side) & (x <= side + ARM_ROOT_SLICE)]
    if not len(near):
        return {}
    z = near[:, 2] - root[2]
    return {"torso_band": _slab_girth(band[:, [0, 2]] - root[[0, 2]]) + 2 * np.pi * clearance if len(band) else 0.0,
            "torso_side": side + clearance, "arm_root_lo": float(near[:, 1].min()) - clearance,
            "arm_root_hi": float(near[:, 1].max()) + clearance, "arm_root_front": float(z.max()) + clearance,
            "arm_root_back": float(z.min()) - clearance}


def _ellipse_perimeter(a: float, b: float) -> float:
    return 4.0 * quarter_length(a, b)


def body_measurements_cached(character) -> dict:
    from stages.rig.procedural import body_measurements
    return body_measurements(character)


def quarter_length(a: float, b: float) -> float:
    """Length of a quarter ellipse with semi-axes a, b (Ramanujan)."""
    return float(np.pi * (3 * (a + b) - np.sqrt((3 * a + b) * (a + 3 * b))) / 4)
