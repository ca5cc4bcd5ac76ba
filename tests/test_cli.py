"""The command line: exit codes, one-line errors without tracebacks, validate."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


def cli(*args, cwd=None, env=None):
    e = dict(os.environ, **(env or {}))
    return subprocess.run([sys.executable, "-m", "pipeline", *args], cwd=cwd or REPO, env=e,
                          capture_output=True, text=True, timeout=600)


@pytest.mark.parametrize("text, fragment", [
    ("simulation:\n  dt: [1,\n", "YAML syntax error"),
    ("simulation:\n  itrations: 3\n", "did you mean 'iterations'"),
    ("garments:\n  - {type: tube, name: a, pin: {collider: 3}}\n", "garments[0].pin.collider"),
    ("frames: {count: -5}\n", "frames.count"),
    ("character: {source: gltf, path: missing.glb}\n", "file not found"),
])
def test_bad_scenes_exit_2_with_one_line_and_no_traceback(tmp_path, text, fragment):
    f = tmp_path / "bad.yaml"
    f.write_text(text)
    for cmd in ("validate", "run"):
        r = cli(cmd, str(f), cwd=tmp_path)
        assert r.returncode == 2, (cmd, r.stdout, r.stderr)
        assert "Traceback" not in r.stderr
        lines = [l for l in r.stderr.splitlines() if l.strip()]
        assert len(lines) == 1 and lines[0].startswith("error: ") and fragment in lines[0], r.stderr
        assert str(f) in lines[0]
    assert not list(tmp_path.rglob("*.rrd*"))  # nothing written, not even a temporary file


def test_corrupt_gltf_is_one_clear_error(tmp_path):
    (tmp_path / "broken.glb").write_bytes(b"glTF\x02\x00\x00\x00\x10\x00")
    f = tmp_path / "s.yaml"
    f.write_text("character: {source: gltf, path: broken.glb}\n")
    r = cli("validate", str(f), cwd=tmp_path)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "broken.glb" in r.stderr


def test_unknown_joint_reference_suggests_a_name(tmp_path):
    f = tmp_path / "s.yaml"
    f.write_text("garments:\n  - {type: tube, name: skirt, at_joint: pelvs}\n")
    r = cli("validate", str(f), cwd=tmp_path)
    assert r.returncode == 2 and "garments[0].at_joint" in r.stderr and "did you mean 'pelvis'" in r.stderr


def test_validate_default_scene():
    r = cli("validate", "scenes/default.yaml")
    assert r.returncode == 0, r.stderr
    assert "ok" in r.stdout and "procedural" in r.stdout


def test_bad_frames_flag():
    r = cli("run", "scenes/default.yaml", "--frames", "0")
    assert r.returncode == 2 and "--frames" in r.stderr
