"""Hostile YAML and files that are not files (issue 42, classes 1 and 2): a billion-laughs alias
bomb, a recursive alias, nesting thousands deep, a complex (mapping/list) key, a FIFO, /dev/zero and
an oversize file, as a scene to `validate` and `run` and as a sweep file to `sweep`: exit 2, one line
naming the file and the problem, no traceback, within a bounded time, the earlier recording intact."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline.cli import main

REPO = Path(__file__).resolve().parent.parent
EARLIER = b"an earlier recording, kept byte for byte"


def _bomb(levels: int = 12) -> str:
    lines = ['a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for i in range(1, levels):
        lines.append(f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]")
    return "\n".join(lines) + "\n"


def _deep_block(levels: int) -> str:
    s, ind = "a:\n", ""
    for _ in range(levels):
        ind += " "
        s += ind + "b:\n"
    return s + ind + " 1\n"


SCENE_TEXTS = {   # case -> (text, fragment expected in the one line)
    "alias bomb": (_bomb(), "expands to more than"),
    "recursive alias": ("garments: &g [1, *g]\n", "recursive alias"),
    "flow nesting 10,000 deep": ("a: " + "[" * 10000 + "]" * 10000 + "\n", "nested more than"),
    "block nesting 1,500 deep": (_deep_block(1500), "nested"),
    "complex list key": ("? [1, 2]\n: 3\n", "key is a list"),
    "complex mapping key": ("? {a: 1}\n: 3\n", "key is a mapping"),
}


def _one_line(err: str, name: str, fragment: str):
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert name in lines[0] and fragment in lines[0], err
    assert "Traceback" not in err


@pytest.mark.parametrize("case", sorted(SCENE_TEXTS))
@pytest.mark.parametrize("command", ["validate", "run"])
def test_hostile_yaml_scene_is_one_line(case, command, tmp_path, monkeypatch, capsys):
    text, fragment = SCENE_TEXTS[case]
    scene = tmp_path / "scene.yaml"
    scene.write_text(text)
    (tmp_path / "scene.rrd").write_bytes(EARLIER)
    monkeypatch.chdir(tmp_path)
    assert main([command, str(scene), "-o", str(tmp_path / "scene.rrd")] if command == "run"
                else [command, str(scene)]) == 2
    _one_line(capsys.readouterr().err, "scene.yaml", fragment)
    assert (tmp_path / "scene.rrd").read_bytes() == EARLIER
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.rrd", "scene.yaml"]


@pytest.mark.parametrize("case", ["alias bomb", "recursive alias", "flow nesting 10,000 deep",
                                  "complex mapping key"])
def test_hostile_yaml_sweep_is_one_line(case, tmp_path, monkeypatch, capsys):
    text, fragment = SCENE_TEXTS[case]
    sweep = tmp_path / "sw.yaml"
    sweep.write_text("base: {}\ngrid: {gravity: [-9.81]}\n" + text)
    monkeypatch.chdir(tmp_path)
    assert main(["sweep", str(sweep)]) == 2
    _one_line(capsys.readouterr().err, "sw.yaml", fragment)


def test_aliases_of_plain_size_still_work(tmp_path, capsys):
    """Anchors and aliases used as intended (a shared value) are not refused."""
    from pipeline.scene import parse_scene_text
    sc = parse_scene_text("garments:\n  - {type: pattern, name: a, kind: &k long_skirt}\n"
                          "  - {type: pattern, name: b, kind: *k}\n", source="s.yaml")
    assert [g["name"] for g in sc["garments"]] == ["a", "b"]
    assert sc["garments"][1]["kind"] == "long_skirt"


@pytest.mark.parametrize("command", ["validate", "run", "sweep"])
def test_a_fifo_is_refused_unopened(command, tmp_path, capsys):
    """A FIFO would block the first open forever: refused by stat, in a subprocess with a timeout
    so a regression fails instead of hanging the suite."""
    fifo = tmp_path / "scene.yaml"
    os.mkfifo(fifo)
    r = subprocess.run([sys.executable, "-m", "pipeline", command, str(fifo)], cwd=REPO,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    _one_line(r.stderr, "scene.yaml", "FIFO")


@pytest.mark.parametrize("command", ["validate", "sweep"])
def test_a_device_is_refused(command, capsys):
    assert main([command, "/dev/zero"]) == 2
    _one_line(capsys.readouterr().err, "/dev/zero", "character device")


def test_an_oversize_scene_is_refused(tmp_path, capsys):
    scene = tmp_path / "big.yaml"
    scene.write_text("# padding\n" * 500_000)
    assert main(["validate", str(scene)]) == 2
    _one_line(capsys.readouterr().err, "big.yaml", "more than the limit")


def test_a_folder_as_scene(tmp_path, capsys):
    assert main(["validate", str(tmp_path)]) == 2
    _one_line(capsys.readouterr().err, str(tmp_path), "is a folder")


def test_merge_keys_work_with_the_mappings_own_keys_overriding(tmp_path):
    from pipeline.scene import load_scene
    from pipeline.schema import SceneError
    scene = tmp_path / "merge.yaml"
    scene.write_text("character: {clip: rest}\ngarments:\n  - &base {type: rectangle, name: a, width: 0.7}\n"
                     "  - <<: *base\n    name: b\n  - {<<: [*base], name: c, width: 0.5}\n")
    got = [(g["name"], g["width"], g["type"]) for g in load_scene(scene)["garments"]]
    assert got == [("a", 0.7, "rectangle"), ("b", 0.7, "rectangle"), ("c", 0.5, "rectangle")]
    scene.write_text("garments:\n  - &base {type: rectangle, name: a}\n  - {<<: *base, name: b, name: c}\n")
    with pytest.raises(SceneError, match="merge.yaml:3:.*duplicate key 'name'"):
        load_scene(scene)
    scene.write_text("garments:\n  - {<<: 3, name: b}\n")
    with pytest.raises(SceneError, match="merge.yaml:2:.*merging"):
        load_scene(scene)
    # a merge bomb: ten merges of ten merges ... is counted as its expansion
    bomb = "a: &a {k0: 0}\n" + "".join(f"{c}: &{c} {{<<: [{', '.join(['*' + p] * 10)}], x{c}: 1}}\n"
                                       for p, c in zip("abcdefg", "bcdefgh"))
    scene.write_text(bomb)
    with pytest.raises(SceneError, match="expands to more than 200,000 values"):
        load_scene(scene)
