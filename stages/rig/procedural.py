"""The built-in procedural character: a parametric humanoid skeleton, its skin and linear-blend
weights (generated around it by stages.rig.capsule_skin, which dresses any skeleton), procedural
clips and body measurements.

Conventions (see stages.rig.types): Y up, metres, the character faces +Z, its left side is +X, it
stands on y = 0 in the bind pose. The procedural skeleton is bound in an A-pose (arms 45 degrees
below horizontal by default): hanging arms would fuse with the torso under a smooth union, a
T-pose makes T-shirt sleeves sit unnaturally and skirts want free space beside the hips.

The skin and weights: see stages.rig.capsule_skin.
"""
from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from stages.rig.body_params import BodyParams
from stages.rig.capsule_skin import skin_skeleton
from stages.rig.transforms import forward_kinematics
from stages.rig.types import Character

# ---------------------------------------------------------------------------------------------
# Skeleton

# name, parent, position as a fraction of height (left side; right mirrors x), semi-axes
# (width, depth) as a fraction of height, girth factor that scales it.
_TORSO = (
    ("pelvis", None, (0.0, 0.545, 0.0), (0.094, 0.068), "hips"),
    ("spine", "pelvis", (0.0, 0.625, -0.004), (0.080, 0.058), "waist"),
    ("chest", "spine", (0.0, 0.715, 0.0), (0.092, 0.064), "chest"),
    ("neck", "chest", (0.0, 0.818, -0.006), (0.033, 0.035), None),
    ("head", "neck", (0.0, 0.900, 0.004), (0.048, 0.056), None),
)
_LIMB_RADII = {  # (width, depth) fraction of height; factor
    "clavicle": ((0.036, 0.030), "chest"),
    "upperarm": ((0.033, 0.033), "arms"),
    "forearm": ((0.025, 0.024), "arms"),
    "hand": ((0.022, 0.014), "arms"),
    "thigh": ((0.052, 0.052), "legs"),
    "shin": ((0.031, 0.031), "legs"),
    "foot": ((0.022, 0.022), "legs"),
    "toes": ((0.028, 0.012), "legs"),
}
# Limb segment lengths as fractions of height (Drillis & Contini style proportions).
_UPPERARM, _FOREARM, _HAND = 0.186, 0.146, 0.100


def humanoid_skeleton(params: BodyParams = BodyParams()):
    """The procedural humanoid skeleton in its bind pose.

    Returns (joint_names: tuple[str, ...] (21 joints), parents: (J,) int32 (parents[j] < j, root
    'pelvis' = 0), rest_local: (J, 4, 4) float64 parent-frame rest transforms). Every joint's bind
    rotation is the identity, so local rotations in clips are expressed in world-aligned axes.
    Left limbs are at +X. Positions come from proportions of `params.height`; the skin generator
    then rescales skeleton and mesh together so the mesh spans exactly y in [0, height].
    """
    names, parents, pos, _ = _skeleton_table(params)
    local = np.tile(np.eye(4), (len(names), 1, 1))
    for j, p in enumerate(parents):
        local[j, :3, 3] = pos[j] - (pos[p] if p >= 0 else 0.0)
    return names, parents, local


def _skeleton_table(params: BodyParams):
    """(names, parents, bind positions (J,3), radii (J,2)) plus end sites, internal."""
    h = params.height
    names: list[str] = []
    parents: list[int] = []
    pos: list[np.ndarray] = []
    radii: list[np.ndarray] = []

    def add(name, parent, p, r):
        names.append(name)
        parents.append(-1 if parent is None else names.index(parent))
        pos.append(np.asarray(p, dtype=np.float64) * h)
        radii.append(np.asarray(r, dtype=np.float64) * h)

    for name, parent, p, r, factor in _TORSO:
        add(name, parent, p, np.asarray(r) * (getattr(params, factor) if factor else 1.0))
    a = np.radians(params.arm_angle_deg)
    arm_dir = np.array([np.cos(a), -np.sin(a), 0.0])
    for side, sx in (("l", 1.0), ("r", -1.0)):
        m = np.array([sx, 1.0, 1.0])
        shoulder = np.array([0.105, 0.812, -0.004])
        elbow = shoulder + _UPPERARM * arm_dir
        wrist = elbow + _FOREARM * arm_dir
        for name, parent, p in (
            ("clavicle", "chest", (0.018, 0.795, 0.012)),
            ("upperarm", "clavicle", shoulder),
            ("forearm", "upperarm", elbow),
            ("hand", "forearm", wrist),
        ):
            r, factor = _LIMB_RADII[name]
            add(f"{name}_{side}", f"{parent}_{side}" if parent != "chest" else parent,
                np.asarray(p) * m, np.asarray(r) * getattr(params, factor))
    for side, sx in (("l", 1.0), ("r", -1.0)):
        m = np.array([sx, 1.0, 1.0])
        for name, parent, p in (
            ("thigh", "pelvis", (0.054, 0.525, 0.0)),
            ("shin", "thigh", (0.052, 0.285, 0.002)),
            ("foot", "shin", (0.050, 0.042, -0.006)),
            ("toes", "foot", (0.052, 0.013, 0.078)),
        ):
            r, factor = _LIMB_RADII[name]
            # the thigh tops make the outline of the hips, so they follow the hips factor too
            f = getattr(params, factor) * (params.hips if name == "thigh" else 1.0)
            add(f"{name}_{side}", f"{parent}_{side}" if parent != "pelvis" else parent,
                np.asarray(p) * m, np.asarray(r) * f)
    names_t = tuple(names)
    positions = np.array(pos)
    ends = {names_t.index("head"): np.array([0.0, 1.0, 0.004]) * h}
    for side, sx in (("l", 1.0), ("r", -1.0)):
        ends[names_t.index(f"hand_{side}")] = positions[names_t.index(f"hand_{side}")] + _HAND * h * arm_dir * [sx, 1, 1]
        ends[names_t.index(f"toes_{side}")] = np.array([0.052 * sx, 0.010, 0.118]) * h
    table_radii = np.array(radii)
    return names_t, np.array(parents, dtype=np.int32), positions, (table_radii, ends)


