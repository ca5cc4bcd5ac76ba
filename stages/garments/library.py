"""Built-in garment patterns sized from the character's measurements, and the garment maker
(pattern -> flat meshes -> placed panels -> sewn Garment).

Kinds: 'tshirt', 'short_skirt', 'long_skirt', 'shorts', 'trousers', 'cape', 'square'. Sizes come from
`stages.garments.measurements.garment_measurements(character)` (stages.rig.procedural.body_measurements
plus shoulder and arm sizes from the skeleton): girths with ease, lengths as fractions of the body's
heights.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from stages.errors import InputError
from stages.garments.patterns import (Panel, Pattern, PatternAttachment, Placement, Seam, SeamSide, cubic, line,
                                      quad)
from stages.garments import tshirt_open as open_top
from stages.garments.fit import FIT_GAP_MAX, signed_skin_distance
from stages.garments.measurements import quarter_length
from stages.garments.types import COMMON_BONE

_WAISTBAND = (SeamSide("front", "waist"), SeamSide("back", "waist"))
# the humanoid parts (stages.rig.humanoid.HumanoidJoints) each kind is placed on
WAIST_EASE = 0.05   # share added to the hugged waist loop (band_top) of shorts and trousers
# a sleeve cap up to this much longer than its scooped armhole is eased in by the sewing; beyond it
# the armhole is deepened to the cap's length (CesiumMan's cap was 27 % longer and its seam stayed
# open). Not below: the built-in body's cap is 6.6 % longer (deepened, the walk's armpit p99 strain
# rose 10.2 -> 11.1 %), the BVH body's 11 %; at 0.1 the tall slim body's collar fallback left a
# shoulder seam 4.8 mm open
CAP_EASE = 0.2
KINDS = ("tshirt", "short_skirt", "long_skirt", "shorts", "trousers", "cape", "square")


def _need(meas: dict, *keys):
    for k in keys:
        if k not in meas or not np.isfinite(meas[k]):
            raise InputError("garment measurements", f"missing or NaN {k!r} (have {sorted(meas)})")


def _cos_bezier(name, start, end):
    """A cubic close to half a cosine period from `start` to `end` (flat at both ends)."""
    (u0, v0), (u1, v1) = start, end
    k = 0.364 * (u1 - u0)
    return cubic(name, (u0 + k, v0), (u1 - k, v1), (u1, v1))


def tshirt(meas: dict, *, ease: float = 0.08, length_below_waist: float | None = None,
           sleeve_length: float | None = None, edge_length: float = 0.025, name: str = "tshirt") -> Pattern:
    """Front, back and two sleeves, sized to clear the body and its colliders (garment_measurements
    with colliders), else the body plus ease.

    Design (bind pose): the torso panels are a rounded-box tube from the hem to the fold line,
    whose columns then bend over the shoulders onto the ridge plane, where front and back meet in
    the shoulder seams. Each sleeve is a tube around the upper arm (radius arm_radius + 1 cm)
    whose top is its cut by the vertical plane x = x_p: an ellipse of semi-axes R and
    R / cos(arm angle), centred on the arm axis, reaching the ridge (shoulder_top) at its top and
    the armpit at its bottom; unrolled, that cut is the cosine-shaped sleeve cap. The torso's
    armholes run from the armpit to the shoulder point with the cap's length. Seams are sewn in
    two stages: sides, shoulders and sleeve underarms first, then the armholes.
    """
    _need(meas, "height", "chest", "waist", "hips", "waist_y", "hips_y", "shoulder_y", "shoulder_half", "neck_y",
          "arm_girth")
    h = meas["height"]
    hem_y = meas["hips_y"] - 0.02 * h if length_below_waist is None else meas["waist_y"] - length_below_waist
    below_hips = hem_y < meas["hips_y"] + 0.05
    chest = max(meas["chest"] + ease, meas.get("clear_chest", 0.0))
    hem = max(chest, meas["waist"] + ease, meas.get("clear_waist", 0.0),
              max(meas["hips"] + ease, meas.get("clear_hips", 0.0)) if below_hips else 0.0)
    hw, cw = hem / 4, chest / 4
    R = meas.get("arm_radius", meas["arm_girth"] / (2 * np.pi) + 0.02) + 0.01
    alpha = float(np.clip(meas.get("arm_angle", np.pi / 4), 0.0, np.radians(70)))
    half_cut = R / np.cos(alpha)                     # vertical semi-axis of the sleeve's cut
    y_s = meas.get("shoulder_top", meas["shoulder_y"] + 0.05 * h) + 0.01
    y_c = y_s - half_cut
    xj = meas["shoulder_half"]
    x_p = xj + max(meas["shoulder_y"] - y_c, 0.0) / max(np.tan(alpha), 1e-3) if alpha > 0.05 else xj
    y_a = y_c - half_cut
    depth = meas.get("torso_depth", 0.075 * h)
    neck_half = meas.get("neck_half", 0.045 * h)
    ha = y_a - hem_y
    if open_top.fits(meas, y_a, hem_y, edge_length):     # the arm's root fills the torso's side (a chibi)
        return open_top.open_top_tshirt(meas, hem_y=hem_y, chest=chest, hem=hem, sleeve_length=sleeve_length,
                                        edge_length=edge_length, name=name)
    fold = max(y_s - depth - hem_y, ha + 0.03)
    lift = y_s - hem_y - fold
    u_s = min(x_p, cw - 0.03)
    u_n = min(neck_half, u_s - 0.04)
    hs = fold + quarter_length(0.5 * depth, lift)
    hn = fold + quarter_length(depth, lift)

    def neckline(front: bool) -> float:
        """Neck depth (pattern v below hn) where the centre column's fold meets the neck box."""
        psi = np.linspace(0.0, np.pi / 2, 91)
        y = y_s - lift + lift * np.sin(psi)
        z = depth * np.cos(psi)
        lim = meas.get("neck_front", 0.03 * h) if front else -meas.get("neck_back", -0.03 * h)
        hit = (y > meas.get("neck_low", meas["neck_y"])) & (z < lim)
        k = int(np.argmax(hit)) if hit.any() else psi.size - 1
        arc = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(y), np.diff(z)))])
        return max(hn - (fold + arc[k]) + 0.01, 0.02)

    # armhole: from the armpit inwards, then up to the shoulder point
    lam = np.pi * R                                  # half the sleeve's circumference
    sl = 0.1 * h if sleeve_length is None else sleeve_length
    rise = R * np.tan(alpha)
    cap_len = Panel("cap", (line("a", (lam, 0.0)), _cos_bezier("cap", (lam, 0.0), (0.0, 2 * rise)),
                            line("b", (0.0, -0.1))), Placement("plane")).edge_length(1)

    def armhole(scoop, ha=ha):
        dy = hs - ha
        return cubic("armhole_l", (u_s + 0.5 * (cw - u_s), ha), (u_s - scoop, ha + 0.4 * dy), (u_s, hs))

    def hole_length(scoop, ha=ha):
        return Panel("h", (line("a", (cw, ha)), armhole(scoop, ha), line("b", (0.0, hs)), line("c", (0.0, ha))),
                     Placement("plane")).edge_length(1)

    def solve(length, lo, hi):
        """The argument in [lo, hi] where the increasing `length` reaches the cap's (bisection)."""
        for _ in range(30):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if length(mid) < cap_len else (lo, mid)
        return 0.5 * (lo + hi)
    # the armhole as long as the sleeve cap (no gathering in the seam): scooped inwards, at most to a
    # 2 cm strip beside the neckline; for a cap longer still by more than CAP_EASE (a thick arm beside
    # a wide neck), also deepened, the armpit lowered
    scoop_max = max(u_s - u_n - 0.02, 0.0)
    scoop = solve(hole_length, 0.0, scoop_max) if hole_length(0.0) < cap_len else 0.0
    if hole_length(scoop_max) < cap_len / (1.0 + CAP_EASE):
        drop = solve(lambda d: hole_length(scoop_max, ha - d), 0.0, 0.5 * ha)
        # the armpit lower by `drop` and the hem too, so the side seam keeps its length: sewn to a
        # sleeve whose underarm is higher, a shortened side pulled the hem 5 cm up (CesiumMan)
        hem_y, fold, hs, hn = hem_y - drop, fold + drop, hs + drop, hn + drop
    dy = hs - ha
    panels, seams = [], []
    for pname, angle, neck_depth in (("front", 0.0, neckline(True)), ("back", 180.0, neckline(False))):
        edges = (
            line("hem", (hw, 0.0)),
            line("side_l", (cw, ha)),
            armhole(scoop, ha),
            line("shoulder_l", (u_n, hn)),
            cubic("neck", (u_n, hn - 4 / 3 * neck_depth), (-u_n, hn - 4 / 3 * neck_depth), (-u_n, hn)),
            line("shoulder_r", (-u_s, hs)),
            cubic("armhole_r", (-u_s + scoop, ha + 0.4 * dy), (-u_s - 0.5 * (cw - u_s), ha), (-cw, ha)),
            line("side_r", (-hw, 0.0)),
        )
        ridge = ((-u_s, hs), (-u_n, hn), (u_n, hn), (u_s, hs))
        panels.append(Panel(pname, edges, Placement("torso", angle_deg=angle, span_deg=180.0, shift=hem_y,
                                                    offset=0.015, wrap_until=ha, exponent=4.0, arms=False,
                                                    fold_at=fold, ridge=ridge)))
    seams += [Seam(SeamSide("front", "side_l"), SeamSide("back", "side_r")),
              Seam(SeamSide("back", "side_l"), SeamSide("front", "side_r")),
              Seam(SeamSide("front", "shoulder_l"), SeamSide("back", "shoulder_r")),
              Seam(SeamSide("back", "shoulder_l"), SeamSide("front", "shoulder_r"))]
    t_mid = (xj - x_p) / np.cos(alpha)               # axis coordinate where the arm axis meets x = x_p
    v_mid = sl + rise
    for side in ("l", "r"):
        # u > 0 of a sleeve faces the back on the left arm and the front on the right arm (see placement)
        first, second = ("cap_back", "cap_front") if side == "l" else ("cap_front", "cap_back")
        edges = (line("cuff", (lam, 0.0)), line("under_a", (lam, sl)),
                 _cos_bezier(first, (lam, sl), (0.0, v_mid + rise)),
                 _cos_bezier(second, (0.0, v_mid + rise), (-lam, sl)), line("under_b", (-lam, 0.0)))
        pname = f"sleeve_{side}"
        panels.append(Panel(pname, edges, Placement(f"arm_{side}", angle_deg=0.0, span_deg=360.0,
                                                    shift=t_mid - v_mid, offset=0.01, wrap_until=sl)))
        seams.append(Seam(SeamSide(pname, "under_a"), SeamSide(pname, "under_b")))
        front_hole, back_hole = ("armhole_l", "armhole_r") if side == "l" else ("armhole_r", "armhole_l")
        seams.append(Seam(SeamSide(pname, "cap_front"), SeamSide("front", front_hole), stage=1))
        seams.append(Seam(SeamSide(pname, "cap_back"), SeamSide("back", back_hole), stage=1))
    # each shoulder line on one bone (the common ancestor of its nearest colliders' bones, the chest
    # on the built-in character): pinned to neck, clavicle and upper arm it was torn between them
    atts = (PatternAttachment("front", "shoulder_l", joint=COMMON_BONE),
            PatternAttachment("front", "shoulder_r", joint=COMMON_BONE))
    return Pattern(name, tuple(panels), tuple(seams), edge_length, atts,
                   fit_edges=(SeamSide("front", "neck"), SeamSide("back", "neck")), fit_band=0.9)


