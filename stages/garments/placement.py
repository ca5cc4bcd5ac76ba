"""Placement: wrap flat panels onto generalised cylinders / cones around body parts in the bind pose.

Each body part has an axis in the bind pose (frame 0 of the motion, relative frame): origin O,
direction A (the panel's v direction), reference radial direction Q (angle 0) and P = A x Q
(angle 90). At axis coordinate t the cross-section is an ellipse centred on the axis with
semi-axes (a, b) along (P, Q): the smallest axis-aligned ellipse (of the slab's aspect ratio)
containing the part's skinned vertices within a few cm of t, plus the panel's offset; torso
cross-sections also cover the arms' roots, 'hips' cross-sections never shrink downwards (a skirt
hangs over the legs). A panel point (u, v) goes to t = v + shift and to the ellipse point whose
arc length from the panel's angle is u / (W(v) / 2) times half the arc the panel spans (W: the
outline's width at v, frozen above wrap_until); the ellipse is enlarged when the panel is wider
than that arc, so panels are never compressed. Outward normals: (u, v) counter-clockwise maps to
normals pointing away from the axis.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from stages.errors import InputError
from stages.garments.patterns import Pattern, Placement
from stages.garments.triangulate import FlatPattern
from stages.rig.humanoid import Limb, limb, limb_joint_sets, subtree

SLAB = 0.03        # m, half height of the body slab measured for one cross-section level
LEVEL_STEP = 0.01  # m, spacing of cross-section levels along the axis
MIDLINE_GAP = 0.015  # m, a leg tube's inner side off the body's mid-plane
LIMB_REACH = 0.04  # m, how far beyond a limb's skin its own colliders can stand (delta, slack, hull offset)


@dataclass(frozen=True)
class BodyAxis:
    """A body part's axis in the bind pose: origin O (3,), unit A, Q, P (3,), metres / relative frame."""

    origin: np.ndarray
    a: np.ndarray
    q: np.ndarray
    p: np.ndarray


def part_joints(character, part: str, joint_origins: np.ndarray) -> set:
    """Joints whose dominant vertices make up a body part."""
    parents = np.asarray(character.parents)
    root = character.root_joint
    legs = set()
    for c in np.flatnonzero(parents == root):
        if joint_origins[c, 1] < joint_origins[root, 1] - 1e-3:
            legs |= subtree(parents, int(c))
    # the limbs found by name or shape, also of one joint (a chibi's arm is not torso; its legs start
    # at the root's height, not below it)
    limbs = limb_joint_sets(character)
    legs |= limbs["leg_l"] | limbs["leg_r"]
    arms = limbs["arm_l"] | limbs["arm_r"]
    if part == "hips":
        return (legs | {root}) - arms
    if part == "torso":
        return set(range(len(parents))) - legs - arms
    return {part_limb(character, part).follow[0]}


def part_limb(character, part: str) -> Limb:
    """The Limb ('arm_l', 'leg_r', ...) a sleeve or trouser leg is placed on (humanoid.limb)."""
    kind, side = part.split("_")
    found = limb(character, kind, side)
    if found is None:
        raise InputError(f"placement {part!r}", f"no {kind} found in {character.name!r}: expected joints named "
                         "like upperarm_l/forearm_l/hand_l, LeftArm/LeftForeArm/LeftHand (or thigh/shin/foot), or "
                         "a branch shaped like one")
    return found


def body_axis(character, part: str, joint_world: np.ndarray) -> BodyAxis:
    """`part`'s axis in the pose joint_world (J, 4, 4): the trunk's, vertical through the root; a
    limb's, pointing from its lower to its upper point (Limb.points)."""
    y, z = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])
    joint_world = np.asarray(joint_world)
    if part in ("torso", "hips"):
        o = joint_world[character.root_joint, :3, 3].copy()
        o[1] = 0.0
        return BodyAxis(o, y, z, np.cross(y, z))
    kind = part.split("_")[0]
    found = part_limb(character, part)
    pts = found.points(character, joint_world)
    o = pts[0]
    d = pts[1] - o
    if not np.linalg.norm(d) > 1e-9:     # a rig with two joints at one place (a robot's stacked pivots)
        names = character.joint_names
        u, lo = found.follow[0], found.follow[1]
        raise InputError(f"placement {part!r}", f"joints {names[u]!r} and {names[lo]!r} are at the same place "
                         f"({np.linalg.norm(d):.3g} m apart): the {kind}'s axis needs a bone of some length")
    a = -d / np.linalg.norm(d)
    ref = y if kind == "arm" else z
    q = ref - (ref @ a) * a
    if np.linalg.norm(q) < 1e-6:
        q = z - (z @ a) * a
    q /= np.linalg.norm(q)
    return BodyAxis(o, a, q, np.cross(a, q))


