"""Sewing patterns: flat panels with placements, seams and attachments (issue 7).

2D pattern coordinates: metres, u across the panel (to the wearer's left on a front panel seen from
the front), v up the panel (hem at small v). Outlines are closed and counter-clockwise in (u, v), so
the panel's outward normal is u x v: placement keeps that side facing away from the body.

An outline is a sequence of named edges; edge k starts where edge k-1 ends (edge 0 starts where the
last one ends), so each edge lists only its remaining control points:
- 'line'  : (end,)
- 'arc'   : (through, end) - the circular arc from the start through `through` to `end`
- 'quad'  : (control, end) - quadratic Bezier
- 'cubic' : (control1, control2, end) - cubic Bezier
Seams join edge ranges of panels (a run of consecutive edges, walked in outline order); the two
sides get the same number of boundary vertices when meshed.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stages.checks import ContractError

EDGE_KINDS = {"line": 1, "arc": 2, "quad": 2, "cubic": 3}
BODY_PARTS = ("torso", "hips", "arm_l", "arm_r", "leg_l", "leg_r", "plane")


@dataclass(frozen=True)
class Edge:
    """One outline edge. name: unique within its panel. kind: 'line', 'arc', 'quad' or 'cubic'.
    points: control points after the edge's start, metres, pattern (u, v) coordinates (see module)."""

    name: str
    kind: str
    points: tuple

    def __post_init__(self):
        if self.kind not in EDGE_KINDS:
            raise ContractError(f"Edge[{self.name!r}].kind: expected one of {sorted(EDGE_KINDS)}, got {self.kind!r}")
        p = np.asarray(self.points, dtype=np.float64)
        if p.shape != (EDGE_KINDS[self.kind], 2) or not np.isfinite(p).all():
            raise ContractError(f"Edge[{self.name!r}].points: a {self.kind!r} edge needs "
                                f"{EDGE_KINDS[self.kind]} finite (u, v) points, got {self.points!r}")
        object.__setattr__(self, "points", tuple(tuple(float(c) for c in q) for q in p))

    @property
    def end(self) -> np.ndarray:
        return np.asarray(self.points[-1])

    def evaluate(self, start, t: np.ndarray) -> np.ndarray:
        """(len(t), 2) points at curve parameters t in [0, 1]."""
        a = np.asarray(start, dtype=np.float64)
        t = np.asarray(t, dtype=np.float64)[:, None]
        p = [np.asarray(q) for q in self.points]
        if self.kind == "line":
            return a + t * (p[0] - a)
        if self.kind == "quad":
            return (1 - t) ** 2 * a + 2 * (1 - t) * t * p[0] + t ** 2 * p[1]
        if self.kind == "cubic":
            return (1 - t) ** 3 * a + 3 * (1 - t) ** 2 * t * p[0] + 3 * (1 - t) * t ** 2 * p[1] + t ** 3 * p[2]
        return _arc(a, p[0], p[1], t[:, 0])


def _arc(a, m, b, t):
    """Points of the circle arc a -> m -> b at parameters t (a straight line when collinear)."""
    d = 2 * (a[0] * (m[1] - b[1]) + m[0] * (b[1] - a[1]) + b[0] * (a[1] - m[1]))
    scale = max(np.linalg.norm(b - a), np.linalg.norm(m - a), 1e-12)
    if abs(d) < 1e-9 * scale * scale:
        return a + t[:, None] * (b - a)
    sa, sm, sb = a @ a, m @ m, b @ b
    c = np.array([sa * (m[1] - b[1]) + sm * (b[1] - a[1]) + sb * (a[1] - m[1]),
                  sa * (b[0] - m[0]) + sm * (a[0] - b[0]) + sb * (m[0] - a[0])]) / d
    ang = lambda q: math.atan2(q[1] - c[1], q[0] - c[0])
    t0, tm, t1 = ang(a), ang(m), ang(b)
    # go from t0 to t1 in the direction that passes tm
    ccw = (tm - t0) % (2 * np.pi) < (t1 - t0) % (2 * np.pi)
    sweep = (t1 - t0) % (2 * np.pi) if ccw else -((t0 - t1) % (2 * np.pi))
    th = t0 + sweep * t
    r = np.linalg.norm(a - c)
    return c + r * np.stack([np.cos(th), np.sin(th)], axis=1)


