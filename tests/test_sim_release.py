"""Cloth a limb tears lets go of it (stages.sim.release): which contact entries are released, which
are not, and when they are restored, on a constructed collider set (a torso hull, a limb ball)."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from stages.garments.types import BEND, STRETCH
from stages.hulls.types import ColliderSet, SphereCollider
from stages.sim.collider_query import IGNORED
from stages.sim.release import CLEAR, LimbRelease
from stages.sim.scenes import convex_mesh, fibonacci_points, hull_set

BALL = np.array([0.6, 0.0, 0.0])     # joint 1's ball (a limb), radius 0.1; joint 0's hull round the origin


def _colliders() -> ColliderSet:
    hull = hull_set(convex_mesh(fibonacci_points(40, (0.2, 0.3, 0.25))), bone=0).hulls
    ball = SphereCollider(1, "ball", BALL, 0.1, np.zeros((0, 3)))
    return ColliderSet(hulls=hull, spheres=(ball,), delta=0.0, min_triangles=4)


def _strip(n_garments=1):
    """Per garment two stretch edges (0-1, 2-3) of rest 1 cm and a bend edge (1-2), 4 particles."""
    g = SimpleNamespace(springs=np.array([[0, 1], [2, 3], [1, 2]]), kinds=np.array([STRETCH, STRETCH, BEND]),
                        rest_lengths=np.array([0.01, 0.01, 0.01]))
    return [g] * n_garments, np.arange(n_garments + 1) * 4


def _release(contact, garments, offsets, limbs=(1,)):
    return LimbRelease(garments, offsets, np.ones(offsets[-1]), _colliders(), np.array([0, 1]), limbs, contact,
                       threshold=2.0)


def _x(stretch_a, stretch_b):
    """Particle 1 on the ball's surface, 0 stretch_a cm away along -x; particle 3 on the hull's top
    (no limb), 2 stretch_b cm away."""
    on_ball = BALL + [-0.1, 0.0, 0.0]
    top = np.array([0.0, 0.31, 0.0])
    return np.array([on_ball - [0.01 * stretch_a, 0, 0], on_ball, top - [0.01 * stretch_b, 0, 0], top])


def test_an_edge_torn_on_a_limb_lets_go_of_that_limb_only():
    garments, offsets = _strip()
    contact = np.full((4, 2), -1, np.int32)
    r = _release(contact, garments, offsets)
    poses = np.tile(np.eye(4), (2, 1, 1))
    r.after_frame(5, _x(3.5, 3.5), contact, poses)     # both edges 250 % over their rest length
    # the end on the ball and its partner 3.5 cm off it: only the end within reach of the limb
    assert contact[1, 1] == IGNORED and contact[0, 1] == -1
    assert (contact[:, 0] == -1).all()                 # the hull's joint is not a limb: never released
    assert r.counts(8).tolist() == [0, 0, 0, 0, 0, 1, 0, 0]


def test_edges_under_the_threshold_release_nothing():
    garments, offsets = _strip()
    contact = np.full((4, 2), -1, np.int32)
    r = _release(contact, garments, offsets)
    r.after_frame(3, _x(2.9, 2.9), contact, np.tile(np.eye(4), (2, 1, 1)))    # 190 %: under 200 %
    assert (contact == -1).all() and r.counts(5).sum() == 0


def test_a_released_particle_is_caught_again_once_clear_of_the_limb():
    garments, offsets = _strip()
    contact = np.full((4, 2), -1, np.int32)
    r = _release(contact, garments, offsets)
    poses = np.tile(np.eye(4), (2, 1, 1))
    x = _x(3.5, 1.0)
    r.after_frame(1, x, contact, poses)
    assert contact[1, 1] == IGNORED
    x[:, 0] -= 0.5 * CLEAR          # inside the clearance: still released
    x[0] = x[1] - [0.015, 0, 0]     # the edge relaxed
    r.after_frame(2, x, contact, poses)
    assert contact[1, 1] == IGNORED
    x[:, 0] -= CLEAR                 # 1.5 CLEAR outside the ball
    r.after_frame(3, x, contact, poses)
    assert contact[1, 1] == -1 and not r.released


def test_a_limb_the_garment_ignores_is_never_released_nor_restored():
    garments, offsets = _strip(2)
    contact = np.full((8, 2), -1, np.int32)
    contact[4:, 1] = IGNORED                           # garment 1's ignore_colliders: the limb
    r = _release(contact, garments, offsets)
    assert r.releasable[:, 1].tolist() == [True, False]
    x = np.concatenate([_x(3.5, 1.0), _x(3.5, 1.0) + [0.0, 0.0, 0.001]])
    r.after_frame(1, x, contact, np.tile(np.eye(4), (2, 1, 1)))
    assert contact[1, 1] == IGNORED and (contact[4:, 1] == IGNORED).all() and len(r.released) == 1
    x[:, 0] -= 5 * CLEAR
    r.after_frame(2, x, contact, np.tile(np.eye(4), (2, 1, 1)))
    assert contact[1, 1] == -1 and (contact[4:, 1] == IGNORED).all()


def test_a_torn_run_is_run_again_only_when_the_scene_leaves_it_to_the_default_preset():
    from pipeline.run import TORN_RELEASE, sim_params, torn_release
    from pipeline.scene import parse_scene_text

    def scene(text):
        s = parse_scene_text(text, source="s.yaml")
        return s, sim_params(s)
    assert torn_release(*scene("{}")) and TORN_RELEASE == 2.0
    assert sim_params(parse_scene_text("{}", source="s.yaml")).limb_release == 0.0      # off until it tears
    assert not torn_release(*scene("simulation: {preset: paper}"))
    assert not torn_release(*scene("simulation: {limb_release: 0}"))       # the scene keeps the stop
    assert not torn_release(*scene("simulation: {limb_release: 1.5}"))     # already on
