"""Fuzzing the scene checks: hypothesis mutates a valid scene (types, ranges, keys, paths, raw text;
numbers far out of physical range, pattern options of every kind, YAML anchors, merges and complex
keys) and corrupts the bytes of the mesh files it names or makes them a FIFO, a device or a folder; `validate` must then either accept it or give
exit 2 with one line naming the scene file, never a traceback nor the last-resort exit 1.

The character is not built: `load_character` is replaced by a stand-in that stops the command
(a BaseException, which no handler catches) once every check before the character has passed, so
a few hundred cases run in seconds. What needs the character is covered by tests/test_bad_input.py.
"""
from __future__ import annotations

import copy
import functools
import os

import numpy as np
import pytest
import yaml

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings, strategies as st  # noqa: E402

from pipeline.cli import main  # noqa: E402

SHEET_OBJ = ("".join(f"v {x} 0 {z}\n" for z in range(3) for x in range(3)) +
             "f 1 2 4\nf 2 5 4\nf 2 3 5\nf 3 6 5\nf 4 5 7\nf 5 8 7\nf 5 6 8\nf 6 9 8\n").encode()

BASE = {
    "name": "fuzz",
    "seed": 3,
    "character": {"source": "procedural", "clip": "rest", "body": {"height": 1.7, "hips": 1.1}},
    "frames": {"start": 0.0, "count": 4, "blend_in": 0.0},
    "colliders": {"delta": 0.01, "split": "motion", "map": {"type": "auto", "n_theta": 12}},
    "garments": [
        {"type": "rectangle", "name": "flag", "width": 0.5, "height": 0.4, "resolution": [6, 5],
         "center": [0, 1.5, 0.3], "pin": {"indices": [0, 5]}},
        {"type": "tube", "name": "skirt", "at_joint": "pelvis", "n_around": 12, "n_down": 6},
        {"type": "mesh", "name": "sheet", "path": "sheet.obj", "translate": [0, 1.8, 0], "pin": {"indices": [8]}},
        {"type": "pattern", "name": "tee", "kind": "tshirt", "options": {"sleeve_length": 0.2}},
    ],
    "obstacles": [
        {"type": "box", "name": "crate", "center": [1, 0.2, 0], "size": [0.4, 0.4, 0.4]},
        {"type": "mesh", "name": "rock", "path": "rock.obj", "scale": 0.5, "translate": [-1, 0, 0]},
    ],
    "simulation": {"dt": 0.03, "substeps": 1, "iterations": 3, "gravity": [0, -9.81, 0]},
    "output": "out.rrd",
}


# a few hundred cases in the default run; GARMENT_FUZZ_EXAMPLES=5000 for a longer hunt
EXAMPLES = int(os.environ.get("GARMENT_FUZZ_EXAMPLES", "250"))


class ReachedCharacter(BaseException):
    """Every check before the character passed."""


def _paths(node, prefix=()):
    """Every key path in the scene tree (dict keys and list indices)."""
    yield prefix
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _paths(v, prefix + (i,))


PATHS = [p for p in _paths(BASE) if p]

values = st.recursive(
    st.none() | st.booleans() | st.integers(-10**6, 10**6) | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=12) | st.sampled_from(["", "rest", "pelvis", "sheet.obj", "rock.obj", "nope.obj", ".", "/",
                                              "sub", "sub/x.rrd", "a.obj/b.rrd", "mesh", "pattern", "-1", "1e400"]),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=3),
    max_leaves=6)


def _set(tree, path, value):
    node = tree
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = value


def _delete(tree, path):
    node = tree
    for k in path[:-1]:
        node = node[k]
    del node[path[-1]]


NUMBER_PATHS = [p for p in PATHS if isinstance(_leaf := functools.reduce(lambda n, k: n[k], p, BASE), (int, float))
                and not isinstance(_leaf, bool)]
numbers = (st.sampled_from([0, -0.0, -1, 1e-300, -1e-9, 1e300, -1e300, 2**63, 1e4, 50, 0.5])
           | st.floats(-1e12, 1e12) | st.integers(-2**70, 2**70))
from pipeline.scene import PATTERN_OPTIONS  # noqa: E402

mutation = st.one_of(
    st.tuples(st.just("set"), st.sampled_from(PATHS), values),
    st.tuples(st.just("set"), st.sampled_from(NUMBER_PATHS), numbers),
    st.tuples(st.just("set"), st.just(("garments", 3, "kind")),
              st.sampled_from(["tshirt", "short_skirt", "long_skirt", "shorts", "trousers", "cape", "square"])),
    st.tuples(st.just("add key"), st.just(("garments", 3, "options")),
              st.tuples(st.sampled_from(sorted(PATTERN_OPTIONS)), numbers | values)),
    st.tuples(st.just("delete"), st.sampled_from(PATHS), st.none()),
    st.tuples(st.just("add key"), st.sampled_from([p for p in PATHS if isinstance(p[-1], str)] + [("x",)]),
              st.tuples(st.text(min_size=1, max_size=10), values)),
)


