"""Keeping a dressed garment apart from itself and from the garments worn under it.

Sewing has no cloth x cloth collision, and the simulation's cloth phase can only keep cloth apart
that starts apart (its fail-safe reverts to a crossing-free start). So dressing starts the garments
apart geometrically:
- `separate_legs`: a two-legged garment's legs each on their own side of the plane between the
  thighs (tubes wrapped around close thighs met and passed through each other at that plane);
- a garment worn over others is moved out along rays from the body's vertical axis beyond them
  (`over.push_over`, OVER_CLEARANCE), far enough that their folds do not poke through it.
"""
from __future__ import annotations

import numpy as np

LEG_GAP = 0.003     # m: each leg's inner side stays this far from the plane between the thighs
LEG_SQUEEZE = 0.03  # m: a leg's vertices nearer the plane than this are squeezed towards their side
# m beyond the farthest hit on a garment worn under it, over the cloth gap: at the gap alone (7 mm)
# the folds of the bvh shorts poked through the T-shirt worn over them between its vertices (102
# edges through each other, as many as dressed independently: 245); 1 cm left 8 (the first
# simulated frames sort those); 2 cm none, but the tucked skirt, held 2.7 cm off the T-shirt, then
# ended the built-in walk at p99 strain 11.6 % (1 cm: 8.4 %)
OVER_CLEARANCE = 0.01


def leg_plane(character, origins: np.ndarray):
    """(point (3,), unit normal (3,) towards the wearer's left leg) of the vertical plane halfway
    between the thighs' upper joints (bind pose `origins` (J, 3)); None without two legs."""
    from stages.rig.humanoid import humanoid_joints, limb
    hj = humanoid_joints(character)
    legs = [limb(character, "leg", s, hj) for s in ("l", "r")]
    if None in legs:
        return None
    # each leg's upper joint: a chain's hip, a one-joint leg's only joint (its upper point)
    a, b = origins[legs[0].joints[0]], origins[legs[1].joints[0]]
    n = np.array([a[0] - b[0], 0.0, a[2] - b[2]])
    ln = float(np.linalg.norm(n))
    if ln < 1e-6:
        return None
    return 0.5 * (a + b), n / ln


def separate_legs(positions: np.ndarray, left: np.ndarray, right: np.ndarray, plane, gap: float = LEG_GAP) -> np.ndarray:
    """(N, 3) positions with each vertex of `left` (indices, the left leg's) at least `gap` on the
    left of `plane` (leg_plane), each of `right` on the right; vertices in both (a crotch seam
    welded) and the others as they are. Moves along the plane's normal only, keeping the vertices'
    order along it: the distances d < LEG_SQUEEZE of a leg's vertices map linearly from
    [their least, LEG_SQUEEZE] onto [gap, LEG_SQUEEZE] (flattened onto the plane, the tube's near
    and far sides met there and folded through each other)."""
    p = np.array(positions, np.float64)
    if plane is None:
        return p
    m, n = plane
    both = np.intersect1d(left, right)
    for idx, sign in ((np.setdiff1d(left, both), 1.0), (np.setdiff1d(right, both), -1.0)):
        d = sign * ((p[idx] - m) @ n)
        lo = float(d.min(initial=np.inf))
        if lo >= gap:
            continue
        low = d < LEG_SQUEEZE
        moved = gap + (d[low] - lo) * (LEG_SQUEEZE - gap) / (LEG_SQUEEZE - lo)
        p[idx[low]] += np.outer(sign * (moved - d[low]), n)
    return p