def waistband_y(meas: dict) -> float:
    """Height skirts and pants are worn at: the waist, or skirt_top where the arms' colliders come down beside it."""
    return min(meas["waist_y"], meas.get("skirt_top", meas["waist_y"]))


def skirt(meas: dict, *, length: float, flare: float, ease: float = 0.2, hip_ease: float | None = None,
          edge_length: float = 0.025, name: str = "skirt") -> Pattern:
    """Two panels (front, back) from the waist: hip-wide below the hips, flared to the hem.

    Hip girth: with collider clearances (garment_measurements with colliders) the larger of
    hips + hip_ease (default 0.06) and clear_skirt (what the hips, thighs and their colliders need);
    without them hips + hip_ease (default 0.32, enough for the built-in character's joint spheres).
    """
    _need(meas, "height", "waist", "hips", "waist_y", "hips_y")
    top_y = waistband_y(meas)
    # the curve from the top to the hip width spans at least two edges: where the top sits at the
    # hips (CesiumMan: 2 cm above them) it was one kinked edge, and a side seam pair at it stayed
    # 5.2 mm open (long skirt, 0.6228 m; 2.5 cm edges): from 2 edges on, 0.6 mm
    dh = min(max(top_y - meas["hips_y"], 2.0 * edge_length), 0.8 * length)
    ht = max(meas["waist"] + ease, meas.get("clear_top", 0.0)) / 4
    body = max(meas["hips"], meas["waist"])
    if "clear_skirt" in meas:
        hh = max(body + (0.06 if hip_ease is None else hip_ease), meas["clear_skirt"]) / 4
    else:
        hh = (body + (0.32 if hip_ease is None else hip_ease)) / 4
    # the flare, at most half the length wider than the hips on each half panel (a chibi's 16 cm
    # long skirt flared from its 1.4 m hips was a disc 1.1 m across; adults' skirts stay below it)
    hem = min(max(hh * flare, hh), hh + 0.5 * length)
    L = length
    below = L - dh
    hip_at = hh + (hem - hh) * 0.0
    panels = []
    for pname, angle in (("front", 0.0), ("back", 180.0)):
        edges = (line("hem", (hem, 0.0)), line("side_l_lo", (hip_at, below)),
                 quad("side_l_hi", (hh, below + 0.5 * dh), (ht, L)), line("waist", (-ht, L)),
                 quad("side_r_hi", (-hh, below + 0.5 * dh), (-hip_at, below)), line("side_r_lo", (-hem, 0.0)))
        panels.append(Panel(pname, edges, Placement("hips", angle_deg=angle, span_deg=180.0,
                                                    shift=top_y - L, offset=0.015)))
    seams = (Seam(SeamSide("front", ("side_l_lo", "side_l_hi")), SeamSide("back", ("side_r_hi", "side_r_lo"))),
             Seam(SeamSide("back", ("side_l_lo", "side_l_hi")), SeamSide("front", ("side_r_hi", "side_r_lo"))))
    atts = (PatternAttachment("front", "waist", joint="root", sewing=True),
            PatternAttachment("back", "waist", joint="root", sewing=True))
    return Pattern(name, tuple(panels), seams, edge_length, atts, fit_edges=_WAISTBAND, fit_band=1.03)


