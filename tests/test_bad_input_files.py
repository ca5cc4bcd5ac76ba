"""The bad-input battery, part two (issue 42): files the pipeline reads or writes that are not what
they seem (named pipes, devices, a glTF buffer or OBJ material file that is a pipe, a YAML bomb in a
GarmentCode body file), a filesystem that fills up while the recording is written, what a killed run
leaves behind, SIGTERM, and legal but implausible values (a warning, and the run goes on).

Every case ends within the subprocess timeout (a FIFO opened for reading would block forever), in
one line naming the file, and leaves an earlier recording byte for byte.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pipeline.cli import main
from tests.test_bad_input import EARLIER, FAST, REPO, _assert_one_clear_line, _case_folder, _left, cli


def _gltf_with_external_buffer(folder: Path) -> Path:
    """A small humanoid as .gltf JSON whose buffer is the file buf.bin beside it."""
    from stages.rig.gltf_io import _parse_glb
    from tests.test_rig_gltf_frames import HUMANOID, STORE, build_figure
    glb = folder / "figure.glb"
    build_figure(HUMANOID, STORE["+y"]).write_glb(glb)
    text, bin_chunk = _parse_glb(glb, glb.read_bytes())
    doc = json.loads(text)
    doc["buffers"][0]["uri"] = "buf.bin"
    (folder / "figure.gltf").write_text(json.dumps(doc))
    (folder / "buf.bin").write_bytes(bin_chunk)
    return folder / "figure.gltf"


def test_a_gltf_buffer_that_is_a_fifo_is_one_line(tmp_path):
    gltf = _gltf_with_external_buffer(tmp_path)
    scene = _case_folder(tmp_path, f"character: {{source: gltf, path: {gltf.name}, clip: rest}}\n"
                                   "frames: {count: 2}\noutput: out.rrd\n", {})
    r = cli("validate", str(scene), cwd=tmp_path)
    assert r.returncode == 0, r.stderr                     # the same file with a real buffer is fine
    (tmp_path / "buf.bin").unlink()
    os.mkfifo(tmp_path / "buf.bin")
    before = _left(tmp_path)
    for cmd in ("validate", "run"):
        r = cli(cmd, str(scene), *(["-q"] if cmd == "run" else []), cwd=tmp_path)
        _assert_one_clear_line(r.stderr, scene, ["buf.bin", "FIFO"], r.returncode)
        assert _left(tmp_path) == before and (tmp_path / "out.rrd").read_bytes() == EARLIER


def test_an_obj_material_library_that_is_a_fifo_does_not_block(tmp_path):
    """trimesh reads `mtllib` through the resolver, which now refuses what is not a regular file;
    the mesh itself is read without its materials."""
    (tmp_path / "m.obj").write_text("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4 3\n")
    os.mkfifo(tmp_path / "m.mtl")
    scene = _case_folder(tmp_path, FAST + "garments:\n  - {type: mesh, name: sheet, path: m.obj}\n", {})
    r = cli("validate", str(scene), cwd=tmp_path)
    assert r.returncode == 0 and "1 mesh files read" in r.stdout, r.stderr


@pytest.mark.parametrize("trouble", ["pattern is a fifo", "body file is a YAML bomb"])
def test_garmentcode_files_that_hang_or_explode_are_one_line(trouble, tmp_path, assets_dir):
    spec = tmp_path / "skirt_specification.json"
    if trouble == "pattern is a fifo":
        os.mkfifo(spec)
        fragments = ["garments[0].path", spec.name, "FIFO"]
    else:
        spec.write_bytes((assets_dir / "garmentcode" / "examples" / "flare_skirt_specification.json").read_bytes())
        bomb = "a: &a [x, x, x, x, x, x, x, x, x, x]\n" + "".join(
            f"{c}: &{c} [*{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}]\n" for p, c in zip("abcdefg", "bcdefgh"))
        (tmp_path / "body_measurements.yaml").write_text(bomb + "body: *h\n")
        fragments = ["garments[0].path", "body_measurements.yaml", "expands to more than"]
    scene = _case_folder(tmp_path, FAST + f"garments:\n  - {{type: garmentcode, name: skirt, path: {spec.name}}}\n",
                         {})
    before = _left(tmp_path)
    r = cli("validate", str(scene), cwd=tmp_path)
    _assert_one_clear_line(r.stderr, scene, fragments, r.returncode)
    assert _left(tmp_path) == before


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_a_killed_runs_temporaries_are_removed_by_the_next_run(tmp_path, monkeypatch, capsys):
    scene = _case_folder(tmp_path, FAST + "colliders: {report_every: 0}\n", {})
    dead, alive = _dead_pid(), os.getppid()
    stale = [tmp_path / f".out.rrd.tmp-{dead}", tmp_path / f".out.rrd.probe-{dead}"]
    live = tmp_path / f".out.rrd.tmp-{alive}"        # another run still writing: kept
    other = tmp_path / f".other.rrd.tmp-{dead}"      # another output's: not this run's business
    for p in stale + [live, other]:
        p.write_bytes(b"partial")
    monkeypatch.chdir(tmp_path)
    assert main(["run", str(scene), "-q"]) == 0, capsys.readouterr().err
    assert not any(p.exists() for p in stale)
    assert live.exists() and other.exists()
    assert (tmp_path / "out.rrd").read_bytes() != EARLIER   # replaced by the new recording


def test_an_export_write_failure_is_one_line_and_keeps_the_earlier_file(tmp_path, monkeypatch):
    from pipeline import export
    target = tmp_path / "a.npz"
    target.write_bytes(b"earlier")
    (tmp_path / f".a.npz.tmp-{_dead_pid()}").write_bytes(b"partial")

    def full(*a, **k):
        raise OSError(28, "No space left on device")
    with pytest.raises(export.ExportError, match="a.npz: cannot write the export \\(No space left on device\\)"):
        with export._atomic(target) as tmp:
            tmp.write_bytes(b"half")
            full()
    assert target.read_bytes() == b"earlier"
    assert [p.name for p in tmp_path.iterdir()] == ["a.npz"]   # neither this temporary nor the dead one's


def test_a_filesystem_filling_up_while_recording_stops_the_run(tmp_path, monkeypatch):
    """The watch sees the free space under MIN_FREE_BYTES (here: any), raises in the writing thread;
    the result is one InputError, the earlier file kept, no temporary left."""
    import rerun as rr

    from pipeline import disk
    from pipeline.recording import atomic_recording
    from stages.errors import InputError
    out = tmp_path / "out.rrd"
    out.write_bytes(EARLIER)
    monkeypatch.setattr(disk, "MIN_FREE_BYTES", 2 ** 62)
    logged = 0
    with pytest.raises(InputError, match="cannot write the recording: the filesystem of .* is full"):
        with atomic_recording(out, scene_name="t", scene_text="", seed=0) as rec:
            deadline = time.monotonic() + 30     # the watch checks once a second
            while time.monotonic() < deadline:
                rec.log("p", rr.Points3D([[0.0, 0.0, float(logged)]]))
                logged += 1
                time.sleep(0.01)
    assert out.read_bytes() == EARLIER and [p.name for p in tmp_path.iterdir()] == ["out.rrd"]


def test_a_cut_off_recording_is_not_complete(tmp_path):
    from pipeline.recording import atomic_recording, is_complete
    out = tmp_path / "r.rrd"
    with atomic_recording(out, scene_name="t", scene_text="name: t", seed=0):
        pass
    assert is_complete(out)
    cut = tmp_path / "cut.rrd"
    cut.write_bytes(out.read_bytes()[:-40])
    assert not is_complete(cut)


def test_the_output_is_refused_on_a_full_filesystem_before_the_run(tmp_path, monkeypatch, capsys):
    from pipeline import disk
    scene = _case_folder(tmp_path, FAST, {})
    monkeypatch.setattr(disk, "MIN_FREE_BYTES", 2 ** 62)
    monkeypatch.chdir(tmp_path)
    before = _left(tmp_path)
    code = main(["run", str(scene), "-q"])
    _assert_one_clear_line(capsys.readouterr().err, scene, ["output", "is full", "kB free"], code)
    assert _left(tmp_path) == before


def test_sigterm_is_handled_like_ctrl_c(tmp_path):
    """A `kill` mid-run: exit 143, the temporary recording removed, the earlier one kept."""
    scene = _case_folder(tmp_path, FAST.replace("count: 2", "count: 3000") + "colliders: {report_every: 0}\n", {})
    before = _left(tmp_path)
    env = dict(os.environ, PYTHONPATH=str(REPO))
    p = subprocess.Popen([sys.executable, "-m", "pipeline", "run", str(scene)], cwd=tmp_path, env=env,
                         stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
    try:
        for line in p.stderr:              # the stage lines: the recording is open from 'rig' on
            if line.startswith("colliders"):
                break
        p.send_signal(signal.SIGTERM)
        err = p.stderr.read()
        code = p.wait(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
    assert code == 143, err
    assert err.strip().splitlines()[-1] == "terminated (SIGTERM): no recording written", err
    assert "Traceback" not in err
    assert _left(tmp_path) == before and (tmp_path / "out.rrd").read_bytes() == EARLIER


def test_implausible_but_legal_values_warn_and_run(tmp_path, monkeypatch, capsys):
    scene = _case_folder(tmp_path, FAST + "simulation: {gravity: [0, -100, 0], dt: 0.2}\n"
                                          "obstacles:\n  - {type: box, name: b, size: [1, 1, 1], thickness: 0.5}\n", {})
    monkeypatch.chdir(tmp_path)
    assert main(["validate", str(scene)]) == 0
    err = capsys.readouterr().err
    for key, value in (("simulation.gravity", "length 100"), ("simulation.dt", "0.2"),
                       ("obstacles[0].thickness", "0.5")):
        line = next((x for x in err.splitlines() if key in x), None)
        assert line is not None and line.startswith("warning: ") and value in line and "implausible" in line, err
        assert str(scene) in line


def test_a_sweep_grid_too_large_is_refused_before_it_is_expanded(tmp_path, monkeypatch, capsys):
    (tmp_path / "base.yaml").write_text(FAST)
    axes = "".join(f"  simulation.{k}: [0.1, 0.2, 0.3, 0.4, 0.5]\n"
                   for k in ("drag", "lift", "friction", "damping", "inertia_scale", "bend_stiffness"))
    sweep = tmp_path / "big.yaml"
    sweep.write_text("base: base.yaml\ngrid:\n" + axes)
    monkeypatch.chdir(tmp_path)
    assert main(["sweep", str(sweep), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "15,625 jobs" in err and "10,000" in err and "big.yaml" in err, err
    assert not (tmp_path / "sweeps").exists()


@pytest.mark.parametrize("argv, fragments", [
    (["matrix", "--character", "foo"], ["--character", "'foo'", "'built-in'", "'CesiumMan'"]),
    (["matrix", "--garment", "skirt"], ["--garment", "'skirt'", "'short_skirt'"]),
    (["run", "scene.yaml", "--frames", "1000000000"], ["--frames", "100,000"]),
])
def test_unknown_names_and_huge_counts_on_the_command_line(argv, fragments, tmp_path, monkeypatch, capsys):
    (tmp_path / "scene.yaml").write_text(FAST)
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("error: "), err
    for f in fragments:
        assert f in err, (f, err)


SHEET_UV_OBJ = ("".join(f"v {x} 1.5 {z}\n" for z in (0, 0.1, 0.2) for x in (0, 0.1, 0.2))
                + "".join(f"vt {u} {v}\n" for v in (0, 0.5, 1) for u in (0, 0.5, 1))
                + "".join(f"f {a}/{a} {b}/{b} {c}/{c}\n" for a, b, c in ((1, 2, 4), (2, 5, 4), (2, 3, 5), (3, 6, 5),
                                                                    (4, 5, 7), (5, 8, 7), (5, 6, 8), (6, 9, 8))))


def test_a_mesh_garment_keeps_its_uvs_in_every_export_and_through_the_recording(tmp_path, monkeypatch, capsys):
    """The file's 9 UVs come out in the run's npz and OBJ, and again when the recording is exported."""
    import numpy as np
    (tmp_path / "sheet.obj").write_text(SHEET_UV_OBJ)
    scene = _case_folder(tmp_path, FAST.replace("output: out.rrd", "output: {path: out.rrd, export: [npz, obj], "
                                                                   "export_dir: run}")
                         + "colliders: {report_every: 0}\ngarments:\n  - {type: mesh, name: sheet, path: sheet.obj}\n", {})
    monkeypatch.chdir(tmp_path)
    assert main(["run", str(scene), "-q"]) == 0, capsys.readouterr().err
    assert main(["export", "out.rrd", "--format", "npz,obj", "-o", "again"]) == 0, capsys.readouterr().err
    for folder, stem in (("run", "scene"), ("again", "out")):   # a recording's exports are named after it
        d = np.load(tmp_path / folder / f"{stem}.sheet.npz")
        uv = d["uv"][d["uv_faces"]]                             # per corner
        x0 = d["vertices_seq"][0][d["faces"]]                   # the sheet lies flat at y = 1.5 at frame 0
        assert d["uv"].shape == (9, 2)
        np.testing.assert_allclose(uv, x0[..., [0, 2]] / 0.2, atol=1e-5)   # u = x / 0.2, v = z / 0.2
        obj = (tmp_path / folder / f"{stem}.sheet.obj").read_text().splitlines()
        assert sum(line.startswith("vt ") for line in obj) == 9


def test_a_glb_of_several_meshes_is_a_clear_choice(tmp_path, monkeypatch, capsys):
    import trimesh
    s = trimesh.Scene()
    s.add_geometry(trimesh.creation.box(), geom_name="shirt", node_name="shirt")
    s.add_geometry(trimesh.creation.icosphere(subdivisions=1).apply_translation([3, 0, 0]), geom_name="buttons",
                   node_name="buttons")
    s.export(tmp_path / "two.glb")
    monkeypatch.chdir(tmp_path)
    for part, expect, fragments in ((None, 2, ["garments[0]", "two.glb", "holds 2 meshes", "'shirt'", "'buttons'",
                                               "part: all"]),
                                    ("nope", 2, ["part 'nope' is not one of its meshes", "'shirt'"]),
                                    ("shirt", 0, []), (1, 0, []), ("all", 0, [])):
        more = "" if part is None else f", part: {part}"
        scene = _case_folder(tmp_path, FAST + f"garments:\n  - {{type: mesh, name: g, path: two.glb{more}}}\n", {})
        code = main(["validate", str(scene)])
        out = capsys.readouterr()
        if expect:
            _assert_one_clear_line(out.err, scene, fragments, code)
        else:
            assert code == 0, out.err


def test_a_run_that_would_exceed_the_memory_is_one_line_before_it_allocates(tmp_path, monkeypatch, capsys):
    """The estimate (pipeline.preflight.check_memory) against a machine of 64 MB available."""
    from pipeline import preflight
    monkeypatch.setattr(preflight, "available_memory", lambda: 64 * 1024 ** 2)
    scene = _case_folder(tmp_path, FAST.replace("count: 2", "count: 5000"), {})
    monkeypatch.chdir(tmp_path)
    before = _left(tmp_path)
    for cmd in ("validate", "run"):
        code = main([cmd, str(scene)] + (["-q"] if cmd == "run" else []))
        _assert_one_clear_line(capsys.readouterr().err, scene, ["frames.count", "5,000 frames", "GB of memory",
                                                                "0.1 GB available"], code)
        assert _left(tmp_path) == before and (tmp_path / "out.rrd").read_bytes() == EARLIER
    monkeypatch.setattr(preflight, "available_memory", lambda: None)   # unknown: no refusal
    assert main(["validate", str(scene)]) == 0


@pytest.mark.parametrize("argv", [["measure", "builtin", "-o", "p"], ["matrix", "--json", "p"], ["bench", "--json", "p"]])
def test_an_output_file_flag_naming_a_fifo_is_one_line(argv, tmp_path, monkeypatch, capsys):
    os.mkfifo(tmp_path / "p")
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2   # checked before any work: opened for writing, the FIFO would block
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "'p' is a FIFO" in err, err


def test_more_sweep_workers_than_the_memory_holds_are_capped_with_a_warning(monkeypatch):
    import warnings
    from types import SimpleNamespace

    from pipeline import preflight, sweep
    monkeypatch.setattr(preflight, "available_memory", lambda: 3 * sweep.WORKER_BYTES + 1)
    sw = SimpleNamespace(path="s.yaml")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert sweep.memory_capped_workers(64, sw) == 3
        assert sweep.memory_capped_workers(2, sw) == 2
    assert len(caught) == 1 and "64 workers" in str(caught[0].message) and "running 3 workers" in str(caught[0].message)
    monkeypatch.setattr(preflight, "available_memory", lambda: None)
    assert sweep.memory_capped_workers(64, sw) == 64
