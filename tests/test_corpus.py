"""`python -m pipeline matrix --corpus` (pipeline.corpus): the pairs it writes, how it judges a row,
and a small run end to end."""
from __future__ import annotations

import yaml

from pipeline.corpus import (IN_BODY_MAX, MEMORY_MAX_MB, SEAM_GAP_MAX, SLIDE_MAX, START_SHARE, CorpusCharacter, cases_of, character_specs, run_corpus, table,
                             verdict, write_sweep)


def _character(n_clips: int, wears: list[str]) -> CorpusCharacter:
    return CorpusCharacter("c", {"source": "gltf", "path": "/x/c.glb"}, [(f"clip{i}", 1.0 + i) for i in range(n_clips)],
                           list(wears))


def test_every_clip_and_every_kind_is_worn_once_and_scenes_start_inside_the_clip():
    for n_clips, wears in ((1, ["tshirt", "shorts", "cape"]), (5, ["tshirt", "shorts"]), (3, ["cape"])):
        c = _character(n_clips, wears)
        cases = cases_of(c)
        single = [k for k in cases if len(k["garments"]) == 1]
        assert {k["character"]["clip"] for k in single} == {name for name, _ in c.clips}
        assert {k["garments"][0]["kind"] for k in single} == set(wears)
        assert len(single) == max(n_clips, len(wears))
        for k in cases:
            duration = dict(c.clips)[k["character"]["clip"]]
            assert k["frames.start"] == round(START_SHARE * duration, 3) and 0 < k["frames.start"] < duration
            assert set(k) == {"label", "character", "frames.start", "garments"}     # no tuning keys
        outfit = [k for k in cases if len(k["garments"]) == 2]
        assert len(outfit) == (1 if {"tshirt", "shorts"} <= set(wears) else 0)
        if outfit:   # listed inner first: the shorts under the T-shirt
            assert [g["kind"] for g in outfit[0]["garments"]] == ["shorts", "tshirt"]
    full = cases_of(_character(3, ["tshirt", "cape"]), full=True)
    assert len([k for k in full if len(k["garments"]) == 1]) == 6
    assert cases_of(_character(2, [])) == []


def test_the_sweep_file_is_a_valid_sweep(tmp_path):
    from pipeline.sweep_file import load_sweep
    c = CorpusCharacter("builtin", {"source": "procedural"}, [("walk", 1.2)], ["short_skirt"])
    path = write_sweep(tmp_path, cases_of(c), frames=5, timeout=100.0)
    sw = load_sweep(path)
    assert len(sw.jobs) == 1 and sw.out == tmp_path.resolve()
    data = yaml.safe_load(path.read_text())
    assert data["base"] == {"frames": {"count": 5}}


def test_verdict_names_each_target_missed():
    ok = {"status": "ok", "particles": 1000, "in_body_max": 0, "crossings_self_max": 0, "crossings_between_max": 0,
          "strain_p99_pct": 4.0}
    assert verdict(ok) == []
    assert verdict({**ok, "in_body_max": int(IN_BODY_MAX * 1000)}) == []
    assert "particles in the body" in verdict({**ok, "in_body_max": 6})[0]
    assert "3 cloth edges" in verdict({**ok, "crossings_self_max": 1, "crossings_between_max": 2})[0]
    assert "strain p99 10.5 %" in verdict({**ok, "strain_p99_pct": 10.5})[0]
    assert verdict({**ok, "seam_gap_mm": SEAM_GAP_MAX}) == []
    assert verdict({**ok, "seam_gap_mm": 2.7}) == ["seams 2.7 mm open when joined"]
    assert verdict({**ok, "floor_cm": 0.0}) == []     # a hem on the floor
    assert verdict({**ok, "floor_cm": -255.7}) == []  # under it: the floor is no verdict (none in that scene)
    assert verdict({**ok, "floor_cm": 0.2, "slide_cm": SLIDE_MAX}) == []
    # a top that slid off the body onto the floor
    assert verdict({**ok, "floor_cm": 0.2, "slide_cm": 87.4}) == [
        "slid 87 cm off where it was dressed (waistband / collar from its skin)"]
    assert verdict({**ok, "peak_memory_mb": MEMORY_MAX_MB}) == []
    assert verdict({**ok, "peak_memory_mb": 8400.0}) == [f"peak memory 8400 MB (limit {MEMORY_MAX_MB:.0f} MB)"]
    failed = verdict({"status": "failed", "failure": "sewing", "message": "sewing did not close seam a / b"})
    assert failed == ["sewing: sewing did not close seam a / b"]


def test_every_character_file_of_the_assets_is_listed(assets_dir):
    assets = assets_dir
    labels = [label for label, _ in character_specs(assets)]
    assert labels[0] == "builtin" and "CesiumMan" in labels and "cmu_131_01_walk" in labels
    files = {p.stem for p in assets.iterdir() if p.suffix.lower() in (".glb", ".gltf", ".bvh")}
    assert set(labels[1:]) == files


def test_a_small_corpus_runs_end_to_end(tmp_path):
    """The built-in character's clips in a short skirt, 2 frames each: a row per clip with its verdict."""
    rows = run_corpus(tmp_path, frames=2, characters=["builtin"], kinds=["short_skirt"], jobs=1, with_patterns=False,
                      echo=lambda *a: None)
    assert len(rows) >= 2 and all(r["character"] == "builtin" for r in rows)
    assert all(r["status"] == "ok" for r in rows)
    # each job's own peak memory (the worker's high-water mark is reset per job): a real figure, in range
    assert all(100 < r["peak_memory_mb"] < MEMORY_MAX_MB for r in rows)
    assert any(r["frames"] > 2 for r in rows)   # a blend-in from the rest pose before the clip's frames
    text = table(rows)
    assert text.count("| builtin |") == len(rows) and f"of {len(rows)} pairs pass" in text
    assert (tmp_path / "table.csv").is_file()


