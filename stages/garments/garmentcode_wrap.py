"""The wrap of GarmentCode panels round the body before sewing (garmentcode_place): GarmentCode
places its panels flat, a few centimetres in front of, behind and beside its body, and lets its
simulator pull the stitches together; here upright panels are first bent round the body's vertical
axis (a ring whose circumference is the panels' width at each height), circle-skirt sectors hung as a
cone round it, and sleeve panels bent round the arm's axis, so that the seams start (nearly) closed
and the sewing does not drag cloth across the body.

Frames: the pattern body's (metres, Y up, floor at 0, facing +Z, centred on x = 0).
"""
from __future__ import annotations

import math

import numpy as np

from stages.garments.garmentcode import GCPattern, edge_points, panel_part

WRAP_BIN = 0.02   # m: height bins of the wrap's ring widths
FACING_COS = 0.7   # panels whose horizontal normals are within ~45 degrees face one way (one group)


MAX_APEX = 1.0   # m: a top arc of a larger radius (a waistband's slight curve) is wrapped as a cylinder
MIN_SPAN = math.radians(45)   # a sector narrower than this (a curved waistband piece) too
RING_DY = 0.03   # m: cone panels whose top edges are this close in height hang as one cone
WAIST_DY = 0.005   # m: a cone panel's waist arc has its ends this near the panel's top


def cone_apex(p) -> tuple | None:
    """(apex (2,) panel uv, angle the panel spans about it (rad), the waist edge's height in the body
    frame (m), the waist edge's index) when the panel is a sector of an annulus hung from its inner
    arc (a circle or flare skirt's waist, made to hang as a cone): a circle-arc edge whose ends are
    the panel's highest points (within WAIST_DY), whose centre lies above it, and no vertex of the
    panel nearer that centre than the arc; else None. (A half-circle sector's straight sides are as
    high as the waist arc's ends: the highest edge alone does not tell the waist.)"""
    from stages.garments.garmentcode import arc_center
    ys = p.to_3d(p.vertices)[:, 1]
    for k, e in enumerate(p.edges):
        if e.kind != "circle" or min(ys[e.start], ys[e.end]) < ys.max() - WAIST_DY:
            continue
        c, r, _ = arc_center(p.vertices[e.start], p.vertices[e.end], e.radius, e.large_arc, e.right)
        mid = edge_points(p, e, [0.5])[0]
        if p.to_3d(c[None])[0, 1] <= p.to_3d(mid[None])[0, 1] + 1e-3:
            continue
        q = p.vertices - c
        if np.linalg.norm(q, axis=1).min() < r * (1.0 - 1e-3):
            continue
        span = float(np.ptp(np.unwrap(np.arctan2(q[:, 1], q[:, 0]))))
        if r > MAX_APEX or span < MIN_SPAN:
            return None
        return c, span, float(ys[[e.start, e.end]].mean()), k
    return None


def cone_rings(gc: GCPattern, cones: dict) -> dict:
    """{panel index: the cone panels (a set, itself included) that close one circle with it}: cone
    panels (cones: cone_apex by panel index) stitched to each other by edges other than their waist
    arcs (a skirt's side seams, not the waist nor a tier's seam to the one above), or whose top
    edges are within RING_DY in height. A dress's skirt front and back meet at side seams with their
    waists 5 cm apart in height; each closed a whole circle by itself, through the other."""
    index = {p.name: i for i, p in enumerate(gc.panels)}
    ring = {i: {i} for i in cones}

    def join(i, j):
        merged = ring[i] | ring[j]
        for k in merged:
            ring[k] = merged

    for i in cones:
        for j in cones:
            if i < j and abs(cones[i][2] - cones[j][2]) <= RING_DY:
                join(i, j)
    for st in gc.stitches:
        i, j = index[st.a[0]], index[st.b[0]]
        if i != j and i in cones and j in cones and st.a[1] != cones[i][3] and st.b[1] != cones[j][3]:
            join(i, j)
    return ring


