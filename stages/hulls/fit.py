"""Colliders of a character: a simplified inflated hull per rigid region; per flexible region a
sphere (paper A) or swept hulls (stages/hulls/swept.py).

Frames: every collider lives in the bone-local frame of its joint, x_local = inverse_bind[j] @ x_model
(stages/rig/types.py), so it follows its bone rigidly at run time.
"""
from __future__ import annotations

import numpy as np

from stages.checks import ContractError
from stages.errors import InputError
from stages.hulls import kernels
from stages.hulls.hull import convex_hull, inflate_hull, mesh_volume
from stages.hulls.simplify import simplify_hull
from stages.hulls.types import ColliderSet, ConvexMesh, HullCollider, HullFitReport, SphereCollider
from stages.rig.regions import is_hull_ready
from stages.rig.transforms import transform_points
from stages.rig.types import Character, RegionSplit


def joint_sphere(points_local: np.ndarray, center_local: np.ndarray, delta: float) -> tuple[np.ndarray, float]:
    """Sphere at the joint enclosing a flexible region: radius = farthest point + delta (metres)."""
    p = np.asarray(points_local, dtype=np.float64).reshape(-1, 3)
    c = np.asarray(center_local, dtype=np.float64).reshape(3)
    if p.shape[0] == 0:
        raise InputError("joint sphere", "the flexible region has no vertices")
    radius = float(np.sqrt(((p - c) ** 2).sum(axis=1).max())) + float(delta)
    if not radius > 0:
        raise InputError("joint sphere", f"degenerate sphere (radius {radius}): all points at the joint and delta 0")
    return c.copy(), radius


def distance_to_hull(points: np.ndarray, hull: ConvexMesh) -> np.ndarray:
    """(P,) Euclidean distance from each point to the solid convex hull (0 inside)."""
    return kernels.distance_to_convex(np.ascontiguousarray(points, dtype=np.float64), hull.vertices,
                                      hull.faces, np.ascontiguousarray(hull.planes))


def hausdorff_to_hull(outer: ConvexMesh, inner: ConvexMesh) -> float:
    """One-sided Hausdorff distance from the surface of `outer` to the solid `inner` (metres).

    Exact when inner is convex: the distance to a convex set is a convex function, so its maximum
    over the polytope `outer` is reached at a vertex of `outer`. When outer contains inner (as here)
    no point of outer's surface is inside inner, so this is also the distance to inner's surface.
    """
    return float(distance_to_hull(outer.vertices, inner).max())


def containment(points: np.ndarray, hull: ConvexMesh) -> float:
    """Worst signed plane distance max_p max_f (n_f . p - d_f): <= 0 iff every point is inside.

    For a point outside it is a lower bound of its distance to the hull (the exact sign matters).
    """
    pl = hull.planes
    return float((points @ pl[:, :3].T - pl[:, 3]).max())


CONTAIN_TOLERANCE = 1e-7  # metres: a region vertex this close outside still counts as contained


def fit_hull(points_local: np.ndarray, delta: float, min_triangles: int, *, source="region",
             priority: str = "qem", max_offset: float | None = None) -> tuple[ConvexMesh, ConvexMesh, ConvexMesh, HullFitReport]:
    """Raw hull, inflated hull, simplified hull and fit report of one rigid region (bone-local).

    A coplanar region falls back to a slab of half-thickness max(delta, 1e-4 m) (see hull.py).
    """
    raw = convex_hull(points_local, source=source, flat_thickness=max(delta, 1e-4))
    inflated = inflate_hull(raw, delta)
    simplified = simplify_hull(inflated, min_triangles, priority=priority, max_offset=max_offset)
    worst = containment(points_local, simplified)
    report = HullFitReport(
        faces_raw=int(raw.faces.shape[0]), faces_inflated=int(inflated.faces.shape[0]),
        faces_simplified=int(simplified.faces.shape[0]), volume_raw=mesh_volume(raw),
        volume_simplified=mesh_volume(simplified), hausdorff=hausdorff_to_hull(simplified, raw),
        contains_region=bool(worst <= CONTAIN_TOLERANCE), worst_violation=worst)
    return raw, inflated, simplified, report


