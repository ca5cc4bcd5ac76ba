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
        errors = [l for l in lines if l.startswith("error: ")]
        # one error line, last; anything before it is a stage announcement ("rig ...")
        assert len(errors) == 1 and lines[-1] == errors[0] and fragment in errors[0], r.stderr
        assert all(l.endswith(" ...") for l in lines[:-1]), r.stderr
        assert str(f) in errors[0]
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


def test_unknown_ignored_collider_joint_is_named(tmp_path):
    f = tmp_path / "s.yaml"
    f.write_text("garments:\n  - {type: tube, name: skirt, ignore_colliders: [hand_l, hand_rr]}\n")
    r = cli("validate", str(f), cwd=tmp_path)
    assert r.returncode == 2 and "garments[0].ignore_colliders[1]" in r.stderr and "did you mean 'hand_r'" in r.stderr
    f.write_text("garments:\n  - {type: tube, name: skirt, ignore_colliders: hand_l}\n")
    r = cli("validate", str(f), cwd=tmp_path)
    assert r.returncode == 2 and "garments[0].ignore_colliders" in r.stderr and "Traceback" not in r.stderr


def test_a_sweep_file_run_as_a_scene_says_how_to_run_it(tmp_path):
    """`run` on a sweep file: one line naming the file, its 'base' key and the sweep command, not
    'unknown key base; did you mean seed', and no recording."""
    out = tmp_path / "x.rrd"
    r = cli("run", "scenes/sweep_example.yaml", "-o", str(out))
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1, r.stderr
    assert "sweep_example.yaml:7:1: base: this is a sweep file" in lines[0] and "pipeline sweep" in lines[0]
    assert not out.exists()


def test_validate_default_scene():
    r = cli("validate", "scenes/default.yaml")
    assert r.returncode == 0, r.stderr
    assert "ok" in r.stdout and "procedural" in r.stdout


def test_bad_frames_flag():
    r = cli("run", "scenes/default.yaml", "--frames", "0")
    assert r.returncode == 2 and "--frames" in r.stderr


def test_pattern_option_of_another_kind_is_named(tmp_path):
    f = tmp_path / "s.yaml"
    f.write_text("garments:\n  - {type: pattern, name: t, kind: tshirt, options: {flare: 1.5}}\n")
    r = cli("validate", str(f), cwd=tmp_path)
    assert r.returncode == 2 and "garments[0].options.flare" in r.stderr and "sleeve_length" in r.stderr


def test_mesh_garment_runs_from_a_file(tmp_path):
    import trimesh
    import numpy as np
    n = 12
    u = np.linspace(-0.3, 0.3, n)
    xx, zz = np.meshgrid(u, u, indexing="ij")
    v = np.column_stack([xx.ravel(), np.zeros(n * n), zz.ravel()])
    tri = [[i * n + j, i * n + j + 1, (i + 1) * n + j] for i in range(n - 1) for j in range(n - 1)] + \
          [[(i + 1) * n + j, i * n + j + 1, (i + 1) * n + j + 1] for i in range(n - 1) for j in range(n - 1)]
    trimesh.Trimesh(v, np.array(tri), process=False).export(tmp_path / "sheet.obj")
    f = tmp_path / "s.yaml"
    f.write_text("character: {clip: rest}\nframes: {count: 3}\nsimulation: {body_audit: false}\n"
                 "garments:\n  - {type: mesh, name: sheet, path: sheet.obj, translate: [0, 1.9, 0]}\n")
    r = cli("run", str(f), "-q", "-o", str(tmp_path / "out.rrd"), cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    from tests.rrd_read import rows
    pos = rows(tmp_path / "out.rrd", "sim/sheet/mesh", "Mesh3D:vertex_positions")
    assert len(pos) == 3 and pos[0][1].shape == (n * n, 3)
    assert abs(float(pos[0][1][:, 1].mean()) - 1.9) < 1e-4
    assert float(pos[-1][1][:, 1].mean()) < 1.9                  # it falls


def test_missing_obstacle_mesh_is_found_by_validate(tmp_path):
    f = tmp_path / "s.yaml"
    f.write_text("obstacles:\n  - {type: mesh, name: rock, path: rock.stl}\n")
    r = cli("validate", str(f), cwd=tmp_path)
    assert r.returncode == 2 and "obstacles[0].path: file not found" in r.stderr and "rock.stl" in r.stderr


def test_ctrl_c_turned_into_another_error_by_a_library_exits_130(monkeypatch, capsys):
    """numba swallows a KeyboardInterrupt raised inside its compile callbacks and then fails with a
    RuntimeError ("no compiled object yet"): after a Ctrl-C that error is an interrupt (exit 130), not
    a bug (exit 1); without one it is still a bug. The handler is put back afterwards."""
    import os
    import signal

    from pipeline import cli
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)   # a background session ignores it
    try:
        def compile_interrupted(args):
            try:
                os.kill(os.getpid(), signal.SIGINT)
                for _ in range(1000):      # the handler runs between bytecodes
                    pass
            except KeyboardInterrupt:
                pass                       # swallowed, as numba's ctypes callback does
            raise RuntimeError("no compiled object yet for <Library 'lbs_kernel'>")

        def plain_bug(args):
            raise RuntimeError("a bug")
        monkeypatch.setattr(cli, "cmd_validate", compile_interrupted)
        assert cli.main(["validate", "scenes/default.yaml"]) == 130
        assert "interrupted" in capsys.readouterr().err
        monkeypatch.setattr(cli, "cmd_validate", plain_bug)
        assert cli.main(["validate", "scenes/default.yaml"]) == 1
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, previous)
