"""GarmentCode sleeves made to the character's arms: a sleeve is cut for the pattern body's arm, and
on a character whose arm (with its collider and the cloth's clearance) is rounder, the sleeve is
stretched round it from the first frame: CesiumMan's arm needs 55 cm, shirt_mean's sleeve is 46 cm
round, and the sewn sleeve held edges at 2-3.5x their length (the run stopped at frame 33). Here the
arm panels of a side are widened across the arm (about its line) until the sleeve's upper arm is as
round as the character's arm needs; the sleeve's length and the armhole are kept.

Frames: the pattern body's (metres, Y up, facing +Z); each arm's frame as garmentcode_wrap's sleeves
(rows: across the arm (up and out), along it (hand to shoulder), +Z), about the pattern body's
shoulder point.
"""
from __future__ import annotations

import math
from dataclasses import replace as dc_replace

import numpy as np

from stages.garments.garmentcode import GCPanel, GCPattern, map_panel, panel_part

SLEEVE_EASE = 0.04   # m: a sleeve round the upper arm is at least the arm's need plus this (movement)
UPPER_ARM = 0.45     # share of the pattern body's arm_length from the armpit down that the upper arm spans


def arm_frame(body, side: float) -> tuple[np.ndarray, np.ndarray]:
    """(F (3, 3) rows: across the arm, along it from the hand to the shoulder, +Z; the shoulder point
    (3,)) of the pattern body's arm on `side` (+1 left, +x)."""
    a = body.arm_angle
    up = -np.array([side * math.cos(a), -math.sin(a), 0.0])
    z = np.array([0.0, 0.0, 1.0])
    return np.stack([np.cross(up, z), up, z]), np.array([side * body.shoulder_half, body.shoulder_y - 0.04, 0.0])


def arm_side(p: GCPanel) -> float:
    return 1.0 if float(np.mean(p.to_3d(p.vertices)[:, 0])) >= 0 else -1.0


def upper_arm_girth(gc: GCPattern, body, side: float, step: float = 0.005) -> float | None:
    """The circumference (m) of the sleeve on `side` round the upper arm: at each level along
    the arm, the sum of its arm panels' widths across the arm (the panels that stand along it, as
    wrap_sleeves rings them), its lower quartile over the levels from the armpit (the widest level,
    where the cap meets the sleeve's underarm) down the upper arm (UPPER_ARM of the body's arm_length)
    or to the sleeve's end, 1 cm in from the ends; None without such panels."""
    from stages.garments.garmentcode_wrap import _spans, panel_outlines
    F, c = arm_frame(body, side)
    sel = [i for i, p in enumerate(gc.panels) if panel_part(p) == "arm" and arm_side(p) == side
           and abs(float((F @ p.normal)[1])) < 0.5]
    if not sel:
        return None
    outlines = panel_outlines(gc, lambda q: (q - c) @ F.T)
    lo_y = min(float(outlines[i][:, 1].min()) for i in sel)
    hi_y = max(float(outlines[i][:, 1].max()) for i in sel)
    levels = np.arange(lo_y + 0.01, hi_y - 0.01, step)
    if levels.size < 2:
        return None
    width, present = np.zeros(levels.size), np.zeros((len(sel), levels.size), bool)
    for k, i in enumerate(sel):
        n = F @ gc.panels[i].normal * np.array([1.0, 0.0, 1.0])
        n /= np.linalg.norm(n)
        lo, hi = _spans(outlines[i] @ np.array([n[2], 0.0, -n[0]]), outlines[i][:, 1], levels)
        present[k] = np.isfinite(lo)
        width += np.where(present[k], hi - lo, 0.0)
    pit = int(np.flatnonzero(width >= 0.98 * width.max())[-1])   # of a straight sleeve: its top
    arm_l = float(body.values.get("arm_length", 55.0)) / 100
    # the levels the armpit's panels all cross (a cuff sewn on below is other panels; where one half's
    # cap or slanted end stops short of the other's, the sleeve is not whole)
    whole = (present == present[:, [pit]]).all(axis=0)
    upper = whole & (levels <= levels[pit]) & (levels >= levels[pit] - UPPER_ARM * arm_l)
    return float(np.percentile(width[upper], 25))   # not the least: a slanted end cuts its levels short


def fit_sleeves(gc: GCPattern, body, need: float, exact_arcs: bool = False) -> tuple[GCPattern, dict]:
    """(pattern, {side: widening factor}) with each side's arm panels widened across the arm about
    its line until the sleeve's upper-arm girth (upper_arm_girth) is at least `need` + SLEEVE_EASE
    (m: the character's arm round its collider with the cloth's clearance); sides already as
    round are left."""
    panels, widened = list(gc.panels), {}
    for side in (1.0, -1.0):
        girth = upper_arm_girth(gc, body, side)
        if girth is None or girth <= 0 or girth >= need + SLEEVE_EASE - 1e-3:   # within a millimetre: as round
            continue
        k = (need + SLEEVE_EASE) / girth
        F, c = arm_frame(body, side)
        A = np.eye(3) + (k - 1.0) * np.outer(F[0], F[0])
        for i, p in enumerate(gc.panels):
            if panel_part(p) == "arm" and arm_side(p) == side:
                panels[i] = map_panel(p, A, c, exact_arcs)
        widened[side] = k
    return dc_replace(gc, panels=tuple(panels)), widened