def fit_colliders(character: Character, split: RegionSplit, *, delta: float = 0.01,
                  min_triangles: int = 40, priority: str = "qem", max_offset: float | None = None,
                  flexible: str = "sphere", poses: np.ndarray | None = None,
                  deviation: np.ndarray | None = None, core: bool = True, progress=None) -> ColliderSet:
    """Hull colliders for split.hull_bones; for split.sphere_joints spheres (flexible='sphere', the
    paper) or swept hulls (flexible='swept', stages/hulls/swept.py).

    delta: inflation thickness (m), also added to sphere radii. min_triangles: simplification floor.
    priority / max_offset: see simplify_hull (max_offset None = only the floor stops simplification,
    as in the paper; with a low floor, set it to bound how far a hull may grow past the inflated one).
    poses: (F, J, 4, 4) joint world transforms of the motion sample (needed by 'swept');
    deviation: (V, K) from stages.rig.motion_range.bone_deviation over those poses (computed if None).
    core: add to each hull the points of its bone inside the body near its region (swept.bone_core),
    so hulls of patches of skin meet inside the body.
    progress: optional callback(done, total) after each hull (total grows once the swept parts are known).
    Bone-local points = inverse_bind[b] @ bind-pose vertices. Sphere centre = the joint origin in its
    own frame: inverse_bind[j] @ (translation of inv(inverse_bind[j])), ~0 up to rounding.
    """
    if not (np.isfinite(delta) and delta >= 0):
        raise ContractError(f"fit_colliders: delta must be a non-negative thickness, got {delta}")
    if split.dominant_joint.shape[0] != character.vertices.shape[0]:
        raise ContractError(f"fit_colliders: split has {split.dominant_joint.shape[0]} vertices, "
                            f"character {character.vertices.shape[0]}")
    if flexible not in ("sphere", "swept", "balls"):
        raise ContractError(f"fit_colliders: flexible must be 'sphere', 'swept' or 'balls', got {flexible!r}")
    if flexible in ("swept", "balls") and poses is None:
        raise ContractError(f"fit_colliders: flexible={flexible!r} needs the poses of the motion sample")

    def hull(bone, name, idx, pts, kind="rigid", joint=-1):
        raw, inflated, simplified, report = fit_hull(pts, delta, min_triangles, source=f"hull {name!r}",
                                                     priority=priority, max_offset=max_offset)
        return HullCollider(bone=int(bone), name=name, region_points=pts, raw=raw, inflated=inflated,
                            simplified=simplified, report=report, kind=kind,
                            region_vertices=np.asarray(idx, np.int64), joint=int(joint))

    from stages.hulls import swept
    core = core and character.triangles.shape[0] > 0      # "inside the body" needs a surface
    if core:
        from stages.geometry.skin_distance import SkinDistance
        body = SkinDistance(character)
        body.refit(character.vertices)

    def with_core(b, idx, pts):
        if not core:
            return pts
        c = swept.bone_core(character, b, idx)
        c = c[body.inside(c)] if c.size else c
        return np.ascontiguousarray(np.concatenate([pts, transform_points(character.inverse_bind[b], c)]))

    hulls = []
    total = len(split.hull_bones)
    tick = progress or (lambda done, total: None)
    for b in split.hull_bones:
        idx = split.rigid_vertices(b)
        pts = np.ascontiguousarray(transform_points(character.inverse_bind[b], character.vertices[idx]))
        hulls.append(hull(b, character.joint_names[b], idx, with_core(b, idx, pts)))
        tick(len(hulls), total)
    sphere_joints, notes = list(split.sphere_joints), []
    if flexible == "balls":
        return _with_balls(character, split, poses, hulls, delta=delta, min_triangles=min_triangles,
                           body=body if core else None)
    if flexible == "swept" and sphere_joints:
        from stages.rig.motion_range import bone_deviation
        from stages.rig.skinning import skin_poses
        skinned = skin_poses(character, poses)
        if deviation is None:
            deviation = bone_deviation(character, poses, skinned)
        parts, notes = swept.swept_parts(character, split, deviation)
        sphere_joints = []
        total += len(parts)
        swept_cores = core_points(character, parts, poses, skinned, body) if core else [None] * len(parts)
        for (j, b, idx), name, c in zip(parts, swept.part_names(character, parts), swept_cores):
            tick(len(hulls) + len(sphere_joints), total)
            pts = swept.swept_points(character, poses, skinned, b, idx)
            if not is_hull_ready(pts):
                sphere_joints.append(j)
                notes.append(f"flexible region of joint {character.joint_names[j]!r}: too small or flat "
                             "for a swept hull; a joint sphere instead")
                continue
            pts = pts if c is None else np.ascontiguousarray(np.concatenate([pts, c]))
            # it claims its own vertices: the ring's are only held near their bind place (swept.RING_REACH)
            hulls.append(hull(b, name, idx, pts, kind="swept", joint=j))
        tick(total, total)
        sphere_joints = sorted(set(sphere_joints))
    spheres = []
    for j in sphere_joints:
        name = character.joint_names[j]
        idx = split.flexible_vertices(j)
        ib = character.inverse_bind[j]
        pts = np.ascontiguousarray(transform_points(ib, character.vertices[idx]))
        joint_model = np.linalg.inv(ib)[:3, 3]
        try:
            center, radius = joint_sphere(pts, transform_points(ib, joint_model[None])[0], delta)
        except InputError as err:
            raise InputError(f"sphere of joint {name!r}", err.problem) from None
        spheres.append(SphereCollider(joint=int(j), name=name, center=center, radius=radius, region_points=pts,
                                      region_vertices=idx.astype(np.int64)))
    return ColliderSet(hulls=tuple(hulls), spheres=tuple(spheres), delta=float(delta),
                       min_triangles=int(min_triangles), flexible=flexible, notes=tuple(notes))