def _corrupt(data: bytes, how, rnd: np.random.Generator) -> bytes:
    kind, amount = how
    if kind == "truncate":
        return data[: int(len(data) * amount)]
    if kind == "flip":
        b = bytearray(data)
        for i in rnd.integers(0, len(b), max(1, int(len(b) * amount))):
            b[i] = int(rnd.integers(0, 256))
        return bytes(b)
    if kind == "garbage":
        return bytes(rnd.integers(0, 256, int(400 * amount) + 1, dtype=np.uint8))
    return data


corruption = st.one_of(st.none(), st.tuples(st.sampled_from(["truncate", "flip", "garbage"]),
                                            st.floats(0.0, 1.0)))
NOT_A_FILE = ("fifo", "device", "folder")   # in place of a mesh file: opened, a FIFO blocks, /dev/zero never ends


def _place(path, data) -> None:
    if path.is_dir() and not path.is_symlink():   # hypothesis reuses the folder between examples
        path.rmdir()
    elif path.is_symlink() or path.exists():
        path.unlink()
    if data == "fifo":
        os.mkfifo(path)
    elif data == "device":
        os.symlink("/dev/zero", path)
    elif data == "folder":
        path.mkdir()
    else:
        path.write_bytes(data)


def _run(tmp_path, capsys, monkeypatch, text: str, sheet, rock):
    (tmp_path / "scene.yaml").write_text(text, encoding="utf-8", errors="surrogatepass")
    _place(tmp_path / "sheet.obj", sheet)
    _place(tmp_path / "rock.obj", rock)
    before = sorted(p.name for p in tmp_path.rglob("*"))
    scene = str(tmp_path / "scene.yaml")
    try:
        code = main(["validate", scene])
    except ReachedCharacter:
        code = None
    err = capsys.readouterr().err
    assert "Traceback" not in err
    if code not in (None, 0):
        lines = [line for line in err.splitlines() if line.strip()]
        assert code == 2, err                        # never the last-resort exit 1
        assert len(lines) == 1 and lines[0].startswith("error: ") and scene in lines[0], err
    assert sorted(p.name for p in tmp_path.rglob("*")) == before   # validate writes nothing
    return code


@pytest.fixture
def stand_in(monkeypatch):
    import pipeline.run

    def reached(scene):
        raise ReachedCharacter
    monkeypatch.setattr(pipeline.run, "load_character", reached)


@settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(mutations=st.lists(mutation, min_size=1, max_size=3), sheet=corruption | st.sampled_from(NOT_A_FILE),
       rock=corruption | st.sampled_from(NOT_A_FILE), seed=st.integers(0, 2**32 - 1))
def test_mutated_scenes_and_corrupt_meshes_are_accepted_or_one_line(tmp_path, capsys, monkeypatch, stand_in,
                                                                    mutations, sheet, rock, seed):
    tree = copy.deepcopy(BASE)
    for op, path, arg in mutations:
        try:
            if op == "set":
                _set(tree, path, arg)
            elif op == "delete":
                _delete(tree, path)
            else:
                node = tree
                for k in path:
                    node = node[k]
                if isinstance(node, dict):
                    node[arg[0]] = arg[1]
        except (KeyError, IndexError, TypeError):
            pass   # an earlier mutation removed or replaced the parent
    monkeypatch.chdir(tmp_path)
    rnd = np.random.default_rng(seed)
    _run(tmp_path, capsys, monkeypatch, yaml.safe_dump(tree, allow_unicode=True),
         *(f if f in NOT_A_FILE else _corrupt(SHEET_OBJ, f, rnd) if f else SHEET_OBJ for f in (sheet, rock)))


