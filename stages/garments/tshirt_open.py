"""The T-shirt for arms whose root fills the torso's side (a chibi's block arm, held out at the height
of its whole torso, under a head that sits on the torso): no shoulders to sew over.

`library.tshirt` hangs a shirt from shoulder seams on a ridge above the armholes, its armpit two
sleeve radii below the shoulder top. Where the arm's root is as tall as the torso, that armpit falls
below the hem (a Kenney mini: 5 cm below it) and there is no shoulder between the arm and the head.
This cut is a tube round the torso, from the hem to just under the head (its top edge is the
neckline, hugged onto the body and pinned to it), with an armhole on each side from the armpit
round the front (back) of the arm's root up to that top edge; each sleeve is a U round the arm's
front, underside and back, its end at the torso's side sewn to the front and back armholes, open
over the arm's top: that lies under the head, whose collider (a chibi's is the hull of its head, 4-5
cm off the skin under its cheeks) overlaps the arm's there. A closed sleeve's top was held between
the two (dressed p99 strain 35 %, static clip), and each time the arm rose (melee, shoot, pick-up)
it was torn past 500 % and the run stopped.
"""
from __future__ import annotations

import numpy as np

from stages.garments.patterns import (Panel, Pattern, PatternAttachment, Placement, Seam, SeamSide, cubic, line)
from stages.garments.types import COMMON_BONE

ROUNDED_BOX = 2.0 ** 0.25
ROOT_KEYS = ("torso_side", "arm_root_lo", "arm_root_hi", "arm_root_front", "arm_root_back")
SLEEVE_CLEARANCE = 0.01   # m, a sleeve's radius over the arm's (as library.tshirt)
TOP_EDGES = 2             # at least this many edges of the armhole above the armpit


def _rounded_box(b: float, c: float, above: float, n: int = 720) -> tuple[float, float]:
    """(perimeter, length of the part higher than `above`) of the superellipse |y/b|^4 + |z/c|^4 = 1."""
    t = np.linspace(0.0, 2 * np.pi, n + 1)
    y = b * np.sign(np.cos(t)) * np.abs(np.cos(t)) ** 0.5
    z = c * np.sign(np.sin(t)) * np.abs(np.sin(t)) ** 0.5
    seg = np.hypot(np.diff(y), np.diff(z))
    high = 0.5 * (y[1:] + y[:-1]) > above
    return float(seg.sum()), float(seg[high].sum())


def fits(meas: dict, armpit_y: float, hem_y: float, edge_length: float) -> bool:
    """Whether this cut is the one to use: the regular T-shirt's armpit (`armpit_y`) leaves less than
    two edges of side seam above its hem, and the arm's root was measured beside the torso."""
    return armpit_y - hem_y < 2 * edge_length and all(k in meas for k in ROOT_KEYS)