def _pants(meas: dict, *, leg_length: float, hem_radius: float, ease: float, hip_ease: float | None,
           crotch_drop: float, edge_length: float, name: str) -> Pattern:
    """Shorts and trousers (see `shorts`): a seat (front + back, waist to crotch, sewn at the
    sides) and two leg tubes (inseam on the inner side) whose tops are sewn to the seat's bottom
    halves and, between the legs, to each other (the crotch seams, front and back).

    Bottom of the seat: girth G (hips + hip_ease, at least clear_seat), quarter c = G / 4 per panel
    half. Top of a leg tube (girth 2 lam): its outer part (2c, from the front centre round the
    outside to the back centre) sews to the seat, its inner part (2 (lam - c), G / (2 pi): about
    the seat's depth) to the other leg. The crotch is `crotch_drop` below crotch_y. Leg tube u = 0 is on the leg's outer side (Placement angle +-90),
    u > 0 turns backwards on the left leg and forwards on the right one.
    """
    _need(meas, "height", "waist", "hips", "waist_y", "hips_y")
    h = meas["height"]
    top_y = waistband_y(meas)
    crotch = min(meas.get("crotch_y", meas["hips_y"] - 0.05 * h) - crotch_drop, top_y - 0.08)
    H = top_y - crotch
    below = min(max(meas["hips_y"] - crotch, 0.02), H - 0.03)
    dh = H - below
    body = max(meas["hips"], meas["waist"])
    G = max(body + (0.06 if hip_ease is None else hip_ease), meas.get("clear_seat", 0.0)) \
        if "clear_seat" in meas else body + (0.32 if hip_ease is None else hip_ease)
    c = G / 4
    # the waist: with colliders, the loop the hugged waistband makes plus WAIST_EASE (cut to the
    # clearance ellipse it was 13-29 % longer, and the free band ends bulged 1-3 cm off the body)
    ht = ((1 + WAIST_EASE) * meas["band_top"] if "band_top" in meas
          else max(meas["waist"] + ease, meas.get("clear_top", 0.0))) / 4
    # inner part: the seat's depth (front centre to back centre) at the crotch, about G / (2 pi)
    # for the seat's elliptic cross-section; longer, the crotch seam bulges up into the body
    lam = c + 0.5 * G / (2 * np.pi)
    lam_h = min(np.pi * hem_radius, lam)
    panels = []
    for pname, angle in (("front", 0.0), ("back", 180.0)):
        edges = (line("hem_r", (0.0, 0.0)), line("hem_l", (c, 0.0)), line("side_l_lo", (c, below)),
                 quad("side_l_hi", (c, below + 0.5 * dh), (ht, H)), line("waist", (-ht, H)),
                 quad("side_r_hi", (-c, below + 0.5 * dh), (-c, below)), line("side_r_lo", (-c, 0.0)))
        panels.append(Panel(pname, edges, Placement("hips", angle_deg=angle, span_deg=180.0, shift=crotch,
                                                    offset=0.015)))
    L = leg_length
    pieces = {"l": ("crotch_back", "seat_back", "seat_front", "crotch_front"),
              "r": ("crotch_front", "seat_front", "seat_back", "crotch_back")}
    for side, angle in (("l", 90.0), ("r", -90.0)):
        # v = L at the crotch height on the thigh axis (pointing up from the knee to the hip joint)
        hip_y = meas.get(f"hip_joint_y_{side}", meas["hips_y"])
        up = max(meas.get(f"thigh_up_y_{side}", 1.0), 0.3)
        a, b_, cc, d = pieces[side]
        edges = (line("hem", (lam_h, 0.0)), line("under_a", (lam, L)), line(a, (c, L)), line(b_, (0.0, L)),
                 line(cc, (-c, L)), line(d, (-lam, L)), line("under_b", (-lam_h, 0.0)))
        panels.append(Panel(f"leg_{side}", edges, Placement(f"leg_{side}", angle_deg=angle, span_deg=360.0,
                                                           shift=(crotch - hip_y) / up - L, offset=0.01)))
    seams = [Seam(SeamSide("front", ("side_l_lo", "side_l_hi")), SeamSide("back", ("side_r_hi", "side_r_lo"))),
             Seam(SeamSide("back", ("side_l_lo", "side_l_hi")), SeamSide("front", ("side_r_hi", "side_r_lo"))),
             Seam(SeamSide("front", "hem_l"), SeamSide("leg_l", "seat_front")),
             Seam(SeamSide("back", "hem_r"), SeamSide("leg_l", "seat_back")),
             Seam(SeamSide("front", "hem_r"), SeamSide("leg_r", "seat_front")),
             Seam(SeamSide("back", "hem_l"), SeamSide("leg_r", "seat_back")),
             Seam(SeamSide("leg_l", "crotch_front"), SeamSide("leg_r", "crotch_front")),
             Seam(SeamSide("leg_l", "crotch_back"), SeamSide("leg_r", "crotch_back")),
             Seam(SeamSide("leg_l", "under_a"), SeamSide("leg_l", "under_b")),
             Seam(SeamSide("leg_r", "under_a"), SeamSide("leg_r", "under_b"))]
    atts = (PatternAttachment("front", "waist", joint="root", sewing=True),
            PatternAttachment("back", "waist", joint="root", sewing=True))
    return Pattern(name, tuple(panels), tuple(seams), edge_length, atts, fit_edges=_WAISTBAND)