# ---------------------------------------------------------------------------------------------
# Character


def procedural_character(params: BodyParams = BodyParams(),
                         motions=("rest", "walk", "arm_raise", "turn")) -> Character:
    """The procedural humanoid: A-pose skin, 21-joint skeleton, LBS weights and clips.

    The skin is generated with `skin_skeleton`, then skeleton and mesh are scaled together so the
    mesh spans exactly y in [0, params.height]. Clips are built by
    `stages.rig.procedural_motion.make_clip` (names: rest, walk, arm_raise, turn).
    """
    from stages.rig.procedural_motion import make_clip

    names, parents, positions, (radii, ends) = _skeleton_table(params)
    verts, tris, sj, sw = skin_skeleton(names, parents, positions, params, radii=radii, end_sites=ends)
    # exact height and ground contact: uniform scale about the origin (x = z = 0), then lift
    y0, y1 = verts[:, 1].min(), verts[:, 1].max()
    s = params.height / (y1 - y0)
    shift = np.array([0.0, -y0 * s, 0.0])
    verts = verts * s + shift
    positions = positions * s + shift
    local = np.tile(np.eye(4), (len(names), 1, 1))
    for j, p in enumerate(parents):
        local[j, :3, 3] = positions[j] - (positions[p] if p >= 0 else 0.0)
    world = forward_kinematics(parents, local)
    inverse_bind = np.linalg.inv(world)
    clips = tuple(make_clip(m, names, parents, local, params) for m in motions)
    return Character(
        name="procedural",
        vertices=verts,
        triangles=tris,
        primitive_ids=np.zeros(len(verts), np.int32),
        joint_names=names,
        parents=parents,
        rest_local=local,
        inverse_bind=inverse_bind,
        skin_joints=sj,
        skin_weights=sw,
        clips=clips,
        root_joint=0,
        source="procedural",
    )


# ---------------------------------------------------------------------------------------------
# Measurements

def body_measurements(character: Character) -> dict:
    """Tape-measure sizes of a character in its bind pose, metres.

    height: mesh y extent. chest, waist, hips: girths = perimeter of the convex hull of the
    torso's horizontal cross-section (the loop around the root joint's vertical axis) at 72 %,
    62 % and 53 % of the height above the lowest vertex (the 'hips' slice is at hip-joint
    level). chest_y, waist_y, hips_y: those heights (world y).
    arm_length (shoulder to wrist) and leg_length (hip to ankle): sums of bind-pose bone lengths
    of the left chain, found by joint name (procedural, Mixamo-like or CMU names); NaN when the
    names are not recognised.
    """
    v = character.vertices
    y0, y1 = float(v[:, 1].min()), float(v[:, 1].max())
    h = y1 - y0
    world = forward_kinematics(character.parents, character.rest_local)
    root_xz = world[character.root_joint, [0, 2], 3]
    out = {"height": h}
    for key, y in _torso_slices(character, world[:, :3, 3], y0, h).items():
        # a tape in a gap between meshes (a chibi's torso ends just above its leg joints) goes to the
        # nearest height within 5 % of the body's where it meets the body
        for dy in (0.0, *[s * k * 0.01 * h for k in range(1, 6) for s in (1, -1)]):
            g = _girth(v, character.triangles, y + dy, root_xz)
            if np.isfinite(g):
                y += dy
                break
        out[f"{key}_y"] = y
        out[key] = g
    from stages.rig.humanoid import limb_chain
    pos = world[:, :3, 3]
    for key, kind in (("arm_length", "arm"), ("leg_length", "leg")):
        chain = limb_chain(character, kind, "l")
        out[key] = float(np.linalg.norm(np.diff(pos[chain], axis=0), axis=1).sum()) if chain else float("nan")
    return out


