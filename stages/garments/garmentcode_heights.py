"""GarmentCode heights: how a pattern body's heights map onto a character's (garmentcode_place.body_map).

The map goes through matching levels of the two bodies (floor, hips, waist, bust, shoulders, top of
the head), met where the garment hangs from, with every span's slope bounded (limited_heights); above
the waist the cut keeps its own heights where the levels would stretch it (cut_above).
"""
from __future__ import annotations

import numpy as np

# a panel's height is mapped with a slope within these bounds: CesiumMan's bust-to-shoulder span is
# 3.8 cm against the pattern body's 22.5 cm, and the landmarks' own slope (0.17) squashed the top of
# the hooded top 6x: its V neckline became a 2 cm high line, the sewn cloth held edges at 1.4 % and
# 430 % of their rest lengths, and the run stopped at frame 1 (an edge 4,813 % of its frame-0 length)
SLOPE_BOUNDS = (0.75, 1.33)


def limited_heights(src: np.ndarray, dst: np.ndarray, anchor: float, bounds=SLOPE_BOUNDS) -> tuple:
    """(src', dst'): the piecewise linear height map through (src, dst) (ascending) with `anchor`
    (a pattern-body height) added as a breakpoint kept where the landmarks put it, and every segment's
    slope clamped to `bounds`, integrated out from the anchor: near the anchor the garment sits on
    the character's landmark, and no span of cloth is squashed or stretched more than the bounds.
    Below the anchor the lowest breakpoint (the floor) is then brought back to its landmark as far as
    the bounds allow, by the spans nearest it first (a leg, far from where the garment hangs): the
    length the clamped spans above gained or lost would otherwise put a jumpsuit's hems 11 cm
    below CesiumMan's floor (its bust-to-shoulder span, 0.17 of the pattern body's, held at 0.75)."""
    a = float(np.clip(anchor, src[0], src[-1]))
    s = np.unique(np.r_[src, a])
    d = np.interp(s, src, dst)
    slope = np.clip(np.diff(d) / np.diff(s), *bounds)
    k = int(np.searchsorted(s, a))
    miss = float(np.sum(slope[:k] * np.diff(s)[:k]) - (d[k] - d[0]))    # > 0: the floor would end below its landmark
    for i in range(k):
        if abs(miss) < 1e-12:
            break
        w = s[i + 1] - s[i]
        new = float(np.clip(slope[i] - miss / w, *bounds))
        miss -= (slope[i] - new) * w
        slope[i] = new
    out = np.empty_like(d)
    out[k] = d[k]
    for i in range(k + 1, s.size):
        out[i] = out[i - 1] + slope[i - 1] * (s[i] - s[i - 1])
    for i in range(k - 1, -1, -1):
        out[i] = out[i + 1] - slope[i] * (s[i + 1] - s[i])
    return s, out


def cut_above(src: np.ndarray, dst: np.ndarray, anchor: float, waist: float, bounds=SLOPE_BOUNDS) -> tuple:
    """(src', dst'): the height map (src, dst) (ascending; from limited_heights) with the cut's own
    heights (slope 1 from the anchor, where the garment hangs) above `waist`, and below it the map's
    own tilted to meet them at the waist, its lowest point (the floor) kept, as far as `bounds` keep
    every span below the waist (as near the cut as they allow; the map unchanged where nothing does).
    The landmarks took the CMU walk's bust-to-shoulder span at 1.27x the cut: a shirt's upper torso
    placed 27 % longer than cut, and the sewing, letting it go, pulled the shirt 8 cm down off the
    shoulders (the cloth above 1.2 m: median 1.25 -> 1.18 m in the first rounds; as cut, 1.25 -> 1.28 m)."""
    a = float(np.interp(anchor, src, dst))
    low = src < waist
    ss = np.r_[src[low], waist]
    dd = np.r_[dst[low], float(np.interp(waist, src, dst))]
    slope, span = np.diff(dd) / np.diff(ss), waist - src[0]
    lo, hi = (bounds[0] - slope.min()) * span, (bounds[1] - slope.max()) * span
    if lo > hi:
        return src, dst
    delta = float(np.clip(a - (anchor - waist) - dd[-1], lo, hi))
    out_s = np.r_[ss, anchor, src[src > anchor]]
    out_d = np.r_[dd + delta * (ss - src[0]) / span, a, a + (src[src > anchor] - anchor)]
    if not np.all(np.diff(out_d) > 0):
        return src, dst
    return out_s, out_d