def _crotch_depth(meas: dict, side: str) -> float:
    """Distance along the thigh from the hip joint down to the crotch height."""
    h = meas["height"]
    crotch = meas.get("crotch_y", meas["hips_y"] - 0.05 * h) - 0.06
    return (meas.get(f"hip_joint_y_{side}", meas["hips_y"]) - crotch) / max(meas.get(f"thigh_up_y_{side}", 1.0), 0.3)


def shorts(meas: dict, *, leg_length: float | None = None, ease: float = 0.2, hip_ease: float | None = None,
           leg_ease: float = 0.03, crotch_drop: float = 0.06, edge_length: float = 0.025,
           name: str = "shorts") -> Pattern:
    """Shorts: a seat from the waist to the crotch (front and back panels) and two leg tubes
    (default leg_length: 12 % of the height below the crotch, above the knee), waistband pinned
    to the pelvis. Sizes: seat girth from hips and clear_seat, waist from the hugged waist loop
    band_top + WAIST_EASE (without colliders: waist + ease and clear_top), hem radius
    thigh_low_radius + leg_ease (see _pants)."""
    _need(meas, "height")
    # 12 % of the height below the crotch, at most half the way to the floor
    crotch = (meas["crotch_y"] if "crotch_y" in meas else meas.get("hips_y", np.inf) - 0.05 * meas["height"]) \
        - meas.get("floor_y", 0.0)
    L = min(0.12 * meas["height"], 0.5 * crotch) if leg_length is None else leg_length
    r = meas.get("thigh_low_radius", 0.055 * meas["height"]) + leg_ease
    return _pants(meas, leg_length=L, hem_radius=r, ease=ease, hip_ease=hip_ease, crotch_drop=crotch_drop,
                  edge_length=edge_length, name=name)


