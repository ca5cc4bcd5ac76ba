"""The bad-input battery: every kind of bad input a new user makes is one clear line before the run.

Each case writes a scene (and the files it names) into a fresh folder holding an earlier recording,
runs `validate` and `run` through the CLI's `main()` (in-process: the imports are paid once) and
asserts: exit 2, exactly one line on stderr naming the scene file, the item and the bad value, no
traceback, the earlier recording byte for byte and no other file left (no temporary, no probe).
A few cases go through a real subprocess, and the last-resort handler (a bug: exit 1) is checked
both ways.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pipeline.cli import main

REPO = Path(__file__).resolve().parent.parent
EARLIER = b"an earlier recording, kept byte for byte"

# --- mesh files -------------------------------------------------------------------------------

SHEET_OBJ = "".join(f"v {x} 0 {z}\n" for z in range(3) for x in range(3)) + \
    "".join(f"f {a} {b} {c}\n" for a, b, c in ((1, 2, 4), (2, 5, 4), (2, 3, 5), (3, 6, 5),
                                             (4, 5, 7), (5, 8, 7), (5, 6, 8), (6, 9, 8)))

MESH_FILES = {   # kind -> (file name, bytes, fragment of the problem expected in the message)
    "empty": ("m.obj", b"", "is empty"),
    "blank": ("m.obj", b"\n  \n", "is empty"),
    "no faces": ("m.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\n", "no triangle faces"),
    "degenerate faces": ("m.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 1 2\nf 2 3 3\n", "degenerate"),
    "collinear faces": ("m.obj", b"v 0 0 0\nv 1 0 0\nv 2 0 0\nv 3 0 0\nf 1 2 3\nf 2 3 4\n", "degenerate"),
    "nan vertex": ("m.obj", b"v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "non-finite"),
    "garbage obj": ("m.obj", bytes(np.random.default_rng(1).integers(0, 256, 400, dtype=np.uint8)), "m.obj"),
    "garbage stl": ("m.stl", bytes(np.random.default_rng(2).integers(0, 256, 300, dtype=np.uint8)), "m.stl"),
    "garbage glb": ("m.glb", b"glTF\x02\x00\x00\x00\x10\x00garbage", "cannot read"),
    "a folder": ("m.obj", None, "is a folder"),
    "missing": ("m.obj", "missing", "file not found"),
}
BOX_OBJ = (b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n"
           b"f 1 3 2\nf 1 4 3\nf 5 6 7\nf 5 7 8\nf 1 2 6\nf 1 6 5\nf 2 3 7\nf 2 7 6\nf 3 4 8\nf 3 8 7\n"
           b"f 4 1 5\nf 4 5 8\n")   # closed: no boundary loop
NON_MANIFOLD = ("m.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\nf 1 2 3\nf 2 1 4\nf 1 2 5\n", "non-manifold")


def _write_mesh(folder: Path, name: str, data) -> None:
    if data is None:
        (folder / name).mkdir()
    elif data == "fifo":   # a named pipe: opened, it blocks the reader until a writer comes
        os.mkfifo(folder / name)
    elif data != "missing":
        (folder / name).write_bytes(data)


# --- the cases --------------------------------------------------------------------------------
# id -> (scene text, files {name: bytes | None (folder) | "missing"}, fragments the error line must hold,
#        commands). "{dir}" in the scene text is the case's folder.

RUN_ONLY, BOTH = ("run",), ("validate", "run")
FAST = "character: {clip: rest}\nframes: {count: 2}\noutput: out.rrd\n"
CASES = {}

for kind, (name, data, problem) in MESH_FILES.items():
    CASES[f"garment mesh: {kind}"] = (
        FAST + f"garments:\n  - {{type: mesh, name: shirt, path: {name}}}\n",
        {name: data}, ["garments[0].path", "'shirt'", name, problem], BOTH)
    CASES[f"obstacle mesh: {kind}"] = (
        FAST + f"obstacles:\n  - {{type: mesh, name: rock, path: {name}}}\n",
        {name: data}, ["obstacles[0].path", "'rock'", name, problem], BOTH)
CASES["garment mesh: non-manifold edges"] = (
    FAST + "garments:\n  - {type: mesh, name: shirt, path: m.obj}\n",
    {"m.obj": NON_MANIFOLD[1]}, ["garments[0].path", "'shirt'", "m.obj", "non-manifold"], BOTH)
CASES["garment mesh: second garment bad, first fine"] = (
    FAST + "garments:\n  - {type: mesh, name: ok, path: good.obj}\n  - {type: mesh, name: torn, path: m.obj}\n",
    {"good.obj": SHEET_OBJ.encode(), "m.obj": b"v 0 0 0\n"}, ["garments[1].path", "'torn'", "no triangle faces"], BOTH)

CASES.update({
    "empty scene file": ("", {}, ["the scene file is empty"], BOTH),
    "comment-only scene file": ("# a scene, some day\n\n   # nothing yet\n", {}, ["the scene file is empty"], BOTH),
    "duplicate garment names": (
        FAST + "garments:\n  - {type: rectangle, name: cloth}\n  - {type: tube, name: skirt}\n"
               "  - {type: rectangle, name: cloth}\n",
        {}, ["garments[2].name", "'cloth'", "garments[0]"], BOTH),
    "duplicate obstacle names": (
        FAST + "obstacles:\n  - {type: box, name: b, size: [1, 1, 1]}\n  - {type: sphere, name: b, radius: 1}\n",
        {}, ["obstacles[1].name", "'b'", "obstacles[0]"], BOTH),
    "pinned index out of range (rectangle)": (
        FAST + "garments:\n  - {type: rectangle, name: flag, resolution: [10, 10], pin: {indices: [0, 9, 100]}}\n",
        {}, ["garments[0].pin.indices[2]", "'flag'", "100", "100 particles"], BOTH),
    "pinned index out of range (mesh)": (
        FAST + "garments:\n  - {type: mesh, name: sheet, path: s.obj, pin: {indices: [3, 12]}}\n",
        {"s.obj": SHEET_OBJ.encode()}, ["garments[0].pin.indices[1]", "'sheet'", "12", "9 particles"], BOTH),
    "pin by the top boundary of a closed mesh (needs the character)": (
        FAST + "garments:\n  - {type: mesh, name: bag, path: box.obj, translate: [0, 1, 0], "
               "pin: {boundary: top, collider: spine}}\n",
        {"box.obj": BOX_OBJ}, ["garments[0].pin", "'bag'", "'top_loop'", "without boundary"], BOTH),
    "bad mesh with the output in a new folder (no folder left)": (
        FAST.replace("out.rrd", "new/sub/out.rrd") + "obstacles:\n  - {type: mesh, name: rock, path: m.stl}\n",
        {"m.stl": b"solid x\nendsolid x\n"}, ["obstacles[0].path", "'rock'", "m.stl"], BOTH),
    "character: corrupt glb": (
        "character: {source: gltf, path: c.glb}\noutput: out.rrd\n", {"c.glb": b"glTF\x02\x00\x00\x00\x10\x00"},
        ["character.path", "c.glb", "truncated"], BOTH),
    "character: corrupt bvh": (
        "character: {source: bvh, path: c.bvh}\noutput: out.rrd\n", {"c.bvh": b"HIERARCHY\nROOT hips\n{\n OFFSET 0 0\n"},
        ["character.path", "c.bvh", "line 4"], BOTH),
    "character: empty bvh": (
        "character: {source: bvh, path: c.bvh}\noutput: out.rrd\n", {"c.bvh": b""}, ["character.path", "c.bvh"], BOTH),
    "output: parent is a file": (
        FAST.replace("out.rrd", "afile/out.rrd"), {"afile": b"x"}, ["output", "afile", "is a file"], BOTH),
    "output: an existing folder": (
        FAST.replace("out.rrd", "adir"), {"adir": None}, ["output", "adir", "is a folder"], BOTH),
    "output: a folder that cannot be created": (
        FAST.replace("out.rrd", "/proc/no_such_dir/out.rrd"), {}, ["output", "/proc/no_such_dir", "cannot create"], RUN_ONLY),
    "output: a location that is not writable": (
        FAST.replace("out.rrd", "/proc/out.rrd"), {}, ["output", "/proc", "cannot write"], RUN_ONLY),
})

SKIRT = "garments:\n  - {{type: pattern, name: skirt, kind: {kind}, options: {{{options}}}}}\n"
CASES.update({   # issue 42: files that are not files, values out of physical range
    "garment mesh: a FIFO": (FAST + "garments:\n  - {type: mesh, name: shirt, path: p.obj}\n", {"p.obj": "fifo"},
                             ["garments[0].path", "'shirt'", "p.obj", "FIFO"], BOTH),
    "obstacle mesh: a FIFO": (FAST + "obstacles:\n  - {type: mesh, name: rock, path: p.stl}\n", {"p.stl": "fifo"},
                              ["obstacles[0].path", "p.stl", "FIFO"], BOTH),
    "garment mesh: /dev/zero": (FAST + "garments:\n  - {type: mesh, name: shirt, path: /dev/zero}\n", {},
                                ["garments[0].path", "/dev/zero", "character device"], BOTH),
    "character: a FIFO glb": ("character: {source: gltf, path: c.glb}\noutput: out.rrd\n", {"c.glb": "fifo"},
                              ["character.path", "c.glb", "FIFO"], BOTH),
    "character: /dev/zero as a bvh": ("character: {source: bvh, path: /dev/zero}\noutput: out.rrd\n", {},
                                      ["character.path", "/dev/zero", "character device"], BOTH),
    "output: a character device": (FAST.replace("out.rrd", "/dev/null"), {},
                                   ["output", "/dev/null", "character device"], BOTH),
    "output: a FIFO": (FAST.replace("out.rrd", "p.rrd"), {"p.rrd": "fifo"}, ["output", "p.rrd", "FIFO"], BOTH),
    "output.export_dir: a file": (
        FAST.replace("output: out.rrd", "output: {path: out.rrd, export: [npz], export_dir: exp}")
        + "garments:\n  - {type: rectangle, name: flag}\n", {"exp": b"x"}, ["output.export_dir", "exp", "is a file"],
        BOTH),
    "option: negative ease": (FAST + SKIRT.format(kind="short_skirt", options="ease: -0.1"), {},
                              ["garments[0].options.ease", "-0.1", ">= 0.0"], BOTH),
    "option: ease 50": (FAST + SKIRT.format(kind="short_skirt", options="ease: 50"), {},
                        ["garments[0].options.ease", "50.0", "<= 0.5"], BOTH),
    "option: negative length": (FAST + SKIRT.format(kind="long_skirt", options="length: -0.3"), {},
                                ["garments[0].options.length", "-0.3", "> 0.0"], BOTH),
    "option: infinite length": (FAST + SKIRT.format(kind="cape", options="length: .inf"), {},
                                ["garments[0].options.length", "finite"], BOTH),
    "option: of another kind": (FAST + SKIRT.format(kind="tshirt", options="flare: 1.5"), {},
                                ["garments[0].options.flare", "kind 'tshirt'", "sleeve_length"], BOTH),
    "plane: zero normal": (FAST + "obstacles:\n  - {type: plane, name: floor, normal: [0, 0, 0]}\n", {},
                           ["obstacles[0].normal", "non-zero"], BOTH),
    "box: negative size": (FAST + "obstacles:\n  - {type: box, name: b, size: [1, -1, 1]}\n", {},
                           ["obstacles[0].size[1]", "-1.0", "> 0.0"], BOTH),
    "colliders.delta: 0": (FAST + "colliders: {delta: 0}\n", {}, ["colliders.delta", "0.0", "> 0.0"], BOTH),
    "tube: 4 million particles": (FAST + "garments:\n  - {type: tube, name: t, n_around: 2000, n_down: 2000}\n", {},
                                  ["garments[0]", "4,000,000 particles", "100,000"], BOTH),
    "blend_in at a tiny dt": (FAST.replace("{count: 2}", "{count: 2, blend_in: 20}") + "simulation: {dt: 0.0001}\n", {},
                              ["frames.blend_in", "200,000 blend-in frames", "100,000"], BOTH),
    "dt below its range": (FAST + "simulation: {dt: 1.0e-9}\n", {}, ["simulation.dt", ">= 0.0001"], BOTH),
    "gravity 1e4": (FAST + "simulation: {gravity: [0, -1.0e+4, 0]}\n", {},
                    ["simulation.gravity[1]", "-10000.0", ">= -1000.0"], BOTH),
    "a number YAML reads as text": (FAST + "simulation: {gravity: [0, -1e4, 0]}\n", {},
                                    ["simulation.gravity[1]", "'-1e4'", "write it as -1.0e+04"], BOTH),
})


def _case_folder(tmp_path: Path, text: str, files: dict) -> Path:
    (tmp_path / "out.rrd").write_bytes(EARLIER)
    for name, data in files.items():
        _write_mesh(tmp_path, name, data)
    (tmp_path / "scene.yaml").write_text(text)
    return tmp_path / "scene.yaml"


def _left(tmp_path: Path) -> set:
    return {str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*")}


def _assert_one_clear_line(err: str, scene: Path, fragments, code: int, expect: int = 2):
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == expect, err
    assert "Traceback" not in err
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert str(scene) in lines[0], lines[0]
    for f in fragments:
        assert f in lines[0], (f, lines[0])


@pytest.mark.parametrize("case", list(CASES))
def test_bad_input_is_one_line_before_the_run(case, tmp_path, monkeypatch, capsys):
    text, files, fragments, commands = CASES[case]
    scene = _case_folder(tmp_path, text, files)
    before = _left(tmp_path)
    monkeypatch.chdir(tmp_path)
    for cmd in commands:
        code = main([cmd, str(scene)] + (["-q"] if cmd == "run" else []))
        out = capsys.readouterr()
        _assert_one_clear_line(out.err, scene, fragments, code)
        assert (tmp_path / "out.rrd").read_bytes() == EARLIER          # the earlier recording is kept
        assert _left(tmp_path) == before, _left(tmp_path) ^ before      # nothing written, not even a temp file


@pytest.mark.parametrize("output, fragment", [("afile/out.rrd", "is a file"), ("adir", "is a folder"),
                                              ("", "is a folder")])
def test_bad_output_flag_names_the_flag(output, fragment, tmp_path, monkeypatch, capsys):
    scene = _case_folder(tmp_path, FAST, {"afile": b"x", "adir": None})
    monkeypatch.chdir(tmp_path)
    before = _left(tmp_path)
    code = main(["run", str(scene), "-q", "-o", output])
    _assert_one_clear_line(capsys.readouterr().err, scene, ["--output", fragment], code)
    assert _left(tmp_path) == before and (tmp_path / "out.rrd").read_bytes() == EARLIER


def cli(*args, cwd, pre: str = ""):
    """The CLI in a real process; `pre` is Python run before main() (to plant a bug)."""
    code = f"import sys\n{pre}\nfrom pipeline.cli import main\nsys.exit(main(sys.argv[1:]))\n"
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.run([sys.executable, "-c", code, *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=600)


@pytest.mark.parametrize("case", ["garment mesh: garbage stl", "obstacle mesh: garbage stl", "empty scene file",
                                  "output: an existing folder", "pinned index out of range (rectangle)"])
def test_bad_input_in_a_real_process(case, tmp_path):
    text, files, fragments, commands = CASES[case]
    scene = _case_folder(tmp_path, text, files)
    before = _left(tmp_path)
    for cmd in commands:
        r = cli(cmd, str(scene), "-q" if cmd == "run" else "--debug", cwd=tmp_path)
        _assert_one_clear_line(r.stderr, scene, fragments, r.returncode)
        assert _left(tmp_path) == before and (tmp_path / "out.rrd").read_bytes() == EARLIER


PLANT_BUG = """
import pipeline.run
def broken(scene):
    raise ZeroDivisionError("planted bug")
