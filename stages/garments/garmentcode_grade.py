"""How a GarmentCode pattern is graded from the body it was made for to the character (garmentcode_place):
across by the characters' girth ratios, up by the heights' ratio."""
from __future__ import annotations

from dataclasses import dataclass, replace as dc_replace

import numpy as np

from stages.garments.garmentcode import GCPattern, map_panel, map_panel_points, panel_part


@dataclass(frozen=True)
class Grade:
    """How a pattern is graded from its body to the character. Across (x, z, about the body's vertical
    axis) by a factor that depends on the height in the pattern body's frame: `across` at `levels`
    (ascending, m), held beyond the ends; up (y) by `up`; arm panels across by the one factor `arm`
    (a sleeve keeps its shape along the arm)."""

    levels: tuple
    across: tuple
    up: float
    arm: float

    @classmethod
    def uniform(cls, k: float, sy: float) -> "Grade":
        return cls((0.0,), (float(k),), float(sy), float(k))

    def at(self, y):
        return np.interp(y, self.levels, self.across)


def grade(gc: GCPattern, g: Grade, exact_arcs: bool = False) -> GCPattern:
    """The pattern graded to another body: the garment as placed on its body scaled across by g.at
    (its height) and up by g.up (garmentcode.map_panel_points: each panel's outline in its own plane,
    exact for upright panels; tilted ones keep their in-plane part; curves through their mapped control
    points; circle arcs through their mapped ends and midpoint, or with exact_arcs as map_panel_points);
    arm panels by diag(g.arm, g.up, g.arm)."""
    def body_map_of(x):
        k = g.at(x[:, 1])
        return np.c_[x[:, 0] * k, x[:, 1] * g.up, x[:, 2] * k]
    S = np.diag([g.arm, g.up, g.arm])
    return dc_replace(gc, panels=tuple(map_panel(p, S, exact_arcs=exact_arcs) if panel_part(p) == "arm"
                                       else map_panel_points(p, body_map_of, exact_arcs) for p in gc.panels))


def graded_body(body, g: Grade):
    """The GarmentCode body (garmentcode_place.GCBody) as graded by g: its levels up, its girths by g at their levels."""
    sy = g.up
    return dc_replace(body, height=body.height * sy, waist_y=body.waist_y * sy, hips_y=body.hips_y * sy,
                      bust_y=body.bust_y * sy, shoulder_y=body.shoulder_y * sy, waist=body.waist * g.at(body.waist_y),
                      hips=body.hips * g.at(body.hips_y), bust=body.bust * g.at(body.bust_y),
                      shoulder_half=body.shoulder_half * g.arm)


def grading(gc: GCPattern, body, meas: dict) -> Grade:
    """Across, up to the waist: the largest ratio of the character's clearance girth (body and colliders,
    measurements.clearance_measurements) to the pattern body's girth at the levels (hips, waist, bust)
    its upright panels cover, so that a garment snug on its body closes over the character's colliders;
    from the waist up to the bust, when the panels cover it, going over to the ratio at the bust, held
    above it (shoulders, neckline, sleeves): on the CMU walk (waist 1.05, bust 0.87) a tee graded 1.05
    all over sat at its placement 17 % narrower than its cut at the shoulders, the sewn neckline and
    shoulders came out as wide as cut and the tee slid down the sloping shoulders to the hips. Up: the
    ratio of the heights."""
    ys = np.concatenate([p.to_3d(p.vertices)[:, 1] for p in gc.panels if panel_part(p) != "arm"] or [np.zeros(0)])
    ratios = {}
    for y, key, girth in ((body.hips_y, "clear_hips", body.hips), (body.waist_y, "clear_waist", body.waist),
                          (body.bust_y, "clear_chest", body.bust)):
        if ys.size and ys.min() - 0.05 <= y <= ys.max() + 0.05 and key in meas:
            ratios[key] = meas[key] / girth
    k = max(ratios.values()) if ratios else meas.get("clear_waist", body.waist) / body.waist
    sy = meas["height"] / body.height
    if "clear_chest" in ratios and body.waist_y < body.bust_y:
        top = ratios["clear_chest"]
        return Grade((body.waist_y, body.bust_y), (float(k), float(top)), float(sy), float(top))
    return Grade.uniform(k, sy)