@dataclass(frozen=True)
class Placement:
    """Where a panel goes on the body in the bind pose (frame 0 of the motion).

    body: 'torso' (vertical axis through the chest), 'hips' (vertical axis through the root; the
        cross-section grows monotonically downwards so a skirt hangs over the legs), 'arm_l' /
        'arm_r' (axis from the upper-arm joint along the upper arm, v pointing to the shoulder),
        'leg_l' / 'leg_r' (axis from the hip joint along the thigh, v pointing up), or 'plane' (flat,
        no wrapping: the panel lies in the plane through `center` with normal `normal`).
    angle_deg: angle around the axis of the panel's u = 0 line. Torso / hips: 0 = front (+Z),
        90 = the wearer's left (+X), 180 = back. Arms / legs: 0 = the side facing up (arms) or
        forward (legs).
    span_deg: angle covered by the panel's reference width (180: front or back half; 360: a
        sleeve closing on itself).
    shift: metres along the axis of the panel's v = 0 (torso / hips: world height of v = 0 above
        the floor under the root; limbs: signed distance from the limb joint, negative = outwards
        along the limb).
    offset: clearance from the body, metres (added to the body's cross-section).
    wrap_until: panel v above which the reference width stops following the outline (e.g. the
        armpit of a T-shirt panel); None = follow the outline everywhere.
    center, normal: for 'plane' only (metres, relative frame at frame 0; unit normal).
    exponent: cross-section shape, a superellipse |p/a|^n + |q/b|^n = 1 (2: ellipse; 4: a rounded
        box, e.g. an upper torso whose shoulders and arm roots are wide in front and back).
    arms: torso only: whether the cross-section must also cover the upper arms' roots (a cape) or
        not (a T-shirt, whose sleeves cover them).
    stretch: True: a panel narrower than the arc of its span is stretched round the body to cover it
        (front and back meet at their side seams); False: it lies on the body at its own width,
        centred on angle_deg (a cape, which has no side seam to reach: stretched to 120 degrees of
        the shoulders its top rows started 37 % (CesiumMan) to 106 % (a chibi) long, p99).
    fold_at, ridge: torso only: above panel height fold_at each panel column bends over the top of
        the body (a quarter superellipse in the column's vertical plane) so that it ends on the
        ridge plane through the axis (front and back meet there: a T-shirt's shoulder line). ridge:
        ((u, v), ...) points of the panel's top line, u ascending; the column at u ends on the ridge
        at arc length ridge(u) - fold_at (ridge interpolated, constant beyond its ends).
    """

    body: str
    angle_deg: float = 0.0
    span_deg: float = 180.0
    shift: float = 0.0
    offset: float = 0.02
    wrap_until: float | None = None
    center: tuple = (0.0, 0.0, 0.0)
    normal: tuple = (0.0, 0.0, 1.0)
    exponent: float = 2.0
    arms: bool = True
    stretch: bool = True
    fold_at: float | None = None
    ridge: tuple = ()

    def __post_init__(self):
        if self.body not in BODY_PARTS:
            raise ContractError(f"Placement.body: expected one of {BODY_PARTS}, got {self.body!r}")
        for name in ("angle_deg", "span_deg", "shift", "offset"):
            if not np.isfinite(getattr(self, name)):
                raise ContractError(f"Placement.{name}: expected a finite number, got {getattr(self, name)}")
        if not 0 < self.span_deg <= 360:
            raise ContractError(f"Placement.span_deg: expected (0, 360], got {self.span_deg}")
        if not (np.isfinite(self.exponent) and 1.5 <= self.exponent <= 12):
            raise ContractError(f"Placement.exponent: expected [1.5, 12], got {self.exponent}")
        if self.fold_at is not None:
            r = np.asarray(self.ridge, dtype=np.float64)
            if not np.isfinite(self.fold_at) or r.ndim != 2 or r.shape[1] != 2 or r.shape[0] < 2 \
                    or not np.isfinite(r).all() or np.any(np.diff(r[:, 0]) <= 0) or np.any(r[:, 1] <= self.fold_at):
                raise ContractError("Placement.fold_at / ridge: expected a finite fold height and >= 2 ridge "
                                    "points (u ascending) above it")
            object.__setattr__(self, "ridge", tuple(tuple(float(c) for c in q) for q in r))
        if self.offset < 0:
            raise ContractError(f"Placement.offset: expected >= 0, got {self.offset}")
        n = np.asarray(self.normal, dtype=np.float64)
        if n.shape != (3,) or not np.linalg.norm(n) > 0 or np.asarray(self.center).shape != (3,):
            raise ContractError("Placement.center / normal: expected 3 numbers each, normal non-zero")


