"""Tucked-in layering (issue 15): an outer garment whose waistband is pinned over an inner one.

- The cloth phase with a pinned outer layer: the inner layer pressed against it by a collider (the
  body) stays under it, without a crossing, when there is room between the two; with less room than
  the thickness the phase cannot keep them apart (what the dressing must avoid).
- The dressing leaves that room: a skirt whose waistband is hugged over a T-shirt worn under it
  (make_garment's `under`) has its pinned band outside the T-shirt all round, a thickness off it;
  hugged onto the colliders alone (as before) the band ends inside the T-shirt's sides.
"""
from __future__ import annotations

import numpy as np
import pytest

from stages.sim.cloth_contact import kernels as CK
from stages.sim.cloth_contact.bench import SheetSim, grid_sheet
from stages.sim.cloth_contact.ccd import count_edge_triangle_crossings
from stages.sim.cloth_contact.setup import mesh_edges

H = 0.003


def _band_over_sheet(room: float):
    """An inner sheet (layer 0) draped on a sphere of radius 0.2 (the body) and an outer sheet
    (layer 1) over it whose middle rows are pinned (inverse mass 0, the waistband) `room` above the
    sphere's top; the inner sheet starts between them. Returns (sim, inner slice, pinned mask)."""
    xi, ti = grid_sheet(13, 13, 0.3, 0.3, (-0.15, 0.2 + 0.5 * min(room, H), -0.15))
    xo, to = grid_sheet(11, 11, 0.26, 0.26, (-0.13, 0.2 + room, -0.13))
    x = np.concatenate([xi, xo])
    t = np.concatenate([ti, to + xi.shape[0]])
    off = [0, xi.shape[0], x.shape[0]]
    sim = SheetSim(x, t, off, layers=[0, 1], dt=1 / 600, thickness=H, sphere=(np.zeros(3), 0.2))
    pinned = np.zeros(x.shape[0], bool)
    rows = np.arange(xo.shape[0]).reshape(11, 11)
    pinned[off[1] + rows[:, 4:7].ravel()] = True        # a band across the middle of the outer sheet
    sim.inv_mass[pinned] = 0.0
    # the inner sheet is pushed up against the band (as the body colliders push a tucked-in shirt out)
    sim.xp[: off[1], 1] -= 0.002
    return sim, slice(0, off[1]), pinned


def _crossings(sim):
    edges = mesh_edges(sim.triangles)[0]
    ones_e = np.ones(edges.shape[0], np.uint8)
    ones_t = np.ones(sim.triangles.shape[0], np.uint8)
    return count_edge_triangle_crossings(sim.x, edges, sim.triangles, ones_e, ones_t)


def _run(room: float, steps: int = 120):
    """The band `room` above the sphere: (sim, inner slice, pinned, most crossing edges in a step,
    deepest the inner sheet went into the sphere after the first 20 steps (m, > 0 inside))."""
    sim, inner, pinned = _band_over_sheet(room)
    band0 = sim.x[pinned].copy()
    cross = 0
    depth = 0.0
    for k in range(steps):
        sim.step()
        cross = max(cross, _crossings(sim))
        if k >= 20:
            depth = max(depth, 0.2 - float(np.linalg.norm(sim.x[inner], axis=1).min()))
    np.testing.assert_array_equal(sim.x[pinned], band0)         # the cloth phase never moves the band
    return sim, inner, cross, depth


def test_inner_layer_stays_under_a_pinned_band_with_room():
    sim, inner, cross, depth = _run(room=2.5 * H)
    assert cross == 0
    assert sim.counters[CK.N_CONTACTS] > 0 and sim.counters[CK.N_LEFT] == 0
    assert depth < 1e-4                                          # on the sphere, not in it
    # under the band the inner sheet lies between the sphere and the band, a thickness below it
    r = np.linalg.norm(sim.x[inner], axis=1)
    under = np.linalg.norm(sim.x[inner][:, [0, 2]], axis=1) < 0.03
    assert under.any() and np.all(r[under] <= 0.2 + 2.5 * H - H)


def test_without_room_under_a_pinned_band_the_inner_layer_is_pushed_into_the_body():
    # the band pinned closer to the sphere than the thickness: the phase keeps the thickness by
    # pushing the inner sheet into the sphere (in the walk: the body colliders push it out again,
    # the fail-safe freezes it, crossings stay), which is why the dressing must leave the room
    sim, inner, cross, depth = _run(room=0.5 * H)
    assert cross == 0
    assert depth > 0.3 * H