def _cone(p, uv: np.ndarray, apex: np.ndarray, full: float, top: float) -> np.ndarray:
    """(N, 3) a sector panel's points hung as part of a cone round the body's axis: slant distance
    from the apex kept, the sectors of all cone panels (`full` rad in all) closing the circle; the
    waist edge stays at its placed height."""
    R = p.rotation
    down = (R.T @ np.array([0.0, -1.0, 0.0]))[:2]
    down /= np.linalg.norm(down)
    n = p.normal * np.array([1.0, 0.0, 1.0])
    n /= np.linalg.norm(n)
    t2 = (R.T @ np.array([n[2], 0.0, -n[0]]))[:2]
    sign = 1.0 if down[0] * t2[1] - down[1] * t2[0] > 0 else -1.0
    q = uv - apex
    rho = np.linalg.norm(q, axis=1)
    theta = np.arctan2(down[0] * q[:, 1] - down[1] * q[:, 0], q @ down)
    share = min(full / (2 * np.pi), 0.95)
    apex_y = top + rho.min() * math.sqrt(1 - share * share)
    phi = math.atan2(n[0], n[2]) + sign * theta * (2 * np.pi / full)
    r = rho * share
    return np.c_[r * np.sin(phi), apex_y - rho * math.sqrt(1 - share * share), r * np.cos(phi)]


def panel_outlines(gc: GCPattern, to_frame=None, step: float = 0.005) -> list:
    """Each panel's outline (M, 3), sampled every `step` m or finer, in the pattern frame or the frame
    to_frame ((N, 3) -> (N, 3)) takes it to."""
    out = []
    for p in gc.panels:
        q = []
        for e in p.edges:
            n = max(2, int(np.ceil(np.ptp(edge_points(p, e, [0.0, 1.0]), axis=0).max() / step)) + 1)
            n = max(n, 33) if e.kind != "straight" else n
            q.append(edge_points(p, e, np.arange(n) / n))
        x = p.to_3d(np.concatenate(q))
        out.append(to_frame(x) if to_frame is not None else x)
    return out


def _spans(s: np.ndarray, y: np.ndarray, levels: np.ndarray) -> tuple:
    """(lo, hi) of the closed outline (lateral s, height y) across each level (inf, -inf where it
    does not reach)."""
    s0, s1, y0, y1 = s, np.roll(s, -1), y, np.roll(y, -1)
    L = levels[:, None]
    cross = ((y0 - L) * (y1 - L) <= 0) & (y0 != y1)
    at = s0 + (L - y0) / np.where(y0 != y1, y1 - y0, 1.0) * (s1 - s0)
    return np.where(cross, at, np.inf).min(axis=1), np.where(cross, at, -np.inf).max(axis=1)


def joined_panels(gc: GCPattern, to_frame=None) -> dict:
    """{frozenset((i, j)): [(low, high), ...]}: for each pair of panels a stitch joins side by side
    (i != j, both edges running more up than across: a centre-front, side or crotch seam, not a
    waist seam), the heights (m) its stitches span, in the pattern frame or the frame to_frame
    ((N, 3) -> (N, 3)) takes it to."""
    index = {p.name: i for i, p in enumerate(gc.panels)}
    t = np.linspace(0.0, 1.0, 9)
    out = {}
    for st in gc.stitches:
        if st.a[0] == st.b[0]:
            continue
        q = []
        for pn, k in (st.a, st.b):
            p = gc.panels[index[pn]]
            x = p.to_3d(edge_points(p, p.edges[k], t))
            q.append(to_frame(x) if to_frame is not None else x)
        if any(abs(x[-1, 1] - x[0, 1]) < np.linalg.norm((x[-1] - x[0])[[0, 2]]) for x in q):
            continue
        ys = np.concatenate([x[:, 1] for x in q])
        out.setdefault(frozenset((index[st.a[0]], index[st.b[0]])), []).append((float(ys.min()), float(ys.max())))
    return out


