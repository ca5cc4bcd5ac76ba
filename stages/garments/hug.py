"""Bands brought onto the body: a waistband, a collar or a cape's top walked in towards the body
until the colliders or the skin stop it (`hug`), and a pinned band's vertices spaced along where it
ended as on the pattern (`respace`); the band's rest lengths cut to that loop (`band_rest`) and its
panel gathered below it where it is much shorter than cut (`gather_below`)."""
from __future__ import annotations

import numpy as np

from stages.garments.placement import UNDER_REACH, near_colliders

HUG_GAP = 0.004    # m: a hugged band stays this far outside the colliders
HUG_STEP = 0.002   # m: radial search step


def respace(points: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(K, 3) the vertices of a run (in order, `points` on a polyline, e.g. a hugged band) moved along
    that polyline so that their spacing is proportional to their pattern spacing (uv (K, 2)); the
    ends stay. Hugged along rays to the body's axis, a band's vertices crowd where the body is flat
    and spread where it is round (0.55-1.2 x their placed spacing on the bvh shorts), and pinned
    there the spread edges stayed stretched (up to 33 %)."""
    p = np.asarray(points, np.float64)
    if p.shape[0] < 3:
        return p.copy()
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    f = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(np.asarray(uv, np.float64), axis=0), axis=1))])
    if s[-1] <= 0.0 or f[-1] <= 0.0:
        return p.copy()
    want = f / f[-1] * s[-1]
    return np.stack([np.interp(want, s, p[:, k]) for k in range(3)], axis=1)


def hug(points: np.ndarray, targets: np.ndarray, character, skinned: np.ndarray, bind, gap: float = HUG_GAP,
        under: np.ndarray | None = None, under_gap: float = 0.0, through_arms: bool = False) -> np.ndarray:
    """(N, 3) `points` (a waistband, a collar) each moved on the straight line towards its target
    (N, 3) as far as it stays `gap` outside every collider and outside the body: walking in from where
    it was placed, it stops before the first blocked position (and never passes its target). A band
    wrapped around an ellipse that contains the body's cross-section stands off a boxy section by
    centimetres; this brings it onto the colliders.

    under: optional (M, 3) points on the garments worn under this one (triangle_grid_points): positions
    closer than under_gap to one are blocked too, and the walk of a point with one within UNDER_REACH
    starts UNDER_REACH farther out, so the band ends outside what it is worn over (a waistband over a
    tucked-in shirt) where the placement put it inside.

    through_arms: the arms (bind.arm_joints) do not block the walk, neither their colliders nor the
    skin inside them: a waistband hugs the trunk. A chibi's arms stand out from its waist in the bind
    pose; stopped by them, its skirt's waistband was hugged round the arms' roots, 0.59 m wide on a
    0.3 m waist, and the skirt started stretched (p99 60 %). The legs still block it: a waistband
    sits over the thighs' tops."""
    from scipy.spatial import cKDTree

    from stages.garments.band import collider_list as _collider_list
    from stages.geometry.winding import winding_number
    p = np.asarray(points, np.float64)
    d = np.asarray(targets, np.float64) - p
    length = np.linalg.norm(d, axis=1)
    has_under = under is not None and len(under) > 0 and p.shape[0] > 0
    if has_under:
        tree = cKDTree(np.asarray(under, np.float64))
        # points with a garment under them within reach start farther out (the others as placed)
        near = tree.query(p, distance_upper_bound=UNDER_REACH + under_gap)[0] < np.inf
        p = p - (UNDER_REACH * near / np.maximum(length, 1e-12))[:, None] * d
        d = np.asarray(targets, np.float64) - p
        length = np.linalg.norm(d, axis=1)
    if p.shape[0] == 0 or length.max(initial=0.0) < HUG_STEP:
        return p.copy()
    steps = np.arange(0.0, length.max(), HUG_STEP)                  # moves tried, m
    s = np.minimum(steps[:, None], length[None, :])                 # (S, N)
    cand = p[None] + (s / np.maximum(length, 1e-12)[None, :])[..., None] * d[None]
    flat = cand.reshape(-1, 3)
    arms = bind.arm_joints if through_arms and bind is not None else frozenset()
    inside_skin = winding_number(skinned, character.triangles, flat) >= 0.5
    if arms:
        every = {int(c[0]) for c in _collider_list(bind.colliders)} if bind.colliders is not None else set()
        on_arm = near_colliders(bind, flat, gap, joints=arms)
        blocked = near_colliders(bind, flat, gap, joints=every - arms) | (inside_skin & ~on_arm)
        on_arm = on_arm.reshape(s.shape)
    else:
        blocked = near_colliders(bind, flat, gap) | inside_skin
    if has_under:
        blocked |= tree.query(flat, distance_upper_bound=under_gap)[0] < under_gap
    blocked = blocked.reshape(s.shape)
    blocked[-1] = True                                              # never past the target
    first = np.argmax(blocked, axis=0)                              # first blocked step per point
    if arms:
        # an arm is walked through only where it joins the trunk on the way in (the walk never
        # leaves arm or trunk between them: a chibi's arm block); an arm with free space between
        # it and the trunk (a forearm hanging beside the hips) stops the walk, as any collider does
        stop = on_arm | blocked
        at_arm = np.argmax(stop, axis=0)
        step = np.arange(s.shape[0])[:, None]
        free_between = ((step >= at_arm) & (step < first) & ~stop).any(axis=0)
        first = np.where(free_between, at_arm, first)
    k = np.maximum(first - 1, 0)
    return cand[k, np.arange(p.shape[0])]


GATHER_FROM = 0.8    # a band hugged shorter than this share of its cut length is gathered into its panel


def gather_below(tri: np.ndarray, tri_rest: np.ndarray, uv: np.ndarray, run: np.ndarray, placed: np.ndarray,
                 panel_of_vertex: np.ndarray) -> None:
    """In place: where a fit edge (`run`, its vertices in order) is hugged to less than GATHER_FROM of
    its cut length, its panel's rest shape is gathered to that length along it, easing back to the
    cut `GATHER_BAND` into the panel (gather.ease: a flat fan, which a top walked towards a point is; the metric gathering of seams, gather.gathered_lengths, left the chibi cape at p99 5.7 % against 1.8 %): a cape's
    top walked onto a chibi's neck ends a third shorter than cut, and the edges from it to the row
    below stayed compressed at every frame (p99 |strain| 11-21 %). Used for bands walked towards a
    point (a cape's top onto the neck's base); a chibi's skirt waist, walked to the body's axis, ends
    at 0.74-0.77 of its cut and gathered so its skirt drapes worse (idle long skirt p99 6.4 -> 19.3 %,
    11 crossings)."""
    from stages.garments.gather import GATHER_BAND, ease
    if len(run) < 3:
        return
    cut = float(np.linalg.norm(np.diff(uv[run], axis=0), axis=1).sum())
    hugged = float(np.linalg.norm(np.diff(placed[run], axis=0), axis=1).sum())
    if not (cut > 0.0 and hugged < GATHER_FROM * cut):
        return
    verts = np.flatnonzero(panel_of_vertex == panel_of_vertex[run[0]])
    x = np.array(uv, np.float64, copy=True)
    ease(x, run, verts, hugged / cut, GATHER_BAND)
    own = np.isin(tri, verts).all(axis=1)
    tri_rest[own] = np.linalg.norm(x[tri[own][:, [1, 2, 0]]] - x[tri[own]], axis=2)


def band_rest(tri: np.ndarray, tri_rest: np.ndarray, run: np.ndarray, placed: np.ndarray, factor: float) -> None:
    """In place: the rest length of every triangle edge joining consecutive vertices of `run` (a
    fit edge's vertices in order) becomes `factor` times its placed (hugged) length, never longer
    than the pattern's (where the hug stretched the band around a collider, a rest length that long
    held the band's end away from its seam: 8.9 mm open on CesiumMan's walk pose)."""
    n = placed.shape[0]
    want = {}
    for a, b in zip(run[:-1], run[1:]):
        want[min(a, b) * n + max(a, b)] = factor * float(np.linalg.norm(placed[a] - placed[b]))
    for k in range(3):
        a, b = tri[:, k], tri[:, (k + 1) % 3]
        code = np.minimum(a, b) * n + np.maximum(a, b)
        for t in np.flatnonzero(np.isin(code, list(want))):
            tri_rest[t, k] = min(max(want[int(code[t])], 1e-4), tri_rest[t, k])
