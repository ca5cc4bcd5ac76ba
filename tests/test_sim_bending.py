"""Bend springs and the shape the body gives the cloth (issue 15).

A bend spring joins the far corners of two adjacent triangles at their distance unfolded flat (the
pattern's). Where cloth is curved, that chord is shorter than at rest, so the spring pushes the two
corners apart; as stiff as the mesh edges (bend_stiffness 1, the paper preset) it wins against them
and a sewn sleeve cannot keep its shape: without gravity it shears into a slanting tube, its rings
tilted and its edges strained. The default (0.2) lets the curve stand.
"""
from __future__ import annotations

import numpy as np
import pytest

from stages.garments.simple import tube_skirt
from stages.garments.types import STRETCH, build_garment
from stages.maps.build import build_maps
from stages.sim.scenes import convex_mesh, fibonacci_points, hull_set, toy_character, toy_motion
from stages.sim.simulate import simulate
from stages.sim.types import PRESETS, SimParams


N_RINGS = 9


def sewn_tube(radius: float, length: float = 0.2, edge: float = 0.025, n_down: int = N_RINGS):
    """A tube whose rest shape is its flat pattern: a rectangle 2 pi radius wide, rolled and closed."""
    n_around = int(round(2 * np.pi * radius / edge))
    x, tri = tube_skirt(radius, radius, length, n_around, n_down, center=(0.0, 1.0, 0.0))
    i, k = tri // n_down, tri % n_down      # vertex (angle i, ring k) = i * n_down + k
    closing = (i == n_around - 1).any(axis=1, keepdims=True) & (i == 0)   # the seam's triangles
    flat = np.stack([np.where(closing, n_around, i) * (2 * np.pi * radius / n_around),
                     k * length / (n_down - 1)], axis=-1)                      # (T, 3, 2)
    rest = np.linalg.norm(flat[:, [1, 2, 0]] - flat, axis=-1)                 # edge k: corner k -> k + 1
    return build_garment("tube", x, tri, triangle_rest=rest)


def settle(garment, params: SimParams, frames: int = 30):
    """The garment alone, no gravity, beside a small hull far below (simulate needs a collider)."""
    mesh = convex_mesh(fibonacci_points(40, (0.02, 0.02, 0.02), (0.0, -3.0, 0.0)))
    cs = hull_set(mesh)
    res = simulate(toy_character(mesh.vertices, mesh.faces), toy_motion(frames), cs, build_maps(cs), [garment],
                   params)
    return res.garments[0].positions[-1].astype(np.float64)


def ring_shape(garment, pos):
    """Mean |strain| of the edges round the tube (the rings' edges), and how far each of its N_RINGS
    rings is tilted out of the horizontal (standard deviation of its heights, m)."""
    s = garment.springs[garment.kinds == STRETCH]
    rest = garment.rest_lengths[garment.kinds == STRETCH]
    ring = np.abs(pos[s[:, 1], 1] - pos[s[:, 0], 1]) < 0.2 * rest     # the edges round, not down
    e = np.abs(np.linalg.norm(pos[s[:, 1]] - pos[s[:, 0]], axis=1) / rest - 1.0)
    heights = pos[:, 1].reshape(-1, N_RINGS)                           # (angle, ring)
    return float(e[ring].mean()), heights.std(axis=0)


@pytest.fixture(scope="module")
def tube():
    return sewn_tube(0.05)


def test_the_default_lets_a_sewn_sleeve_keep_its_girth(tube):
    pos = settle(tube, SimParams(gravity=(0.0, 0.0, 0.0), tethers=False, body_audit=False))
    strain, tilt = ring_shape(tube, pos)     # measured: 0.06 %, 0.11 cm
    assert strain < 0.002, f"ring edges strained {100 * strain:.2f} % at the defaults"
    assert tilt.max() < 0.005, f"rings tilted: heights spread {np.round(100 * tilt, 2)} cm"


def test_bend_springs_as_stiff_as_the_edges_shear_it(tube):
    # the paper preset's bend stiffness at the default steps: the shear this default avoids
    pos = settle(tube, SimParams(gravity=(0.0, 0.0, 0.0), tethers=False, body_audit=False, bend_stiffness=1.0))
    strain, tilt = ring_shape(tube, pos)     # measured: 1.34 %, 2.2 cm (its ends 6 cm off the axis)
    assert strain > 0.005
    assert tilt.min() > 0.01


def test_the_paper_preset_keeps_its_bend_stiffness():
    assert PRESETS["paper"]["bend_stiffness"] == 1.0
    assert SimParams.preset("paper").bend_stiffness == 1.0
    assert SimParams().bend_stiffness == pytest.approx(0.2)