@dataclass(frozen=True)
class Panel:
    """A flat pattern piece: name, closed counter-clockwise outline of named edges, placement."""

    name: str
    edges: tuple
    placement: Placement

    def __post_init__(self):
        o = f"Panel[{self.name!r}]"
        if len(self.edges) < 2 or not all(isinstance(e, Edge) for e in self.edges):
            raise ContractError(f"{o}.edges: expected at least 2 Edge objects")
        object.__setattr__(self, "edges", tuple(self.edges))
        names = [e.name for e in self.edges]
        if len(set(names)) != len(names):
            raise ContractError(f"{o}.edges: edge names must be unique, got {names}")
        poly = self.polyline(64)
        if _self_intersects(poly):
            raise ContractError(f"{o}: the outline intersects itself")
        if polygon_area(poly) <= 0:
            raise ContractError(f"{o}: the outline must be counter-clockwise with positive area "
                                f"(signed area {polygon_area(poly):.4g} m^2)")

    def edge_index(self, name: str) -> int:
        for i, e in enumerate(self.edges):
            if e.name == name:
                return i
        raise ContractError(f"Panel[{self.name!r}]: no edge {name!r}; edges: {[e.name for e in self.edges]}")

    def start_of(self, i: int) -> np.ndarray:
        return self.edges[i - 1].end

    def edge_length(self, i: int, samples: int = 256) -> float:
        p = self.edges[i].evaluate(self.start_of(i), np.linspace(0, 1, samples + 1))
        return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())

    def sample_edge(self, i: int, n: int) -> np.ndarray:
        """(n, 2) points splitting edge i into n pieces of equal arc length (start included, end not)."""
        dense = self.edges[i].evaluate(self.start_of(i), np.linspace(0, 1, 64 * n + 1))
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(dense, axis=0), axis=1))])
        want = s[-1] * np.arange(n) / n
        return np.stack([np.interp(want, s, dense[:, 0]), np.interp(want, s, dense[:, 1])], axis=1)

    def polyline(self, per_edge: int = 16) -> np.ndarray:
        return np.concatenate([self.sample_edge(i, per_edge if self.edges[i].kind != "line" else 1)
                               for i in range(len(self.edges))])

    @property
    def area(self) -> float:
        """Area of the outline, m^2 (curves sampled finely)."""
        return polygon_area(self.polyline(256))


@dataclass(frozen=True)
class SeamSide:
    """A run of consecutive edges of one panel, in outline order (wrapping allowed)."""

    panel: str
    edges: tuple

    def __post_init__(self):
        if isinstance(self.edges, str):
            object.__setattr__(self, "edges", (self.edges,))
        object.__setattr__(self, "edges", tuple(self.edges))
        if not self.edges:
            raise ContractError(f"SeamSide[{self.panel!r}]: needs at least one edge")


@dataclass(frozen=True)
class Seam:
    """Two edge runs sewn together. reverse=True (usual for two outward-facing panels, whose
    outlines run in opposite directions along a shared edge) pairs a's start with b's end.
    stage: sewing order; seams of stage k start pulling once the earlier stages are closed."""

    a: SeamSide
    b: SeamSide
    reverse: bool = True
    stage: int = 0

    def __post_init__(self):
        if not (isinstance(self.stage, (int, np.integer)) and 0 <= self.stage <= 8):
            raise ContractError(f"Seam.stage: expected an integer in [0, 8], got {self.stage!r}")


@dataclass(frozen=True)
class PatternAttachment:
    """Particles pinned to a bone after sewing: the vertices of `edges` of `panel` (all of them, or
    those at the given fractions 0..1 of the edge run's length when `at` is given). joint: a joint
    name, 'root', 'common' (one bone: the common ancestor of the nearest colliders' bones, see
    stages.garments.types.Attachment) or None (the bone of the nearest collider). sewing: pin the middle half of the
    run (by length) already while sewing, where it was placed (a waistband holding a skirt or
    trousers up, so the garment cannot slide down the body before its seams are closed); the
    run's ends and seam vertices stay free so the seams there can close."""

    panel: str
    edges: tuple
    at: tuple | None = None
    joint: str | None = None
    sewing: bool = False

    def __post_init__(self):
        if isinstance(self.edges, str):
            object.__setattr__(self, "edges", (self.edges,))
        object.__setattr__(self, "edges", tuple(self.edges))
        if self.at is not None and not all(0.0 <= float(a) <= 1.0 for a in self.at):
            raise ContractError("PatternAttachment.at: fractions must be in [0, 1]")