def _outline_width(boundary_uv: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Width (max u - min u) of the closed outline at heights v (0 where the line misses it)."""
    a, b = boundary_uv, np.roll(boundary_uv, -1, axis=0)
    lo, hi = np.minimum(a[:, 1], b[:, 1]), np.maximum(a[:, 1], b[:, 1])
    vv = v[:, None]
    hit = (vv >= lo[None]) & (vv <= hi[None]) & (hi > lo)[None]
    tt = (vv - a[None, :, 1]) / np.where(hi > lo, b[:, 1] - a[:, 1], 1.0)[None]
    u = a[None, :, 0] + tt * (b[:, 0] - a[:, 0])[None]
    umax = np.where(hit, u, -np.inf).max(axis=1)
    umin = np.where(hit, u, np.inf).min(axis=1)
    return np.where(np.isfinite(umax), umax - umin, 0.0)


def _superellipse(phi: np.ndarray, n: float):
    """(sin-like, cos-like) of the superellipse |x|^n + |y|^n = 1 at parameter phi (n = 2: sin, cos)."""
    s, c = np.sin(phi), np.cos(phi)
    if n == 2.0:
        return s, c
    return np.sign(s) * np.abs(s) ** (2.0 / n), np.sign(c) * np.abs(c) ** (2.0 / n)


def _cross_sections(points: np.ndarray, axis: BodyAxis, levels: np.ndarray, offset: float, monotone_down: bool,
                    exponent: float = 2.0):
    """(L, 2) superellipse semi-axes (along P, Q) at axis coordinates `levels`."""
    if levels.size == 0:     # the caller's range of levels was empty (a body of a few centimetres)
        raise InputError("body cross-sections", "no levels to measure: the range between the body's landmarks "
                         f"is shorter than the {LEVEL_STEP} m step (a body this small cannot be dressed)")
    rel = points - axis.origin
    t, p, q = rel @ axis.a, rel @ axis.p, rel @ axis.q
    ab = np.full((levels.size, 2), np.nan)
    for k, lv in enumerate(levels):
        m = np.abs(t - lv) <= SLAB
        if not m.any():
            continue
        hp, hq = max(np.abs(p[m]).max(), 0.01), max(np.abs(q[m]).max(), 0.01)
        s = max(1.0, float((np.abs(p[m] / hp) ** exponent + np.abs(q[m] / hq) ** exponent).max() ** (1 / exponent)))
        ab[k] = (s * hp, s * hq)
    have = np.flatnonzero(~np.isnan(ab[:, 0]))
    if have.size == 0:
        ab[:] = 0.05
    else:
        for c in range(2):
            ab[:, c] = np.interp(np.arange(levels.size), have, ab[have, c])
    # running max over neighbouring levels: clearance between the measured slabs
    pad = np.pad(ab, ((2, 2), (0, 0)), mode="edge")
    ab = np.max(np.stack([pad[i:i + levels.size] for i in range(5)]), axis=0)
    if monotone_down:   # levels ascend with t (= up): a level is at least as wide as any above it
        ab = np.maximum.accumulate(ab[::-1], axis=0)[::-1]
    return ab + offset


def _arc_table(a: float, b: float, phi0: float, n: int = 721, exponent: float = 2.0, a_neg: float | None = None):
    """(phi, signed arc length from phi0) of the superellipse with semi-axes a (a_neg on the -P
    side when given) and b."""
    phi = phi0 + np.linspace(-np.pi, np.pi, n)
    sn, cs = _superellipse(phi, exponent)
    pts = np.stack([np.where(sn >= 0, a, a if a_neg is None else a_neg) * sn, b * cs], axis=1)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    return phi, s - s[n // 2]


def collider_points(colliders, joint_world0: np.ndarray):
    """[(joint, (K, 3) surface points in the relative frame at frame 0)] of every collider."""
    out = []
    if colliders is None:
        return out
    for h in colliders.hulls:
        m = joint_world0[h.bone]
        out.append((h.bone, h.simplified.vertices @ m[:3, :3].T + m[:3, 3]))
    k = np.arange(96) + 0.5
    phi = np.arccos(1 - 2 * k / 96)
    th = np.pi * (1 + 5 ** 0.5) * k
    dirs = np.stack([np.cos(th) * np.sin(phi), np.cos(phi), np.sin(th) * np.sin(phi)], axis=1)
    for sp in colliders.spheres:
        m = joint_world0[sp.pose_index]    # joint_world0: ColliderSet.frame_poses at frame 0 (J + balls)
        out.append((sp.joint, (sp.center + sp.radius * dirs) @ m[:3, :3].T + m[:3, 3]))
    return out


def _collider_joints(character, part: str, joint_origins: np.ndarray, with_arms: bool = True) -> set:
    """Joints whose colliders a panel on `part` must clear (torso: the upper arms' roots too
    when with_arms)."""
    if part in ("torso", "hips"):
        # the arms found as chains and as limbs of fewer joints (a chibi's one-joint arm is a whole
        # arm as thick as a leg, not a root: kept, it spread a cape's top out to the hands)
        limbs = limb_joint_sets(character)
        arms = limbs["arm_l"] | limbs["arm_r"]
        keep = set()
        for side in ("l", "r"):
            arm = limb(character, "arm", side)
            if arm is not None and arm.is_chain and part == "torso" and with_arms:
                keep.add(arm.joints[0])
        return (set(range(character.n_joints)) - arms) | keep
    return part_joints(character, part, joint_origins)


def place_panel(uv: np.ndarray, boundary_uv: np.ndarray, pl: Placement, character, joint_world: np.ndarray,
                skinned: np.ndarray, dominant: np.ndarray, col_points=()) -> np.ndarray:
    """(N, 3) positions of one panel's vertices (module docstring); joint_world (J, 4, 4): the bind pose."""
    if pl.body == "plane":
        n = np.asarray(pl.normal, dtype=np.float64)
        n = n / np.linalg.norm(n)
        up = np.array([0.0, 1.0, 0.0]) if abs(n[1]) < 0.99 else np.array([0.0, 0.0, -1.0])
        av = up - (up @ n) * n
        av /= np.linalg.norm(av)
        pu = np.cross(av, n)
        return np.asarray(pl.center, dtype=np.float64) + uv[:, :1] * pu + uv[:, 1:] * av
    joint_origins = np.asarray(joint_world)[:, :3, 3]
    axis = body_axis(character, pl.body, joint_world)
    joints = part_joints(character, pl.body, joint_origins)
    cj = _collider_joints(character, pl.body, joint_origins, pl.arms)
    if pl.body.startswith("leg_"):
        mid = float(joint_origins[character.root_joint, 0])
        margin = _midline_margin(_part_points(joints, skinned, dominant, col_points, cj), axis, mid)
        # a trouser leg below the knee wraps the shin: the part beyond the thigh's length is placed
        # around the shin's own axis (from the knee), so it follows a bent knee (a one-joint leg's
        # lower point: halfway down its skin, the same straight bone)
        leg = part_limb(character, pl.body)
        ch = leg.follow
        up, knee, end = leg.points(character, joint_world)
        thigh = float(np.linalg.norm(knee - up))
        low = uv[:, 1] + pl.shift < -thigh
        if low.any() and (~low).any():
            o, e = knee, end
            a = (o - e) / np.linalg.norm(o - e)
            q = np.array([0.0, 0.0, 1.0]) - a[2] * a
            q /= np.linalg.norm(q)
            shin = BodyAxis(o, a, q, np.cross(a, q))
            out = np.empty((uv.shape[0], 3))
            out[~low] = _wrap(uv[~low], boundary_uv, pl, axis, _part_points({ch[0]}, skinned, dominant, col_points),
                              mid, margin)
            out[low] = _wrap(uv[low], boundary_uv, replace(pl, shift=pl.shift + thigh), shin,
                             _part_points({ch[1]}, skinned, dominant, col_points), mid, margin)
            return out
        return _wrap(uv, boundary_uv, pl, axis, _part_points(joints, skinned, dominant, col_points, cj), mid, margin)
    arm = axis if pl.body.startswith("arm_") else None
    return _wrap(uv, boundary_uv, pl, axis, _part_points(joints, skinned, dominant, col_points, cj, arm))


def _midline_margin(pts: np.ndarray, axis: BodyAxis, midline_x: float) -> float:
    """How far a leg tube's inner side stays off the mid-plane: MIDLINE_GAP, or halfway to a leg (skin
    and colliders, `pts`) nearer to it than 2 MIDLINE_GAP (a chibi's block legs, 6 mm: the tube's side
    lay inside them); a leg reaching across it (a thigh's colliders) keeps MIDLINE_GAP."""
    side = 1.0 if axis.origin[0] >= midline_x else -1.0
    inner = float((side * (pts[:, 0] - midline_x)).min())
    return 0.5 * inner if 0.0 < inner < 2 * MIDLINE_GAP else MIDLINE_GAP


def _part_points(joints: set, skinned, dominant, col_points, collider_joints: set | None = None,
                 limb: BodyAxis | None = None) -> np.ndarray:
    """Skinned vertices whose dominant joint is in `joints`, plus the collider points of
    `collider_joints` (default: the same joints). limb: a limb's axis: its collider points farther
    from it than its skin's farthest vertex + LIMB_REACH are left out: they belong to the torso (a
    bone that moves little in the clip makes torso skin rigid with it, or its balls carry its
    weight: CesiumMan's upper-arm colliders reach 39 cm from the arm, and a sleeve wrapped around
    them spanned from the hips to above the head)."""
    cj = joints if collider_joints is None else collider_joints
    skin = skinned[np.isin(dominant, list(joints))]
    cols = [p for j, p in col_points if j in cj]
    if limb is not None and skin.shape[0] and cols:
        def radius(p):
            rel = p - limb.origin
            return np.linalg.norm(rel - np.outer(rel @ limb.a, limb.a), axis=1)
        reach = radius(skin).max() + LIMB_REACH
        cols = [p[radius(p) <= reach] for p in cols]
    return np.concatenate([skin] + cols)


def _wrap(uv: np.ndarray, boundary_uv: np.ndarray, pl: Placement, axis: BodyAxis, pts: np.ndarray,
          midline_x: float | None = None, margin: float = MIDLINE_GAP) -> np.ndarray:
    """Panel vertices wrapped around `axis` on the cross-sections of `pts` (see place_panel);
    midline_x: legs: x of the body's mid-plane, which the tube's inner side stays `margin` off."""
    t = uv[:, 1] + pl.shift
    levels = np.arange(t.min() - LEVEL_STEP, t.max() + 2 * LEVEL_STEP, LEVEL_STEP)
    ex = float(pl.exponent)
    ab = _cross_sections(pts, axis, levels, pl.offset, pl.body == "hips", ex)
    v_lv = levels - pl.shift
    vcap = v_lv if pl.wrap_until is None else np.minimum(v_lv, pl.wrap_until)
    width = _outline_width(boundary_uv, vcap)
    if np.any(width <= 0):   # levels beyond the outline: nearest valid width
        ok = np.flatnonzero(width > 0)
        if ok.size == 0:
            raise InputError(f"placement on {pl.body!r}", f"the panel's outline has no width at any level "
                             f"(v {float(vcap.min()):.3g}..{float(vcap.max()):.3g} m): a degenerate outline")
        width = np.interp(np.arange(width.size), ok, width[ok])
    phi0 = np.radians(pl.angle_deg)
    span = np.radians(pl.span_deg)
    level = np.clip(np.round((t - levels[0]) / LEVEL_STEP).astype(int), 0, levels.size - 1)
    fold = pl.fold_at is not None
    if fold:   # columns above the fold keep the fold level's cross-section position
        kf = int(np.clip(np.round((pl.fold_at + pl.shift - levels[0]) / LEVEL_STEP), 0, levels.size - 1))
        level = np.where(uv[:, 1] > pl.fold_at, kf, level)
    out = np.empty((uv.shape[0], 3))
    for k in np.unique(level):
        a, b = ab[k]
        if midline_x is None:
            phi, s = _arc_table(a, b, phi0, exponent=ex)
            half_arc = 0.5 * (np.interp(phi0 + span / 2, phi, s) - np.interp(phi0 - span / 2, phi, s))
            grow = max(1.0, 0.5 * width[k] / half_arc)
            a, b = a * grow, b * grow
            a_neg = a
            phi, s = _arc_table(a, b, phi0, exponent=ex)
            half_arc *= grow
            if not pl.stretch:     # at its own width: the arc its width covers, not the span's
                half_arc = min(half_arc, 0.5 * width[k])
        else:
            # a leg tube: its side towards the body's mid-plane stays on this side of it (it would
            # be inside the other leg); a wider tube grows outwards and front / back instead
            c = axis.origin + levels[k] * axis.a
            gap = (midline_x - c[0]) / (axis.p[0] if abs(axis.p[0]) > 1e-6 else 1e-6)
            a_in = float(np.clip(abs(gap) - margin, 0.02, a))
            inner_pos = gap > 0

            def table(f):
                out_a = a * f
                return _arc_table(a_in if inner_pos else out_a, b * f, phi0, exponent=ex,
                                  a_neg=out_a if inner_pos else a_in)

            def half(f):
                phi, s = table(f)
                return 0.5 * (np.interp(phi0 + span / 2, phi, s) - np.interp(phi0 - span / 2, phi, s))
            lo, hi = 1.0, 1.0
            while half(hi) < 0.5 * width[k] and hi < 64:
                lo, hi = hi, hi * 2
            for _ in range(30 if hi > 1.0 else 0):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if half(mid) < 0.5 * width[k] else (lo, mid)
            f = hi
            phi, s = table(f)
            half_arc = half(f)
            a, a_neg, b = (a_in, a * f, b * f) if inner_pos else (a * f, a_in, b * f)
        m = level == k
        target = uv[m, 0] / (0.5 * width[k]) * half_arc
        sn, cs = _superellipse(np.interp(target, s, phi), ex)
        out[m] = axis.origin + t[m, None] * axis.a + (np.where(sn >= 0, a, a_neg) * sn)[:, None] * axis.p \
            + (b * cs)[:, None] * axis.q
    if fold:
        out = _fold_over(out, uv, pl, axis)
    return out


def _quarter_arc(dq: np.ndarray, h: np.ndarray, n: int = 65):
    """(psi (n,), cumulative arc length (N, n)) of quarter ellipses t = h sin psi, q = dq cos psi."""
    psi = np.linspace(0.0, np.pi / 2, n)
    pts = np.stack([h[:, None] * np.sin(psi), dq[:, None] * np.cos(psi)], axis=2)
    seg = np.linalg.norm(np.diff(pts, axis=1), axis=2)
    return psi, np.concatenate([np.zeros((dq.size, 1)), np.cumsum(seg, axis=1)], axis=1)


def _fold_over(out: np.ndarray, uv: np.ndarray, pl: Placement, axis: BodyAxis) -> np.ndarray:
    """Bend the columns above pl.fold_at over the top of the body onto the ridge plane (q = 0).

    A column at u leaves the fold level at distance dq from the ridge plane and follows the quarter
    ellipse t = t_f + H sin psi, q = dq cos psi, whose height H makes its length equal to
    ridge(u) - fold_at (so both panels of a shoulder seam end on the ridge at the same point);
    beyond the ridge (a longer column) it continues straight across the ridge plane.
    """
    m = uv[:, 1] > pl.fold_at
    if not m.any():
        return out
    x = out[m]
    rel = x - axis.origin
    dq = np.abs(rel @ axis.q)
    sgn = np.where(rel @ axis.q >= 0, 1.0, -1.0)
    # the column's foot on the ridge plane at the fold level
    base = axis.origin + (pl.fold_at + pl.shift) * axis.a + (rel @ axis.p)[:, None] * axis.p
    ridge = np.asarray(pl.ridge)
    want = np.interp(uv[m, 0], ridge[:, 0], ridge[:, 1]) - pl.fold_at
    # H by bisection: the quarter-ellipse length grows with H (from dq at H = 0)
    lo, hi = np.zeros(dq.size), np.maximum(want, 1e-6)
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        _, s = _quarter_arc(dq, mid, 17)
        longer = s[:, -1] > want
        hi = np.where(longer, mid, hi)
        lo = np.where(longer, lo, mid)
    h = 0.5 * (lo + hi)
    psi, s = _quarter_arc(dq, h)
    L = uv[m, 1] - pl.fold_at
    ps = np.array([np.interp(L[i], s[i], psi) for i in range(dq.size)])
    beyond = np.maximum(L - s[:, -1], 0.0)
    x = base + (h * np.sin(ps))[:, None] * axis.a + (sgn * (dq * np.cos(ps) - beyond))[:, None] * axis.q
    out = out.copy()
    out[m] = x
    return out


def frame_poses0(colliders, character, motion) -> np.ndarray:
    """Collider frames at frame 0: the joints' transforms, then the skinned balls' (if any)."""
    jw = motion.joint_world[0]
    return jw if colliders is None else colliders.frame_poses(character.inverse_bind, jw)


def bind_geometry(character, motion):
    """(skinned vertices at frame 0 (V, 3), joint origins at frame 0 (J, 3), dominant joint (V,))."""
    from stages.rig.skinning import skin
    skinned = skin(character, motion, frames=[0])[0]
    origins = motion.joint_world[0][:, :3, 3]
    dominant = character.skin_joints[np.arange(character.skin_joints.shape[0]), np.argmax(character.skin_weights, axis=1)]
    return skinned, origins, dominant


MAX_DISTANCES = 16_000_000   # (collider, point) distances in one matrix at most (128 MB): RiggedSimple's 65,430
                             # balls times the 17,800 points of the crotch search went past 8 GB
POINT_CHUNK = 50_000         # points tested at once, fewer for hulls of many faces (their plane distances are
                             # (points, faces): RiggedSimple's swept hulls took 1 GB for 17,800 points)


def near_colliders(bind, points: np.ndarray, gap: float, joints=None) -> np.ndarray:
    """(N,) bool: points whose signed distance (types._signed_distance) to some collider of `bind`
    is below `gap` (m), POINT_CHUNK points at a time. With many colliders (more than MAX_DISTANCES
    distances in all) each hull is tested on its own and each sphere only on the points within its
    radius + gap (+ 1 um for rounding) of its centre: the matrix's answers without the matrix.
    joints: only the colliders of these bones (None: all)."""
    from scipy.spatial import cKDTree

    from stages.garments.types import _collider_distances, _colliders, _signed_distance
    cols = _colliders(bind.colliders) if bind is not None and bind.colliders is not None else []
    if joints is not None:
        cols = [c for c in cols if int(c[0]) in joints]
    p = np.asarray(points, np.float64).reshape(-1, 3)
    faces = max([c.simplified.faces.shape[0] for _, _, c, _ in cols if hasattr(c, "simplified")], default=1)
    step = max(1, min(POINT_CHUNK, MAX_DISTANCES // faces))
    if p.shape[0] > step:
        return np.concatenate([near_colliders(bind, p[a:a + step], gap, joints) for a in range(0, len(p), step)])
    if not cols or p.shape[0] == 0:
        return np.zeros(p.shape[0], bool)
    if len(cols) * p.shape[0] <= MAX_DISTANCES:
        return _collider_distances(bind, p, joints)[0].min(axis=0) < gap
    out = np.zeros(p.shape[0], bool)
    spheres = [(c, frame) for _, _, c, frame in cols if not hasattr(c, "simplified")]
    for c, frame in [(c, frame) for _, _, c, frame in cols if hasattr(c, "simplified")]:
        out |= _signed_distance(c, bind.collider_to_local(frame, p)) < gap
    # each sphere's centre in the points' frame: collider_to_local is rigid, x_local = A x + b
    basis = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    centres = [np.linalg.solve((q[1:] - q[0]).T, c.center - q[0])
               for c, q in ((c, bind.collider_to_local(frame, basis)) for c, frame in spheres)]
    radii = np.array([c.radius for c, _ in spheres])
    near = cKDTree(p).query_ball_point(np.array(centres).reshape(-1, 3), np.maximum(radii + gap + 1e-6, 0.0))
    for (c, frame), idx in zip(spheres, near):
        if idx:
            out[idx] |= _signed_distance(c, bind.collider_to_local(frame, p[idx])) < gap
    return out


def inside_body(character, skinned: np.ndarray, points: np.ndarray, colliders=None, bind=None) -> np.ndarray:
    """(N,) bool: points inside the skinned body mesh (winding number >= 0.5) or inside a collider."""
    from stages.geometry.winding import winding_number
    ins = winding_number(skinned, character.triangles, points) >= 0.5
    if colliders is not None and bind is not None and (colliders.hulls or colliders.spheres):
        ins |= near_colliders(bind, points, 0.0)
    return ins


def place_pattern(pattern: Pattern, flat: FlatPattern, character, motion, colliders=None, *, max_tries: int = 15):
    """(N, 3) placed positions of all panels (concatenated as in `flat`), relative frame at frame 0,
    and {panel: final Placement} after clearance fixes: a panel with vertices inside the body or a
    collider is moved out 1 cm at a time (sleeves: along the arm, outwards; others: more offset)."""
    from dataclasses import replace

    skinned, _, dominant = bind_geometry(character, motion)
    pose = motion.joint_world[0]
    cp = collider_points(colliders, frame_poses0(colliders, character, motion))
    out, used = [], {}
    for panel, fp in zip(pattern.panels, flat.panels):
        pl = panel.placement
        for attempt in range(max_tries + 1):
            x = place_panel(fp.uv, fp.uv[:fp.n_boundary], pl, character, pose, skinned, dominant, cp)
            # the body mesh must be clear; particles starting inside an (inflated) collider are
            # pushed out by the sewing simulation's collision response
            bad = inside_body(character, skinned, x)
            if not bad.any() or pl.body == "plane":
                break
            if bad.sum() <= FEW_INSIDE * x.shape[0]:
                # a few vertices (an armhole corner in the arm's root): out along the skin's normal
                x[bad] = push_out(x[bad], character, skinned, pl.offset)
                if not inside_body(character, skinned, x).any():
                    break
            if attempt == max_tries:
                raise InputError(f"pattern {pattern.name!r} panel {panel.name!r}",
                                 f"{int(bad.sum())} vertices still inside the body after {max_tries} cm of clearance moves")
            if pl.body.startswith("arm"):
                pl = replace(pl, shift=pl.shift - 0.01)
            else:
                pl = replace(pl, offset=pl.offset + 0.01)
        out.append(x)
        used[panel.name] = pl
    # panels around the same trunk share one offset, so their seams start closed whatever panel
    # had to move out
    for body in ("torso", "hips"):
        names = [p.name for p in pattern.panels if p.placement.body == body]
        top = max((used[n].offset for n in names), default=0.0)
        for i, (panel, fp) in enumerate(zip(pattern.panels, flat.panels)):
            if panel.name in names and used[panel.name].offset < top:
                used[panel.name] = replace(used[panel.name], offset=top)
                out[i] = place_panel(fp.uv, fp.uv[:fp.n_boundary], used[panel.name], character, pose, skinned,
                                     dominant, cp)
    return np.concatenate(out), used


FEW_INSIDE = 0.02  # share of a panel's vertices inside the body that are pushed out instead of moving the panel


def push_out(points: np.ndarray, character, skinned: np.ndarray, clearance: float, *,
             along_normal: bool = False) -> np.ndarray:
    """(N, 3) points inside the body moved to their nearest skin vertex plus `clearance` along its
    normal. along_normal: instead, moved along that vertex's normal to `clearance` outside its
    tangent plane, and only those still inside then onto the vertex: neighbouring points sharing a
    nearest vertex stay apart (snapped onto it, dress_pencil's skirt on the CMU walk had 54 pairs of
    particles at one point, which the sewing's cloth collision could not part). GarmentCode panels,
    sewn with cloth collision, take it; the built-in patterns keep the snap (on a chibi's block body,
    moved along the normals of its few vertices, the female's short skirt was dressed at p99 strain
    58 % against 22 %)."""
    from scipy.spatial import cKDTree

    from stages.rig.skinning import vertex_normals
    n = vertex_normals(skinned, character.triangles)
    p = np.asarray(points, np.float64)
    _, i = cKDTree(skinned).query(p)
    if not along_normal:
        return skinned[i] + clearance * n[i]
    depth = clearance - np.einsum("ij,ij->i", p - skinned[i], n[i])
    out = p + np.maximum(depth, 0.0)[:, None] * n[i]
    still = inside_body(character, skinned, out) if len(out) else np.zeros(0, bool)
    out[still] = skinned[i[still]] + clearance * n[i[still]]
    return out


UNDER_REACH = 0.05  # m: with garments worn under it, a band's walk starts this much farther out
UNDER_SAMPLES = 6   # surface samples of a garment worn under: a barycentric grid of n + 1 per side


def triangle_grid_points(positions: np.ndarray, triangles: np.ndarray, n: int = UNDER_SAMPLES) -> np.ndarray:
    """(T (n + 1)(n + 2) / 2, 3) points on a triangle mesh: each triangle's barycentric grid with n
    steps per side (corners and edges included), so every surface point is within about a third of
    an edge / n of one."""
    w = np.array([(i, j, n - i - j) for i in range(n + 1) for j in range(n + 1 - i)], np.float64) / n
    tri = np.asarray(positions, np.float64)[np.asarray(triangles)]
    return np.einsum("sk,tkd->tsd", w, tri).reshape(-1, 3)