def trousers(meas: dict, *, leg_length: float | None = None, ease: float = 0.2, hip_ease: float | None = None,
             leg_ease: float = 0.04, crotch_drop: float = 0.06, edge_length: float = 0.025,
             name: str = "trousers") -> Pattern:
    """Trousers: as shorts with leg tubes down to 3 % of the height above the ankle joint (along
    thigh and shin, which the tubes follow through a bent knee); hem radius shin_radius +
    leg_ease."""
    _need(meas, "height", "hips_y")
    if leg_length is None:
        L = min(meas.get(f"thigh_len_{s}", 0.24 * meas["height"]) + meas.get(f"shin_len_{s}", 0.24 * meas["height"])
                - _crotch_depth(meas, s) for s in ("l", "r")) - 0.03 * meas["height"]
    else:
        L = leg_length
    r = meas.get("shin_radius", 0.05 * meas["height"]) + leg_ease
    return _pants(meas, leg_length=L, hem_radius=r, ease=ease, hip_ease=hip_ease, crotch_drop=crotch_drop,
                  edge_length=edge_length, name=name)


def cape(meas: dict, *, length: float | None = None, edge_length: float = 0.03, name: str = "cape") -> Pattern:
    _need(meas, "height", "shoulder_y", "shoulder_half")
    h = meas["height"]
    # 45 % of the height, but at most 65 % of the way from its top to the floor (a chibi's shoulders
    # are at 40 % of its height)
    L = min(0.45 * h, 0.65 * (meas["shoulder_y"] + 0.03 * h - meas.get("floor_y", 0.0))) if length is None else length
    top = meas["shoulder_half"] + 0.02
    bottom = top + 0.25 * L
    edges = (line("hem", (bottom, 0.0)), line("side_l", (top, L)), line("top", (-top, L)), line("side_r", (-bottom, 0.0)))
    p = Panel("cape", edges, Placement("torso", angle_deg=180.0, span_deg=120.0,
                                       shift=meas["shoulder_y"] + 0.03 * h - L, offset=0.03, wrap_until=L,
                                       stretch=False))
    atts = (PatternAttachment("cape", "top", joint=COMMON_BONE, sewing=True),)
    # its top is gathered onto the neck (fit_band 1: the band's rest is the hugged length): walked
    # towards the neck's base, the top of a chibi's cape ends 36 % shorter than cut, and those pinned
    # edges stayed compressed at every frame (p99 strain 36 % on every clip)
    return Pattern(name, (p,), (), edge_length, atts, fit_edges=(SeamSide("cape", "top"),), fit_hug="neck",
                   fit_band=1.0)


