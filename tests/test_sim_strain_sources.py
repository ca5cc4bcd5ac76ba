"""What holds a garment's most strained edges (stages.sim.strain_sources): collider distances against
independent references, the joints named for a constructed frame, and the run's note on a real run."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from stages.hulls.types import ColliderSet, SphereCollider
from stages.sim.scenes import convex_mesh, fibonacci_points, hull_set
from stages.sim.strain_sources import collider_distances, strain_sources


def _set(hull_bone=0, sphere_joint=1, sphere_center=(0.6, 0.0, 0.0), radius=0.2) -> ColliderSet:
    mesh = convex_mesh(fibonacci_points(40, (0.2, 0.3, 0.25)))
    hull = hull_set(mesh, bone=hull_bone).hulls
    s = SphereCollider(sphere_joint, "ball", np.asarray(sphere_center, float), radius, np.zeros((0, 3)))
    return ColliderSet(hulls=hull, spheres=(s,), delta=0.0, min_triangles=4)


def _poses(shift_joint_1=(0.0, 0.0, 0.0)):
    poses = np.tile(np.eye(4), (2, 1, 1))
    poses[1, :3, 3] = shift_joint_1
    return poses


def test_collider_distances_match_references():
    """Spheres: |p - c| - r, posed; hulls: trimesh's signed distance, exact inside, a lower bound outside."""
    cs = _set()
    rng = np.random.default_rng(5)
    pts = np.concatenate([rng.uniform(-0.4, 0.4, (300, 3)), rng.uniform(-0.5, 1.3, (300, 3))])
    shift = np.array([0.3, -0.1, 0.2])
    d, owner = collider_distances(cs, _poses(shift), pts)
    assert owner.tolist() == [0, 1]
    np.testing.assert_allclose(d[1], np.linalg.norm(pts - (np.array([0.6, 0.0, 0.0]) + shift), axis=1) - 0.2,
                               atol=1e-12)
    m = cs.hulls[0].simplified
    true = -trimesh.proximity.signed_distance(trimesh.Trimesh(m.vertices, m.faces), pts)   # trimesh: + inside
    inside = true < 0
    assert inside.sum() > 20 and (~inside).sum() > 20
    np.testing.assert_allclose(d[0][inside], true[inside], atol=1e-9)
    assert np.all(d[0][~inside] <= true[~inside] + 1e-9)


def test_the_joint_under_the_most_strained_edges_is_named():
    """A strip of 100 edges along x; the most strained ones lie on the (posed) ball of joint 1, the
    others on the hull of joint 0: joint 1 holds all of the top edges, joint 0 none; unposed, the
    ball is elsewhere and nothing is named for it."""
    cs = _set()
    shift = np.array([0.0, 1.0, 0.0])
    x = np.linspace(-0.004, 0.004, 101)[:, None] * [1.0, 0.0, 0.0]     # 8 mm strips, lying on ...
    top = cs.hulls[0].simplified.vertices[np.argmax(cs.hulls[0].simplified.vertices[:, 1])]
    on_hull = top + x                                                   # ... the hull's top vertex
    on_ball = np.array([0.6, 0.2, 0.0]) + shift + x                     # ... and the posed ball's top
    pos = np.concatenate([on_hull, on_ball])
    edges = np.concatenate([np.stack([np.arange(100), np.arange(1, 101)], 1),
                            101 + np.stack([np.arange(100), np.arange(1, 101)], 1)])
    strain = np.concatenate([np.full(100, 0.01), np.linspace(0.2, 0.3, 100)])
    got = strain_sources(pos, edges, strain, cs, _poses(shift), top=0.05)
    assert list(got) == [1] and got[1] == pytest.approx(1.0)
    strain = strain[::-1].copy()     # now the hull's edges are the most strained
    got = strain_sources(pos, edges, strain, cs, _poses(shift), top=0.05)
    assert list(got) == [0] and got[0] == pytest.approx(1.0)
    assert strain_sources(pos, edges, strain[::-1].copy(), cs, _poses(), top=0.05) == {}
    assert strain_sources(pos, edges, strain, None, None) == {}


def test_the_run_names_the_joint_holding_the_strain(monkeypatch):
    """pipeline.cloth_checks.strain_source_notes on a small simulated sheet landing on joint 1's ball (the
    limit lowered so that its strain counts): one line naming 'hand'."""
    import pipeline.cloth_checks as cloth_checks
    import stages.sim.audit as audit_module
    from stages.garments.simple import rectangle_cloth
    from stages.garments.types import build_garment
    from stages.sim import SimParams, simulate
    from stages.sim.audit import audit_cloth
    from tests.test_sim_ignore_colliders import _two_joint_character
    from stages.rig.types import Motion
    ch = _two_joint_character()
    frames = 20
    motion = Motion("still", np.arange(frames) / 30.0, np.tile(np.eye(4), (frames, 2, 1, 1)), np.zeros((frames, 3)))
    cs = ColliderSet(hulls=(), spheres=(SphereCollider(1, "hand_ball", np.zeros(3), 0.15, np.zeros((0, 3))),),
                     delta=0.0, min_triangles=4)
    x, tri = rectangle_cloth(0.1, 0.1, 6, 6, center=(0.0, 0.2, 0.0))     # small: all of it lands on the ball's cap
    g = build_garment("sheet", x, tri)
    result = simulate(ch, motion, cs, None, [g], SimParams(body_audit=False))
    audit = audit_cloth(result, [g])
    assert audit.garments[0].strain_p99.max() < audit_module.STRAIN_P99_LIMIT
    assert cloth_checks.strain_source_notes(audit, [g], result, cs, ch, motion) == ()    # under the limit: nothing
    monkeypatch.setattr(audit_module, "STRAIN_P99_LIMIT", 0.0)
    notes = cloth_checks.strain_source_notes(audit, [g], result, cs, ch, motion)
    assert len(notes) == 1 and "garment 'sheet'" in notes[0] and "the colliders of hand 100 %" in notes[0]
