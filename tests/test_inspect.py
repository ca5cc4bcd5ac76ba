"""`python -m pipeline inspect`: the real assets, the built-in character, --json, bad files."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline.inspect import describe, text

REPO = Path(__file__).resolve().parent.parent


def cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "pipeline", *args], cwd=cwd or REPO, env=dict(os.environ),
                          capture_output=True, text=True, timeout=600)


def test_cesium_man(assets_dir):
    f = describe(str(assets_dir / "CesiumMan.glb"))
    assert f["kind"] == "gltf" and f["joints"]["count"] == 19
    assert f["mesh"]["vertices"] == 3273 and f["mesh"]["triangles"] == 4672
    assert 1.45 < f["mesh"]["height_m"] < 1.55
    assert f["units"]["up_axis"].startswith("file +Y (auto")
    assert any(n.startswith("floor: lifted") for n in f["units"]["notes"])
    assert [(c["name"], c["frames"]) for c in f["clips"]] == [("Anim_0", 50)]
    assert f["clips"][0]["duration_s"] == pytest.approx(2.0, abs=0.05)
    parts = f["humanoid"]["parts"]
    # CesiumMan's names (leg_joint_L_1 ...) match no known naming: every limb comes from the shape
    assert all(parts[p]["found"] == "shape" for p in ("arm_l", "arm_r", "leg_l", "leg_r"))
    assert parts["leg_l"]["joints"][0] == "leg_joint_L_1" and parts["leg_r"]["joints"][0] == "leg_joint_R_1"
    assert "_L_" in parts["arm_l"]["joints"][0] and parts["arm_r"]["joints"][0].startswith("Skeleton_arm_joint_R")
    assert parts["neck"]["joints"] == ["Skeleton_neck_joint_1"]
    assert f["humanoid"]["missing"] == [] and f["humanoid"]["garments_blocked"] == {}


def test_tree_lists_every_joint_once_under_its_parent(assets_dir):
    f = describe(str(assets_dir / "cmu_131_01_walk.bvh"))
    tree = f["joints"]["tree"]
    assert sorted(t["index"] for t in tree) == list(range(f["joints"]["count"])) and len(tree) == 38
    seen = {}
    for t in tree:   # depth-first: the parent was listed before, one level up
        if t["parent"] is None:
            assert t["depth"] == 0
        else:
            assert seen[t["parent"]] == t["depth"] - 1
        seen[t["name"]] = t["depth"]


def test_cmu_bvh(assets_dir):
    f = describe(str(assets_dir / "cmu_131_01_walk.bvh"))
    assert f["kind"] == "bvh" and f["joints"]["root"] == "Hips"
    assert f["clips"][0]["frames"] == 995
    assert f["clips"][0]["duration_s"] == pytest.approx(994 / 120, abs=1e-3)
    assert "120 Hz" in f["units"]["notes"][0]
    parts = f["humanoid"]["parts"]
    assert parts["arm_l"] == {"joints": ["LeftShoulder", "LeftElbow", "LeftWrist"], "found": "name", "why": ""}
    assert parts["leg_r"] == {"joints": ["RightHip", "RightKnee", "RightAnkle"], "found": "name", "why": ""}
    assert parts["head"]["found"] == "shape" and f["humanoid"]["missing"] == []


def test_rigged_simple_lists_what_each_garment_misses(assets_dir):
    f = describe(str(assets_dir / "RiggedSimple.glb"))
    assert f["joints"]["count"] == 4 and f["mesh"]["vertices"] > 0
    h = f["humanoid"]
    assert set(h["missing"]) >= {"arm_l", "arm_r", "leg_l", "leg_r", "neck"}
    assert h["garments_blocked"]["tshirt"] == ["arm_l", "arm_r", "neck"]
    assert h["garments_blocked"]["trousers"] == ["leg_l", "leg_r"]
    out = text(f)
    assert "garment 'cape' cannot be dressed" in out and "(MISSING)" in out


def test_builtin_matches_by_name():
    f = describe("builtin")
    assert [c["name"] for c in f["clips"]] == ["rest", "walk", "arm_raise", "turn"]
    assert f["mesh"]["height_m"] == pytest.approx(1.75, abs=1e-3)
    parts = f["humanoid"]["parts"]
    assert parts["arm_r"] == {"joints": ["upperarm_r", "forearm_r", "hand_r"], "found": "name", "why": ""}
    assert parts["neck"]["joints"] == ["neck"] and parts["head"]["joints"] == ["head"]


def test_cli_text_and_json_on_every_asset(assets_dir):
    files = sorted(p for p in assets_dir.iterdir() if p.suffix.lower() in (".glb", ".gltf", ".bvh"))
    assert len(files) >= 3
    for p in files:
        r = cli("inspect", str(p))
        assert r.returncode == 0, r.stderr
        assert r.stdout.startswith(f"{p}: ") and "joints (" in r.stdout and "garment anchors" in r.stdout
        j = cli("inspect", "--json", str(p))
        assert j.returncode == 0, j.stderr
        facts = json.loads(j.stdout)
        assert facts["file"] == str(p) and facts["joints"]["count"] == len(facts["joints"]["tree"])


@pytest.mark.parametrize("name, content, fragment", [
    ("bad.glb", b"not a glb", "bad.glb: "),
    ("bad.bvh", b"HIERARCHY\nROOT x {\n", "bad.bvh: "),
    ("empty.gltf", b"", "empty.gltf: "),
    ("scene.yaml", b"name: x\n", "not a character file"),
    ("missing.glb", None, "file not found"),
])
def test_bad_file_is_one_error_line_exit_2(tmp_path, name, content, fragment):
    p = tmp_path / name
    if content is not None:
        p.write_bytes(content)
    r = cli("inspect", str(p))
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = [l for l in r.stderr.splitlines() if l.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and str(p) in lines[0] and fragment in lines[0], r.stderr
    assert "Traceback" not in r.stderr and r.stdout == ""
