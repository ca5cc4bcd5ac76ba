"""The recording file: atomic writes, metadata, determinism, read back with the SDK's reader."""
from __future__ import annotations

import numpy as np
import pytest

from pipeline.logs import log_mesh_series, log_scalar_series
from pipeline.recording import atomic_recording
from tests.rrd_read import entity_paths, rows, same_content, timelines


def write(path, values, *, fail=False):
    with atomic_recording(path, scene_name="t", scene_text="name: t\n", seed=0) as rec:
        log_scalar_series(rec, "sim/step_ms", np.asarray(values, float), np.arange(len(values)) / 30.0, name="step")
        if fail:
            raise RuntimeError("stage failed")


def test_success_writes_readable_file_with_meta_and_timelines(tmp_path):
    p = tmp_path / "out" / "a.rrd"
    write(p, [1.0, 2.0, 3.0])
    assert p.is_file()
    assert {"/meta/scene", "/meta/provenance", "/sim/step_ms"} <= entity_paths(p)
    assert timelines(p) == {"frame", "sim_time"}          # no wall-clock log_time
    got = rows(p, "sim/step_ms", "Scalars:scalars")
    assert [f for f, _ in got] == [0, 1, 2]
    assert np.allclose([v for _, v in got], [[1.0], [2.0], [3.0]])
    text = rows(p, "meta/scene", "TextDocument:text")
    assert "name: t" in str(text[0][1])
    assert not list(tmp_path.glob("out/.*tmp*"))


def test_failure_leaves_no_file_and_keeps_the_earlier_one(tmp_path):
    p = tmp_path / "a.rrd"
    with pytest.raises(RuntimeError):
        write(p, [1.0], fail=True)
    assert not p.exists() and not list(tmp_path.iterdir())
    write(p, [5.0, 6.0])
    before = p.read_bytes()
    with pytest.raises(RuntimeError):
        write(p, [7.0], fail=True)
    assert p.read_bytes() == before
    assert [f.name for f in tmp_path.iterdir()] == ["a.rrd"]


def test_a_failed_rename_leaves_no_temporary_file(tmp_path):
    """The final path became a folder while the run went on (the reported case left a complete
    hidden .<name>.tmp-<pid> behind): the rename fails, the error propagates, no temporary stays."""
    p = tmp_path / "a.rrd"
    with pytest.raises(OSError):
        with atomic_recording(p, scene_name="t", scene_text="name: t\n", seed=0) as rec:
            log_scalar_series(rec, "sim/x", np.ones(2), np.arange(2) / 30.0, name="x")
            p.mkdir()
            (p / "keep").write_text("a folder in the way")
    assert sorted(f.name for f in tmp_path.iterdir()) == ["a.rrd"] and p.is_dir()


def test_same_input_gives_identical_content(tmp_path):
    write(tmp_path / "a.rrd", [1.0, 2.0])
    write(tmp_path / "b.rrd", [1.0, 2.0])
    write(tmp_path / "c.rrd", [1.0, 2.5])
    assert same_content(tmp_path / "a.rrd", tmp_path / "b.rrd")
    assert not same_content(tmp_path / "a.rrd", tmp_path / "c.rrd")


def test_mesh_series_logs_static_triangles_and_per_frame_positions_with_normals(tmp_path):
    import trimesh
    m = trimesh.creation.icosphere(1)
    pos = np.stack([m.vertices + [0, k, 0] for k in range(4)])
    p = tmp_path / "m.rrd"
    with atomic_recording(p, scene_name="m", scene_text="", seed=0) as rec:
        log_mesh_series(rec, "sim/cloth/mesh", m.faces.astype(np.int32), pos, np.arange(4) / 30.0)
    tri = rows(p, "sim/cloth/mesh", "Mesh3D:triangle_indices")
    assert len(tri) == 1 and tri[0][0] is None and tri[0][1].shape == (len(m.faces), 3)
    verts = rows(p, "sim/cloth/mesh", "Mesh3D:vertex_positions")
    assert [f for f, _ in verts] == [0, 1, 2, 3]
    assert np.allclose(verts[3][1], pos[3], atol=1e-6)
    normals = rows(p, "sim/cloth/mesh", "Mesh3D:vertex_normals")
    n = normals[0][1]
    assert np.allclose(np.linalg.norm(n, axis=1), 1, atol=1e-5)
    assert (np.einsum("ij,ij->i", n, m.vertices) > 0.9).all()   # outward on a sphere