def open_top_tshirt(meas: dict, *, hem_y: float, chest: float, hem: float, sleeve_length: float | None,
                    edge_length: float, name: str) -> Pattern:
    """Front, back and two sleeves (see the module docstring). hem_y, chest, hem: as library.tshirt
    sizes them (the hem's height, the chest's and the hem's girths)."""
    h = meas["height"]
    # round the torso where the arms leave it, measured on its surface (a low-poly box torso's few
    # vertices near the chest gave a girth 13 % short, and the side seams stayed 5 mm open)
    chest = max(chest, meas.get("torso_band", 0.0))
    cw, hw = chest / 4, max(hem, chest) / 4
    top_y = min(meas["neck_low"], meas["arm_root_hi"])      # the neckline: under the head
    # the sleeve round the arm's root as the placement wraps it: a rounded box (superellipse n = 4)
    # through the corners of the root's extent (a box's corners lie ROUNDED_BOX times its half-sizes out)
    mid = 0.5 * (meas["arm_root_lo"] + meas["arm_root_hi"])
    B = ROUNDED_BOX * 0.5 * (meas["arm_root_hi"] - meas["arm_root_lo"])
    C = ROUNDED_BOX * 0.5 * (meas["arm_root_front"] - meas["arm_root_back"])
    girth, free = _rounded_box(B, C, top_y - mid)
    lam = 0.5 * girth                                  # half the sleeve's girth
    sewn = 0.5 * (girth - free)                        # its front (back) part below the neckline
    armpit = mid - B
    # at least one edge of side seam below the armpit: the hem comes down where the sleeve reaches it
    hem_y = min(hem_y, armpit - edge_length)
    ha, H = armpit - hem_y, top_y - hem_y
    if H - ha < TOP_EDGES * edge_length or sewn < TOP_EDGES * edge_length:
        from stages.errors import InputError
        raise InputError("garment 'tshirt'", f"the arm's root ({meas['arm_root_lo']:.3f}-{meas['arm_root_hi']:.3f} m "
                                             f"high) leaves {(top_y - armpit) * 100:.1f} cm of torso above the armpit "
                                             "under the head: a T-shirt cannot be cut for this body; a cape or a mesh "
                                             "garment fits it")

    def armhole(inset: float, sign: float, rising: bool):
        """From the armpit (on the side, the panel's edge u = cw) round the arm's root to the neckline."""
        c1, c2 = (sign * (cw - 0.55 * inset), ha), (sign * (cw - inset), ha + 0.45 * (H - ha))
        if rising:
            return cubic(f"armhole_{'l' if sign > 0 else 'r'}", c1, c2, (sign * (cw - inset), H))
        return cubic(f"armhole_{'l' if sign > 0 else 'r'}", c2, c1, (sign * cw, ha))

    def hole_length(inset: float) -> float:
        return Panel("h", (line("a", (cw, ha)), armhole(inset, 1.0, True), line("b", (0.0, H)), line("c", (0.0, 0.0))),
                     Placement("plane")).edge_length(1)
    # the armhole as long as the sleeve's part sewn to it: reaching as far round the root as needed
    lo, hi = 0.0, cw - 2 * edge_length
    if hole_length(hi) < sewn:
        sewn = hole_length(hi)
    for _ in range(30):
        m = 0.5 * (lo + hi)
        lo, hi = (m, hi) if hole_length(m) < sewn else (lo, m)
    inset = 0.5 * (lo + hi)
    u_t = cw - inset
    panels, seams = [], []
    for pname, angle in (("front", 0.0), ("back", 180.0)):
        edges = (line("hem", (hw, 0.0)), line("side_l", (cw, ha)), armhole(inset, 1.0, True), line("neck", (-u_t, H)),
                 armhole(inset, -1.0, False), line("side_r", (-hw, 0.0)))
        panels.append(Panel(pname, edges, Placement("torso", angle_deg=angle, span_deg=180.0, shift=hem_y,
                                                    offset=0.015, wrap_until=ha, exponent=4.0, arms=False)))
    seams += [Seam(SeamSide("front", "side_l"), SeamSide("back", "side_r")),
              Seam(SeamSide("back", "side_l"), SeamSide("front", "side_r"))]
    sl = 0.1 * h if sleeve_length is None else sleeve_length
    # the sleeve's end on the torso's side, along the arm from its shoulder point
    alpha = float(np.clip(meas.get("arm_angle", 0.0), 0.0, np.radians(70)))
    t_end = (meas["shoulder_half"] - meas["torso_side"]) / np.cos(alpha)
    for side in ("l", "r"):
        # the sleeve is open over the arm's top (no cloth under the head: raised, the arm pressed a
        # closed sleeve's top into the head's collider and tore it): a U round the arm's front, underside
        # and back, its middle (u = 0) under the arm, where the placement's angle 180 puts it; from
        # there u > 0 faces the front on the left arm and the back on the right arm (see placement)
        first, second = ("cap_front", "cap_back") if side == "l" else ("cap_back", "cap_front")
        edges = (line("cuff", (sewn, 0.0)), line("open_a", (sewn, sl)), line(first, (0.0, sl)),
                 line(second, (-sewn, sl)), line("open_b", (-sewn, 0.0)))
        pname = f"sleeve_{side}"
        panels.append(Panel(pname, edges, Placement(f"arm_{side}", angle_deg=180.0, span_deg=360.0 * sewn / lam,
                                                    shift=t_end - sl, offset=SLEEVE_CLEARANCE, wrap_until=sl,
                                                    exponent=4.0)))
        front_hole, back_hole = ("armhole_l", "armhole_r") if side == "l" else ("armhole_r", "armhole_l")
        seams.append(Seam(SeamSide(pname, "cap_front"), SeamSide("front", front_hole), stage=1))
        seams.append(Seam(SeamSide(pname, "cap_back"), SeamSide("back", back_hole), stage=1))
    # the neckline holds the shirt up (no shoulders): pinned to the torso while sewing and after
    atts = (PatternAttachment("front", "neck", joint=COMMON_BONE, sewing=True),
            PatternAttachment("back", "neck", joint=COMMON_BONE, sewing=True))
    return Pattern(name, tuple(panels), tuple(seams), edge_length, atts,
                   fit_edges=(SeamSide("front", "neck"), SeamSide("back", "neck")), fit_band=0.9)
