"""GarmentCode patterns on any character: the flat panels as this pipeline's `Pattern` (meshed with
Triangle), their 3D placement on the pattern's body (GarmentCode's translation / rotation) mapped
onto the character's bind pose from the two bodies' measurements, then sewn.

The map (`BodyMap`): heights piecewise linear through matching landmarks (floor, hips, waist, bust,
shoulders, top of the head), met where the garment hangs from (its top, at most the shoulders) and
elsewhere with each span's slope kept within SLOPE_BOUNDS (a body's short torso does not squash a
top 6x); horizontal offsets from the body's vertical axis scaled by the ratio of
the character's girth to the pattern body's at that height (hips, waist, bust); arm panels (label
'arm') turned about the pattern body's shoulder point by the difference of the two arm angles and
carried to the character's shoulder joint. Panels that then start far from the panels they are
sewn to (a hood beside the head, sleeves off their armholes) are moved onto them (align_to_stitches).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace as dc_replace
from pathlib import Path

import numpy as np
import yaml

from stages.errors import InputError
from stages.garments.garmentcode import GCPattern, edge_points, panel_part
from stages.garments.garmentcode_band import band_floor, band_vertices, lift_band, worn_from_waistband
from stages.garments.garmentcode_grade import Grade, grade, graded_body, grading
from stages.garments.garmentcode_heights import cut_above, limited_heights
from stages.garments.garmentcode_legs import apart, leg_axes
from stages.garments.garmentcode_shoulders import shoulder_lift, shoulder_pairs, shoulder_surface
from stages.garments.garmentcode_sleeves import fit_sleeves
from stages.garments.garmentcode_wrap import wrap_legs, wrap_ring, wrap_sleeves
from stages.garments.patterns import Edge, Panel, Pattern, PatternAttachment, Placement, Seam, SeamSide
from stages.garments.types import TRUNK_BONE

# GarmentCode's default body, under the real assets folder (pipeline.assets.assets_dir)
DEFAULT_BODY = Path("garmentcode") / "bodies" / "mean_all.yaml"
BODY_KEYS = ("height", "head_l", "waist_line", "hips_line", "bust_line", "waist", "hips", "bust",
             "shoulder_w", "arm_pose_angle")


@dataclass(frozen=True)
class GCBody:
    """A GarmentCode body (body_measurements.yaml, cm and degrees), as metres and radians.

    height: m. waist_y, hips_y, bust_y, shoulder_y: levels above the floor, m (shoulder_y: height -
    head_l, the base of the neck). waist, hips, bust: girths, m. shoulder_half: half of shoulder_w,
    m. arm_angle: arm_pose_angle, rad below the horizontal. values: every key of the file (cm, deg).
    source: the file."""

    height: float
    waist_y: float
    hips_y: float
    bust_y: float
    shoulder_y: float
    waist: float
    hips: float
    bust: float
    shoulder_half: float
    arm_angle: float
    values: dict
    source: str


def read_body(path) -> GCBody:
    """A GarmentCode body_measurements.yaml (top key `body`); errors name the file and the key."""
    from stages.input_files import read_text_file
    from stages.safe_yaml import load_checked
    src = str(path)

    def fail(message: str) -> InputError:   # the checks' line names the file (and line, column) already
        err = InputError(src, message)
        err.args = (message,)
        return err
    try:   # a regular file of bounded size, YAML that cannot expand or nest without bound
        data, _ = load_checked(read_text_file(Path(path), "body measurements file", fail), src, fail)
    except yaml.YAMLError as e:
        raise InputError(src, f"cannot read the body measurements ({e.__class__.__name__}: {e})") from None
    body = data.get("body") if isinstance(data, dict) else None
    if not isinstance(body, dict):
        raise InputError(src, "body: expected a mapping of GarmentCode body measurements (cm, degrees)")
    for k in BODY_KEYS:
        v = body.get(k)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
            raise InputError(src, f"body.{k}: expected a positive number (cm or degrees), got {v!r}")
    b = {k: float(v) for k, v in body.items() if isinstance(v, (int, float))}
    top = b["height"] - b["head_l"]
    waist = top - b["waist_line"]
    return GCBody(b["height"] / 100, waist / 100, (waist - b["hips_line"]) / 100, (top - b["bust_line"]) / 100,
                  top / 100, b["waist"] / 100, b["hips"] / 100, b["bust"] / 100, b["shoulder_w"] / 200,
                  math.radians(b["arm_pose_angle"]), b, src)


def body_of(spec_path, default_body: Path) -> GCBody:
    """The body a pattern was made for: body_measurements.yaml beside the spec, else GarmentCode's
    default body (mean_all) at `default_body` (the caller's assets folder / DEFAULT_BODY)."""
    beside = Path(spec_path).parent / "body_measurements.yaml"
    if beside.is_file():
        return read_body(beside)
    if not Path(default_body).is_file():
        raise InputError(str(spec_path), f"no body_measurements.yaml beside the pattern and no default body at "
                                         f"{default_body} (GarmentCode's mean_all.yaml; GARMENT_ASSETS sets the folder)")
    return read_body(Path(default_body))


def to_pattern(gc: GCPattern, edge_length: float, name: str, density: float = 0.2) -> tuple[Pattern, dict]:
    """(Pattern, {panel: u sign}) of a GarmentCode pattern: panels as outlines of edges 'e0', 'e1', ...
    (circle arcs through their midpoint), clockwise loops mirrored (u -> -u, the sign -1) so every
    outline is counter-clockwise; stitches as seams (reversed unless right_wrong); edges labelled
    lower_interface / collars held while sewing (attachments with sewing=True, pinned to their
    nearest bone)."""
    from stages.checks import ContractError
    panels, signs = [], {}
    for p in gc.panels:
        s = 1.0 if p.ccw else -1.0
        signs[p.name] = s
        m = np.array([s, 1.0])
        edges = []
        for k, e in enumerate(p.edges):
            end = tuple(p.vertices[e.end] * m)
            if e.kind == "straight":
                edges.append(Edge(f"e{k}", "line", (end,)))
            elif e.kind == "circle":
                mid = edge_points(p, e, [0.5])[0] * m
                edges.append(Edge(f"e{k}", "arc", (tuple(mid), end)))
            else:
                kind = "quad" if e.kind == "quadratic" else "cubic"
                edges.append(Edge(f"e{k}", kind, tuple(tuple(np.asarray(c) * m) for c in e.control) + (end,)))
        try:   # patterns.Panel: edge k starts where edge k-1 ends (edge 0 where the last ends), as here
            panels.append(Panel(p.name, tuple(edges), Placement("plane")))
        except ContractError as err:
            raise InputError(gc.source, f"pattern.panels.{p.name}: cannot be meshed: {err}") from None
    seams = tuple(Seam(SeamSide(st.a[0], f"e{st.a[1]}"), SeamSide(st.b[0], f"e{st.b[1]}"), reverse=not st.right_wrong)
                  for st in gc.stitches)
    held = tuple(PatternAttachment(p.name, f"e{k}", joint=TRUNK_BONE, sewing=True)
                 for p in gc.panels for k, e in enumerate(p.edges) if e.label in ("lower_interface",))
    try:
        return Pattern(name, tuple(panels), seams, edge_length, held, density=density), signs
    except ContractError as err:
        raise InputError(gc.source, f"cannot be sewn: {err}") from None


def stitch_lengths(gc: GCPattern) -> list[tuple[float, float]]:
    """(length of side A, length of side B), m, of every stitch."""
    from stages.garments.garmentcode import edge_length
    return [tuple(edge_length(gc.panel(pn), gc.panel(pn).edges[k]) for pn, k in (st.a, st.b)) for st in gc.stitches]


GATHER_NOTED = 1.25   # sides' length ratio from which a seam left open is explained as gathered


def gathered_note(gc: GCPattern, seam: str) -> str:
    """Why the seam labelled 'panel.eA / panel.eB' may stay open: '' or a sentence giving its sides'
    lengths when they differ by GATHER_NOTED or more (GarmentCode gathers the longer side into the
    shorter; this sewing gathers the longer side onto the shorter by its rest lengths (gather.gathered_rest),
    and on the body such seams can still stall: the sampled tee's armholes, 37.6 vs 22.2 cm)."""
    for st, (la, lb) in zip(gc.stitches, stitch_lengths(gc)):
        if f"{st.a[0]}.e{st.a[1]} / {st.b[0]}.e{st.b[1]}" == seam and max(la, lb) >= GATHER_NOTED * min(la, lb):
            return (f"its sides are {la * 100:.1f} cm and {lb * 100:.1f} cm long: GarmentCode gathers the longer "
                    f"side; this sewing gathers it onto the shorter (gather.gathered_rest), which sides "
                    f"{GATHER_NOTED:.2f}x apart or more do not always close over the body")
    return ""


def check_stitch_chains(gc: GCPattern, pattern: Pattern, flat) -> None:
    """InputError when the stitches, followed from panel to panel, join two points of one panel that
    no stitch of that panel with itself (a dart) joins: sewing would have to fold the panel onto
    itself (GarmentCode's standing_lapel example: its collar stitches chain two points of each collar
    panel 7 cm apart; the library cannot stitch it either)."""
    from stages.garments.library import seam_label
    from stages.garments.sewing import merge_pairs
    pairs = flat.seam_pairs
    if pairs.size == 0:
        return
    group = merge_pairs(flat.uv.shape[0], pairs)
    pv = flat.panel_of_vertex
    own = pairs[pv[pairs[:, 0]] == pv[pairs[:, 1]]]          # pairs of a panel with itself (darts)
    own_group = merge_pairs(flat.uv.shape[0], own)
    order = np.lexsort((pv, group))
    g, p = group[order], pv[order]
    dup = np.flatnonzero((g[1:] == g[:-1]) & (p[1:] == p[:-1]))
    for i in dup:
        u, v = order[i], order[i + 1]
        if own_group[u] == own_group[v]:
            continue
        seams = sorted({seam_label(pattern.seams[k]) for k in flat.seam_index[np.isin(group[pairs[:, 0]], group[u])]})
        far = float(np.linalg.norm(flat.uv[u] - flat.uv[v]))
        raise InputError(gc.source, f"the stitches {', '.join(seams)} join two points of panel "
                                    f"{pattern.panels[pv[u]].name!r} {far * 100:.1f} cm apart (followed from panel to "
                                    f"panel, no stitch of that panel joins them): sewn, the panel would fold onto itself")


@dataclass(frozen=True)
class BodyMap:
    """From the pattern body's frame (m, GarmentCode) to the character's relative frame at frame 0.

    src_y, dst_y: (K,) matching levels (ascending). src_girth_y, ratio: (3,) levels (pattern body)
    and the character / pattern girth ratio there (hips, waist, bust). axis: (3,) the character's
    vertical axis point (root x, z). arm_turn: rad, the character's arm angle minus the pattern
    body's (positive: lower). shoulder_src: (2,) pattern body shoulder point (|x|, y), m;
    shoulders_dst: {+1: (3,), -1: (3,)} the character's upper-arm joints (left +x, right -x).
    legs_dst: {+1: (2, 3), -1: (2, 3)} each leg's hip and ankle joints (sides without a leg chain
    left out)."""

    src_y: np.ndarray
    dst_y: np.ndarray
    src_girth_y: np.ndarray
    ratio: np.ndarray
    axis: np.ndarray
    arm_turn: float
    shoulder_src: np.ndarray
    shoulders_dst: dict
    legs_dst: dict

    def y(self, y):
        return np.interp(y, self.src_y, self.dst_y, left=None, right=None) + np.where(
            y > self.src_y[-1], (y - self.src_y[-1]) * (self.dst_y[-1] - self.dst_y[-2]) / (self.src_y[-1] - self.src_y[-2]), 0.0)

    def torso_inverse(self, q: np.ndarray) -> np.ndarray:
        """(N, 3) pattern-body points that `torso` takes to the character's points q (N, 3)."""
        y = np.interp(q[:, 1], self.dst_y, self.src_y)
        k = np.interp(y, self.src_girth_y, self.ratio)
        return np.c_[(q[:, 0] - self.axis[0]) / k, y, (q[:, 2] - self.axis[2]) / k]

    def leg_axes(self) -> dict:
        """{side: (2, 3) hip and ankle points in the pattern body's frame} of the character's legs."""
        return {side: self.torso_inverse(q) for side, q in self.legs_dst.items()}

    def torso(self, p: np.ndarray) -> np.ndarray:
        k = np.interp(p[:, 1], self.src_girth_y, self.ratio)
        return np.c_[self.axis[0] + p[:, 0] * k, self.y(p[:, 1]), self.axis[2] + p[:, 2] * k]

    def arm(self, p: np.ndarray, side: float) -> np.ndarray:
        """Turn about the pattern shoulder (in the x-y plane) by arm_turn, then carry to the joint."""
        c = np.array([side * self.shoulder_src[0], self.shoulder_src[1], 0.0])
        a = -side * self.arm_turn
        rot = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
        return (p - c) @ rot.T + self.shoulders_dst[side]


def body_map(body: GCBody, meas: dict, character, origins: np.ndarray, anchor: float | None = None,
             band: tuple | None = None) -> BodyMap:
    """The BodyMap from `body` to the character measured in `meas` (garment_measurements). anchor:
    the pattern-body height the garment hangs from (the top of its torso panels, at most the
    shoulders: garment_anchor), where it meets the character's landmark; heights away from it keep
    the landmarks' slope within SLOPE_BOUNDS (limited_heights); None: the landmarks themselves.
    band: (pattern-body height of its waist seam, m to lift it by) (garmentcode_band.lift_band)."""
    from stages.rig.humanoid import limb_chain
    floor = meas.get("floor_y", 0.0)
    top = floor + meas["height"]
    sh = meas.get("shoulder_top", meas["shoulder_y"] + 0.03 * meas["height"])
    src = [0.0, body.hips_y, body.waist_y, body.bust_y, body.shoulder_y, body.height]
    dst = [floor, meas["hips_y"], meas["waist_y"], meas["chest_y"], sh, top]
    keep = [0] + [i for i in range(1, 6) if dst[i] > dst[i - 1] + 1e-3 and src[i] > src[i - 1]]
    src, dst = np.array(src)[keep], np.array(dst)[keep]
    if anchor is not None:
        src, dst = limited_heights(src, dst, anchor)
        w = body.waist_y
        # only where the map stretches the cut above the waist (a squashed cut, CesiumMan's 3.8 cm
        # bust-to-shoulder span held at 0.75, expands up against the shoulders it hangs from; as cut
        # there, its tops tore on the forearms 9-10 frames earlier)
        if anchor > w > src[0] and np.interp(anchor, src, dst) - np.interp(w, src, dst) > anchor - w:
            src, dst = cut_above(src, dst, anchor, w)
    if band is not None:
        src, dst = lift_band(src, dst, src[-1] if anchor is None else anchor, *band)
    ratio = np.array([meas.get("clear_hips", meas["hips"]) / body.hips, meas.get("clear_waist", meas["waist"]) / body.waist,
                      meas.get("clear_chest", meas["chest"]) / body.bust])
    ratio = np.where(np.isfinite(ratio) & (ratio > 0), ratio, 1.0)
    root = origins[character.root_joint]
    shoulders = {}
    for side, s in ((1.0, "l"), (-1.0, "r")):
        chain = limb_chain(character, "arm", s)
        shoulders[side] = (origins[chain[0]].copy() if chain else
                           np.array([root[0] + side * meas["shoulder_half"], meas["shoulder_y"], root[2]]))
    turn = meas.get("arm_angle", body.arm_angle) - body.arm_angle
    return BodyMap(src, dst, np.array([body.hips_y, body.waist_y, body.bust_y]), ratio,
                   np.array([root[0], 0.0, root[2]]), float(turn),
                   np.array([body.shoulder_half + 0.02, body.shoulder_y - 0.04]), shoulders,
                   leg_axes(character, origins))


def mismatch(body: GCBody, meas: dict, top: bool = False) -> dict:
    """{measure: (character, pattern body), m}: height and the girths, for the warning; for a top
    (`top`: hung from the shoulders) also the shoulders' width between the upper-arm joints."""
    out = {"height": (meas["height"], body.height), "bust": (meas["chest"], body.bust),
           "waist": (meas["waist"], body.waist), "hips": (meas["hips"], body.hips)}
    if top and "shoulder_half" in meas:
        out["shoulders"] = (2 * meas["shoulder_half"], 2 * body.shoulder_half)
    return out


SLIP_WIDTH = 1.3   # a top graded this many times wider at the shoulders than the character slides off them


def mismatch_warning(body: GCBody, meas: dict, name: str, g: Grade | None = None,
                     tolerance: float = 0.05, top: bool = False) -> str | None:
    """One line when a measure differs by more than `tolerance` (share), else None. For a top whose
    graded shoulders (grading keeps the cut above the bust) come out SLIP_WIDTH times the
    character's or wider, the line says it will slide off them and how to get one cut to measure:
    CesiumMan's upper-arm joints are 18 cm apart, the sampled patterns' bodies 36-38 cm, and every
    such top slid down to the chest in the walk."""
    far = {m: (c, b) for m, (c, b) in mismatch(body, meas, top).items() if abs(c / b - 1.0) > tolerance}
    if not far:
        return None
    g = g or Grade.uniform(1.0, 1.0)
    parts = ", ".join(f"{m} {c * 100:.0f} cm vs {b * 100:.0f} cm ({(c / b - 1) * 100:+.0f} %)" for m, (c, b) in far.items())
    across = f"x{g.across[0]:.3f} across" + (f" (x{g.across[-1]:.3f} above the bust)" if abs(g.across[-1] - g.across[0]) > 5e-4 else "")
    line = (f"garment {name!r}: the pattern was made for the body in {body.source}; this character differs: {parts} "
            f"(character vs pattern body); dressed graded {across} and x{g.up:.3f} up")
    if "shoulders" in far:
        graded, own = 2 * body.shoulder_half * g.arm, far["shoulders"][0]
        if graded >= SLIP_WIDTH * own:
            line += (f"; its shoulders come out {graded * 100:.0f} cm wide on the character's {own * 100:.0f} cm, so it "
                     "will slide off them: `python -m pipeline measure` writes this character's body file for "
                     "GarmentCode to cut the pattern to measure")
    return line


def garment_anchor(gc: GCPattern, body: GCBody) -> float:
    """The pattern-body height a garment hangs from: the top of its panels that are not arms,
    at most the body's shoulders (a top, a dress: the shoulders; a skirt, trousers: the waist; a
    hood above the head is carried by the shoulders)."""
    ys = [p.to_3d(p.vertices)[:, 1].max() for p in gc.panels if panel_part(p) != "arm"]
    return min(max(ys), body.shoulder_y) if ys else body.shoulder_y


def place_gc(gc: GCPattern, flat, signs: dict, bmap: BodyMap, body: GCBody | None = None) -> np.ndarray:
    """(N, 3) positions of the meshed panels (flat: FlatPattern of to_pattern's Pattern, same panel
    order) in the character's relative frame at frame 0; with `body`, upright panels wrapped round
    the body first (wrap_ring), trouser legs round each leg (wrap_legs), sleeves round the arms."""
    uvs = [fp.uv * np.array([signs[p.name], 1.0]) for p, fp in zip(gc.panels, flat.panels)]
    pts = [p.to_3d(uv) for p, uv in zip(gc.panels, uvs)]
    if body is not None:
        ringed = wrap_legs(gc, pts, wrap_ring(gc, pts, body, uvs), body, bmap.leg_axes())
        pts = wrap_sleeves(gc, ringed, body)
    out = []
    for p, x in zip(gc.panels, pts):
        part = panel_part(p)
        if part == "arm":
            side = 1.0 if float(np.mean(x[:, 0])) >= 0 else -1.0
            out.append(bmap.arm(x, side))
        else:
            out.append(bmap.torso(x))
    placed = np.concatenate(out)
    if body is not None:
        sides = [None if panel_part(p) != "arm" else (1.0 if float(np.mean(x[:, 0])) >= 0 else -1.0)
                 for p, x in zip(gc.panels, pts)]
        placed = align_to_stitches(placed, flat, sides)
    return placed


DETACHED_GAP = 0.08   # m: a panel whose stitches to other panels are mostly this far open is moved to them


def align_to_stitches(placed: np.ndarray, flat, arm_side: list) -> np.ndarray:
    """placed (N, 3) with detached groups of panels translated by the mean offset of their stitches'
    pairs to the panels they are sewn to that are not detached. A group: each side's arm panels
    together (arm_side: +1 / -1, None for a panel that is not an arm), every other panel alone;
    detached: its stitches to panels outside it start mostly (median) more than DETACHED_GAP open.
    GarmentCode lays a hood beside the head, its neck edges 15-20 cm from the neckline they are
    sewn to, and the sewing dragged the top up and back (edges crushed to 1 % of their length); a
    shirt's sleeves mapped to CesiumMan's shoulder joints start 8-10 cm from armholes that the
    torso's map put lower, and their seams did not close (8.6 mm open after 40 rounds)."""
    pv, pairs = flat.panel_of_vertex, flat.seam_pairs
    if pairs.size == 0:
        return placed
    a, b = pv[pairs[:, 0]], pv[pairs[:, 1]]
    gap = np.linalg.norm(placed[pairs[:, 0]] - placed[pairs[:, 1]], axis=1)
    groups = [np.flatnonzero([s == side for s in arm_side]) for side in (1.0, -1.0)]
    groups = [g for g in groups if g.size] + [np.array([i]) for i, s in enumerate(arm_side) if s is None]
    detached = np.zeros(len(arm_side), bool)
    for grp in groups:
        m = np.isin(a, grp) != np.isin(b, grp)           # stitches to panels outside the group
        detached[grp] = m.any() and float(np.median(gap[m])) > DETACHED_GAP
    out = placed.copy()
    for grp in groups:
        if not detached[grp[0]]:
            continue
        own = np.isin(a, grp) & ~detached[b]
        other = np.isin(b, grp) & ~detached[a]
        if own.sum() + other.sum() < 3:
            continue
        shift = np.concatenate([placed[pairs[own, 1]] - placed[pairs[own, 0]],
                                placed[pairs[other, 0]] - placed[pairs[other, 1]]]).mean(axis=0)
        sel = np.isin(pv, grp)
        out[sel] = placed[sel] + shift
    return out


def junction_pairs(pairs: np.ndarray) -> np.ndarray:
    """The seam pairs (K, 2) plus a pair between every two vertices that sewing merges into one
    (a group of three or more: where seams meet) not already paired. A hood's neck edges and the
    torso's two front halves meet at a V: the hoods' corners were each pulled only towards their own
    torso half's corner, the torso halves towards each other, and on the CMU walk the chain settled
    with a hood corner 13 mm off (hoody_mean; standing_lapel_fix's collars 6.6 mm): paired with every
    corner of the junction, 0.6 and 1.9 mm."""
    from stages.garments.sewing import merge_pairs
    if pairs.size == 0:
        return pairs
    group = merge_pairs(int(pairs.max()) + 1, pairs)
    have = {(int(a), int(b)) for a, b in np.sort(pairs, axis=1)}
    extra = []
    for g in np.unique(group[pairs[:, 0]]):
        mem = np.flatnonzero(group == g)
        extra += [(int(a), int(b)) for i, a in enumerate(mem) for b in mem[i + 1:] if (a, b) not in have]
    return np.concatenate([pairs, np.array(extra, pairs.dtype).reshape(-1, 2)]) if extra else pairs


# GarmentCode's simulator holds the waist seam at the waist level and the collars at the neck's width;
# here the waist seam is brought onto the body (hug to the axis) and held while sewing; the collars
# are left free (None): hugged to the neck joint they pulled the neckline narrower than the neck (the
# sleeveless top's shoulder seams dragged 7 cm towards the neck, 14 mm open), held where the wrap put
# them the shoulder seams could not close over the shoulders (15 cm open)
HOLD_LABELS = {"lower_interface": "axis", "left_collar": None, "right_collar": None}
CLEARANCE = 0.01   # m: vertices placed inside the body are pushed this far out of the skin
BAND_TOLERANCE = 0.003   # m: a waist seam placed this far below garmentcode_band.band_floor is left there
# sewing rounds at least: stiff seam springs (128 correction rounds) close a hood's or a sleeve's
# seams in 6 rounds and leave the cloth round them crushed (edges at 18-29 % of their rest length)
# or stretched (x1.9-3.5); the simulation's first frame then relaxes them, and an edge growing 6x is
# read as a blow-up (hoody_mean, shirt_mean on CesiumMan: stopped at frame 1). Rounds after the seams
# closed let the panels relax with the seams held: 20 rounds, the shortest edge 29 %, the longest x1.9
RELAX_ITERATIONS = 20


def place_gc_garment(gc: GCPattern, body: GCBody, character, motion, colliders, *, edge_length: float = 0.025,
                     name: str | None = None, density: float = 0.2):
    """The pattern graded to the character, meshed and placed on its bind pose, unsewn: (graded
    GCPattern, Pattern, FlatPattern, placed (N, 3) positions, mismatch warning or None). What
    `validate` checks and make_gc_garment sews."""
    from stages.garments.measurements import garment_measurements
    from stages.garments.placement import bind_geometry, inside_body, push_out
    from stages.garments.triangulate import triangulate_pattern
    meas = garment_measurements(character, colliders, motion)
    worn = worn_from_waistband(meas) if garment_anchor(gc, body) < 0.5 * (body.waist_y + body.bust_y) else meas
    g = grading(gc, body, worn)
    gbody = graded_body(body, g)

    def graded_pattern(exact_arcs):
        graded = grade(gc, g, exact_arcs)
        if "arm_radius" in meas:   # sleeves round the character's arms (and their colliders)
            graded, _ = fit_sleeves(graded, gbody, 2 * math.pi * meas["arm_radius"], exact_arcs)
        return graded, *to_pattern(graded, edge_length, name or gc.name, density)
    try:
        graded, pattern, signs = graded_pattern(False)
    except InputError:   # graded far from a similarity (x1.42 across, x0.39 up on a chibi), an arm-
        # hole's circle through its mapped ends and midpoint crossed the panel's other edges
        graded, pattern, signs = graded_pattern(True)
    flat = triangulate_pattern(pattern)
    check_stitch_chains(graded, pattern, flat)
    skinned0, origins, _ = bind_geometry(character, motion)
    anchor = garment_anchor(graded, gbody)
    placed = place_gc(graded, flat, signs, body_map(gbody, worn, character, origins, anchor), gbody)
    band, floor = band_vertices(graded, pattern, flat), band_floor(meas)
    if band.size and floor is not None and placed[band, 1].min() < floor - BAND_TOLERANCE:
        # the waist seam below the tops of the legs: placed again with all of it (up to its highest
        # pattern-body point) lifted onto the trunk; the wrap moves points up and down a little
        # and a few rounds bring its lowest point to the floor
        src_y = np.concatenate([p.to_3d(fp.uv * np.array([signs[p.name], 1.0]))[:, 1]
                                for p, fp in zip(graded.panels, flat.panels)])
        lift = 0.0
        for _ in range(4):
            lift += floor - float(placed[band, 1].min())
            bmap = body_map(gbody, worn, character, origins, anchor, (float(src_y[band].max()), lift))
            placed = place_gc(graded, flat, signs, bmap, gbody)
            if placed[band, 1].min() >= floor - BAND_TOLERANCE:
                break
    # a top's shoulder seams closed over the shoulders, not through them (garmentcode_shoulders)
    arm_panel = np.array([panel_part(p) == "arm" for p in graded.panels])
    over = shoulder_pairs(placed, flat, arm_panel, origins[character.root_joint], meas["chest_y"],
                          meas.get("shoulder_top", meas["shoulder_y"]))
    if len(over):
        placed[:, 1] += shoulder_lift(placed, over, shoulder_surface(character, colliders, motion), CLEARANCE)
    bad = inside_body(character, skinned0, placed)
    if bad.any():
        placed[bad] = push_out(placed[bad], character, skinned0, CLEARANCE, along_normal=True)
    top = garment_anchor(gc, body) > 0.5 * (body.bust_y + body.shoulder_y)    # hung from the shoulders
    return graded, pattern, flat, placed, mismatch_warning(body, meas, name or gc.name, g, top=top)


def tangled_left(x: np.ndarray, triangles: np.ndarray, pairs: np.ndarray) -> int:
    """Edges through the garment's own triangles once its seams are joined and untangled."""
    from stages.garments.sewing import merged_mesh
    from stages.garments.untangle import untangle
    pos, mtri, _ = merged_mesh(x, triangles, pairs)
    return int(untangle(pos, mtri)[1])


def make_gc_garment(gc: GCPattern, body: GCBody, character, motion, colliders, maps, *, edge_length: float = 0.025,
                    name: str | None = None, density: float = 0.2, sew_params=None, ignore_joints=(), progress=None):
    """GarmentCode pattern -> sewn Garment on the character in the bind pose (frame 0 of `motion`).

    Returns (Garment, SewingLog, GarmentBuild, warning or None). The panels are placed by the
    pattern's own translation / rotation mapped onto the character (body_map); vertices inside the
    body are pushed out; the waist seam GarmentCode attaches while simulating (lower_interface) is
    brought onto the body (hug.hug, to the body's axis) and held there while sewing (the
    middle half, seam vertices free), and after sewing stays pinned to its nearest bone of the trunk
    (the waist holds a skirt up); collars are left free (HOLD_LABELS)."""
    from stages.garments.library import GarmentBuild, hug_targets, seam_label
    from stages.garments.hug import hug, respace
    from stages.garments.placement import bind_geometry
    from stages.garments.gather import gathered_rest
    from stages.garments.sewing import SewParams, merged_mesh, seam_gaps, sew
    from stages.garments.untangle import untangle_sewn
    from stages.garments.triangulate import run_vertices
    from stages.garments.types import attach_indices, bind_pose, build_garment

    name = name or gc.name
    gc, pattern, flat, placed, warning = place_gc_garment(gc, body, character, motion, colliders,
                                                          edge_length=edge_length, name=name, density=density)
    tri, uv = flat.triangles, flat.uv
    tri_rest, _ = gathered_rest(tri, uv, flat.seam_pairs, flat.seam_index, flat.panel_of_vertex)
    skinned0, origins, _ = bind_geometry(character, motion)
    pose = bind_pose(character, motion, colliders)
    held, waist = [], []
    for p in gc.panels:
        for j, e in enumerate(p.edges):
            if HOLD_LABELS.get(e.label) is None:
                continue
            mode = HOLD_LABELS[e.label]
            idx = run_vertices(pattern, flat, SeamSide(p.name, (f"e{j}",)))
            if mode is not None:
                placed[idx] = hug(placed[idx], hug_targets(character, origins, placed[idx], mode), character,
                                  skinned0, pose, through_arms=mode == "axis")
                placed[idx] = respace(placed[idx], uv[idx])
            held.append(idx)
            if e.label == "lower_interface":
                waist.append(idx)
    seam_v = flat.seam_pairs.ravel()

    def middle_half(idx):
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(uv[idx], axis=0), axis=1))])
        f = s / max(s[-1], 1e-12)
        return np.setdiff1d(idx[(f >= 0.25) & (f <= 0.75)], seam_v)

    # the trunk's bones only: a waist on CesiumMan lies next to its hanging hand, whose bone the
    # nearest collider would give (the hand then dragged the waistband 14 cm off the hips)
    pins = [attach_indices(m, TRUNK_BONE) for m in (middle_half(i) for i in held) if m.size]
    shift = np.concatenate([[0.0], np.cumsum([np.ptp(p.uv[:, 0]) + 0.1 for p in flat.panels])])[:-1]
    flat3 = np.concatenate([np.c_[p.uv[:, 0] - p.uv[:, 0].min() + s, p.uv[:, 1], np.zeros(len(p.uv))]
                            for p, s in zip(flat.panels, shift)])
    sp = sew_params if sew_params is not None else SewParams()
    # sewn with self collision (SewParams.self_collision): without it the seams pulled the panels through
    # each other (js_mean_all on CesiumMan: 845 edges through the garment placed, 273 sewn)
    sp = dc_replace(sp, min_iterations=max(sp.min_iterations, min(RELAX_ITERATIONS, sp.max_iterations)),
                    self_collision=True)
    def sew_with(pairs, start=placed):
        return sew(name, start, tri, tri_rest, pairs, character, motion, colliders, maps, sp, density=density,
                   flat_positions=flat3, pair_stage=None, pins=pins, bind=pose if pins else None,
                   progress=progress)
    sewn, log = sew_with(flat.seam_pairs)
    corners = junction_pairs(flat.seam_pairs)
    if not log.converged and sp.self_collision:
        # cloth caught on cloth (dress_pencil on the CMU walk: one armhole pair 13 mm open at the
        # corner where three seams meet): the seams closed from there without self collision, its
        # crossings left to untangle_sewn (sewn again from the placement: 374 edges through the
        # garment after sewing, 232 after untangling; from the stalled sewing: see the commit)
        sp = dc_replace(sp, self_collision=False)
        collided = log
        sewn, log = sew_with(flat.seam_pairs, start=sewn)
        log = dc_replace(log, seconds=collided.seconds + log.seconds,
                         notes=collided.notes + (f"with self collision the seams stayed {collided.gap_max[-1] * 1000:.1f} mm "
                                                 f"open: closed from there without",) + log.notes)
    if not log.converged and len(corners) > len(flat.seam_pairs):
        # sewn again with a junction's corners drawn together (only then: garments that close without
        # them are sewn as before; with them from the start, hoody_mean on CesiumMan sewed closed too
        # but its run stopped at frame 41, an edge torn where the forearm presses the cloth to the trunk)
        earlier = log
        sewn, log = sew_with(corners)
        log = dc_replace(log, seconds=earlier.seconds + log.seconds,
                         notes=earlier.notes + (f"seams {earlier.gap_max[-1] * 1000:.1f} mm open: sewn again with the "
                                                f"corners where seams meet drawn together",) + log.notes)
    if log.converged and sp.self_collision and log.gap_max[-1] > min(sp.target, sp.tolerance):
        # closed to the tolerance with self collision, stalled above the target (the sampled tee on
        # CesiumMan: 3.9-4.9 mm from iteration 8 on; closed without it: 1.0 mm): the last millimetres
        # without it, kept when they close further and untangling leaves no more cloth through cloth
        sp = dc_replace(sp, self_collision=False, min_iterations=2)
        tight, tight_log = sew_with(flat.seam_pairs, start=sewn)
        if tight_log.gap_max[-1] < log.gap_max[-1] and tangled_left(tight, tri, flat.seam_pairs) <= \
                tangled_left(sewn, tri, flat.seam_pairs):
            sewn, log = tight, dc_replace(tight_log, seconds=log.seconds + tight_log.seconds, notes=log.notes + (
                f"seams {log.gap_max[-1] * 1000:.1f} mm open with self collision: closed from there without",)
                + tight_log.notes)
    pos, mtri, remap = merged_mesh(sewn, tri, flat.seam_pairs)
    pos = apart(gc, placed, flat, pos, remap, character, origins)    # wide trouser legs through each other
    pos, log = untangle_sewn(pos, mtri, log)
    atts = [attach_indices(np.unique(remap[i]), TRUNK_BONE) for i in waist]
    g = build_garment(name, pos, mtri, density=density, triangle_rest=tri_rest, attachments=atts,
                      bind=pose if atts else None, ignore_joints=ignore_joints)
    gaps = seam_gaps(sewn, flat.seam_pairs)
    by_seam = {seam_label(s): float(gaps[flat.seam_index == j].max())
               for j, s in enumerate(pattern.seams) if (flat.seam_index == j).any()}
    fit = np.unique(remap[np.concatenate(held)]).astype(np.int64) if held else np.zeros(0, np.int64)
    build = GarmentBuild(flat3, placed, tri, flat.seam_pairs, log, {}, fit, by_seam)
    return g, log, build, warning