def wrap_ring(gc: GCPattern, points: list, body, uvs: list) -> list:
    """The pattern-frame positions `points` (one (N, 3) array per panel) with every panel that stands
    upright (horizontal normal, not an arm) bent round the body's vertical axis: at each height the
    upright panels together make a ring whose circumference is the sum of their widths there (at
    least the pattern body's girth + 6 cm), each panel keeping its lateral arc length and the side it
    faces; heights are re-spaced from the waist up and down so that distances down a flaring panel
    stay those of the flat panel (a flat circle-skirt panel held in a plane would have its waist seam
    a deep arc away from the waistband's). GarmentCode's own placement leaves the panels flat in
    front of and behind the body."""
    up = []
    for p, x in zip(gc.panels, points):
        n = p.normal
        up.append(panel_part(p) != "arm" and abs(n[1]) < 0.5 and len(x) > 0)
    cones = {i: c for i, c in ((i, cone_apex(p)) for i, p in enumerate(gc.panels) if up[i]) if c is not None}
    points = list(points)
    if cones:
        rings = cone_rings(gc, cones)
        for i, (apex, _, top, _) in cones.items():
            full = sum(cones[j][1] for j in rings[i])
            points[i] = _cone(gc.panels[i], uvs[i], apex, full, top)
            up[i] = False
    if not any(up):
        return points
    girth = lambda y: np.interp(y, [body.hips_y, body.waist_y, body.bust_y], [body.hips, body.waist, body.bust]) + 0.06
    normals = [p.normal for p in gc.panels]
    return _ring(points, normals, up, girth, body.waist_y, joined_panels(gc), panel_outlines(gc))


