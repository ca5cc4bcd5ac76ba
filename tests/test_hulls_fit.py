"""fit_colliders on a hand-built two-bone character and on every region of CesiumMan."""
from __future__ import annotations

import numpy as np
import pytest

from stages.errors import InputError
from stages.hulls import fit_colliders, fit_report_totals, joint_sphere
from stages.hulls.hull import convex_hull, mesh_volume
from stages.rig.types import Character, RegionSplit
from tests.test_hulls_simplify import assert_contains, assert_convex


def two_bone_character():
    """Bone 0 at the origin, bone 1 at (0, 1, 0) rotated 90 deg about z; a box of points on each
    bone (rigid) and a ring of points around joint 1 (flexible)."""
    rng = np.random.default_rng(0)
    box0 = rng.uniform([-0.1, 0.05, -0.1], [0.1, 0.9, 0.1], size=(60, 3))
    box1 = rng.uniform([-0.08, 1.1, -0.08], [0.08, 1.8, 0.08], size=(60, 3))
    ang = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    ring = np.c_[0.12 * np.cos(ang), np.full(12, 1.0), 0.12 * np.sin(ang)]
    verts = np.concatenate([box0, box1, ring])
    rot = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]], dtype=float)  # bind pose of joint 1
    bind = np.stack([np.eye(4), np.eye(4)])
    bind[1, :3, :3] = rot
    bind[1, :3, 3] = [0, 1, 0]
    inverse_bind = np.linalg.inv(bind)
    rest = bind.copy()
    n = verts.shape[0]
    sj = np.zeros((n, 4), np.int32)
    sj[:, 1] = 1
    sw = np.zeros((n, 4))
    sw[:60, 0] = 1
    sw[60:120, 0], sw[60:120, 1] = 0.0, 1.0
    sw[120:, 0], sw[120:, 1] = 0.5, 0.5
    ch = Character(name="two", vertices=verts, triangles=np.zeros((0, 3), np.int32),
                   primitive_ids=np.zeros(n, np.int32), joint_names=("root", "child"),
                   parents=np.array([-1, 0], np.int32), rest_local=rest, inverse_bind=inverse_bind,
                   skin_joints=sj, skin_weights=sw)
    rigid = np.r_[np.ones(120, bool), np.zeros(12, bool)]
    region = np.r_[np.zeros(60, np.int32), np.ones(60, np.int32), np.ones(12, np.int32)]
    split = RegionSplit(dominant_joint=region.copy(), dominant_weight=np.r_[np.ones(120), np.full(12, 0.5)],
                        rigid=rigid, region_joint=region, hull_bones=(0, 1), sphere_joints=(1,), threshold=0.9)
    return ch, split, box0, box1, ring, inverse_bind


def test_two_bone_character_colliders():
    ch, split, box0, box1, ring, ib = two_bone_character()
    cs = fit_colliders(ch, split, delta=0.01, min_triangles=12)
    assert [h.bone for h in cs.hulls] == [0, 1] and [s.joint for s in cs.spheres] == [1]
    for h, box, b in zip(cs.hulls, (box0, box1), (0, 1)):
        local = box @ ib[b][:3, :3].T + ib[b][:3, 3]  # independent bone-local transform
        assert np.allclose(h.region_points, local)
        assert_convex(h.simplified, 1e-9)
        assert_contains(h.simplified, local, 1e-9)
        r = h.report
        assert r.faces_raw == h.raw.faces.shape[0] and r.faces_simplified == h.simplified.faces.shape[0]
        assert r.faces_simplified <= r.faces_inflated and r.faces_simplified >= 12
        assert r.volume_raw == pytest.approx(mesh_volume(convex_hull(local)))
        assert r.excess_volume > 0 and r.contains_region and r.worst_violation <= -0.01 * (1 - 1e-9)
        assert r.hausdorff >= 0.01 * (1 - 1e-9)
    # bone 1's box lies along +y in the model, i.e. along +x in its bone frame (rotated 90 deg about z)
    h1 = cs.hulls[1].region_points
    assert h1[:, 0].min() > 0.05 and np.abs(h1[:, 1]).max() <= 0.08 + 1e-12
    s = cs.spheres[0]
    assert np.allclose(s.center, 0, atol=1e-12)  # the joint origin in its own frame
    assert s.radius == pytest.approx(0.12 + 0.01)
    tot = fit_report_totals(cs)
    assert tot["hulls"] == 2 and tot["spheres"] == 1 and tot["all_contained"]
    assert tot["faces_simplified"] == sum(h.simplified.faces.shape[0] for h in cs.hulls)
    assert tot["excess_volume"] == pytest.approx(sum(h.report.excess_volume for h in cs.hulls))


def test_joint_sphere():
    c, r = joint_sphere(np.array([[1.0, 0, 0], [0, 3.0, 0]]), np.array([0.0, 1.0, 0.0]), 0.5)
    assert np.allclose(c, [0, 1, 0]) and r == pytest.approx(2.0 + 0.5)  # farthest: (0, 3, 0) at 2
    with pytest.raises(InputError):
        joint_sphere(np.zeros((0, 3)), np.zeros(3), 0.1)


def test_cesium_man_every_region(assets_dir):
    from stages.rig.gltf import load_gltf
    from stages.rig.regions import split_regions

    ch = load_gltf(assets_dir / "CesiumMan.glb")
    split = split_regions(ch)
    cs = fit_colliders(ch, split, delta=0.01, min_triangles=40)
    assert len(cs.hulls) == len(split.hull_bones) and len(cs.spheres) == len(split.sphere_joints)
    for h in cs.hulls:
        diag = np.linalg.norm(np.ptp(h.inflated.vertices, axis=0))
        assert_convex(h.simplified, 1e-9 * diag)
        assert_contains(h.simplified, h.region_points, 1e-9 * diag)
        assert_contains(h.simplified, h.inflated.vertices, 1e-9 * diag)
        assert h.report.contains_region
        assert 40 <= h.report.faces_simplified <= h.report.faces_inflated or \
            h.report.faces_simplified == h.report.faces_inflated
    for s in cs.spheres:
        d = np.linalg.norm(s.region_points - s.center, axis=1)
        assert d.max() + 0.01 == pytest.approx(s.radius)
        assert np.abs(s.center).max() < 1e-6
