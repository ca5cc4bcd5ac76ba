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


def cone_apex(p) -> tuple | None:
    """(apex (2,) panel uv, angle the panel spans about it (rad), the top edge's height in the body
    frame (m)) when the panel's top edge (the one
    whose ends are highest in the body frame) is a circle arc whose centre lies above it (a circle or flare skirt's waist:
    the panel is a sector of an annulus, made to hang as a cone), else None."""
    from stages.garments.garmentcode import arc_center
    top = max(range(len(p.edges)),   # the edge whose ends are highest
              key=lambda k: float(p.to_3d(p.vertices[[p.edges[k].start, p.edges[k].end]])[:, 1].mean()))
    e = p.edges[top]
    if e.kind != "circle":
        return None
    c, r, _ = arc_center(p.vertices[e.start], p.vertices[e.end], e.radius, e.large_arc, e.right)
    mid = edge_points(p, e, [0.5])[0]
    if p.to_3d(c[None])[0, 1] <= p.to_3d(mid[None])[0, 1] + 1e-3:
        return None
    q = p.vertices - c
    span = float(np.ptp(np.unwrap(np.arctan2(q[:, 1], q[:, 0]))))
    if r > MAX_APEX or span < MIN_SPAN:
        return None
    return c, span, float(p.to_3d(p.vertices[[e.start, e.end]])[:, 1].mean())


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
        for i, (apex, _, top) in cones.items():
            full = sum(c[1] for c in cones.values() if abs(c[2] - top) <= RING_DY)
            points[i] = _cone(gc.panels[i], uvs[i], apex, full, top)
            up[i] = False
    if not any(up):
        return points
    girth = lambda y: np.interp(y, [body.hips_y, body.waist_y, body.bust_y], [body.hips, body.waist, body.bust]) + 0.06
    normals = [p.normal for p in gc.panels]
    return _ring(points, normals, up, girth, body.waist_y)


def _ring(points: list, normals: list, up: list, girth, anchor: float | None) -> list:
    """The panels `up` of `points` wrapped round the y axis of their frame (normals: each panel's
    outward normal in it): circumference at each level = the sum of the panels' widths there, at
    least girth(level); with `anchor`, levels re-spaced from it along the ring's slant."""
    ys = np.concatenate([x[:, 1] for x, u in zip(points, up) if u])
    edges = np.arange(ys.min() - WRAP_BIN, ys.max() + 2 * WRAP_BIN, WRAP_BIN)
    mid = 0.5 * (edges[:-1] + edges[1:])
    width = np.zeros(mid.size)
    lateral = []
    for nrm, x, u in zip(normals, points, up):
        if not u:
            lateral.append(None)
            continue
        n = np.asarray(nrm, np.float64) * np.array([1.0, 0.0, 1.0])
        n /= np.linalg.norm(n)
        t = np.array([n[2], 0.0, -n[0]])          # the direction of growing angle round the axis
        s = x @ t
        lateral.append((n, t, s))
        b = np.clip(np.digitize(x[:, 1], edges) - 1, 0, mid.size - 1)
        w = np.zeros(mid.size)
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
    # each group of panels facing one way is centred on its direction: GarmentCode lays a sleeve's
    # panels off the arm's axis (the sampled tee's front sleeve spans -32..+1 cm across it, its back
    # -1..+31 cm), which wrapped as they lie put both halves on the same side of the ring, through
    # each other (700 crossing edges on the placed tee); a torso's halves (0..w, -w..0) stay as they are
    facing = [(i, lat[0]) for i, lat in enumerate(lateral) if lat is not None]
    group = {}
    for i, n in facing:
        group[i] = next((group[j] for j, m in facing if j in group and float(n @ m) > FACING_COS), i)
    for g in set(group.values()):
        members = [i for i in group if group[i] == g]
        s_all = np.concatenate([lateral[i][2] for i in members])
        b_all = np.clip(np.digitize(np.concatenate([points[i][:, 1] for i in members]), edges) - 1, 0, mid.size - 1)
        lo, hi = np.full(mid.size, np.inf), np.full(mid.size, -np.inf)
        np.minimum.at(lo, b_all, s_all)
        np.maximum.at(hi, b_all, s_all)
        have = np.isfinite(lo)   # centred at every level: a sleeve cap's halves differ in shape
        for i in members:
            n, t, s_i = lateral[i]
            lateral[i] = (n, t, s_i - np.interp(points[i][:, 1], mid[have], 0.5 * (lo[have] + hi[have])))
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
        wrapped = _ring(local, normals, up_sel, lambda y: np.full(np.shape(y), SLEEVE_GIRTH), None)
        points = [w @ F + c if s else x for w, x, s in zip(wrapped, points, up_sel)]
    return points
