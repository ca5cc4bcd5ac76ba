"""Where a GarmentCode pattern's waist seam (its `lower_interface` edges, held while sewing and pinned
to the trunk afterwards) may sit on a character: on the trunk, above the tops of the legs.

The height map (garmentcode_place.body_map) hangs a garment from its top and keeps every span's slope
within bounds, so a pattern whose waist seam sits low on its body (a dropped waist at the hips, a
low-rise waistband) lands lower still on a character whose legs join the trunk high up: on the CMU
walk's skeleton the hip joints are at 59 % of the height (the pattern body's hips line at 50 %), and
the pencil dress's skirt top was placed 11 cm below them, the sampled dress's waistband level with
them. A band pinned to the trunk there is swept by the thighs at every step: the run stopped as
diverged at frame 19 (the pencil dress, an edge 1,090 % of its length, 40 particles in the body) and
frame 27 (the sampled dress). The seam is lifted to `band_floor`, the span between it and the
garment's top squashed to fit (`lift_band`).
"""
from __future__ import annotations

import numpy as np

# a band pinned to the trunk sits this share of the height above the hip joints at least: on the CMU
# walk a waist seam at the hip joints' level (-1 to +2 cm) stopped as diverged, one 2-4 cm above ran
# (GarmentCode's pencil and flare skirts), and the built-in skirts' waist 4 cm above them passes
BAND_OVER_HIPS = 0.025
# the span between the band and the garment's top is squashed to this share of its height at most;
# beyond, the top goes up too
MIN_SQUASH = 0.6


def band_floor(meas: dict) -> float | None:
    """The lowest height (relative frame, m) a held waist seam may sit at on the character measured
    in `meas` (garment_measurements): BAND_OVER_HIPS of the height above its hip joints, and at
    most the built-in skirts' waist (the waist, or skirt_top where the arms come down beside it).
    None without both legs."""
    hips = [meas[k] for k in ("hip_joint_y_l", "hip_joint_y_r") if k in meas]
    if len(hips) < 2:
        return None
    from stages.garments.library import waistband_y
    return float(min(np.mean(hips) + BAND_OVER_HIPS * meas["height"], waistband_y(meas)))


def lift_band(src: np.ndarray, dst: np.ndarray, anchor: float, band: float, lift: float) -> tuple:
    """(src', dst'): the piecewise linear height map through (src, dst) (src ascending) with `band`
    and `anchor` added as breakpoints and the pattern-body height `band` mapped `lift` (m) higher:
    everything below `band` shifted up, the span from `band` to `anchor` (the garment's top)
    squashed to fit (MIN_SQUASH at most, then shifted up as well) and everything above shifted by
    the anchor's rise. band at or above anchor (a skirt hangs from its waist): the whole map shifted."""
    band = float(np.clip(band, src[0], src[-1]))
    top = float(np.clip(max(anchor, band), src[0], src[-1]))
    s = np.unique(np.r_[src, band, top])
    d = np.interp(s, src, dst)
    at = lambda y: float(np.interp(y, s, d))
    if lift <= 0.0:
        return s, d
    floor = at(band) + lift
    span = at(top) - at(band)
    if span <= 0.0:
        return s, d + lift
    squash = max((at(top) - floor) / span, MIN_SQUASH)
    top_rise = floor + squash * span - at(top)
    out = np.where(s <= band, d + lift, at(top) + top_rise + (d - at(top)) * squash)
    return s, np.where(s >= top, d + top_rise, out)


def band_vertices(gc, pattern, flat) -> np.ndarray:
    """Indices of the meshed pattern's vertices on the lower_interface edges (to_pattern's edges
    'e0', 'e1', ... of the GarmentCode pattern `gc`)."""
    from stages.garments.patterns import SeamSide
    from stages.garments.triangulate import run_vertices
    runs = [run_vertices(pattern, flat, SeamSide(p.name, (f"e{j}",))) for p in gc.panels
            for j, e in enumerate(p.edges) if e.label == "lower_interface"]
    return np.unique(np.concatenate(runs)) if runs else np.zeros(0, np.int64)


def worn_from_waistband(meas: dict) -> dict:
    """The measurements a skirt or trousers (a garment hung from the waist) is placed by: its waist at
    waistband_y, where the built-in ones are worn. On CesiumMan that is 0.78 m, below the upper arms'
    colliders where they come down beside the measured waist (0.93 m): worn there, the arms swung
    through the waistbands and the flare skirt, the pencil skirt and the pants stopped as diverged.
    Lowered, the waist takes the girth the body and colliders need there (clear_top), the hips go
    down with it (the waist-to-hips span scaled as the floor-to-waist one) and take the widest girth
    below the band (clear_skirt)."""
    from stages.garments.library import waistband_y
    band, waist, floor = waistband_y(meas), meas["waist_y"], meas.get("floor_y", 0.0)
    if band >= waist - 1e-3 or "clear_top" not in meas:
        return meas
    hips = min(meas["hips_y"], band - (waist - meas["hips_y"]) * (band - floor) / (waist - floor))
    out = dict(meas, waist_y=band, hips_y=hips, clear_waist=meas["clear_top"])
    if "clear_skirt" in meas:
        out["clear_hips"] = max(meas.get("clear_hips", 0.0), meas["clear_skirt"])
    return out