def _ring(points: list, normals: list, up: list, girth, anchor: float | None, joined=None,
          outlines=None, straight: bool = False) -> list:
    """The panels `up` of `points` wrapped round the y axis of their frame (normals: each panel's
    outward normal in it): circumference at each level = the sum of the panels' widths there, at
    least girth(level); with `anchor`, levels re-spaced from it along the ring's slant. joined:
    joined_panels of the points' frame: panels stitched to each other side by side.
    outlines: each panel's closed outline (M, 3) in the same frame (panel_outlines), for exact
    spans across at each level. straight: each group centred on one straight line across the levels
    (its levels' centres fitted, weighted by its width there) instead of at every level, and the widths
    taken from the outlines: a sleeve's halves whose cap or slanted cuff cuts levels short of its
    overarm seam were sheared there by their levels' centres (edges at 0.4-2.2x their length)"""
    joined = joined or {}
    ys = np.concatenate([x[:, 1] for x, u in zip(points, up) if u])
    edges = np.arange(ys.min() - WRAP_BIN, ys.max() + 2 * WRAP_BIN, WRAP_BIN)
    mid = 0.5 * (edges[:-1] + edges[1:])
    width = np.zeros(mid.size)
    lateral = []
    for i, (nrm, x, u) in enumerate(zip(normals, points, up)):
        if not u:
            lateral.append(None)
            continue
        n = np.asarray(nrm, np.float64) * np.array([1.0, 0.0, 1.0])
        n /= np.linalg.norm(n)
        t = np.array([n[2], 0.0, -n[0]])          # the direction of growing angle round the axis
        s = x @ t
        lateral.append((n, t, s))
        w = np.zeros(mid.size)
        if straight and outlines is not None:   # the outline's exact width: the mesh's rows miss up to an edge
            lo, hi = _spans(outlines[i] @ t, outlines[i][:, 1], mid)
        else:
            b = np.clip(np.digitize(x[:, 1], edges) - 1, 0, mid.size - 1)
            lo, hi = np.full(mid.size, np.inf), np.full(mid.size, -np.inf)
            np.minimum.at(lo, b, s)
            np.maximum.at(hi, b, s)
        have = np.isfinite(lo)
        w[have] = hi[have] - lo[have]
        if have.sum() >= 2:                          # fill bins between the panel's rows
            k = np.flatnonzero(have)
            inside = (np.arange(mid.size) > k[0]) & (np.arange(mid.size) < k[-1])
            w[inside & ~have] = np.interp(mid[inside & ~have], mid[have], w[have])
        width += w
    # each group of panels facing one way is centred on its direction at every level, and panels of
    # a group stitched to each other (`joined`) side by side there: GarmentCode lays a sleeve's
    # panels off the arm's axis (the sampled tee's front sleeve spans -32..+1 cm across it, its back
    # -1..+31 cm), which wrapped as they lie put both halves on the same side of the ring, through
    # each other (700 crossing edges on the placed tee); it lays a trouser's front halves 14 cm apart
    # at the waist (6.9..31 cm and -31..-6.9), which wrapped as they lie left the crotch seams 14 cm
    # open and the side seams 16 cm; gaps between panels not stitched together (a top's straps either
    # side of the neck) are kept
    facing = [(i, lat[0]) for i, lat in enumerate(lateral) if lat is not None]
    group = {}
    for i, n in facing:
        group[i] = next((group[j] for j, m in facing if j in group and float(n @ m) > FACING_COS), i)
    for g in set(group.values()):
        members = sorted((i for i in group if group[i] == g), key=lambda i: float(np.mean(lateral[i][2])))
        cur_hi, old_hi = np.full(mid.size, np.nan), np.full(mid.size, np.nan)
        prev = np.full(mid.size, -1)
        new_lo, new_hi, shifts = np.full(mid.size, np.inf), np.full(mid.size, -np.inf), {}
        for i in members:
            if outlines is not None:   # exact spans: 2 cm bins hold too few mesh vertices for seams to meet
                lo, hi = _spans(outlines[i] @ lateral[i][1], outlines[i][:, 1], mid)
            else:
                b = np.clip(np.digitize(points[i][:, 1], edges) - 1, 0, mid.size - 1)
                lo, hi = np.full(mid.size, np.inf), np.full(mid.size, -np.inf)
                np.minimum.at(lo, b, lateral[i][2])
                np.maximum.at(hi, b, lateral[i][2])
            have = np.isfinite(lo)
            stitched = np.zeros(mid.size, bool)   # levels where a stitch joins this panel to the last one
            for j in set(prev[have].tolist()) - {-1}:
                for y0, y1 in joined.get(frozenset((j, i)), ()):
                    stitched |= (prev == j) & (mid >= y0 - 1e-3) & (mid <= y1 + 1e-3)
            last = have & np.isfinite(cur_hi)
            lo_i = lo.copy()
            lo_i[last] = cur_hi[last] + np.where(stitched, 0.0, lo - old_hi)[last]
            shift = np.zeros(mid.size)
            shift[have] = lo_i[have] - lo[have]
            shifts[i] = (have, shift)
            new_lo[have] = np.minimum(new_lo[have], lo_i[have])
            new_hi[have] = np.maximum(new_hi[have], hi[have] + shift[have])
            cur_hi[have] = hi[have] + shift[have]
            old_hi[have] = hi[have]
            prev = np.where(have, i, prev)
        centre = np.zeros(mid.size)   # centred at every level: a sleeve cap's halves differ in shape
        some = np.isfinite(new_lo)
        centre[some] = 0.5 * (new_lo[some] + new_hi[some])
        if straight and some.sum() >= 2:
            centre = np.interp(mid, mid[some], _line(mid[some], centre[some], new_hi[some] - new_lo[some]))
        for i in members:
            n, t, s_i = lateral[i]
            have, shift = shifts[i]
            if have.any():
                lateral[i] = (n, t, s_i + np.interp(points[i][:, 1], mid[have], (shift - centre)[have]))
            else:   # no level of its own (a waistband lower than a bin, on a chibi): centred as the group there
                lateral[i] = (n, t, s_i - np.interp(points[i][:, 1], mid, centre))
    if straight:
        held = width > 0     # levels beyond the panels' ends (the ring's first and last bins) as their neighbours
        if held.any():
            width = np.interp(mid, mid[held], width[held])
    rho = np.maximum(width, girth(mid)) / (2 * np.pi)
    # heights: the flat distance between bins kept along the ring's slant, from the anchor out
    Y = mid.copy()
    w0 = int(np.clip(np.searchsorted(mid, anchor if anchor is not None else mid[-1]), 0, mid.size - 1))
    for k in range(w0 + 1, mid.size):
        Y[k] = Y[k - 1] + math.sqrt(max(WRAP_BIN ** 2 - (rho[k] - rho[k - 1]) ** 2, 0.25 * WRAP_BIN ** 2))
    for k in range(w0 - 1, -1, -1):
        Y[k] = Y[k + 1] - math.sqrt(max(WRAP_BIN ** 2 - (rho[k] - rho[k + 1]) ** 2, 0.25 * WRAP_BIN ** 2))
    out = []
    for x, lat in zip(points, lateral):
        if lat is None:
            out.append(x)
            continue
        n, t, s = lat
        r = np.interp(x[:, 1], mid, rho)
        phi = math.atan2(n[0], n[2]) + s / r
        out.append(np.c_[r * np.sin(phi), np.interp(x[:, 1], mid, Y), r * np.cos(phi)])
    return out