@pytest.fixture(scope="module")
def tucked():
    """scenes/walk_tshirt_tucked.yaml (4 frames) prepared: (scene, Prepared)."""
    from pathlib import Path

    from pipeline.matrix import Prepared
    from pipeline.scene import load_scene
    s = load_scene(Path(__file__).resolve().parent.parent / "scenes" / "walk_tshirt_tucked.yaml")
    s.settings["frames"]["count"] = 4
    s.settings["colliders"]["report_every"] = 0
    return s, Prepared(s)


def _outside(points, inner, centre):
    """Per point: how far (m) it lies outside the inner garment (Garment) along the horizontal ray
    from the vertical axis through `centre` to it: its distance from the axis minus that of the
    ray's farthest hit on the inner garment's triangles (+inf where the ray misses it)."""
    tri = inner.positions[inner.triangles]
    a, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    out = np.full(points.shape[0], np.inf)
    for k, q in enumerate(points):
        o = np.array([centre[0], q[1], centre[2]])
        d = q - o
        r = float(np.linalg.norm(d))
        d = d / r
        pv = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, pv)
        ok = np.abs(det) > 1e-15
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        tv = o - a
        u = np.einsum("ij,ij->i", tv, pv) * inv
        qv = np.cross(tv, e1)
        v = (qv @ d) * inv
        t = np.einsum("ij,ij->i", e2, qv) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
        if hit.any():
            out[k] = r - t[hit].max()
    return out


def test_waistband_is_hugged_over_the_garment_worn_under_it(tucked):
    import copy

    from scipy.spatial import cKDTree

    from pipeline.dressing import build_scene_garments, dressing_layers
    from stages.garments.placement import triangle_grid_points
    scene, p = tucked
    assert dressing_layers(scene) == [0, 1]
    (shirt, skirt), _ = build_scene_garments(scene, p.character, p.motion, p.colliders, p.maps)
    plain_scene = copy.deepcopy(scene)
    plain_scene.settings["simulation"]["cloth_collision"] = False    # layers off: dressed independently
    assert dressing_layers(plain_scene) == [0, 0]
    (shirt_p, skirt_p), _ = build_scene_garments(plain_scene, p.character, p.motion, p.colliders, p.maps)
    np.testing.assert_array_equal(shirt.positions, shirt_p.positions)   # the inner garment is the same
    band = skirt.positions[skirt.attach_joint >= 0]
    band_p = skirt_p.positions[skirt_p.attach_joint >= 0]
    centre = band_p.mean(axis=0)
    # hugged onto the colliders alone, the band ends inside the T-shirt at its sides
    assert _outside(band_p, shirt, centre).min() < -0.01
    # hugged over the T-shirt: outside it all round, more than a thickness off its surface
    assert _outside(band, shirt, centre).min() > 0.0
    assert cKDTree(triangle_grid_points(shirt.positions, shirt.triangles)).query(band)[0].min() > H


def test_tucked_scene_runs_without_crossings_after_frame_0(tmp_path):
    """scenes/walk_tshirt_tucked.yaml as `run` runs it (8 frames): no cloth edge through cloth after
    frame 0, read back from the recording (main before the dressing over lower layers: 33 T-shirt and
    skirt edges through each other in every frame)."""
    from pathlib import Path

    from pipeline.run import run_scene
    from pipeline.scene import load_scene
    from tests.rrd_read import rows
    s = load_scene(Path(__file__).resolve().parent.parent / "scenes" / "walk_tshirt_tucked.yaml")
    s.settings["frames"]["count"] = 8
    s.settings["colliders"]["report_every"] = 0
    out = tmp_path / "tucked.rrd"
    summary = run_scene(s, output=out, progress=False)
    assert summary.frames > 8        # the blend-in from the rest pose, where the garments are dressed
    for k in ("tshirt", "skirt", "between"):
        series = np.array([float(np.ravel(v)[0]) for _, v in rows(out, f"sim/intersections/{k}", "Scalars:scalars")])
        assert series.size == summary.frames and series[1:].max() == 0, (k, series)
