"""GarmentCode sewing patterns (`*_specification.json`, github.com/maria-korosteleva/GarmentCode) read
into typed dataclasses and turned into this pipeline's `Pattern` (flat panels, seams) for meshing.

Conventions (see ../shared/assets/garmentcode/README.md, established from pygarment's code):
- lengths are in 1 / `properties.units_in_meter` metres (100: centimetres); read here into metres.
- a panel is a closed loop of edges in its own 2D (u, v) frame; a local point goes to the body frame
  (Y up, feet at y = 0, facing +Z, wearer's left +X) as R (u, v, 0) + translation with
  R = Rz Ry Rx of `rotation` (degrees; the library's reader and simulator convention).
- the loop orientation gives the outside of the fabric: outward normal R (0, 0, s), s = +1 for a
  counter-clockwise loop, -1 clockwise.
- curvature (relative control points): a point (x, y) of an edge start -> end is
  start + x d + y perp(d), d = end - start, perp(d) = (-d_v, d_u). quadratic: [[x, y]]; cubic:
  [[x1, y1], [x2, y2]]; circle: [radius, large_arc, right] = an SVG arc with sweep = right in the
  y-up frame (right = 1: counter-clockwise about the centre, bulging to the right of start -> end).
- stitches: two {panel, edge} ends; the default pairs A.start with B.end (reversed), a third entry
  "right_wrong" pairs A.start with B.start.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace as dc_replace
from pathlib import Path

import numpy as np

from stages.errors import InputError

CURVES = ("straight", "quadratic", "cubic", "circle")
PANEL_LABELS = ("body", "leg", "arm")
HELD_LABELS = ("lower_interface", "left_collar", "right_collar", "strapless_top")  # GarmentCode's attachments


@dataclass(frozen=True)
class GCEdge:
    """One edge of a panel loop. start, end: vertex indices. kind: one of CURVES. control: absolute
    control points, metres, panel (u, v) frame: quadratic (1, 2), cubic (2, 2), circle () with
    radius (m), large_arc and right (SVG flags). label: GarmentCode edge label or ''."""

    start: int
    end: int
    kind: str
    control: tuple = ()
    radius: float = 0.0
    large_arc: bool = False
    right: bool = False
    label: str = ""


@dataclass(frozen=True)
class GCPanel:
    """A flat panel. vertices: (V, 2) float64, metres, panel-local (u, v). edges: GCEdge loop in
    order. translation: (3,) metres, body frame. rotation_deg: (3,) Euler angles (x, y, z), degrees,
    R = Rz Ry Rx. label: 'body' | 'leg' | 'arm' | ''. ccw: the loop is counter-clockwise in (u, v)
    (outward normal R (0, 0, +1), else R (0, 0, -1))."""

    name: str
    vertices: np.ndarray
    edges: tuple
    translation: np.ndarray
    rotation_deg: np.ndarray
    label: str
    ccw: bool

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) R = Rz Ry Rx."""
        return euler_xyz_to_R(self.rotation_deg)

    def to_3d(self, uv: np.ndarray) -> np.ndarray:
        """(N, 3) body-frame points (metres) of panel-local points (N, 2)."""
        uv = np.asarray(uv, np.float64)
        return np.c_[uv, np.zeros(len(uv))] @ self.rotation.T + self.translation

    @property
    def normal(self) -> np.ndarray:
        return self.rotation @ np.array([0.0, 0.0, 1.0 if self.ccw else -1.0])


@dataclass(frozen=True)
class GCStitch:
    """Two panel edges sewn together: (panel name, edge index) each; right_wrong: same-direction
    pairing (A.start with B.start) instead of the default reversed one."""

    a: tuple
    b: tuple
    right_wrong: bool = False


@dataclass(frozen=True)
class GCPattern:
    """A parsed GarmentCode specification. panels: GCPanel tuple (file order). stitches: GCStitch
    tuple. units_in_meter: as in the file. source: the file it was read from."""

    name: str
    panels: tuple
    stitches: tuple
    units_in_meter: float
    source: str

    def panel(self, name: str) -> GCPanel:
        return next(p for p in self.panels if p.name == name)


