"""Built-in garment patterns sized from the character's measurements, and the garment maker
(pattern -> flat meshes -> placed panels -> sewn Garment).

Kinds: 'tshirt', 'short_skirt', 'long_skirt', 'cape', 'square'. Sizes come from
`garment_measurements(character)` (stages.rig.procedural.body_measurements plus shoulder and arm
sizes from the skeleton): girths with ease, lengths as fractions of the body's heights.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from stages.errors import InputError
from stages.garments.patterns import (Panel, Pattern, PatternAttachment, Placement, Seam, SeamSide, cubic, line,
                                      quad)

KINDS = ("tshirt", "short_skirt", "long_skirt", "cape", "square")


def garment_measurements(character) -> dict:
    """body_measurements plus, from the skeleton at rest (metres, world): shoulder_y (upper-arm
    joint height), shoulder_half (|x| of the upper-arm joint from the root), neck_y (neck-base
    joint height or 0.82 height), arm_girth (upper-arm circumference estimate), floor_y."""
    from stages.garments.placement import _chain
    from stages.rig.procedural import body_measurements
    from stages.rig.transforms import forward_kinematics
    m = dict(body_measurements(character))
    w = forward_kinematics(character.parents, character.rest_local)[:, :3, 3]
    h = m["height"]
    y0 = float(character.vertices[:, 1].min())
    root = w[character.root_joint]
    arm = _chain(character, "arm", "l")
    if arm is not None:
        m["shoulder_y"] = float(w[arm[0], 1])
        m["shoulder_half"] = float(abs(w[arm[0], 0] - root[0]))
        dom = character.skin_joints[np.arange(len(character.vertices)), np.argmax(character.skin_weights, axis=1)]
        v = character.vertices[dom == arm[0]]
        if len(v) >= 4:
            d = w[arm[1]] - w[arm[0]]
            d /= np.linalg.norm(d)
            rel = v - w[arm[0]]
            r = np.linalg.norm(rel - np.outer(rel @ d, d), axis=1)
            m["arm_girth"] = float(2 * np.pi * np.percentile(r, 90))
    m.setdefault("shoulder_y", y0 + 0.81 * h)
    m.setdefault("shoulder_half", 0.105 * h)
    m.setdefault("arm_girth", 0.21 * h)
    names = character.joint_names
    neck = next((names.index(n) for n in ("neck", "Neck", "neck_01") if n in names), None)
    m["neck_y"] = float(w[neck, 1]) if neck is not None else y0 + 0.82 * h
    m["floor_y"] = y0
    return m


def _need(meas: dict, *keys):
    for k in keys:
        if k not in meas or not np.isfinite(meas[k]):
            raise InputError("garment measurements", f"missing or NaN {k!r} (have {sorted(meas)})")


def _torso_panel(name, hw, sw, nw, ha, hs, hn, neck_depth, angle, hem_y):
    """Front / back T-shirt body: hem at v = 0, armpits at ha, shoulder points at hs, neck points at hn."""
    dy = hs - ha
    edges = (
        line("hem", (hw, 0.0)),
        line("side_l", (hw, ha)),
        cubic("armhole_l", (sw + 0.4 * (hw - sw), ha), (sw, ha + 0.5 * dy), (sw, hs)),
        line("shoulder_l", (nw, hn)),
        cubic("neck", (nw, hn - 4 / 3 * neck_depth), (-nw, hn - 4 / 3 * neck_depth), (-nw, hn)),
        line("shoulder_r", (-sw, hs)),
        cubic("armhole_r", (-sw, ha + 0.5 * dy), (-sw - 0.4 * (hw - sw), ha), (-hw, ha)),
        line("side_r", (-hw, 0.0)),
    )
    return Panel(name, edges, Placement("torso", angle_deg=angle, span_deg=180.0, shift=hem_y, offset=0.02,
                                       wrap_until=ha))


def tshirt(meas: dict, *, ease: float = 0.12, length_below_waist: float | None = None, sleeve_length: float | None = None,
           edge_length: float = 0.025, name: str = "tshirt") -> Pattern:
    _need(meas, "height", "chest", "waist", "hips", "waist_y", "hips_y", "shoulder_y", "shoulder_half", "neck_y",
          "arm_girth", "arm_length")
    h = meas["height"]
    hem_y = meas["hips_y"] - 0.02 * h if length_below_waist is None else meas["waist_y"] - length_below_waist
    girth = max(meas["chest"], meas["waist"], meas["hips"] if hem_y < meas["hips_y"] + 0.05 else 0.0) + ease
    hw = girth / 4
    sw = meas["shoulder_half"] + 0.01 * h
    nw = 0.045 * h
    hs = meas["shoulder_y"] + 0.02 * h - hem_y
    hn = hs + 0.02 * h
    sleeve_circ = meas["arm_girth"] + 0.08 + 2 * np.pi * 0.02
    lam = sleeve_circ / 2   # wanted armhole length (front = back)
    depth = np.sqrt(max(lam ** 2 / 1.1 ** 2 - (hw - sw) ** 2, (0.08 * h) ** 2))
    ha = hs - depth
    front = _torso_panel("front", hw, sw, nw, ha, hs, hn, 0.06 * h * 0.6, 0.0, hem_y)
    back = _torso_panel("back", hw, sw, nw, ha, hs, hn, 0.012 * h, 180.0, hem_y)
    lam = 0.5 * (front.edge_length(front.edge_index("armhole_l")) + back.edge_length(back.edge_index("armhole_l")))
    sl = 0.12 * h if sleeve_length is None else sleeve_length
    panels = [front, back]
    seams = [Seam(SeamSide("front", "side_l"), SeamSide("back", "side_r")),
             Seam(SeamSide("back", "side_l"), SeamSide("front", "side_r")),
             Seam(SeamSide("front", "shoulder_l"), SeamSide("back", "shoulder_r")),
             Seam(SeamSide("back", "shoulder_l"), SeamSide("front", "shoulder_r"))]
    for side in ("l", "r"):
        # u > 0 of a sleeve faces the back on the left arm and the front on the right arm (see placement)
        first, second = ("cap_back", "cap_front") if side == "l" else ("cap_front", "cap_back")
        edges = (line("cuff", (lam, 0.0)), line("under_a", (lam, sl)), line(first, (0.0, sl)),
                 line(second, (-lam, sl)), line("under_b", (-lam, 0.0)))
        pname = f"sleeve_{side}"
        panels.append(Panel(pname, edges, Placement(f"arm_{side}", angle_deg=0.0, span_deg=360.0,
                                                    shift=-(sl + 0.02 * h), offset=0.02)))
        seams.append(Seam(SeamSide(pname, "under_a"), SeamSide(pname, "under_b")))
        front_hole, back_hole = ("armhole_l", "armhole_r") if side == "l" else ("armhole_r", "armhole_l")
        seams.append(Seam(SeamSide(pname, "cap_front"), SeamSide("front", front_hole)))
        seams.append(Seam(SeamSide(pname, "cap_back"), SeamSide("back", back_hole)))
    atts = (PatternAttachment("front", "shoulder_l"), PatternAttachment("front", "shoulder_r"))
    return Pattern(name, tuple(panels), tuple(seams), edge_length, atts)


def skirt(meas: dict, *, length: float, flare: float, ease: float = 0.2, hip_ease: float = 0.32,
          edge_length: float = 0.025, name: str = "skirt") -> Pattern:
    """Two panels (front, back) from the waist: hip-wide below the hips, flared to the hem. The
    ease is generous because the cloth must clear the inflated colliders (joint spheres at the hips),
    not only the body."""
    _need(meas, "height", "waist", "hips", "waist_y", "hips_y")
    top_y = meas["waist_y"]
    dh = min(max(top_y - meas["hips_y"], 0.02), 0.8 * length)
    ht = (meas["waist"] + ease) / 4
    hh = (max(meas["hips"], meas["waist"]) + hip_ease) / 4
    hem = max(hh * flare, hh)
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
    atts = (PatternAttachment("front", "waist", joint="root"), PatternAttachment("back", "waist", joint="root"))
    return Pattern(name, tuple(panels), seams, edge_length, atts)


def cape(meas: dict, *, length: float | None = None, edge_length: float = 0.03, name: str = "cape") -> Pattern:
    _need(meas, "height", "shoulder_y", "shoulder_half")
    h = meas["height"]
    L = 0.45 * h if length is None else length
    top = meas["shoulder_half"] + 0.02
    bottom = top + 0.25 * L
    edges = (line("hem", (bottom, 0.0)), line("side_l", (top, L)), line("top", (-top, L)), line("side_r", (-bottom, 0.0)))
    p = Panel("cape", edges, Placement("torso", angle_deg=180.0, span_deg=120.0,
                                       shift=meas["shoulder_y"] + 0.03 * h - L, offset=0.03, wrap_until=L))
    atts = (PatternAttachment("cape", "top", at=(0.0, 1.0)),)
    return Pattern(name, (p,), (), edge_length, atts)


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
        kw = dict(length=0.25 * measurements["height"] if short else 0.85 * (measurements["waist_y"] - measurements.get("floor_y", 0.0)),
                  flare=1.35 if short else 1.9, name="skirt" if short else "long_skirt")
        kw.update(overrides)
        return skirt(measurements, **kw)
    if kind == "cape":
        return cape(measurements, **overrides)
    if kind == "square":
        return square(measurements, **overrides)
    raise InputError("garment library", f"unknown kind {kind!r}; kinds: {', '.join(KINDS)}")


@dataclass(frozen=True)
class GarmentBuild:
    """Everything make_garment produced, for logging: the flat meshes (pattern coordinates, z = 0,
    panels side by side), the placed unsewn mesh, the sewing log, and final placements."""

    flat_positions: np.ndarray
    placed_positions: np.ndarray
    unsewn_triangles: np.ndarray
    seam_pairs: np.ndarray
    log: object
    placements: dict


def make_garment(pattern: Pattern, character, motion, colliders, maps, *, sew_params=None, attach: bool = True):
    """Pattern -> Garment on the character in the bind pose (frame 0 of `motion`).

    Returns (Garment, SewingLog, GarmentBuild). The Garment's positions are the sewn shape (merged
    seam vertices), its rest lengths and masses come from the flat panels, and the pattern's
    attachments pin the chosen vertices to their bones.
    """
    from stages.garments.sewing import SewParams, merged_mesh, sew
    from stages.garments.triangulate import run_vertices, triangulate_pattern
    from stages.garments.placement import place_pattern
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
    sewn, log = sew(pattern.name, placed, tri, tri_rest, flat.seam_pairs, character, motion, colliders, maps, sp,
                    density=pattern.density, flat_positions=flat3)
    pos, mtri, remap = merged_mesh(sewn, tri, flat.seam_pairs)
    atts = []
    bind = None
    if attach and pattern.attachments:
        bind = bind_pose(character, motion, colliders)
        for a in pattern.attachments:
            idx = run_vertices(pattern, flat, SeamSide(a.panel, a.edges))
            if a.at is not None:
                s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(uv[idx], axis=0), axis=1))])
                idx = idx[[int(np.argmin(np.abs(s - f * s[-1]))) for f in a.at]]
            joint = character.joint_names[character.root_joint] if a.joint == "root" else a.joint
            atts.append(attach_indices(np.unique(remap[idx]), joint))
    g = build_garment(pattern.name, pos, mtri, density=pattern.density, triangle_rest=tri_rest, attachments=atts,
                      bind=bind)
    build = GarmentBuild(flat3, placed, tri, flat.seam_pairs, log, used)
    return g, log, build
