"""What the simulated cloth says about itself: the speed limit's work (`speed_limit_note`), cloth let
go of the limbs that tore it (`release_note`), what holds
its most strained edges (`strain_source_notes`), and whether it blew up (`check_blown_up`).

Cloth that blew up without going fast: the simulation stops a particle faster than its speed
limit (stages.sim), but with the limit on, a step far too long (dt: 1) stretches the cloth instead:
17,832 % edge strain and 78 m below the floor, and the run ended 'ok'. After the simulation these
bounds are checked per frame; past either, the run is labelled diverged exactly as a fast particle
is (SimulationDiverged: exit 2, a sweep row 'diverged', the recording's meta/diverged).
"""
from __future__ import annotations

import numpy as np

from stages.garments.types import STRETCH
from stages.sim import SimulationDiverged

MAX_STRAIN = 5.0          # an edge 6 times its reference length: cloth stretches by tens of per cent
FAR_HEIGHTS = 5.0         # a particle this many body heights from the body's box (and at least FAR_MIN)
FAR_MIN = 5.0             # m


class ClothBlewUp(SimulationDiverged):
    """SimulationDiverged by strain or distance (the message says which bound, where and by how much;
    `torn_by` can add what tore it)."""

    def __init__(self, frame: int, garment: str, particle: int, what: str, partial=None):
        super().__init__(frame, [particle], [garment], float("nan"), partial=partial)
        self.args = (f"simulation diverged at frame {frame}: garment {garment!r} {what}",)


def _edges(triangles: np.ndarray) -> np.ndarray:
    e = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    return np.unique(np.sort(e, axis=1), axis=0)


def check_blown_up(result, body_world: np.ndarray, height: float, garments=None) -> ClothBlewUp | None:
    """The first frame where a garment's edge is more than MAX_STRAIN longer than its reference, or a
    particle is farther than max(FAR_MIN, FAR_HEIGHTS x height) from the box of the body
    (`body_world`: (F, V, 3) skinned vertices plus root translation) at that frame; else None.

    An edge's reference is its frame-0 length, or, given the simulated `garments` (same order as
    result.garments), the longer of that and its rest length: sewing can leave an edge crushed
    (GarmentCode's dress_s1001 on CesiumMan: 0.07 mm at frame 0 for a 23.4 mm rest), and its return
    to its own length read as an edge stretched 17,955 %, the run stopped as diverged."""
    lo, hi = body_world.min(axis=1), body_world.max(axis=1)          # (F, 3) the body's box per frame
    far = max(FAR_MIN, FAR_HEIGHTS * height)
    worst = None
    for k_g, track in enumerate(result.garments):
        x = np.asarray(track.positions, np.float64)                   # (F, N, 3)
        if garments is None:
            e = _edges(np.asarray(track.triangles))
            rest = np.linalg.norm(x[0, e[:, 0]] - x[0, e[:, 1]], axis=1)
        else:                   # the stretch springs are the triangles' edges, with their rest lengths
            stretch = garments[k_g].kinds == STRETCH
            e = garments[k_g].springs[stretch]
            rest = np.maximum(np.linalg.norm(x[0, e[:, 0]] - x[0, e[:, 1]], axis=1),
                              garments[k_g].rest_lengths[stretch])
        ok = rest > 1e-9
        n = min(len(x), len(lo))
        for f in range(n):
            length = np.linalg.norm(x[f, e[ok, 0]] - x[f, e[ok, 1]], axis=1)
            strain = length / rest[ok] - 1.0
            k = int(np.argmax(strain)) if strain.size else 0
            out = np.maximum(np.maximum(lo[f] - x[f], x[f] - hi[f]), 0.0)
            d = np.linalg.norm(out, axis=1)
            j = int(np.argmax(d))
            found = None
            if strain.size and strain[k] > MAX_STRAIN:
                found = (f, track.name, int(e[ok][k, 0]), f"has an edge stretched {strain[k] * 100:,.0f} % "
                                                          f"(bound {MAX_STRAIN * 100:.0f} %)")
            elif d[j] > far:
                found = (f, track.name, j, f"particle {j} is {d[j]:.1f} m from the body (bound {far:.1f} m)")
            if found:
                if worst is None or found[0] < worst[0]:
                    worst = found
                break
    return None if worst is None else ClothBlewUp(*worst, partial=result)