# where a tape goes on an adult body, as shares of the height above the lowest vertex
SLICE_SHARES = {"chest": 0.72, "waist": 0.62, "hips": 0.53}
SHOULDER_SHARE = 0.81    # the upper-arm joints' height on the same bodies


def _torso_slices(character: Character, joints: np.ndarray, y0: float, h: float) -> dict:
    """{chest, waist, hips}: the heights (world y) the girths are taken at. By adult proportions
    (SLICE_SHARES) unless they miss the torso the skeleton has: a chest tape 5 % of the height
    above the upper-arm joints, or a hips tape 10 % below or 20 % above the upper-leg joints (a
    chibi's or a child's hips and shoulders sit far lower in its height: Kenney's mini characters
    have a head half their height, where the proportional slices cut). Then the slices go between
    the upper-leg joints (hips) and the upper-arm joints, in the same ratios."""
    from stages.rig.humanoid import humanoid_joints
    shares = {k: y0 + f * h for k, f in SLICE_SHARES.items()}
    # each limb's upper point at rest: its upper joint, also on a limb of one joint (a chibi's)
    tops = humanoid_joints(character).points
    if not all(p in tops for p in ("arm_l", "arm_r", "leg_l", "leg_r")):
        return shares
    hip = float(np.mean([tops[p][0][1] for p in ("leg_l", "leg_r")]))
    shoulder = float(np.mean([tops[p][0][1] for p in ("arm_l", "arm_r")]))
    if not shoulder > hip:
        return shares
    if shares["chest"] < shoulder + 0.05 * h and hip - 0.1 * h < shares["hips"] < hip + 0.2 * h:
        return shares       # the adult proportions fit this skeleton well enough (every shipped character)
    span = (shoulder - hip) / (SHOULDER_SHARE - SLICE_SHARES["hips"])
    return {k: hip + (f - SLICE_SHARES["hips"]) * span for k, f in SLICE_SHARES.items()}


def _girth(vertices, triangles, y, axis_xz):
    """Convex-hull perimeter of the cross-section loop at height y that encloses axis_xz (or the
    largest loop when none does)."""
    from scipy.spatial import ConvexHull, QhullError
    from scipy.spatial import cKDTree

    d = vertices[:, 1] - y
    d = np.where(d == 0.0, 1e-12, d)  # a vertex exactly on the plane: nudge it above
    tri_d = d[triangles]
    crossing = (tri_d.min(axis=1) < 0) & (tri_d.max(axis=1) > 0)
    segs = []
    for t in np.flatnonzero(crossing):
        pts = []
        for a, b in ((0, 1), (1, 2), (2, 0)):
            da, db = tri_d[t, a], tri_d[t, b]
            if (da < 0) != (db < 0):
                pa, pb = vertices[triangles[t, a]], vertices[triangles[t, b]]
                pts.append(pa + (pb - pa) * (da / (da - db)))
        segs.append(pts[:2])
    if not segs:
        return float("nan")
    segs = np.asarray(segs)[:, :, [0, 2]]  # (S, 2, 2) in the xz plane
    ends = segs.reshape(-1, 2)
    pairs = cKDTree(ends).query_pairs(1e-9, output_type="ndarray")
    n = len(ends)
    links = np.concatenate([pairs, np.stack([np.arange(0, n, 2), np.arange(1, n, 2)], axis=1)])
    adj = coo_matrix((np.ones(len(links)), (links[:, 0], links[:, 1])), shape=(n, n))
    ncomp, label = connected_components(adj, directed=False)
    best, best_len, fallback_len = None, -1.0, -1.0
    for c in range(ncomp):
        pts = ends[label == c]
        if len(pts) < 3:
            continue
        centred = pts - pts.mean(axis=0)
        _, sv, axes = np.linalg.svd(centred, full_matrices=False)
        # a loop flattened onto a line (a flat plate cut edge-on, a mesh with coincident sheets:
        # Kenney's chibi body) is refused by Qhull; a tape around it measures twice its length
        flat_length = 2.0 * float(np.ptp(centred @ axes[0]))
        per, inside = flat_length, False
        if sv[1] > 1e-9 * max(sv[0], 1e-300):
            try:
                hull = ConvexHull(pts)
                per = float(hull.area)  # in 2D, 'area' is the perimeter
                eq = hull.equations
                inside = np.all(eq[:, :2] @ axis_xz + eq[:, 2] <= 0)
            except QhullError:   # nearly flat beyond the rank test's reach: measured as a flat loop
                pass
        if inside and per > best_len:
            best, best_len = c, per
        if per > fallback_len:
            fallback_len = per
    return best_len if best is not None else fallback_len