def _line(y: np.ndarray, c: np.ndarray, w: np.ndarray) -> np.ndarray:
    """c (a group's centre at levels y) as the straight line fitted to it, weighted by the group's
    width w there, evaluated at y."""
    return np.polyval(np.polyfit(y, c, 1, w=np.sqrt(np.maximum(w, 1e-6))), y)


SLEEVE_GIRTH = 0.36   # m: a sleeve's ring is at least this round (an upper arm of 0.3 m + 6 cm)


def wrap_sleeves(gc: GCPattern, points: list, body) -> list:
    """Arm panels (label 'arm') bent round the arm's axis of the pattern body (from the shoulder
    point (+-shoulder_half, shoulder_y - 4 cm) down at its arm angle), each side on its own: the
    ring of the sleeve's front and back panels, as the torso's (wrap_ring)."""
    points = list(points)
    for side in (1.0, -1.0):
        sel = [panel_part(p) == "arm" and len(x) > 0 and side * float(np.mean(x[:, 0])) > 0
               for p, x in zip(gc.panels, points)]
        if not any(sel):
            continue
        a = body.arm_angle
        up = -np.array([side * math.cos(a), -math.sin(a), 0.0])     # from the hand to the shoulder
        z = np.array([0.0, 0.0, 1.0])
        xa = np.cross(up, z)
        F = np.stack([xa, up, z])                                      # rows: the arm frame's axes
        c = np.array([side * body.shoulder_half, body.shoulder_y - 0.04, 0.0])
        local = [(x - c) @ F.T if s else x for x, s in zip(points, sel)]
        normals = [F @ p.normal for p in gc.panels]
        up_sel = [s and abs(n[1]) < 0.5 for s, n in zip(sel, normals)]
        wrapped = _ring(local, normals, up_sel, lambda y: np.full(np.shape(y), SLEEVE_GIRTH), None,
                        joined_panels(gc, lambda q: (q - c) @ F.T), panel_outlines(gc, lambda q: (q - c) @ F.T),
                        straight=True)
        points = [w @ F + c if s else x for w, x, s in zip(wrapped, points, up_sel)]
    return points


LEG_GIRTH = 0.2    # m: a trouser leg's ring is at least this round (an ankle of 0.2 m)
LEG_MIN = 0.10     # m: legs shorter than this below the crotch (a skirt of left and right halves) stay ringed


