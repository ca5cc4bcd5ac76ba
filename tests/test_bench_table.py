"""`bench` output: the short table from a results dict (no benchmark is run here)."""
from __future__ import annotations

import json

from pipeline import bench
from pipeline.bench_table import rows, table

RESULTS = {
    "machine": {"cpu": "test cpu", "cores": 2, "python": "3.11", "load_average": [1.0, 1.0, 1.0]},
    "sim": {"machine": {"cpus": 2}, "drape_default": {"preset": "default", "frames_per_s": 612.3, "steps_per_s": 9000.0},
            "walk_paper": {"skipped": "no assets"}, "table": "| md |", "bench_wall_s": 12.5},
    "obstacles": {"steps_per_s_total": 865.2, "candidate_pairs_per_traversal": 1267, "brute_pairs_per_pass": 150000},
    "coverage": {"CesiumMan": {"default": {"coverage_min_pct": 99.5, "excess_p95_cm": 2.1}}},
}


def test_rows_pick_the_headline_figures_with_targets():
    r = {what: (fig, target) for what, fig, target in rows(RESULTS)}
    drape = next(k for k in r if "drape default" in k)
    assert r[drape] == ("612 frames/s, 9,000 sub-steps/s", ">= 500 frames/s (issue 15)")
    assert r["sim: walk_paper"][0] == "skipped: no assets"
    assert r["obstacles: candidate pairs per traversal (brute force)"][0] == "1,267 (150,000)"
    assert r["coverage: CesiumMan default"] == ("99.50 %, excess p95 2.1 cm", "100 % covered")
    assert r["sim: bench wall time"][0] == "12.5 s"


def test_table_is_short_and_aligned():
    t = table(RESULTS).splitlines()
    assert t[0].startswith("machine: test cpu, 2 cores") and t[1].split()[:3] == ["what", "figure", "target"]
    assert len(t) == 3 + len(rows(RESULTS)) < 20
    col = t[1].index("figure")
    assert all(line[col - 2:col] == "  " for line in t[2:])


def test_empty_and_odd_results_give_a_table_without_rows():
    assert rows({"machine": {}, "hulls": {"cesium_man": "skipped: not found"}, "maps": {}}) == []
    assert "what" in table({})


def test_run_benchmarks_prints_the_table_or_the_dict(monkeypatch, capsys, tmp_path):
    import types
    fake = types.SimpleNamespace(run_benchmark=lambda: (print("inside the bench"),
                                                        {"steps_per_s_total": 10.0, "candidate_pairs_per_traversal": 1,
                                                         "brute_pairs_per_pass": 2})[1])
    monkeypatch.setitem(__import__("sys").modules, "pipeline.benches.obstacles", fake)
    out = tmp_path / "b.json"
    bench.run_benchmarks(["obstacles"], output=str(out))
    cap = capsys.readouterr()
    line = next(l for l in cap.out.splitlines() if l.startswith("obstacles: cloth on a table, steps/s"))
    assert line.split()[-2:] == ["10", "-"]
    assert "inside the bench" not in cap.out and "inside the bench" in cap.err
    assert json.loads(out.read_text())["obstacles"]["steps_per_s_total"] == 10.0
    bench.run_benchmarks(["obstacles"], output="-")
    cap = capsys.readouterr()
    assert json.loads(cap.out)["obstacles"]["brute_pairs_per_pass"] == 2
