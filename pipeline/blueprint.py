"""The recording's blueprint: what a user sees on opening the `.rrd`.

Built at the end of a run (the cameras need the motion's bounds, the tabs need to know which stages
ran) and sent into the recording as its active and default blueprint:

- the `frame` timeline, playing from the start in a loop at the scene's frame rate;
- blueprint and selection panels collapsed, the time panel visible (compact);
- every 3D view with a fixed camera (`EyeControls3D`) from a front three-quarter view that holds
  what the view shows over the whole clip (body at every frame, garments, obstacles), so nothing
  is cut and the view does not chase the scene's bounding box;
- tabs only for the stages that ran: overview (scene + cloth plots; the scene alone without a
  simulation), rig (bind pose with region labels beside the animated body), colliders, maps,
  garments (sewing), obstacles, performance, meta.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

UP = np.array([0.0, 1.0, 0.0])
FOV_Y = np.radians(50.0)       # the viewer's vertical field of view (re_view_spatial: 55 deg) with a margin
AZIMUTH = np.radians(45.0)     # front three-quarter: this far round from straight ahead
ELEVATION = np.radians(12.0)   # a little above the chest: the garment's top and hem both read


@dataclass
class Box:
    """An axis-aligned box in world metres."""
    lo: np.ndarray
    hi: np.ndarray

    @classmethod
    def of(cls, *point_sets) -> Box:
        pts = [np.asarray(p, np.float64).reshape(-1, 3) for p in point_sets if p is not None and np.size(p)]
        if not pts:
            return cls(np.full(3, -0.5), np.full(3, 0.5))
        return cls(np.min([p.min(0) for p in pts], 0), np.max([p.max(0) for p in pts], 0))

    def union(self, other: Box | None) -> Box:
        return self if other is None else Box(np.minimum(self.lo, other.lo), np.maximum(self.hi, other.hi))

    def padded(self, d: float) -> Box:
        return Box(self.lo - d, self.hi + d)

    def corners(self) -> np.ndarray:
        return np.array([[x, y, z] for x in (self.lo[0], self.hi[0]) for y in (self.lo[1], self.hi[1])
                         for z in (self.lo[2], self.hi[2])])

    @property
    def center(self) -> np.ndarray:
        return (self.lo + self.hi) / 2


@dataclass
class Camera:
    position: np.ndarray
    look_target: np.ndarray
    eye_up: np.ndarray = field(default_factory=lambda: UP.copy())

    def controls(self) -> rrb.EyeControls3D:
        return rrb.EyeControls3D(position=[float(v) for v in self.position],
                                 look_target=[float(v) for v in self.look_target],
                                 eye_up=[float(v) for v in self.eye_up])

    def sees(self, points: np.ndarray, *, aspect: float, fov_y: float = FOV_Y) -> bool:
        """Every point in front of the camera and inside its field of view (a pinhole of `fov_y`)."""
        x, y, depth = self._project(points)
        ty = np.tan(fov_y / 2)
        return bool((depth > 0).all() and (np.abs(y) <= depth * ty + 1e-9).all()
                    and (np.abs(x) <= depth * ty * aspect + 1e-9).all())

    def _project(self, points):
        look = self.look_target - self.position
        look /= np.linalg.norm(look)
        right = np.cross(look, self.eye_up)
        right /= np.linalg.norm(right)
        up = np.cross(right, look)
        rel = np.asarray(points, np.float64).reshape(-1, 3) - self.position
        return rel @ right, rel @ up, rel @ look


def hull_points(*point_sets) -> np.ndarray:
    """The vertices of the convex hull of every given point ((..., 3) arrays, e.g. (F, V, 3) over a
    clip): a camera that sees these sees every point (perspective keeps a convex set convex)."""
    from scipy.spatial import ConvexHull
    pts = np.concatenate([np.asarray(p, np.float64).reshape(-1, 3) for p in point_sets if p is not None and np.size(p)]
                         or [np.zeros((0, 3))])
    if len(pts) < 5:
        return Box.of(pts).corners() if len(pts) else Box(np.full(3, -0.5), np.full(3, 0.5)).corners()
    try:
        return pts[ConvexHull(pts).vertices]
    except Exception:   # flat or degenerate: the box's corners hold it too
        return Box.of(pts).corners()


def dilated(points, r: float) -> np.ndarray:
    """hull_points of the points grown by r in every direction (26 directions, scaled to cover the ball)."""
    dirs = np.array([[i, j, k] for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1) if i or j or k], np.float64)
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    return hull_points((pts[:, None, :] + 1.2 * r * dirs[None]).reshape(-1, 3))


def front_three_quarter(points, forward, *, aspect: float, margin: float = 0.06,
                        azimuth: float = AZIMUTH, elevation: float = ELEVATION) -> Camera:
    """A camera looking from in front of the character (`forward`, horizontal), `azimuth` round to
    its right and `elevation` up, at the middle of what it frames, just far enough that every point
    (a Box's corners or `hull_points`) fits a view of vertical field of view FOV_Y and width / height
    `aspect`, with `margin` of it spare on the tighter side."""
    pts = points.corners() if isinstance(points, Box) else np.asarray(points, np.float64).reshape(-1, 3)
    f = np.asarray(forward, np.float64) * [1, 0, 1]
    f = f / np.linalg.norm(f) if np.linalg.norm(f) > 1e-9 else np.array([0.0, 0.0, 1.0])
    right = np.cross(f, UP)            # the character's right
    d = np.cos(elevation) * (np.cos(azimuth) * f + np.sin(azimuth) * right) + np.sin(elevation) * UP
    cam_right = np.cross(-d, UP)
    cam_right /= np.linalg.norm(cam_right)
    cam_up = np.cross(cam_right, -d)
    ty = np.tan(FOV_Y / 2) * (1 - margin)
    tx = ty * aspect
    target = Box.of(pts).center
    for _ in range(8):   # distance that fits, then centre the picture on what it holds, and again
        rel = pts - target
        x, y, z = rel @ cam_right, rel @ cam_up, rel @ d       # z: towards the camera
        dist = max(float(np.max(np.concatenate([z + np.abs(y) / ty, z + np.abs(x) / tx]))), 0.5)
        depth = dist - z
        u, v = x / depth, y / depth
        du, dv = (u.max() + u.min()) / 2, (v.max() + v.min()) / 2
        if abs(du) < 1e-4 and abs(dv) < 1e-4:
            break
        dt = dist - float(np.median(z))
        target = target + cam_right * du * dt + cam_up * dv * dt
    rel = pts - target
    x, y, z = rel @ cam_right, rel @ cam_up, rel @ d
    dist = max(float(np.max(np.concatenate([z + np.abs(y) / ty, z + np.abs(x) / tx]))), 0.5)
    return Camera(target + d * dist, target.copy())


def facing(character, motion) -> np.ndarray:
    """The way the character faces over the clip (horizontal unit vector): its hips' left-to-right
    axis crossed with up, averaged over the frames (a character that turns into its walk after a
    blend from the bind pose is seen from the front of the walk); the walk's direction when the hips
    are not found; +Z (glTF's front) otherwise."""
    try:
        from stages.rig.humanoid import humanoid_joints
        hj = humanoid_joints(character)
        if hj.leg_l and hj.leg_r:
            p = motion.joint_world[:, :, :3, 3]
            f = np.cross(p[:, hj.leg_l[0]] - p[:, hj.leg_r[0]], UP) * [1, 0, 1]
            f = f / np.maximum(np.linalg.norm(f, axis=1, keepdims=True), 1e-9)
            f = f.mean(0)
            if np.linalg.norm(f) > 1e-3:
                return f / np.linalg.norm(f)
    except Exception:   # a rig without two legs: fall back below
        pass
    walk = (motion.root_translation[-1] - motion.root_translation[0]) * [1, 0, 1]
    if np.linalg.norm(walk) > 0.2:
        return walk / np.linalg.norm(walk)
    return np.array([0.0, 0.0, 1.0])


@dataclass
class Contents:
    """What the run logged, for the blueprint: names of what exists and the boxes the cameras frame."""
    fps: float
    forward: np.ndarray
    # what each camera frames: hull_points (or a Box), world metres
    scene_box: np.ndarray               # body over every frame + garments + obstacles
    body_box: np.ndarray                # body over every frame
    bind_box: np.ndarray                # the bind pose (rig/regions)
    garments: list = field(default_factory=list)      # simulated garments (empty: no simulation)
    sewn: list = field(default_factory=list)          # pattern garments with a sewing log
    sewing_box: np.ndarray | None = None              # flat + placed panels
    obstacles: list = field(default_factory=list)
    floor: bool = False                               # the simulation's floor (floor/mesh)
    hulls: list = field(default_factory=list)         # collider hull names
    spheres: list = field(default_factory=list)       # joint sphere names
    coverage: bool = False
    maps: bool = True


# aspect ratios (width / height) of the views in a 1920 x 1080 window with the side panels collapsed
# (measured on snapshots: 1145 x 952 beside a column of 2/5, 960 x 952 for half, 1920 x 952 whole)
ASPECT_OVERVIEW = 1.15    # 3/5 of the width beside the plots
ASPECT_HALF = 0.95        # the rig tab's two views side by side
ASPECT_WIDE = 1.15        # a 3D view beside a report column (3/5)
ASPECT_FULL = 1.9         # a 3D view alone in its tab


def strain_contents(garments) -> list[str]:
    """The strain series of each garment (`sim/<garment>/strain`, and anything under it)."""
    return [f"+ /sim/{g}/strain/**" for g in garments]


def scene_view(c: Contents, aspect: float) -> rrb.Spatial3DView:
    contents = ["+ /rig/mesh"]
    for g in c.garments:
        # body_cuts: where the body passes through the cloth (pipeline.body_report)
        contents += [f"+ /sim/{g}/mesh", f"+ /sim/{g}/attached", f"+ /sim/{g}/body_cuts"]
    contents += [f"+ /obstacles/{o}/mesh" for o in c.obstacles]
    if c.floor:
        contents.append("+ /floor/mesh")
    return rrb.Spatial3DView(name="scene", origin="/", contents=contents,
                             eye_controls=front_three_quarter(c.scene_box, c.forward, aspect=aspect).controls())


def overview(c: Contents):
    if not c.garments:   # nothing simulated: the scene alone, no empty plots
        return rrb.Horizontal(scene_view(c, ASPECT_FULL), name="overview")
    scene = scene_view(c, ASPECT_OVERVIEW)
    plots = rrb.Vertical(
        rrb.TimeSeriesView(name="particles inside the body / a collider", origin="/sim/penetrations",
                           contents=["+ /sim/penetrations/**"], plot_legend=rrb.Corner2D.LeftTop),
        rrb.TimeSeriesView(name="strain", origin="/sim", contents=strain_contents(c.garments),
                           plot_legend=rrb.Corner2D.LeftTop),
        rrb.TimeSeriesView(name="cloth intersections", origin="/sim/intersections",
                           contents=["+ /sim/intersections/**"], plot_legend=rrb.Corner2D.LeftTop),
        rrb.TextDocumentView(name="garment fit: seam gap, waistband / collar, floor", origin="/sim/fit"),
        name="cloth",
    )
    return rrb.Horizontal(scene, plots, column_shares=[3, 2], name="overview")


def rig_tab(c: Contents):
    translucent = rr.Mesh3D.from_fields(albedo_factor=(214, 182, 156, 90)).visualizer()
    return rrb.Horizontal(
        rrb.Spatial3DView(name="bind pose: region colours (saturated: rigid, labelled by bone; pale: flexible, "
                               "around a joint)", origin="/rig/regions",
                          contents=["+ /rig/regions/**"],
                          eye_controls=front_three_quarter(c.bind_box, c.forward, aspect=ASPECT_HALF, azimuth=0.0).controls()),
        rrb.Spatial3DView(name="animated: body, skeleton and joints", origin="/",
                          contents=["+ /rig/mesh", "+ /rig/skeleton", "+ /rig/joints"],
                          overrides={"/rig/mesh": translucent},
                          eye_controls=front_three_quarter(c.body_box, c.forward, aspect=ASPECT_HALF).controls()),
        name="rig",
    )


def colliders_tab(c: Contents):
    contents = ["+ /colliders/**"]
    for h in c.hulls:
        contents += [f"- /colliders/hulls/{h}/raw", f"- /colliders/hulls/{h}/inflated", f"- /colliders/hulls/{h}/region"]
    contents += [f"- /colliders/spheres/{s}/region" for s in c.spheres]
    contents += ["- /colliders/fit/**", "- /colliders/report"]
    view = rrb.Spatial3DView(name="colliders in their bone frames, coloured by bone as in the rig tab",
                             origin="/", contents=contents,
                             eye_controls=front_three_quarter(dilated(c.body_box, 0.03), c.forward, aspect=ASPECT_WIDE).controls())
    side = [rrb.TextDocumentView(name="collider fit", origin="/colliders/report")]
    if c.coverage:
        side.insert(0, rrb.TimeSeriesView(name="collider fit at the sampled frames", origin="/colliders/fit"))
    return rrb.Horizontal(view, rrb.Vertical(*side), column_shares=[3, 2], name="colliders")


def build(c: Contents) -> rrb.Blueprint:
    tabs = [overview(c), rig_tab(c), colliders_tab(c)]
    if c.maps:
        tabs.append(rrb.Spatial3DView(name="maps", origin="/maps",
                                      eye_controls=front_three_quarter(dilated(c.body_box, 0.06), c.forward,
                                                                       aspect=ASPECT_FULL).controls()))
    if c.sewn:
        tabs.append(rrb.Horizontal(
            rrb.Spatial3DView(name="sewing: flat panels, placed on the body, sewn (progress and seam gap: timeline "
                                   "sewing_iteration)", origin="/garments",
                              eye_controls=front_three_quarter(c.bind_box if c.sewing_box is None else c.sewing_box, c.forward,
                                                               aspect=ASPECT_WIDE).controls()),
            rrb.Vertical(*[rrb.TextDocumentView(name=f"{g}: sewing report", origin=f"/garments/{g}/report")
                           for g in c.sewn]),
            column_shares=[3, 2], name="garments"))
    if c.obstacles:
        contents = [f"+ /obstacles/{o}/**" for o in c.obstacles] + [f"+ /sim/{g}/mesh" for g in c.garments]
        contents += ["+ /sim/contacts/obstacles/points"]
        tabs.append(rrb.Spatial3DView(name="obstacles", origin="/", contents=contents,
                                      eye_controls=front_three_quarter(c.scene_box, c.forward,
                                                                       aspect=ASPECT_FULL).controls()))
    if c.garments:
        tabs.append(rrb.Vertical(
            rrb.TimeSeriesView(name="step time (ms)", origin="/timings/step_ms"),
            rrb.TimeSeriesView(name="contacts (particles per frame)", origin="/sim/contacts",
                               contents=["+ /sim/contacts/**", "- /sim/contacts/obstacles/points"]),
            name="performance"))
    tabs.append(rrb.Vertical(
        rrb.TextDocumentView(name="summary", origin="/meta/summary"),
        rrb.TextDocumentView(name="scene file", origin="/meta/scene"),
        rrb.TextDocumentView(name="provenance", origin="/meta/provenance"),
        name="meta"))
    return rrb.Blueprint(
        rrb.Tabs(*tabs, active_tab=0),
        rrb.TimePanel(timeline="frame", play_state="playing", loop_mode="all", fps=round(float(c.fps), 3), state="collapsed"),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
    )
