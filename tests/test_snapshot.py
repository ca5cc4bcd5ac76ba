"""`python -m pipeline snapshot`: PNGs through the real viewer where it can start, one error line
and exit 2 where it cannot."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pipeline import style
from pipeline.blueprint import Contents, build, hull_points
from pipeline.cli import main
from pipeline.logs import log_mesh_series
from pipeline.recording import atomic_recording
from pipeline.snapshot import SnapshotError, check_vulkan, viewer_binary

REPO = Path(__file__).resolve().parent.parent


def viewer_unavailable() -> str | None:
    """Why the headless viewer cannot run here, or None."""
    try:
        viewer_binary()
        check_vulkan(dict(os.environ, WGPU_BACKEND=os.environ.get("WGPU_BACKEND", "vulkan")))
    except SnapshotError as err:
        return str(err)
    return None


def tiny_recording(path: Path, frames: int = 3, garments=("cloth",)) -> None:
    """A skin-coloured box moving up, a blue 'garment' beside it, and the pipeline's blueprint (an
    overview of the scene alone when `garments` is empty)."""
    import trimesh
    box = trimesh.creation.box((0.4, 1.6, 0.3))
    pos = np.stack([box.vertices + [0, 0.8 + 0.05 * k, 0] for k in range(frames)])
    times = np.arange(frames) / 30.0
    with atomic_recording(path, scene_name="tiny", scene_text="", seed=0) as rec:
        log_mesh_series(rec, "rig/mesh", box.faces.astype(np.int32), pos, times, albedo=style.SKIN)
        log_mesh_series(rec, "sim/cloth/mesh", box.faces.astype(np.int32), pos * [0.5, 0.3, 1.2] + [0.5, 0.6, 0],
                        times, albedo=style.fabric(0))
        hull = hull_points(pos, pos * [0.5, 0.3, 1.2] + [0.5, 0.6, 0])
        rec.send_blueprint(build(Contents(fps=30, forward=np.array([0, 0, 1.0]), scene_box=hull, body_box=hull,
                                          bind_box=hull, garments=list(garments), maps=False)))


def run_cli(*args, env=None):
    return subprocess.run([sys.executable, "-m", "pipeline", *args], capture_output=True, text=True, cwd=REPO,
                          env=env, timeout=300)


@pytest.mark.parametrize("garments", [("cloth",), ()], ids=["overview with plots", "scene alone"])
def test_snapshot_writes_pngs_of_the_scene_view(tmp_path, garments):
    reason = viewer_unavailable()
    if reason:
        pytest.skip(f"the headless Rerun viewer cannot start here: {reason}")
    from PIL import Image
    rrd = tmp_path / "tiny.rrd"
    tiny_recording(rrd, garments=garments)
    out = tmp_path / "shots"
    assert main(["snapshot", str(rrd), "--frames", "0,-1", "-o", str(out)]) == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == ["tiny_f000.png", "tiny_f000_viewer.png", "tiny_f002.png", "tiny_f002_viewer.png", "tiny_open.png"]
    img = np.asarray(Image.open(out / "tiny_f000.png").convert("RGB")).astype(int)
    assert img.shape[0] > 200 and img.shape[1] > 200
    # the scene view shows the skin-coloured box and the blue cloth
    for colour in (style.SKIN, style.fabric(0)) if garments else (style.SKIN,):
        near = (np.abs(img - np.array(colour[:3])).sum(2) < 90).mean()
        assert near > 0.005, colour
    full = Image.open(out / "tiny_f000_viewer.png")
    assert full.size[0] > img.shape[1]


def test_snapshot_outside_the_recording_range_is_one_error_line(tmp_path):
    reason = viewer_unavailable()
    if reason:
        pytest.skip(f"the headless Rerun viewer cannot start here: {reason}")
    rrd = tmp_path / "tiny.rrd"
    tiny_recording(rrd)
    r = run_cli("snapshot", str(rrd), "--frames", "7", "-o", str(tmp_path / "o"))
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "outside the recording's frame range 0..2" in r.stderr


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Vulkan driver discovery is checked on Linux")
def test_no_vulkan_driver_is_one_error_line_and_exit_2(tmp_path):
    rrd = tmp_path / "tiny.rrd"
    tiny_recording(rrd)
    env = dict(os.environ, VK_ICD_FILENAMES=str(tmp_path / "none.json"), WGPU_BACKEND="vulkan")
    r = run_cli("snapshot", str(rrd), "-o", str(tmp_path / "o"), env=env)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: no Vulkan") and "mesa-vulkan-drivers" in lines[0]
    assert not (tmp_path / "o").exists() or not list((tmp_path / "o").iterdir())


def test_missing_recording_is_one_error_line(tmp_path):
    r = run_cli("snapshot", str(tmp_path / "nothing.rrd"), "-o", str(tmp_path / "o"))
    assert r.returncode == 2 and r.stderr.startswith("error: ") and "recording not found" in r.stderr
    assert r.stderr.strip().count("\n") == 0


def test_a_fifo_recording_and_a_viewer_timeout_are_one_error_line(tmp_path, monkeypatch, capsys):
    from pipeline import snapshot
    from pipeline.cli import main
    fifo = tmp_path / "pipe.rrd"
    os.mkfifo(fifo)
    assert main(["snapshot", str(fifo), "-o", str(tmp_path / "o")]) == 2   # stat-checked: never opened
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "FIFO" in err, err

    def times_out(*a, **k):
        raise TimeoutError("the viewer did not answer")
    rrd = tmp_path / "r.rrd"
    rrd.write_bytes(b"x")
    monkeypatch.setattr(snapshot, "snapshot", times_out)
    assert main(["snapshot", str(rrd)]) == 2   # was AttributeError: 'Namespace' object has no attribute 'debug'
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "TimeoutError" in err and "Traceback" not in err, err


def test_the_viewer_is_stopped_when_the_snapshot_fails(tmp_path):
    reason = viewer_unavailable()
    if reason:
        pytest.skip(f"the headless Rerun viewer cannot start here: {reason}")
    from pipeline.snapshot import Viewer
    viewer = Viewer()
    with pytest.raises(RuntimeError):
        with viewer:
            assert viewer.proc.poll() is None and "127.0.0.1" in viewer.proc.args
            raise RuntimeError("a failure while shooting")
    assert viewer.proc.poll() is not None          # stopped, not left running
    assert not Path(viewer.scratch.name).exists()  # its scratch config removed


def test_turned_camera_keeps_its_distance_height_and_target():
    from pipeline.snapshot import turned
    eye = {"position": [0.0, 1.5, 3.0], "look_target": [0.0, 1.0, 0.0], "eye_up": [0.0, 1.0, 0.0]}
    back = turned(eye, 180.0)
    assert np.allclose(back["position"], [0.0, 1.5, -3.0])          # from behind
    side = turned(eye, 90.0)                                          # counter-clockwise from above
    assert np.allclose(side["position"], [3.0, 1.5, 0.0])
    assert back["look_target"] == eye["look_target"] and back["eye_up"] == eye["eye_up"]
    assert np.allclose(turned(eye, 360.0)["position"], eye["position"])