def euler_xyz_to_R(deg) -> np.ndarray:
    """R = Rz Ry Rx of Euler angles (x, y, z) in degrees (GarmentCode's pattern/rotation.py)."""
    x, y, z = np.radians(np.asarray(deg, np.float64))
    rx = np.array([[1, 0, 0], [0, math.cos(x), -math.sin(x)], [0, math.sin(x), math.cos(x)]])
    ry = np.array([[math.cos(y), 0, math.sin(y)], [0, 1, 0], [-math.sin(y), 0, math.cos(y)]])
    rz = np.array([[math.cos(z), -math.sin(z), 0], [math.sin(z), math.cos(z), 0], [0, 0, 1]])
    return rz @ ry @ rx


def rel_to_abs(start, end, xy) -> np.ndarray:
    """A relative control point (x along start -> end, y along it turned +90 degrees) in (u, v)."""
    s, e = np.asarray(start, np.float64), np.asarray(end, np.float64)
    d = e - s
    return s + xy[0] * d + xy[1] * np.array([-d[1], d[0]])


def arc_center(start, end, radius: float, large_arc: bool, right: bool):
    """(centre (2,), radius, signed sweep angle rad) of an SVG-style arc in the y-up frame: right =
    sweep flag (counter-clockwise about the centre). A radius shorter than half the chord is grown
    to it (as SVG does)."""
    s, e = np.asarray(start, np.float64), np.asarray(end, np.float64)
    d = e - s
    L = float(np.linalg.norm(d))
    r = max(float(radius), 0.5 * L)
    h = math.sqrt(max(r * r - 0.25 * L * L, 0.0))
    left = np.array([-d[1], d[0]]) / max(L, 1e-15)
    c = 0.5 * (s + e) + (1.0 if right != large_arc else -1.0) * h * left
    a0 = math.atan2(s[1] - c[1], s[0] - c[0])
    a1 = math.atan2(e[1] - c[1], e[0] - c[0])
    sweep = (a1 - a0) % (2 * math.pi) if right else -((a0 - a1) % (2 * math.pi))
    return c, r, sweep


def edge_points(panel: GCPanel, edge: GCEdge, t) -> np.ndarray:
    """(len(t), 2) points of an edge at curve parameters t in [0, 1] (metres, panel frame)."""
    a, b = panel.vertices[edge.start], panel.vertices[edge.end]
    t = np.asarray(t, np.float64)[:, None]
    if edge.kind == "straight":
        return a + t * (b - a)
    if edge.kind == "quadratic":
        c = np.asarray(edge.control[0])
        return (1 - t) ** 2 * a + 2 * (1 - t) * t * c + t ** 2 * b
    if edge.kind == "cubic":
        c1, c2 = (np.asarray(q) for q in edge.control)
        return (1 - t) ** 3 * a + 3 * (1 - t) ** 2 * t * c1 + 3 * (1 - t) * t ** 2 * c2 + t ** 3 * b
    c, r, sweep = arc_center(a, b, edge.radius, edge.large_arc, edge.right)
    th = math.atan2(a[1] - c[1], a[0] - c[0]) + sweep * t[:, 0]
    return c + r * np.stack([np.cos(th), np.sin(th)], axis=1)


def edge_length(panel: GCPanel, edge: GCEdge, samples: int = 512) -> float:
    p = edge_points(panel, edge, np.linspace(0.0, 1.0, samples + 1))
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


# ---------------------------------------------------------------- reading

def _num(x, where: str, src: str) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
        raise InputError(src, f"{where}: expected a finite number, got {x!r}")
    return float(x)


def _vec(x, n: int, where: str, src: str) -> np.ndarray:
    if not isinstance(x, (list, tuple)) or len(x) != n:
        raise InputError(src, f"{where}: expected a list of {n} numbers, got {x!r}")
    return np.array([_num(v, f"{where}[{i}]", src) for i, v in enumerate(x)])


