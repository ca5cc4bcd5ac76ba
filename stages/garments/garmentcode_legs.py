"""Trouser legs kept apart once sewn: each leg's cloth below the crotch on its own side of the
vertical plane halfway between the character's legs.

Wide trouser legs (GarmentCode's js_mean_all, a jumpsuit) are tubes wider than half the space between
the legs. Wrapped round each leg (garmentcode_wrap.wrap_legs) they overlap in the middle, and sewing
leaves the two inner sides through each other (js_mean_all on the built-in character: 209 edges of
one leg through the other after sewing, from the ankles to the crotch, and the simulation keeps
crossings it starts with to the last frame). Flattening them against the plane as placed does not
last: untangling the placed panels and sewing them pulled them through each other again. With every
vertex of one leg on one side of a plane and every vertex of the other on the other side, no edge of
one can pass through a triangle of the other.

Frames: the character's relative frame at frame 0 (metres, Y up).
"""
from __future__ import annotations

import numpy as np

from stages.garments.garmentcode import GCPattern, panel_part

LEG_GAP = 0.005    # m: a leg's cloth keeps this far to its side of the plane between the legs


def leg_axes(character, origins: np.ndarray) -> dict:
    """{side: (2, 3) hip and ankle joint positions} of the character's two legs (side +1: the one at
    larger x than the root, whatever the rig calls it); {} without two leg chains of three joints.
    Also the legs of garmentcode_place.body_map."""
    from stages.rig.humanoid import limb_chain
    root = origins[character.root_joint]
    out = {}
    for s in ("l", "r"):
        chain = limb_chain(character, "leg", s)
        if chain and len(chain) >= 3:
            q = origins[[chain[0], chain[2]]].astype(np.float64)
            out[1.0 if q[0, 0] >= root[0] else -1.0] = q
    return out if len(out) == 2 else {}


def vertex_sides(gc: GCPattern, placed: np.ndarray, panel_of_vertex: np.ndarray, root_x: float) -> np.ndarray:
    """(N,) +1 / -1 for the placed vertices (N, 3) of a panel that is not a sleeve and lies on one side
    of the character: its vertices at most 2 cm past the root's x the other way, or, for a panel
    labelled `leg`, 80 % of them on its side (a sampled pair of wide pants was placed 3.2 cm over the
    middle; GarmentCode labels a skirt's front and back `leg` too, and they lie across it); 0
    elsewhere."""
    out = np.zeros(len(placed))
    for i, p in enumerate(gc.panels):
        x = placed[panel_of_vertex == i, 0] - root_x
        if panel_part(p) == "arm" or not x.size:
            continue
        side = 1.0 if float(np.mean(x)) >= 0 else -1.0
        if float((side * x).min()) > -0.02 or panel_part(p) == "leg" and float(np.mean(side * x > 0)) >= 0.8:
            out[panel_of_vertex == i] = side
    return out


def below_sides(side: np.ndarray, placed: np.ndarray, panel_of_vertex: np.ndarray, pairs: np.ndarray,
                crotch: float) -> np.ndarray:
    """`side` with the panels wholly below the crotch that have none given the side of the panels they
    are stitched to, when those are all of one side (repeated down a chain): a leg's cuff and the
    flared ruffle sewn under it, wider than the space between the legs (the sampled jumpsuit's crossed
    the other leg's between the ankles). A panel sewn to both sides (a skirt's front) keeps none."""
    side = side.copy()
    n = int(panel_of_vertex.max()) + 1
    of = np.array([side[panel_of_vertex == k][0] if (panel_of_vertex == k).any() else 0.0 for k in range(n)])
    low = np.array([(panel_of_vertex == k).any() and placed[panel_of_vertex == k, 1].max() < crotch for k in range(n)])
    pa, pb = panel_of_vertex[pairs[:, 0]], panel_of_vertex[pairs[:, 1]]
    changed = True
    while changed:
        changed = False
        for k in np.flatnonzero(low & (of == 0)):
            near = {float(of[j]) for j in np.r_[pb[pa == k], pa[pb == k]] if j != k and of[j] != 0}
            if len(near) == 1:
                of[k] = near.pop()
                side[panel_of_vertex == k] = of[k]
                changed = True
    return side


def crotch_height(placed: np.ndarray, pairs: np.ndarray, side: np.ndarray) -> float | None:
    """The lowest placed height (m) of a seam pair joining a left leg panel to a right one (the
    crotch); None when no seam joins the two legs."""
    cross = (side[pairs[:, 0]] * side[pairs[:, 1]]) < 0
    if not cross.any():
        return None
    return float(placed[pairs[cross].ravel(), 1].min())


def legs_apart(pos: np.ndarray, remap: np.ndarray, side: np.ndarray, axes: dict, crotch: float) -> np.ndarray:
    """(M, 3) merged positions `pos` with each leg's vertices below `crotch` moved LEG_GAP onto their
    own side of the plane halfway between the leg axes (`axes`, leg_axes) at their height. remap: (N,)
    merged index of each unsewn vertex; side: (N,) its leg side (vertex_sides); a merged vertex whose
    unsewn vertices disagree (the crotch seam) is left where it is."""
    if not axes:
        return pos
    m = pos.shape[0]
    lo = np.full(m, np.inf)
    hi = np.full(m, -np.inf)
    np.minimum.at(lo, remap, side)
    np.maximum.at(hi, remap, side)
    merged = np.where(lo == hi, lo, 0.0)
    out = np.array(pos, np.float64)
    for s in (1.0, -1.0):
        sel = np.flatnonzero((merged == s) & (out[:, 1] < crotch))
        if sel.size:
            y = out[sel, 1]
            out[sel] = keep_side(out[sel], _axis_at(axes[s], y), _axis_at(axes[-s], y))
    return out


def _axis_at(q: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(K, 3) the point of the axis from q[0] (hip) to q[1] (ankle) at heights y (K,) (clamped)."""
    a, b = q
    t = np.clip((y - a[1]) / (b[1] - a[1]), 0.0, 1.0) if abs(b[1] - a[1]) > 1e-6 else np.zeros_like(y)
    return a + t[:, None] * (b - a)


def apart(gc: GCPattern, placed: np.ndarray, flat, pos: np.ndarray, remap: np.ndarray, character,
          origins: np.ndarray) -> np.ndarray:
    """The sewn garment's merged positions `pos` with its trouser legs kept apart (legs_apart); as they
    are for a garment without two legs sewn together at a crotch, or a character without two legs.
    placed: (N, 3) the panels as placed (flat: their FlatPattern); remap: (N,) merged index."""
    axes = leg_axes(character, origins)
    if not axes:
        return pos
    side = vertex_sides(gc, placed, flat.panel_of_vertex, float(origins[character.root_joint][0]))
    crotch = crotch_height(placed, flat.seam_pairs, side)
    if crotch is None:
        return pos
    side = below_sides(side, placed, flat.panel_of_vertex, flat.seam_pairs, crotch)
    return legs_apart(pos, remap, side, axes, crotch)


def keep_side(x: np.ndarray, own: np.ndarray, other: np.ndarray, gap: float = LEG_GAP) -> np.ndarray:
    """(K, 3) points `x` moved horizontally to at least `gap` on their own side of the vertical plane
    halfway between `own` and `other` (K, 3), the two legs' axis points at each point's height."""
    n = own - other
    n[:, 1] = 0.0
    length = np.linalg.norm(n, axis=1, keepdims=True)
    if not np.all(length > 1e-6):
        return x
    n = n / length
    d = np.einsum("ij,ij->i", x - 0.5 * (own + other), n)
    return x + np.maximum(gap - d, 0.0)[:, None] * n