def square(meas: dict, *, size: float = 1.0, edge_length: float = 0.025, height_above: float = 0.05,
           name: str = "square") -> Pattern:
    _need(meas, "height")
    s = size / 2
    edges = (line("e0", (s, -s)), line("e1", (s, s)), line("e2", (-s, s)), line("e3", (-s, -s)))
    y = meas.get("floor_y", 0.0) + meas["height"] + height_above
    p = Panel("square", edges, Placement("plane", center=(0.0, y, 0.0), normal=(0.0, 1.0, 0.0)))
    return Pattern(name, (p,), (), edge_length, ())


def library_pattern(kind: str, measurements: dict, **overrides) -> Pattern:
    """A built-in pattern sized from `measurements` (see garment_measurements); overrides go to the
    generator (e.g. length=, flare=, ease=, edge_length=, sleeve_length=, name=)."""
    if kind == "tshirt":
        return tshirt(measurements, **overrides)
    if kind in ("short_skirt", "long_skirt"):
        _need(measurements, "height", "waist_y")
        short = kind == "short_skirt"
        # a long skirt reaches 80 % of the way from where it is worn to the floor
        room = waistband_y(measurements) - measurements.get("floor_y", 0.0)
        # a short skirt: a quarter of the height, but at most 45 % of the way to the floor (a chibi's
        # legs are a quarter of its height); a long one 80 % of the way
        kw = dict(length=min(0.25 * measurements["height"], 0.45 * room) if short else 0.8 * room,
                  flare=1.35 if short else 1.9, name="skirt" if short else "long_skirt")
        kw.update(overrides)
        return skirt(measurements, **kw)
    if kind == "shorts":
        return shorts(measurements, **overrides)
    if kind == "trousers":
        return trousers(measurements, **overrides)
    if kind == "cape":
        from stages.garments.quadruped import blanket
        return (blanket if measurements.get("quadruped") else cape)(measurements, **overrides)
    if kind == "square":
        return square(measurements, **overrides)
    raise InputError("garment library", f"unknown kind {kind!r}; kinds: {', '.join(KINDS)}")


def hug_targets(character, origins: np.ndarray, points: np.ndarray, mode: str) -> np.ndarray:
    """(N, 3) where fit-edge points walk to (hug.hug): 'axis', horizontally to the body's
    vertical axis through the root; 'neck', to the base of the neck (a cape's top onto the
    shoulders)."""
    from stages.rig.humanoid import humanoid_joints
    if mode == "neck":
        neck = humanoid_joints(character).neck
        if neck >= 0:
            return np.broadcast_to(origins[neck], points.shape).copy()
    out = points.copy()
    out[:, [0, 2]] = origins[character.root_joint][[0, 2]]
    return out


def seam_label(seam: Seam) -> str:
    return " / ".join(f"{side.panel}.{'+'.join(side.edges)}" for side in (seam.a, seam.b))


@dataclass(frozen=True)
class GarmentBuild:
    """Everything make_garment produced, for logging: the flat meshes (pattern coordinates, z = 0,
    panels side by side), the placed unsewn mesh, the sewing log, and final placements.
    fit_vertices: (K,) int64, the Garment's particles on the pattern's fit_edges (waistband,
    collar), whose distance to the skin is the fit gap. seam_gaps: {seam label: largest gap of its
    vertex pairs after sewing, m}, label 'panel.edge / panel.edge'."""

    flat_positions: np.ndarray
    placed_positions: np.ndarray
    unsewn_triangles: np.ndarray
    seam_pairs: np.ndarray
    log: object
    placements: dict
    fit_vertices: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    seam_gaps: dict = field(default_factory=dict)

    def worst_seam(self) -> tuple[str, float]:
        """(label, gap m) of the seam left most open ('', 0) without seams."""
        return max(self.seam_gaps.items(), key=lambda kv: kv[1], default=("", 0.0))


