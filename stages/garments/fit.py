"""How a garment sits on the body: the fit gap of its waistband / collar after sewing, the hem's
height above the floor and the share of particles inside the true body, per frame.

These are the figures a user checks on a dressed character (issue: garments dress any humanoid);
the pipeline reports them for every pattern garment and `python -m pipeline matrix` tabulates them
over characters x garment kinds.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from stages.checks import ContractError, check_array

FIT_GAP_MAX = 0.02        # m: median waistband / collar distance to the skin a fitted garment keeps
BODY_SHARE_MAX = 0.005    # share of a garment's particles inside the true body at any frame
ANCHOR_SHARE = 0.05       # a garment without fit edges is held by its highest particles at frame 0 (this share)


@dataclass(frozen=True)
class GarmentFit:
    """name: garment name. fit_gap: (K,) float64, m, distance from each fit-edge particle (waistband,
    collar) to the skin (or to a garment worn under it, if nearer) at the bind pose after sewing,
    negative inside the body (empty when the garment has no fit edges). floor_clearance: (F,) float64, m, lowest particle minus the floor
    (the simulation's floor, else the lowest skin vertex over the frames) per frame. body_share: (F,) float64, share of the
    garment's particles inside the true body per frame (nan when the audit was off). slide: (F,)
    float64, m, how far the garment moved off where it was dressed per frame (`garment_slide`; empty
    when the skin's frames were not given).
    """

    name: str
    fit_gap: np.ndarray
    floor_clearance: np.ndarray
    body_share: np.ndarray
    slide: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self):
        o = f"GarmentFit[{self.name!r}]"
        check_array(o, "fit_gap", self.fit_gap, (None,), np.float64)
        f = check_array(o, "floor_clearance", self.floor_clearance, (None,), np.float64).shape[0]
        if not (isinstance(self.body_share, np.ndarray) and self.body_share.shape == (f,)):   # nan: audit off
            raise ContractError(f"{o}.body_share: expected ({f},) float64")
        if self.slide.size:
            check_array(o, "slide", self.slide, (f,), np.float64)

    @property
    def fit_gap_median(self) -> float:
        return float(np.median(self.fit_gap)) if self.fit_gap.size else float("nan")

    def warnings(self, after_frame: int = 1) -> list[str]:
        out = []
        if self.fit_gap.size and abs(self.fit_gap_median) > FIT_GAP_MAX:
            out.append(f"garment {self.name!r}: waistband / collar {self.fit_gap_median * 100:.1f} cm from the skin "
                       f"or the garment under it (median; expected within {FIT_GAP_MAX * 100:.0f} cm)")
        if self.floor_clearance.size and self.floor_clearance.min() < 0:
            k = int(np.argmin(self.floor_clearance))
            out.append(f"garment {self.name!r}: {-self.floor_clearance[k] * 100:.1f} cm below the floor at frame {k}")
        share = self.body_share[after_frame:]
        if share.size and np.nanmax(share, initial=0.0) > BODY_SHARE_MAX:
            k = after_frame + int(np.nanargmax(share))
            out.append(f"garment {self.name!r}: {share.max() * 100:.2f} % of its particles inside the body at frame {k} "
                       f"(expected <= {BODY_SHARE_MAX * 100:.1f} %)")
        return out


def signed_skin_distance(body, points: np.ndarray) -> np.ndarray:
    """(N,) float64, m: distance of (N, 3) points to the skin of `body` (a stages.geometry.skin_distance.SkinDistance
    refitted to the pose of the points), negative inside the body."""
    p = np.ascontiguousarray(points, np.float64)
    return np.where(body.inside(p), -1.0, 1.0) * body.distance(p)


def garment_slide(skin_frames: np.ndarray, positions: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """(F,) float64, m: per frame, the median over the `anchors` particles of how much farther each is
    from the skin vertex nearest it at frame 0 than it was then. skin_frames (F, V, 3) and positions
    (F, N, 3) in one frame (world). A garment that slid off the body (its waistband or collar no
    longer on the waist or neck it was dressed on) reads tens of cm, however low the floor under it;
    one that moves with the body, a few mm: its anchors follow their skin through any pose."""
    from scipy.spatial import cKDTree
    p = np.asarray(positions, np.float64)[:, anchors]
    d0, v = cKDTree(np.asarray(skin_frames[0], np.float64)).query(p[0])
    d = np.linalg.norm(p - np.asarray(skin_frames, np.float64)[:, v], axis=2)
    return np.median(d - d0[None, :], axis=1)


def slide_anchors(positions0: np.ndarray, fit_vertices: np.ndarray) -> np.ndarray:
    """The particles `garment_slide` follows: the fit edges (waistband, collar), else the highest
    ANCHOR_SHARE of the particles at frame 0 (positions0 (N, 3))."""
    if fit_vertices.size:
        return np.asarray(fit_vertices, np.int64)
    k = max(1, int(np.ceil(ANCHOR_SHARE * positions0.shape[0])))
    return np.argsort(positions0[:, 1])[-k:]


def garment_fit(character, bind_skin: np.ndarray, bind_positions: np.ndarray, fit_vertices: np.ndarray,
                track, floor_y: float, skin_distance=None, under: np.ndarray | None = None,
                skin_frames: np.ndarray | None = None) -> GarmentFit:
    """The fit of one simulated garment.

    bind_skin: (V, 3) the skinned body at the bind pose (frame 0, relative frame); bind_positions:
    (N, 3) the sewn garment there (the Garment's positions, same frame). fit_vertices: (K,) int64
    particle ids. track: the garment's GarmentTrack (world). floor_y: m, world floor height.
    skin_distance: a stages.geometry.skin_distance.SkinDistance of the character to reuse (built when None).
    under: optional (M, 3) points on the garments worn under this one (bind pose, same frame): the
    fit gap is then to the nearer of the skin and them (a waistband over a tucked-in shirt).
    skin_frames: optional (F, V, 3) the skin at the track's frames (world): the fit's `slide`.
    """
    from stages.geometry.skin_distance import SkinDistance
    n = track.positions.shape[1]
    gap = np.zeros(0)
    if fit_vertices.size:
        body = skin_distance if skin_distance is not None else SkinDistance(character)
        body.refit(np.ascontiguousarray(bind_skin, np.float64))
        pts = np.asarray(bind_positions, np.float64)[fit_vertices]
        gap = signed_skin_distance(body, pts)
        if under is not None and len(under):
            from scipy.spatial import cKDTree
            gap = np.where(gap > 0, np.minimum(gap, cKDTree(np.asarray(under, np.float64)).query(pts)[0]), gap)
    clearance = track.positions[..., 1].min(axis=1).astype(np.float64) - float(floor_y)
    pen = track.penetrations_body.astype(np.float64)
    share = np.where(pen >= 0, pen / max(n, 1), np.nan)
    slide = np.zeros(0)
    if skin_frames is not None:
        slide = garment_slide(skin_frames, track.positions, slide_anchors(track.positions[0], fit_vertices))
    return GarmentFit(track.name, np.asarray(gap, np.float64), clearance, share, slide)


def fit_table(fits: list, seam_gaps: dict) -> str:
    """Markdown table of GarmentFit figures; seam_gaps: {garment name: largest seam gap m} (pattern
    garments)."""
    rows = ["| garment | seam gap (mm) | waistband / collar to skin or lower layer, median (cm) | lowest point above the floor (cm) | "
            "inside the body, worst frame after 0 (%) |", "| --- | ---: | ---: | ---: | ---: |"]
    for f in fits:
        gap = seam_gaps.get(f.name)
        share = f.body_share[1:]
        rows.append(f"| {f.name} | {'' if gap is None else f'{gap * 1000:.1f}'} | "
                    f"{'' if not f.fit_gap.size else f'{f.fit_gap_median * 100:.1f}'} | "
                    f"{f.floor_clearance.min() * 100:.1f} | "
                    f"{'' if not share.size or np.isnan(share).all() else f'{np.nanmax(share) * 100:.2f}'} |")
    return "\n".join(rows)


def start_warnings(track) -> list[str]:
    """A garment that starts (frame 0) with particles inside a collider or the body."""
    c, b = int(track.penetrations_colliders[0]), int(track.penetrations_body[0])
    if c <= 0 and b <= 0:
        return []
    parts = ([f"{c} inside a collider"] if c > 0 else []) + ([f"{b} inside the body"] if b > 0 else [])
    return [f"garment {track.name!r} starts with {' and '.join(parts)} of its {track.positions.shape[1]} particles "
            "(frame 0): move or resize it"]