@settings(max_examples=max(EXAMPLES // 2, 1), deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cut=st.integers(0, 10**6), drop=st.integers(0, 6),
       insert=st.text(max_size=8) | st.sampled_from(["&a ", "*a", "&a [x, x]\n", "<<: *a\n", "{<<: *a}", "? [a]\n: b\n",
                                                     "? {a: 1}\n", "!!python/object:os.system ", "[[[[[[[[", "{{{{{{",
                                                     "*undefined", "!!binary ", "1e4", ".inf", "-.nan"]))
def test_mangled_scene_text_is_accepted_or_one_line(tmp_path, capsys, monkeypatch, stand_in, cut, insert, drop):
    """Raw text edits: characters inserted or removed anywhere (indentation, quotes, colons), YAML
    anchors, aliases, merges, complex keys and tags."""
    text = yaml.safe_dump(BASE)
    i = cut % (len(text) + 1)
    text = text[:i] + insert + text[i + drop:]
    monkeypatch.chdir(tmp_path)
    _run(tmp_path, capsys, monkeypatch, text, SHEET_OBJ, SHEET_OBJ)


def test_the_base_scene_passes_every_check(tmp_path, capsys, monkeypatch, stand_in):
    """The fuzzer's starting point is valid: its mutants test the checks, not a broken base."""
    monkeypatch.chdir(tmp_path)
    assert _run(tmp_path, capsys, monkeypatch, yaml.safe_dump(BASE), SHEET_OBJ, SHEET_OBJ) is None


@functools.lru_cache(maxsize=1)
def figure_glb() -> bytes:
    """A small skinned glTF figure (tests/test_rig_gltf_frames), stored Z up."""
    import tempfile
    from pathlib import Path

    from tests.test_rig_gltf_frames import HUMANOID, STORE, build_figure
    with tempfile.TemporaryDirectory() as d:
        build_figure(HUMANOID, STORE["+z"]).write_glb(Path(d) / "figure.glb")
        return (Path(d) / "figure.glb").read_bytes()


@pytest.fixture(scope="module")
def built_figure():
    figure_glb()   # built outside the @given test (the figure builder module defines @given tests)


@settings(max_examples=max(EXAMPLES // 2, 1), deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(how=st.tuples(st.sampled_from(["truncate", "flip"]), st.floats(0.0, 0.05)), seed=st.integers(0, 2**32 - 1))
def test_corrupt_character_gltf_is_accepted_or_one_line(tmp_path, capsys, monkeypatch, built_figure, how, seed):
    """The character asset's bytes corrupted (a small skinned glTF figure, loaded for real)."""
    (tmp_path / "figure.glb").write_bytes(_corrupt(figure_glb(), how, np.random.default_rng(seed)))
    text = "character: {source: gltf, path: figure.glb, clip: rest}\noutput: out.rrd\n"
    monkeypatch.chdir(tmp_path)
    _run(tmp_path, capsys, monkeypatch, text, SHEET_OBJ, SHEET_OBJ)


@settings(max_examples=max(EXAMPLES // 10, 1), deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cut=st.integers(0, 10**6), insert=st.text(alphabet="0123456789.-e{} \n\tXYZ", max_size=6) | st.text(max_size=3),
       drop=st.integers(0, 8))
def test_mangled_character_bvh_is_accepted_or_one_line(tmp_path, capsys, monkeypatch, cut, insert, drop):
    """The character asset's text mangled (a small humanoid BVH, loaded for real: a mangle the
    parser accepts builds the skin, so fewer cases)."""
    from tests.bvh_humanoid import humanoid_bvh
    text = humanoid_bvh()
    i = cut % (len(text) + 1)
    (tmp_path / "walk.bvh").write_text(text[:i] + insert + text[i + drop:], encoding="utf-8", errors="surrogatepass")
    monkeypatch.chdir(tmp_path)
    _run(tmp_path, capsys, monkeypatch, "character: {source: bvh, path: walk.bvh, clip: rest}\noutput: out.rrd\n",
         SHEET_OBJ, SHEET_OBJ)


def test_an_inverse_bind_matrix_singular_only_in_its_bottom_row_is_one_line(tmp_path, capsys, monkeypatch, built_figure):
    # found by the fuzzing above: a flipped byte zeroed a matrix's bottom row, its 3 x 3 part still
    # invertible; the loader's inversion of the whole matrix then stopped the run as an internal error
    import pygltflib
    doc = pygltflib.GLTF2.load_from_bytes(figure_glb())
    blob = bytearray(doc.binary_blob())
    acc = doc.accessors[doc.skins[0].inverseBindMatrices]
    view = doc.bufferViews[acc.bufferView]
    start = (view.byteOffset or 0) + (acc.byteOffset or 0)
    m = np.frombuffer(blob, np.float32, 16, start).copy()
    m[[3, 7, 11, 15]] = 0.0                       # column-major: the bottom row
    blob[start:start + 64] = m.tobytes()
    doc.set_binary_blob(bytes(blob))
    (tmp_path / "figure.glb").write_bytes(b"".join(doc.save_to_bytes()))
    monkeypatch.chdir(tmp_path)
    code = _run(tmp_path, capsys, monkeypatch, "character: {source: gltf, path: figure.glb, clip: rest}\noutput: out.rrd\n",
                SHEET_OBJ, SHEET_OBJ)
    assert code == 2