def leg_sides(gc: GCPattern, points: list) -> dict:
    """{panel index: +1 or -1} of the leg panels (label 'leg') that lie on one side of the body's
    mid-plane (x = 0 give or take 2 cm): a trouser leg's front and back, its cuffs."""
    out = {}
    for i, (p, x) in enumerate(zip(gc.panels, points)):
        if panel_part(p) != "leg" or len(x) == 0:
            continue
        side = 1.0 if float(np.mean(x[:, 0])) >= 0 else -1.0
        if float((side * x[:, 0]).min()) > -0.02:
            out[i] = side
    return out


def crotch_level(gc: GCPattern, sides: dict, body) -> float:
    """The pattern-frame height (m) below which the two sides' leg panels are no longer stitched to
    each other (the lowest end of a stitch joining a left leg panel to a right one: the crotch
    point), else the pattern body's crotch (hips line - crotch_hip_diff)."""
    index = {p.name: i for i, p in enumerate(gc.panels)}
    ys = []
    for st in gc.stitches:
        (pa, ka), (pb, kb) = st.a, st.b
        ia, ib = index[pa], index[pb]
        if ia in sides and ib in sides and sides[ia] != sides[ib]:
            for i, k in ((ia, ka), (ib, kb)):
                p = gc.panels[i]
                e = p.edges[k]
                ys.append(float(p.to_3d(p.vertices[[e.start, e.end]])[:, 1].min()))
    if ys:
        return min(ys)
    return body.hips_y - float(body.values.get("crotch_hip_diff", 9.0)) / 100


def wrap_legs(gc: GCPattern, points: list, ringed: list, body, axes: dict) -> list:
    """Trouser legs bent round each leg: below the crotch (crotch_level) the leg panels of each
    side (leg_sides) are a ring round that leg's axis (`axes`: {side: (2, 3) hip and ankle points in
    the pattern frame}, else vertical, half the hips' radius out) instead of round
    the body's (`ringed`: wrap_ring's positions; `points`: the panels as GarmentCode places them);
    from the crotch up to the hips line the two blend, so that the crotch seams run from the
    middle of the body's front and back down between the legs."""
    sides = leg_sides(gc, points)
    if not sides:
        return ringed
    crotch = crotch_level(gc, sides, body)
    band = max(body.hips_y - crotch, 0.05)
    out = list(ringed)
    normals = [p.normal for p in gc.panels]
    for side in (1.0, -1.0):
        sel = [sides.get(i) == side for i in range(len(points))]
        if not any(sel):
            continue
        low = min(float(points[i][:, 1].min()) for i in range(len(points)) if sel[i])
        if crotch - low < LEG_MIN:
            continue
        if side in axes:
            a, b = np.asarray(axes[side], np.float64)
        else:   # no leg joints: a vertical axis midway between the mid-plane and the hips' side
            r = body.hips / (2 * np.pi)
            a, b = np.array([side * 0.5 * r, body.hips_y, 0.0]), np.array([side * 0.5 * r, 0.0, 0.0])

        def off(y):
            t = np.clip((y - a[1]) / (b[1] - a[1]) if abs(b[1] - a[1]) > 1e-6 else 0.0 * y, 0.0, 1.0)
            return np.c_[a[0] + t * (b[0] - a[0]), np.zeros_like(y), a[2] + t * (b[2] - a[2])]

        local = [x - off(x[:, 1]) if s else x for x, s in zip(points, sel)]
        outlines = [q - off(q[:, 1]) for q in panel_outlines(gc)]
        wrapped = _ring(local, normals, sel, lambda y: np.full(np.shape(y), LEG_GIRTH), crotch, joined_panels(gc),
                        outlines)
        for i in np.flatnonzero(sel):
            y0 = points[i][:, 1]
            leg = wrapped[i] + off(y0)
            t = np.clip((y0 - crotch) / band, 0.0, 1.0)[:, None]
            out[i] = (1.0 - t) * leg + t * ringed[i]
    return out