@dataclass(frozen=True)
class Pattern:
    """A garment pattern.

    name: garment name. panels: Panel tuple. seams: Seam tuple. edge_length: target mean edge
    length of the mesh, metres. attachments: PatternAttachment tuple (default pins).
    density: cloth area density, kg/m^2. fit_edges: SeamSide tuple, the edges meant to sit on the
    body (a waistband, a collar): their distance to the skin after sewing is the garment's fit gap;
    before sewing they are brought onto the colliders, walking horizontally to the body's axis
    (fit_hug 'axis') or towards the base of the neck ('neck'). fit_band: when set, the fit edges
    are finished with a band (neckband, waistband ribbing) cut to fit_band times the length of
    the loop they are hugged onto: their edges' rest lengths are those hugged lengths, so sewing
    does not spread them back to the flat pattern's longer run.
    """

    name: str
    panels: tuple
    seams: tuple = ()
    edge_length: float = 0.025
    attachments: tuple = ()
    density: float = 0.2
    fit_edges: tuple = ()
    fit_hug: str = "axis"
    fit_band: float | None = None

    def __post_init__(self):
        o = f"Pattern[{self.name!r}]"
        object.__setattr__(self, "panels", tuple(self.panels))
        object.__setattr__(self, "seams", tuple(self.seams))
        object.__setattr__(self, "attachments", tuple(self.attachments))
        object.__setattr__(self, "fit_edges", tuple(self.fit_edges))
        if self.fit_hug not in ("axis", "neck"):
            raise ContractError(f"{o}.fit_hug: expected 'axis' or 'neck', got {self.fit_hug!r}")
        if self.fit_band is not None and not (np.isfinite(self.fit_band) and 0.5 <= self.fit_band <= 1.5):
            raise ContractError(f"{o}.fit_band: expected a factor in [0.5, 1.5] or None, got {self.fit_band}")
        if not self.panels:
            raise ContractError(f"{o}.panels: needs at least one panel")
        names = [p.name for p in self.panels]
        if len(set(names)) != len(names):
            raise ContractError(f"{o}.panels: panel names must be unique, got {names}")
        if not (np.isfinite(self.edge_length) and 0.002 <= self.edge_length <= 0.5):
            raise ContractError(f"{o}.edge_length: expected metres in [0.002, 0.5], got {self.edge_length}")
        if not (np.isfinite(self.density) and self.density > 0):
            raise ContractError(f"{o}.density: expected a positive number, got {self.density}")
        used = set()
        for k, s in enumerate(self.seams):
            for side in (s.a, s.b):
                ids = self.edge_run(side)
                for i in ids:
                    key = (side.panel, i)
                    if key in used:
                        raise ContractError(f"{o}.seams[{k}]: edge {self.panel(side.panel).edges[i].name!r} of "
                                            f"panel {side.panel!r} is already in a seam")
                    used.add(key)
        for a in self.attachments:
            self.edge_run(SeamSide(a.panel, a.edges))
        for side in self.fit_edges:
            self.edge_run(side)

    def panel(self, name: str) -> Panel:
        for p in self.panels:
            if p.name == name:
                return p
        raise ContractError(f"Pattern[{self.name!r}]: no panel {name!r}; panels: {[p.name for p in self.panels]}")

    def edge_run(self, side: SeamSide) -> list[int]:
        """Edge indices of a run, checked to be consecutive in outline order."""
        p = self.panel(side.panel)
        ids = [p.edge_index(n) for n in side.edges]
        n = len(p.edges)
        for a, b in zip(ids[:-1], ids[1:]):
            if b != (a + 1) % n:
                raise ContractError(f"Pattern[{self.name!r}]: edges {list(side.edges)} of panel {side.panel!r} "
                                    "are not consecutive in outline order")
        return ids


def polygon_area(p: np.ndarray) -> float:
    """Signed area of a closed polygon (counter-clockwise > 0)."""
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _self_intersects(p: np.ndarray) -> bool:
    """Whether any two non-adjacent segments of the closed polygon cross (O(n^2), small n)."""
    a, b = p, np.roll(p, -1, axis=0)
    n = len(p)
    d = b - a
    for i in range(n):
        j = np.arange(i + 2, n)
        if i == 0:
            j = j[j != n - 1]
        if j.size == 0:
            continue
        cross = lambda u, v: u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]
        d1 = cross(d[i], a[j] - a[i])
        d2 = cross(d[i], b[j] - a[i])
        d3 = cross(d[j], a[i] - a[j])
        d4 = cross(d[j], b[i] - a[j])
        if np.any((d1 * d2 < 0) & (d3 * d4 < 0)):
            return True
    return False


def line(name, end) -> Edge:
    return Edge(name, "line", (tuple(end),))


def arc(name, through, end) -> Edge:
    return Edge(name, "arc", (tuple(through), tuple(end)))


def quad(name, control, end) -> Edge:
    return Edge(name, "quad", (tuple(control), tuple(end)))


def cubic(name, c1, c2, end) -> Edge:
    return Edge(name, "cubic", (tuple(c1), tuple(c2), tuple(end)))
