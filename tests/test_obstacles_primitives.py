"""Obstacle meshes: primitives and file loading (clear InputError on bad files)."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from stages.checks import ContractError
from stages.errors import InputError
from stages.obstacles import (Obstacle, ObstacleMotion, box_mesh, cylinder_mesh, load_obstacle_mesh, make_obstacle,
                              plane_mesh, sphere_mesh, table_mesh)


@pytest.mark.parametrize("mesh,volume", [
    (box_mesh((1, 2, 3), (0.5, 1.0, 2.0)), 1.0),
    (sphere_mesh((0, 1, 0), 0.5, 3), None),
    (cylinder_mesh((0, 0.5, 0), 0.3, 1.0, 64), None),
])
def test_closed_primitives_are_outward(mesh, volume):
    m = trimesh.Trimesh(*mesh, process=False)
    assert m.is_watertight and m.volume > 0
    if volume is not None:
        assert m.volume == pytest.approx(volume)


def test_cylinder_is_upright_by_default():
    v, _ = cylinder_mesh((0, 0.5, 0), 0.3, 1.0)
    np.testing.assert_allclose(v.min(axis=0), [-0.3, 0.0, -0.3], atol=1e-3)
    np.testing.assert_allclose(v.max(axis=0), [0.3, 1.0, 0.3], atol=1e-3)


def test_table_top_at_height_with_four_legs():
    v, f = table_mesh((0, 0.75, 0), (1.2, 0.8), top_thickness=0.03, leg_size=0.05)
    assert f.shape[0] == 5 * 12
    assert v[:, 1].max() == pytest.approx(0.75) and v[:, 1].min() == pytest.approx(0.0)


def test_plane_is_two_sided():
    v, f = plane_mesh((0, 0, 0), (0, 0, 1), (2, 3))
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    np.testing.assert_allclose(n, [[0, 0, 1], [0, 0, 1], [0, 0, -1], [0, 0, -1]], atol=1e-12)
    assert np.ptp(v, axis=0) == pytest.approx([2, 3, 0]) or np.ptp(v, axis=0) == pytest.approx([3, 2, 0])


@pytest.mark.parametrize("suffix", [".obj", ".stl", ".ply", ".glb"])
def test_load_round_trip_with_scale_and_transform(tmp_path, suffix):
    v, f = box_mesh((0, 0, 0), (1, 2, 3))
    path = tmp_path / f"box{suffix}"
    trimesh.Trimesh(v, f).export(path)
    m = np.eye(4)
    m[:3, 3] = [0, 1, 0]
    lv, lf = load_obstacle_mesh(path, scale=2.0, transform=m)
    np.testing.assert_allclose(lv.min(axis=0), [-1, -1, -3], atol=1e-6)
    np.testing.assert_allclose(lv.max(axis=0), [1, 3, 3], atol=1e-6)
    assert trimesh.Trimesh(lv, lf).volume == pytest.approx(48.0, rel=1e-6)


def test_load_fixes_inward_winding(tmp_path):
    v, f = box_mesh()
    path = tmp_path / "inside_out.obj"
    trimesh.Trimesh(v, f[:, ::-1], process=False).export(path)
    lv, lf = load_obstacle_mesh(path)
    assert trimesh.Trimesh(lv, lf).volume > 0


def test_load_errors_are_input_errors(tmp_path):
    with pytest.raises(InputError, match="not found"):
        load_obstacle_mesh(tmp_path / "missing.obj")
    bad = tmp_path / "corrupt.glb"
    bad.write_bytes(b"glTF\x02\x00\x00\x00garbage")
    with pytest.raises(InputError):
        load_obstacle_mesh(bad)
    txt = tmp_path / "mesh.xyz"
    txt.write_text("0 0 0\n")
    with pytest.raises(InputError, match="unsupported"):
        load_obstacle_mesh(txt)
    cloud = tmp_path / "cloud.ply"
    trimesh.PointCloud(np.random.default_rng(0).normal(size=(10, 3))).export(cloud)
    with pytest.raises(InputError):
        load_obstacle_mesh(cloud)
    flat = tmp_path / "flat.obj"
    flat.write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n")
    with pytest.raises(InputError, match="degenerate"):
        load_obstacle_mesh(flat)
    ok = tmp_path / "ok.obj"
    trimesh.Trimesh(*box_mesh()).export(ok)
    with pytest.raises(InputError, match="transform"):
        load_obstacle_mesh(ok, transform=np.zeros((4, 4)))


def test_obstacle_contract():
    v, f = box_mesh()
    with pytest.raises(ContractError):
        Obstacle("a", v, f.astype(np.int64))
    with pytest.raises(ContractError):
        Obstacle("a", v, f, thickness=0.0)
    with pytest.raises(ContractError):
        Obstacle("a", v, f, restitution=1.5)
    bad = v.copy()
    bad[0] = np.nan
    with pytest.raises(ContractError):
        Obstacle("a", bad, f)
    degenerate = np.vstack([f, [[0, 0, 1]]]).astype(np.int32)
    with pytest.raises(ContractError):
        Obstacle("a", v, degenerate)
    assert make_obstacle("a", (v, degenerate)).triangles.shape[0] == 12


def test_motion_from_velocity_and_sampling():
    m = ObstacleMotion.from_velocity(linear=(1, 0, 0), angular=(0, np.pi / 2, 0), pivot=(0, 0, 0), duration=2.0)
    p = m.pose_at(1.0)
    np.testing.assert_allclose(p[:3, 3], [1, 0, 0], atol=1e-9)
    np.testing.assert_allclose(p[:3, :3] @ [1, 0, 0], [0, 0, -1], atol=1e-9)
    half = m.pose_at(0.5 + 1.0 / 60.0)  # between keys: slerp + lerp
    assert np.allclose(half[:3, :3] @ half[:3, :3].T, np.eye(3))
    np.testing.assert_allclose(m.pose_at(99.0), m.transforms[-1])