pipeline.run.load_character = broken
"""


def test_a_bug_is_one_line_naming_stage_scene_and_item_exit_1(tmp_path):
    scene = _case_folder(tmp_path, FAST, {})
    before = _left(tmp_path)
    for cmd in ("validate", "run"):
        r = cli(cmd, str(scene), *(["-q"] if cmd == "run" else []), cwd=tmp_path, pre=PLANT_BUG)
        _assert_one_clear_line(r.stderr, scene, ["internal error", "'rig'", "character procedural",
                                                 "ZeroDivisionError: planted bug", "--debug"], r.returncode, expect=1)
        assert _left(tmp_path) == before and (tmp_path / "out.rrd").read_bytes() == EARLIER
    r = cli("run", str(scene), "-q", "--debug", cwd=tmp_path, pre=PLANT_BUG)
    assert r.returncode == 1 and "Traceback" in r.stderr and "planted bug" in r.stderr
    assert r.stderr.strip().splitlines()[-1].startswith("error: internal error")
    assert _left(tmp_path) == before and (tmp_path / "out.rrd").read_bytes() == EARLIER


def test_a_bug_mid_run_leaves_no_recording(tmp_path, monkeypatch, capsys):
    """A bug after the recording was opened (obstacles stage): the temporary file goes, the earlier
    recording stays, and the line names the obstacle being built."""
    import pipeline.dressing

    def broken(o, mesh, duration):
        raise RuntimeError("planted bug\nover two lines")
    monkeypatch.setattr(pipeline.dressing, "_build_scene_obstacle", broken)
    scene = _case_folder(tmp_path, FAST + "colliders: {report_every: 0}\n"
                         "obstacles:\n  - {type: box, name: crate, size: [1, 1, 1]}\n", {})
    before = _left(tmp_path)
    monkeypatch.chdir(tmp_path)
    code = main(["run", str(scene), "-q"])
    _assert_one_clear_line(capsys.readouterr().err, scene, ["'obstacles'", "obstacles[0] ('crate')",
                                                            "planted bug over two lines"], code, expect=1)
    assert _left(tmp_path) == before and (tmp_path / "out.rrd").read_bytes() == EARLIER


def test_latin1_obj_comment_and_binary_stl_header_are_read(tmp_path, monkeypatch, capsys):
    """Not bad input: a Latin-1 byte in an OBJ comment and a binary STL whose free-text header is
    not UTF-8 used to fail with "No module named 'charset_normalizer'"."""
    import trimesh

    (tmp_path / "s.obj").write_bytes(b"# exported by Ren\xe9\n" + SHEET_OBJ.encode())
    stl = bytearray(trimesh.creation.box().export(file_type="stl"))
    stl[:12] = b"\xff\xfe solid \xe9\xe8 "
    (tmp_path / "box.stl").write_bytes(bytes(stl))
    scene = _case_folder(tmp_path, FAST + "garments:\n  - {type: mesh, name: sheet, path: s.obj}\n"
                         "obstacles:\n  - {type: mesh, name: box, path: box.stl}\n", {})
    monkeypatch.chdir(tmp_path)
    code = main(["validate", str(scene)])
    out = capsys.readouterr()
    assert code == 0, out.err
    assert "2 mesh files read" in out.out


def _rerun_cli() -> str:
    import shutil
    exe = Path(sys.executable).with_name("rerun")
    return str(exe) if exe.exists() else (shutil.which("rerun") or pytest.skip("the rerun CLI is not installed"))


def test_deterministic_runs_give_recordings_rerun_compares_equal(tmp_path):
    """The README's promise: same scene + seed, same recording. With --deterministic the wall-clock
    timings stay out, and `rerun rrd compare` (which ignores only log_time) finds two runs equal;
    without it they are in their own timings/ entities."""
    from tests.rrd_read import entity_paths
    outs = []
    for k in range(2):
        out = tmp_path / f"run{k}.rrd"
        r = subprocess.run([sys.executable, "-m", "pipeline", "run", "scenes/default.yaml", "--frames", "3", "-q",
                            "--deterministic", "-o", str(out)], cwd=REPO, capture_output=True, text=True, timeout=900)
        assert r.returncode == 0, r.stderr
        outs.append(out)
    paths = entity_paths(outs[0])
    assert "/sim/skirt/mesh" in paths and "/meta/summary" in paths
    assert not [p for p in paths if p.startswith("/timings")]
    r = subprocess.run([_rerun_cli(), "rrd", "compare", str(outs[0]), str(outs[1])], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]


ZUP_SCENE = ("character: {{source: gltf, path: {glb}, clip: {clip}}}\nframes: {{count: 2}}\noutput: out.rrd\n"
             "colliders: {{report_every: 0}}\n"
             "garments:\n  - {{type: pattern, name: skirt, kind: short_skirt}}\n{more}")


def test_z_up_gltf_dresses_and_runs(tmp_path, monkeypatch, capsys):
    """A glTF stored Z up (a humanoid figure whose root node stands it along +Z) goes through the
    garment stage: `up_axis: auto` stands it up; validate and run both succeed."""
    from tests.test_rig_gltf_frames import HUMANOID, STORE, build_figure
    build_figure(HUMANOID, STORE["+z"]).write_glb(tmp_path / "robot_z.glb")
    scene = tmp_path / "scene.yaml"
    scene.write_text(ZUP_SCENE.format(glb="robot_z.glb", clip="rest",
                                      more="  - {type: tube, name: tube, at_joint: hips}\n"))
    monkeypatch.chdir(tmp_path)
    assert main(["validate", str(scene)]) == 0, capsys.readouterr().err
    assert "up axis: file +Z (auto" in capsys.readouterr().out
    assert main(["run", str(scene), "-q"]) == 0, capsys.readouterr().err
    assert (tmp_path / "out.rrd").is_file()


@pytest.mark.assets
def test_cesium_man_stored_z_up_dresses_and_runs(assets_dir, tmp_path, monkeypatch, capsys):
    """The real asset re-stored Z up (tests/test_rig_gltf_frames.z_up_copy) with a sewn skirt."""
    from tests.test_rig_gltf_frames import z_up_copy
    z_up_copy(assets_dir / "CesiumMan.glb", tmp_path / "cesium_z.glb")
    scene = tmp_path / "scene.yaml"
    scene.write_text(ZUP_SCENE.format(glb="cesium_z.glb", clip=0, more=""))
    monkeypatch.chdir(tmp_path)
    assert main(["run", str(scene), "-q"]) == 0, capsys.readouterr().err
    from tests.rrd_read import rows
    assert "up axis: file +Z (auto" in str(rows(tmp_path / "out.rrd", "rig/notes", "TextDocument:text")[0][1])
    # the clip's 2 frames after the blend-in from the T-pose (dressed there) into its first pose
    assert len(rows(tmp_path / "out.rrd", "sim/skirt/mesh", "Mesh3D:vertex_positions")) > 2


def test_a_pattern_too_fine_for_its_body_is_one_line_before_meshing(tmp_path, monkeypatch, capsys):
    """A long skirt cut at the smallest edge length on the tallest built-in body would mesh into
    ~150,000 particles: refused with the key to change, before triangulating or sewing."""
    scene = tmp_path / "fine.yaml"
    scene.write_text("character: {source: procedural, clip: rest, body: {height: 2.5, hips: 2.0}}\n"
                     "colliders: {report_every: 0}\n"
                     "garments:\n  - {type: pattern, name: skirt, kind: long_skirt, edge_length: 0.005}\n")
    monkeypatch.chdir(tmp_path)
    assert main(["validate", str(scene)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "fine.yaml" in err and "garments[0].edge_length" in err, err
    assert "particles" in err and "at most 100,000" in err