def read_pattern(path) -> GCPattern:
    """Read a GarmentCode `*_specification.json`. Every problem is an InputError naming the file
    and the JSON path of the bad value."""
    from stages.input_files import MAX_TEXT_BYTES, file_problem
    src = str(path)
    problem = file_problem(Path(path), "GarmentCode pattern file", 4 * MAX_TEXT_BYTES)
    if problem:
        raise InputError(src, problem)
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(src, "GarmentCode pattern file not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(src, f"cannot read the pattern file ({e.__class__.__name__}: {e})") from None
    except json.JSONDecodeError as e:
        raise InputError(src, f"not JSON: {e.msg} at line {e.lineno}, column {e.colno}") from None
    name = Path(path).name.removesuffix(".json").removesuffix("_specification")
    return parse_pattern(data, src, name)


def parse_pattern(data, src: str = "<pattern>", name: str = "garmentcode") -> GCPattern:
    if not isinstance(data, dict) or not isinstance(data.get("pattern"), dict):
        raise InputError(src, "pattern: expected a JSON object with a 'pattern' object (a GarmentCode "
                              "*_specification.json)")
    props = data.get("properties", {})
    if not isinstance(props, dict):
        raise InputError(src, f"properties: expected an object, got {props!r}")
    units = _num(props.get("units_in_meter", 100), "properties.units_in_meter", src)
    if units <= 0:
        raise InputError(src, f"properties.units_in_meter: expected a positive number, got {units:g}")
    if props.get("curvature_coords", "relative") != "relative":
        raise InputError(src, f"properties.curvature_coords: only 'relative' is supported, got "
                              f"{props.get('curvature_coords')!r}")
    pat = data["pattern"]
    panels_in = pat.get("panels")
    if not isinstance(panels_in, dict) or not panels_in:
        raise InputError(src, "pattern.panels: expected a non-empty object of panels")
    panels = tuple(_panel(pname, p, units, src) for pname, p in panels_in.items())
    stitches = _stitches(pat.get("stitches", []), {p.name: p for p in panels}, src)
    return GCPattern(name, panels, stitches, units, src)


def _panel(pname: str, p, units: float, src: str) -> GCPanel:
    at = f"pattern.panels.{pname}"
    if not isinstance(p, dict):
        raise InputError(src, f"{at}: expected an object, got {type(p).__name__}")
    vin = p.get("vertices")
    if not isinstance(vin, list) or len(vin) < 3:
        raise InputError(src, f"{at}.vertices: expected at least 3 [u, v] points, got {vin!r}")
    verts = np.array([_vec(v, 2, f"{at}.vertices[{i}]", src) for i, v in enumerate(vin)]) / units
    ein = p.get("edges")
    if not isinstance(ein, list) or len(ein) < 2:
        raise InputError(src, f"{at}.edges: expected a list of at least 2 edges, got {ein!r}")
    edges = []
    for k, e in enumerate(ein):
        ea = f"{at}.edges[{k}]"
        if not isinstance(e, dict):
            raise InputError(src, f"{ea}: expected an object, got {e!r}")
        ends = e.get("endpoints")
        if not (isinstance(ends, list) and len(ends) == 2 and all(isinstance(i, int) and not isinstance(i, bool)
                                                                  and 0 <= i < len(verts) for i in ends)):
            raise InputError(src, f"{ea}.endpoints: expected two vertex indices in 0..{len(verts) - 1}, got {ends!r}")
        i, j = ends
        if k > 0 and i != edges[-1].end:
            raise InputError(src, f"{ea}.endpoints: edge starts at vertex {i} but edge {k - 1} ends at "
                                  f"{edges[-1].end}: the edges must form one closed loop")
        label = e.get("label", "")
        if not isinstance(label, str):
            raise InputError(src, f"{ea}.label: expected a string, got {label!r}")
        edges.append(_edge(e.get("curvature"), i, j, verts, units, label, ea, src))
    if edges[-1].end != edges[0].start:
        raise InputError(src, f"{at}.edges[{len(edges) - 1}].endpoints: the last edge ends at vertex "
                              f"{edges[-1].end}, not at the first edge's start {edges[0].start}: the loop is not closed")
    label = p.get("label", "")
    if not isinstance(label, str):
        raise InputError(src, f"{at}.label: expected a string, got {label!r}")
    tr = _vec(p.get("translation", [0, 0, 0]), 3, f"{at}.translation", src) / units
    rot = _vec(p.get("rotation", [0, 0, 0]), 3, f"{at}.rotation", src)
    panel = GCPanel(pname, verts, tuple(edges), tr, rot, label, True)
    area = _signed_area(loop_points(panel))
    if abs(area) < 1e-8:
        raise InputError(src, f"{at}: the panel has no area")
    return GCPanel(pname, verts, tuple(edges), tr, rot, label, area > 0)


def _edge(curv, i: int, j: int, verts: np.ndarray, units: float, label: str, ea: str, src: str) -> GCEdge:
    a, b = verts[i], verts[j]
    if np.linalg.norm(b - a) < 1e-9:
        raise InputError(src, f"{ea}.endpoints: the edge's two ends coincide (vertices {i} and {j})")
    if curv is None:
        return GCEdge(i, j, "straight", label=label)
    if isinstance(curv, list):   # legacy form: one relative quadratic control point
        curv = {"type": "quadratic", "params": [curv]}
    if not isinstance(curv, dict):
        raise InputError(src, f"{ea}.curvature: expected an object, got {curv!r}")
    kind, params = curv.get("type"), curv.get("params")
    if kind not in ("quadratic", "cubic", "circle"):
        raise InputError(src, f"{ea}.curvature.type: expected quadratic, cubic or circle, got {kind!r}")
    if not isinstance(params, list):
        raise InputError(src, f"{ea}.curvature.params: expected a list, got {params!r}")
    if kind == "circle":
        if len(params) != 3:
            raise InputError(src, f"{ea}.curvature.params: a circle needs [radius, large_arc, right], got {params!r}")
        r = _num(params[0], f"{ea}.curvature.params[0]", src) / units
        if r <= 0:
            raise InputError(src, f"{ea}.curvature.params[0]: expected a positive radius, got {params[0]!r}")
        flags = [_num(params[k], f"{ea}.curvature.params[{k}]", src) for k in (1, 2)]
        return GCEdge(i, j, "circle", radius=r, large_arc=bool(flags[0]), right=bool(flags[1]), label=label)
    n = 1 if kind == "quadratic" else 2
    if len(params) != n:
        raise InputError(src, f"{ea}.curvature.params: a {kind} curve needs {n} control point(s), got {params!r}")
    ctrl = tuple(tuple(rel_to_abs(a, b, _vec(q, 2, f"{ea}.curvature.params[{k}]", src)))
                 for k, q in enumerate(params))
    return GCEdge(i, j, kind, ctrl, label=label)


def _stitches(sin, panels: dict, src: str) -> tuple:
    if not isinstance(sin, list):
        raise InputError(src, f"pattern.stitches: expected a list, got {sin!r}")
    out, used = [], {}
    for k, s in enumerate(sin):
        at = f"pattern.stitches[{k}]"
        if not isinstance(s, list) or len(s) not in (2, 3):
            raise InputError(src, f"{at}: expected [{{panel, edge}}, {{panel, edge}}] (+ 'right_wrong'), got {s!r}")
        rw = len(s) == 3
        if rw and s[2] != "right_wrong":
            raise InputError(src, f"{at}[2]: expected 'right_wrong', got {s[2]!r}")
        ends = []
        for m in (0, 1):
            e = s[m]
            if not isinstance(e, dict) or e.get("panel") not in panels:
                raise InputError(src, f"{at}[{m}].panel: no panel {e.get('panel') if isinstance(e, dict) else e!r}; "
                                      f"panels: {', '.join(panels)}")
            n = len(panels[e["panel"]].edges)
            if not (isinstance(e.get("edge"), int) and 0 <= e["edge"] < n):
                raise InputError(src, f"{at}[{m}].edge: expected an edge index of panel {e['panel']!r} in "
                                      f"0..{n - 1}, got {e.get('edge')!r}")
            key = (e["panel"], e["edge"])
            if key in used or (m == 1 and key == ends[0]):
                raise InputError(src, f"{at}[{m}]: edge {key[1]} of panel {key[0]!r} is already in "
                                      f"pattern.stitches[{used.get(key, k)}] (an edge is sewn once)")
            ends.append(key)
        for key in ends:
            used[key] = k
        out.append(GCStitch(ends[0], ends[1], rw))
    return tuple(out)


def panel_part(p) -> str:
    """'arm', 'leg' or 'body': the panel's label, else guessed from its name (unlabelled files)."""
    if p.label in ("arm", "leg", "body"):
        return p.label
    n = p.name.lower()
    if any(w in n for w in ("sleeve", "cuff", "arm")):
        return "arm"
    if any(w in n for w in ("pant", "leg", "skirt")):
        return "leg"
    return "body"


def loop_points(panel: GCPanel, per_curve: int = 32) -> np.ndarray:
    """(N, 2) the panel's outline, curves sampled (start of each edge included, end not)."""
    pts = []
    for e in panel.edges:
        n = 1 if e.kind == "straight" else per_curve
        pts.append(edge_points(panel, e, np.arange(n) / n))
    return np.concatenate(pts)


def _signed_area(p: np.ndarray) -> float:
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def map_panel(p: GCPanel, A: np.ndarray, pivot=None, exact_arcs: bool = False) -> GCPanel:
    """The panel under the map x -> pivot + A (x - pivot) of the body frame (A: (3, 3)): its outline
    by R^T A R in its own plane (exact when A keeps the plane; a tilted panel keeps its in-plane
    part), its translation mapped. Circle arcs as in map_panel_points."""
    pivot = np.zeros(3) if pivot is None else np.asarray(pivot, np.float64)
    A = np.asarray(A, np.float64)
    return map_panel_points(p, lambda x: pivot + (x - pivot) @ A.T, exact_arcs)


def map_panel_points(p: GCPanel, f, exact_arcs: bool = False) -> GCPanel:
    """The panel under a map f ((N, 3) -> (N, 3) body-frame points): its translation t to f(t), each
    outline point and curve control point x to the in-plane part of f(x) - f(t) (the part along the
    panel's normal dropped: exact when f keeps the plane). Circle arcs become the circles through
    their mapped ends and midpoint; with exact_arcs, those far from the mapped arc the cubics fitted
    to it (_closer_curve: what a panel whose circles cross its other edges is graded with again)."""
    R = p.rotation
    t1 = f(np.asarray(p.translation, np.float64)[None])[0]

    def g(q):   # panel-local points (N, 2) -> mapped panel-local points
        q = np.asarray(q, np.float64).reshape(-1, 2)
        return ((f(p.to_3d(q)) - t1) @ R)[:, :2]
    verts = g(p.vertices)
    edges = []
    for e in p.edges:
        if e.kind == "circle":
            mid = g(edge_points(p, e, [0.5]))[0]
            a, b = verts[e.start], verts[e.end]
            r = _circumradius(a, mid, b)
            best = None
            for large in (False, True):
                c, rr, sweep = arc_center(a, b, r, large, e.right)
                th = math.atan2(a[1] - c[1], a[0] - c[0]) + 0.5 * sweep
                d = np.linalg.norm(c + rr * np.array([math.cos(th), math.sin(th)]) - mid)
                if best is None or d < best[0]:
                    best = (d, large)
            arc = dc_replace(e, radius=r, large_arc=best[1])
            edges.append(_closer_curve(arc, dc_replace(p, vertices=verts), g(edge_points(p, e, ARC_SAMPLES)))
                         if exact_arcs else arc)
        else:
            edges.append(dc_replace(e, control=tuple(tuple(c) for c in g(e.control)) if e.control else ()))
    return dc_replace(p, vertices=verts, edges=tuple(edges), translation=t1)


ARC_SAMPLES = np.linspace(0.0, 1.0, 17)
ARC_TOLERANCE = 0.01   # of the chord: a mapped arc farther than this from its circle is a cubic instead


def _closer_curve(arc: GCEdge, panel: GCPanel, mapped: np.ndarray) -> GCEdge:
    """The mapped circle arc `arc`, or, where the map is far from a similarity (a pattern graded
    x1.42 across and x0.39 up onto a chibi: an armhole's circle through its mapped ends and midpoint
    bulged across the panel's other edges), the cubic Bezier through its ends fitted to `mapped`
    ((S, 2) the arc's points at ARC_SAMPLES, mapped): a Bezier maps exactly under an affine map."""
    circle = edge_points(panel, arc, ARC_SAMPLES)
    chord = float(np.linalg.norm(mapped[-1] - mapped[0]))
    if np.abs(circle - mapped).max() <= ARC_TOLERANCE * max(chord, 1e-9):
        return arc
    t = ARC_SAMPLES[:, None]
    a, b = mapped[0], mapped[-1]
    basis = np.hstack([3 * (1 - t) ** 2 * t, 3 * (1 - t) * t ** 2])
    rhs = mapped - (1 - t) ** 3 * a - t ** 3 * b
    c, *_ = np.linalg.lstsq(basis, rhs, rcond=None)
    cubic = dc_replace(arc, kind="cubic", control=(tuple(c[0]), tuple(c[1])), radius=0.0, large_arc=False, right=False)
    off = np.abs(edge_points(panel, cubic, ARC_SAMPLES) - mapped).max()
    return cubic if off < np.abs(circle - mapped).max() else arc    # one cubic is no fit for a long arc


def _circumradius(a, b, c) -> float:
    la, lb, lc = np.linalg.norm(b - c), np.linalg.norm(a - c), np.linalg.norm(a - b)
    area2 = abs((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))
    return float(la * lb * lc / max(2 * area2, 1e-15)) if area2 > 1e-12 else 1e6