def torn_by(blown: ClothBlewUp, garments, result, colliders, character, motion, ignored=None) -> str | None:
    """What tore the cloth, for the message of a run stopped by the strain bound: the joints whose
    colliders the torn edges (over MAX_STRAIN at the frame, against their rest length) touch
    (stages.sim.strain_sources), and, where one of them is a limb, what lets it pass. None when no
    edge is over the bound against its rest length or none touches a collider. ignored: per garment,
    the joints its ignore_colliders already names (simulate's ignore_colliders): never suggested again
    (a limb already passing through the cloth did not tear it; CesiumMan with a GarmentCode shirt sampled
    for another body was told to ignore the forearm it already ignored)."""
    from stages.rig.humanoid import limb_joint_sets
    from stages.sim.strain_sources import strain_sources
    names = [g.name for g in garments]
    if colliders is None or blown.garment_names[0] not in names:
        return None
    k, f = names.index(blown.garment_names[0]), blown.frame
    g, track = garments[k], result.garments[k]
    sel = g.kinds == STRETCH
    e, rest = g.springs[sel], g.rest_lengths[sel]
    x, poses = _at_frame(track, f, colliders, character, motion)
    strain = np.linalg.norm(x[e[:, 0]] - x[e[:, 1]], axis=1) / np.maximum(rest, 1e-12) - 1.0
    torn = strain > MAX_STRAIN
    if not torn.any():
        return None
    shares = strain_sources(x, e[torn], strain[torn], colliders, poses, top=1.0)
    if not shares:
        return None
    limbs = set().union(*limb_joint_sets(character).values()) - _covered(track, colliders, character, motion)
    limbs -= set(ignored[k] if ignored else ()) | set(getattr(g, "passing_joints", ()))
    named = ", ".join(character.joint_names[j] for j in list(shares)[:4])
    hint = f"{int(torn.sum())} torn edge(s) on the colliders of {named}"
    moving = [character.joint_names[j] for j in shares if j in limbs][:2]
    if moving:
        hint += (f": a limb tearing the cloth against the body; ignore_colliders: [{', '.join(moving)}] "
                 f"in garment {g.name!r} lets it pass through the garment instead")
    return hint


COVER_REACH = 0.02    # m: a particle this near a limb's collider at frame 0 is round that limb
COVER_SHARE = 0.05   # a garment with this share of its particles round a limb covers it (a sleeve)


def _at_frame(track, f: int, colliders, character, motion) -> tuple:
    """(x (N, 3) float64, poses): a garment track's positions at frame f in the colliders' frame (the
    relative frame) and the colliders' poses there (ColliderSet.frame_poses; None without colliders)."""
    x = np.asarray(track.positions[f], np.float64) - motion.root_translation[f]
    poses = colliders.frame_poses(character.inverse_bind, motion.joint_world[f]) if colliders is not None else None
    return x, poses


def _covered(track, colliders, character, motion) -> set:
    """The joints whose colliders a share COVER_SHARE of the track's particles are within COVER_REACH of
    at frame 0: limbs the garment is worn round (a sleeve's arm), which ignore_colliders must not name."""
    from stages.sim.strain_sources import collider_distances
    x0, poses0 = _at_frame(track, 0, colliders, character, motion)
    d, owner = collider_distances(colliders, poses0, x0)
    return {int(j) for j in np.unique(owner) if (d[owner == j].min(axis=0) < COVER_REACH).mean() >= COVER_SHARE}


def release_note(result) -> str | None:
    """A warning naming the frames where cloth a limb tore was let go of it (SimParams.limb_release), or None."""
    got = np.asarray(result.released if result.released is not None else [], np.int64)
    hit = np.flatnonzero(got > 0)
    if hit.size == 0:
        return None
    f = int(hit[np.argmax(got[hit])])
    return (f"simulation: cloth a limb stretched over {result.params.limb_release * 100:.0f} % was let go of it "
            f"(simulation.limb_release) in {hit.size} frame(s) from frame {int(hit[0])}, most at frame {f} "
            f"({int(got[f])} particles): the limb passes through the cloth there until it is out of it")


def speed_limit_note(result) -> str | None:
    """A warning naming the frames where the speed limit acted, or None."""
    hit = np.flatnonzero(result.speed_limited[1:] > 0) + 1
    if hit.size == 0:
        return None
    f = int(hit[np.argmax(result.speed_limited[hit])])
    return (f"simulation: the speed limit ({result.params.speed_limit:.1f} m/s, simulation.speed_limit) capped cloth "
            f"in {hit.size} frame(s), most at frame {f} ({int(result.speed_limited[f])} particles): cloth thrown "
            "by a collider (a limb pressing it onto the body)")


def strain_source_notes(audit, garments, result, colliders, character, motion) -> tuple[str, ...]:
    """For each garment whose p99 strain goes over the limit: the joints whose colliders its most
    strained edges touch at its worst frame (stages.sim.strain_sources), one line each."""
    from stages.garments.types import STRETCH
    from stages.sim.audit import STRAIN_P99_LIMIT, edge_strains
    from stages.sim.strain_sources import TOP_SHARE, TOUCH, strain_sources
    out = []
    for g, track, ga in zip(garments, result.garments, audit.garments):
        if ga.strain_p99.max(initial=0.0) <= STRAIN_P99_LIMIT:
            continue
        f = int(np.argmax(ga.strain_p99))
        sel = g.kinds == STRETCH
        x, poses = _at_frame(track, f, colliders, character, motion)
        strain = edge_strains(x[None], g.springs[sel], g.rest_lengths[sel])[0]
        shares = strain_sources(x, g.springs[sel], strain, colliders, poses)
        if shares:
            named = ", ".join(f"{character.joint_names[j]} {100 * s:.0f} %" for j, s in list(shares.items())[:4])
            out.append(f"garment {g.name!r}: at frame {f} its {100 * TOP_SHARE:.0f} % most strained edges touch "
                       f"(within {1000 * TOUCH:.0f} mm) the colliders of {named}")
    return tuple(out)