def _with_balls(character: Character, split: RegionSplit, poses: np.ndarray, hulls: list, *, delta: float,
                min_triangles: int, body) -> ColliderSet:
    """The rigid hulls plus skinned balls for every flexible vertex (stages/hulls/balls.py)."""
    from stages.hulls.balls import fit_balls
    from stages.rig.skinning import skin_poses
    if body is None:
        from stages.geometry.skin_distance import SkinDistance
        body = SkinDistance(character)
    balls = fit_balls(character, split, poses, skin_poses(character, poses), body, delta=delta, hulls=hulls)
    j = character.n_joints
    names = character.joint_names
    spheres = tuple(SphereCollider(joint=int(balls.joint[k]), name=f"{names[balls.joint[k]]}_ball{k}", center=np.zeros(3),
                                   radius=float(balls.radius[k]), region_points=np.zeros((0, 3)), frame=j + k)
                    for k in range(balls.radius.size))
    notes = (f"{balls.unheld.size} flexible vertices held by no ball inside the body at every pose checked: "
             "balls on the skin there hold it",) if balls.unheld.size else ()
    return ColliderSet(hulls=tuple(hulls), spheres=spheres, delta=float(delta), min_triangles=int(min_triangles),
                       flexible="balls", notes=notes, balls=balls)


CORE_POSES = 60   # poses a swept hull's core points are checked at (evenly spread over the motion)