def test_every_garmentcode_pattern_is_a_scene_on_every_character(tmp_path):
    import pytest

    from pipeline.corpus import pattern_cases, pattern_files
    from pipeline.schema import SceneError
    for sub in ("examples/a_specification.json", "sampled/b_s1/b_s1_specification.json", "sampled/b_s1/other.json"):
        (tmp_path / "garmentcode" / sub).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / "garmentcode" / sub).write_text("{}")
    files = pattern_files(tmp_path / "garmentcode")
    assert [f.name for f in files] == ["a_specification.json", "b_s1_specification.json"]
    assert [f.name for f in pattern_files(tmp_path / "garmentcode", ["b_s1"])] == ["b_s1_specification.json"]
    with pytest.raises(SceneError, match="'nope' not found"):
        pattern_files(tmp_path / "garmentcode", ["nope"])
    for n_clips in (1, 3):
        c = _character(n_clips, [])
        cases = pattern_cases(c, files)
        assert len(cases) == 2 and len({k["label"] for k in cases}) == 2
        for k, f in zip(cases, files):
            assert k["garments"] == [{"type": "garmentcode", "name": f.name[:-len("_specification.json")],
                                      "path": str(f.resolve())}]           # nothing but the path: no tuning
            duration = dict(c.clips)[k["character"]["clip"]]
            assert 0 < k["frames.start"] < duration
        assert {k["character"]["clip"] for k in cases} == {name for name, _ in c.clips[:2]}
    # the sweep file takes them as they are
    from pipeline.sweep_file import load_sweep
    c = CorpusCharacter("builtin", {"source": "procedural"}, [("walk", 1.2)], [])
    assert len(load_sweep(write_sweep(tmp_path / "s", pattern_cases(c, files), frames=5, timeout=10.0)).jobs) == 2


def test_the_outfit_is_asked_for_by_name_and_an_unknown_kind_is_one_error(tmp_path):
    # `matrix --corpus --garment outfit` wrote a case of kind 'outfit', which the sweep refused
    import pytest

    from pipeline.schema import SceneError
    c = _character(3, ["tshirt", "shorts", "cape"])
    only = cases_of(c, kinds=[], outfit=True)
    assert [[g["kind"] for g in k["garments"]] for k in only] == [["shorts", "tshirt"]]
    assert {k["garments"][0]["kind"] for k in cases_of(c, kinds=["cape"], outfit=False)} == {"cape"}
    with pytest.raises(SceneError, match="'robe' is not a built-in kind"):
        run_corpus(tmp_path, frames=2, characters=["builtin"], kinds=["robe"], jobs=1, with_patterns=False,
                   echo=lambda *a: None)


def test_a_folder_of_the_users_own_patterns_replaces_the_assets_and_a_bad_one_is_one_error(tmp_path):
    """matrix --corpus --patterns DIR: the corpus of a user's own patterns (a folder that is not there, or
    holds none, is one error naming it, before anything runs)."""
    import pytest

    from pipeline.schema import SceneError
    with pytest.raises(SceneError, match=r"--patterns: .*nowhere: no such folder"):
        run_corpus(tmp_path / "out", frames=2, characters=["builtin"], kinds=[], jobs=1,
                   pattern_dir=tmp_path / "nowhere", echo=lambda *a: None)
    (tmp_path / "empty").mkdir()
    with pytest.raises(SceneError, match=r"--patterns: .*empty: no \*_specification.json"):
        run_corpus(tmp_path / "out", frames=2, characters=["builtin"], kinds=[], jobs=1,
                   pattern_dir=tmp_path / "empty", echo=lambda *a: None)
    assert not (tmp_path / "out").exists()


def test_the_users_patterns_are_the_scenes_written(tmp_path, monkeypatch):
    import pipeline.sweep
    own = tmp_path / "mine" / "tee_x"
    own.mkdir(parents=True)
    (own / "tee_x_specification.json").write_text("{}")
    seen = {}

    def fake_sweep(path, **kw):
        seen["doc"] = yaml.safe_load(path.read_text())
        return None, []
    monkeypatch.setattr(pipeline.sweep, "run_sweep", fake_sweep)
    run_corpus(tmp_path / "out", frames=2, characters=["builtin"], kinds=[], jobs=1, pattern_dir=tmp_path / "mine",
               echo=lambda *a: None)
    assert [[g["path"] for g in k["garments"]] for k in seen["doc"]["cases"]] == \
        [[str((own / "tee_x_specification.json").resolve())]]


def test_case_labels_keep_the_garment_whole_and_tell_every_pair_apart():
    """The CMU walk's clip is named as its file: its two dresses were both 'cmu_131_01_walk-cmu_131_01_walk-gc-dress'."""
    from pipeline.corpus import LABEL_MAX, case_label, unique_labels
    a = case_label("cmu_131_01_walk", "cmu_131_01_walk", "gc-dress_pencil")
    b = case_label("cmu_131_01_walk", "cmu_131_01_walk", "gc-dress_s1001")
    assert (a, b) == ("cmu_131_01_walk-gc-dress_pencil", "cmu_131_01_walk-gc-dress_s1001")
    assert case_label("kenney_mini_female_b", "attack-kick-right", "short_skirt").endswith("-short_skirt")
    assert case_label("builtin", "walk", "tshirt") == "builtin-walk-tshirt"
    long = "gc-" + "x" * 50
    labels = [k["label"] for k in unique_labels([{"label": case_label("c", "walk", long + s)} for s in "ab"])]
    assert len(set(labels)) == 2 and all(len(x) <= LABEL_MAX for x in labels)