def make_garment(pattern: Pattern, character, motion, colliders, maps, *, sew_params=None, attach: bool = True,
                 progress=None, under=(), under_gap: float = 0.0, ignore_joints=()):
    """Pattern -> Garment on the character in the bind pose (frame 0 of `motion`).

    Returns (Garment, SewingLog, GarmentBuild). The Garment's positions are the sewn shape (merged
    seam vertices), its rest lengths and masses come from the flat panels, and the pattern's
    attachments pin the chosen vertices to their bones.
    under: Garments worn under this one (lower cloth layers, in the same frame): the fit edges
    (a waistband) are hugged onto them, `under_gap` (m) off their surface, instead of onto the
    colliders where they are in the way, so a pinned band leaves room for what is tucked in under it.
    ignore_joints: joints whose colliders the simulation will not let push this garment (build_garment).
    """
    from stages.garments.sewing import SewParams, merged_mesh, seam_gaps, sew
    from stages.garments.untangle import untangle_sewn
    from stages.garments.triangulate import run_vertices, triangulate_pattern
    from scipy.spatial import cKDTree

    from stages.garments.over import push_over
    from stages.garments.hug import band_rest, gather_below, hug, respace
    from stages.garments.placement import UNDER_REACH, bind_geometry, place_pattern, triangle_grid_points
    from stages.garments.separation import OVER_CLEARANCE, leg_plane, separate_legs
    from stages.garments.types import attach_indices, bind_pose, build_garment

    sp = sew_params if sew_params is not None else SewParams()
    flat = triangulate_pattern(pattern)
    tri = flat.triangles
    uv = flat.uv
    tri_rest = np.linalg.norm(uv[tri[:, [1, 2, 0]]] - uv[tri], axis=2)
    placed, used = place_pattern(pattern, flat, character, motion, colliders)
    shift = np.concatenate([[0.0], np.cumsum([np.ptp(p.uv[:, 0]) + 0.1 for p in flat.panels])])[:-1]
    flat3 = np.concatenate([np.c_[p.uv[:, 0] - p.uv[:, 0].min() + s, p.uv[:, 1], np.zeros(len(p.uv))]
                            for p, s in zip(flat.panels, shift)])
    stage = np.array([pattern.seams[k].stage for k in flat.seam_index], np.int64)
    pose = bind_pose(character, motion, colliders)
    bind = pose if pattern.attachments else None

    def chosen(a):
        idx = run_vertices(pattern, flat, SeamSide(a.panel, a.edges))
        if a.at is not None:
            s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(uv[idx], axis=0), axis=1))])
            idx = idx[[int(np.argmin(np.abs(s - f * s[-1]))) for f in a.at]]
        joint = character.joint_names[character.root_joint] if a.joint == "root" else a.joint
        return idx, joint

    skinned0, origins, _ = bind_geometry(character, motion)
    over = np.zeros(placed.shape[0], bool)   # fit-edge vertices hugged over a garment worn under
    if pattern.fit_edges:
        # the edges meant to sit on the body (waistband, collar, a cape's top) are brought onto the
        # colliders (see hug); a waistband is then pinned there
        below = (np.concatenate([triangle_grid_points(g.positions, g.triangles) for g in under])
                 if len(under) else None)
        pinned = {(a.panel, a.edges) for a in pattern.attachments}
        for side in pattern.fit_edges:
            idx = run_vertices(pattern, flat, side)
            if below is not None:
                over[idx] = cKDTree(below).query(placed[idx], distance_upper_bound=UNDER_REACH + under_gap)[0] < np.inf
            placed[idx] = hug(placed[idx], hug_targets(character, origins, placed[idx], pattern.fit_hug), character,
                              skinned0, pose, under=below, under_gap=under_gap,
                              through_arms=pattern.fit_hug == "axis" and (side.panel, side.edges) in pinned)
            if (side.panel, side.edges) in pinned:    # a waistband, pinned where it ends up: evenly
                placed[idx] = respace(placed[idx], uv[idx])   # spaced (a free collar: as hugged)
            if pattern.fit_band is not None:
                if pattern.fit_hug == "neck":   # walked towards a point, a band always ends shorter than cut
                    gather_below(tri, tri_rest, uv, idx, placed, flat.panel_of_vertex)
                band_rest(tri, tri_rest, idx, placed, pattern.fit_band)

    def middle_half(idx):
        """The middle half of a run (by length) without its seam vertices: the ends stay free so that
        the seams there can close even where the placement had to stretch the band around a collider;
        a run without seams (a cape's top) whole, else its free ends swing off the shoulders while
        sewing. Hugged over a garment worn under it, the whole run stays where it was hugged (outside
        it: the seams' ends pulled in would close the band through it)."""
        if not np.isin(idx, flat.seam_pairs.ravel()).any():
            return idx
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(uv[idx], axis=0), axis=1))])
        f = s / max(s[-1], 1e-12)
        return np.setdiff1d(idx[(f >= 0.25) & (f <= 0.75) | over[idx]], flat.seam_pairs.ravel())

    pins = []
    for a in pattern.attachments:
        if a.sewing:
            idx, joint = chosen(a)
            idx = middle_half(idx)
            if idx.size:
                pins.append(attach_indices(idx, joint))

    def sew_held(pins):
        return sew(pattern.name, placed, tri, tri_rest, flat.seam_pairs, character, motion, colliders, maps, sp,
                   density=pattern.density, flat_positions=flat3, pair_stage=stage, pins=pins, bind=bind,
                   progress=progress)
    sewn, log = sew_held(pins)
    runs = [run_vertices(pattern, flat, side) for side in pattern.fit_edges]
    pinned = np.concatenate([np.asarray(a.indices) for a in pins]) if pins else np.zeros(0, np.int64)
    free = [r for r in runs if not np.isin(r, pinned).any()]
    if free:
        # fallback: a collar whose sewing pulled it off the body (its corners stand off the hollow
        # between neck and shoulders, the patterns' flat rest shape pushing them out) is sewn again,
        # held where it was hugged until the seams are closed, then free as before
        from stages.geometry.skin_distance import SkinDistance
        body = SkinDistance(character)
        body.refit(np.ascontiguousarray(skinned0, np.float64))
        gap = float(np.median(signed_skin_distance(body, sewn[np.concatenate(free)])))
        if gap > FIT_GAP_MAX:
            sewn2, log2 = sew_held(pins + [attach_indices(middle_half(r), None) for r in free])
            gap2 = float(np.median(signed_skin_distance(body, sewn2[np.concatenate(free)])))
            if log2.gap_max[-1] <= max(sp.tolerance, log.gap_max[-1]) and gap2 < gap:
                note = (f"fit edges held where hugged while sewing: {gap * 100:.1f} cm from the skin "
                        f"(median) when free, {gap2 * 100:.1f} cm held")
                sewn, log = sewn2, replace(log2, notes=log2.notes + (note,))
    pos, mtri, remap = merged_mesh(sewn, tri, flat.seam_pairs)
    # start apart (stages.garments.separation): the legs on their own sides of the plane between
    # the thighs, the whole garment outside the ones worn under it
    names = [p.name for p in flat.panels]
    if "leg_l" in names and "leg_r" in names:
        legs = [remap[flat.offsets[names.index(k)]:flat.offsets[names.index(k) + 1]] for k in ("leg_l", "leg_r")]
        pos = separate_legs(pos, legs[0], legs[1], leg_plane(character, origins))
    band = np.unique(remap[np.flatnonzero(over)])     # a band hugged over them: placed as it is below
    if len(under):
        rest = np.setdiff1d(np.arange(pos.shape[0]), band)
        pos[rest] = push_over(pos[rest], hug_targets(character, origins, pos[rest], "axis"), under,
                              under_gap + OVER_CLEARANCE)
    if band.size:
        # the seams' ends were free while sewing: where one closed inside a garment worn under it (the
        # sharp side seam of a T-shirt), it goes out over it; the band's edges are cut to the new length
        moved = push_over(pos[band], hug_targets(character, origins, pos[band], pattern.fit_hug), under, under_gap)
        changed = band[np.any(moved != pos[band], axis=1)]
        pos[band] = moved
        if changed.size:
            tri_rest = tri_rest.copy()
            for k in range(3):
                a, b = mtri[:, k], mtri[:, (k + 1) % 3]
                e = (np.isin(a, changed) | np.isin(b, changed)) & np.isin(a, band) & np.isin(b, band)
                tri_rest[e, k] = np.maximum(tri_rest[e, k], np.linalg.norm(pos[a[e]] - pos[b[e]], axis=1))
    # a few edges folded through the garment's own triangles while sewing (a leg's inseam closing
    # at the hem: CesiumMan's shorts 3-4 edges) are moved back out (the simulation would keep them)
    pos, log = untangle_sewn(pos, mtri, log)
    atts = []
    if attach and pattern.attachments:
        for a in pattern.attachments:
            idx, joint = chosen(a)
            atts.append(attach_indices(np.unique(remap[idx]), joint))
    g = build_garment(pattern.name, pos, mtri, density=pattern.density, triangle_rest=tri_rest, attachments=atts,
                      bind=bind, ignore_joints=ignore_joints)
    fit = np.unique(remap[np.concatenate(runs)]).astype(np.int64) if runs else np.zeros(0, np.int64)
    gaps = seam_gaps(sewn, flat.seam_pairs)
    by_seam = {}
    for k, seam in enumerate(pattern.seams):
        m = flat.seam_index == k
        if m.any():
            by_seam[seam_label(seam)] = float(gaps[m].max())
    build = GarmentBuild(flat3, placed, tri, flat.seam_pairs, log, used, fit, by_seam)
    return g, log, build