def core_points(character: Character, parts: list, poses: np.ndarray, skinned: np.ndarray, body) -> list:
    """Per swept part (joint, bone b, vertices): (k, 3) points in b's frame on b and on its parent's
    bone near the part (swept.bone_core) that stay inside the skinned body at the bind pose and at
    every pose (at most CORE_POSES of them, evenly spread). A swept hull of a patch of skin reaches
    down to them, so the hulls of neighbouring patches meet inside the body instead of leaving a
    hollow at a joint (CesiumMan's pelvis: 165 of 24,836 interior samples 3.5 cm deep under no
    collider); a bone point that the skin leaves at some pose would carry the hull out of the body.
    `body`: stages.geometry.skin_distance.SkinDistance (refitted to the bind pose on return)."""
    from stages.hulls import swept
    local, owner = [], []
    for k, (_, b, idx) in enumerate(parts):
        c = swept.bone_core(character, b, idx)
        a = int(character.parents[b])
        if a >= 0:
            c = np.concatenate([c, swept.bone_core(character, a, idx)])
        c = c[body.inside(c)] if c.size else c
        local.append(transform_points(character.inverse_bind[b], c))
        owner.append(np.full(c.shape[0], b, np.int64))
    pts = np.concatenate(local) if local else np.zeros((0, 3))
    bones = np.concatenate(owner) if owner else np.zeros(0, np.int64)
    keep = np.ones(pts.shape[0], bool)
    from stages.hulls.balls import check_pose_indices
    for f in check_pose_indices(poses.shape[0], CORE_POSES):
        body.refit(skinned[f])
        m = poses[f, bones]
        world = np.einsum("nij,nj->ni", m[:, :3, :3], pts) + m[:, :3, 3]
        keep &= body.inside(world)
    body.refit(character.vertices)
    out, start = [], 0
    for c in local:
        out.append(pts[start:start + c.shape[0]][keep[start:start + c.shape[0]]])
        start += c.shape[0]
    return out


def fit_character(character: Character, poses: np.ndarray | None, *, split: str = "motion",
                  flexible: str = "balls", delta: float = 0.01, motion_tolerance: float = 0.5,
                  rigid_threshold: float = 0.9, min_triangles: int = 40,
                  max_offset: float | None = 0.005, sweep_poses: np.ndarray | None = None,
                  progress=None) -> tuple[RegionSplit, ColliderSet]:
    """Region split and colliders in one call: (split, colliders).

    split 'motion' (rigid within motion_tolerance * delta of its bind position in its bone's frame
    over `poses`) or 'weights' (dominant weight >= rigid_threshold, the paper); flexible 'balls'
    (skinned balls, stages/hulls/balls.py), 'swept' or 'sphere' (the paper). poses: (F, J, 4, 4) joint transforms of the motion sample (needed unless
    split='weights' and flexible='sphere'). sweep_poses: the poses swept hulls are fitted over
    (default: poses); a static scene splits on a range-of-motion sample but sweeps only its frames."""
    from stages.rig.motion_range import bone_deviation
    from stages.rig.regions import split_by_motion, split_regions
    deviation = None
    if split == "motion" or flexible in ("swept", "balls"):
        if poses is None:
            raise ContractError(f"fit_character: split={split!r} / flexible={flexible!r} need the motion's poses")
        deviation = bone_deviation(character, poses)
    if split == "motion":
        regions = split_by_motion(character, deviation, motion_tolerance * delta)
    elif split == "weights":
        regions = split_regions(character, threshold=rigid_threshold)
    else:
        raise ContractError(f"fit_character: split must be 'motion' or 'weights', got {split!r}")
    colliders = fit_colliders(character, regions, delta=delta, min_triangles=min_triangles, max_offset=max_offset,
                              flexible=flexible, poses=poses if sweep_poses is None else sweep_poses,
                              deviation=deviation, progress=progress)
    return regions, colliders


def fit_report_totals(colliders: ColliderSet) -> dict:
    """Character totals of the hull fit reports (faces summed, volumes in m^3, distances in m)."""
    reps = [h.report for h in colliders.hulls]
    return {
        "hulls": len(reps),
        "spheres": len(colliders.spheres),
        "faces_raw": int(sum(r.faces_raw for r in reps)),
        "faces_inflated": int(sum(r.faces_inflated for r in reps)),
        "faces_simplified": int(sum(r.faces_simplified for r in reps)),
        "volume_raw": float(sum(r.volume_raw for r in reps)),
        "volume_simplified": float(sum(r.volume_simplified for r in reps)),
        "excess_volume": float(sum(r.excess_volume for r in reps)),
        "hausdorff_max": float(max((r.hausdorff for r in reps), default=0.0)),
        "all_contained": bool(all(r.contains_region for r in reps)),
        "worst_violation": float(max((r.worst_violation for r in reps), default=-np.inf)),
        "sphere_volume": float(sum(4.0 / 3.0 * np.pi * s.radius ** 3 for s in colliders.spheres)),
    }
