"""`python -m pipeline sweep`: jobs from a grid, the metrics table (CSV = Parquet), resume and
--retry-failed, failure labels (sewing, timeout) that do not stop the sweep, geometry kept for a
failed job, one-line errors for bad sweep files, and the same table on a local Ray cluster.

The sweeps here are 2 x 2 jobs of 2 frames on the built-in character (about 5 s a job on 2 cores).
`GARMENT_SWEEP_FULL=1` also runs scenes/sweep_example.yaml (3 characters x 4 garments x 2 seeds) on
the process pool and on a local Ray cluster (about 10 minutes on the 2-core machine)."""
from __future__ import annotations

import json
import os
import textwrap
from pathlib import Path

import numpy as np
import pytest

from pipeline import sweep as S
from pipeline import sweep_file as F

REPO = Path(__file__).resolve().parent.parent

SWEEP = """\
base:
  name: tiny
  character: {source: procedural, clip: walk}
  frames: {count: 2, blend_in: 0}   # the sweep's mechanics: dressed on the clip's first pose, no blend frames
  colliders: {report_every: 0}
  garments:
    - {type: pattern, name: garment, kind: short_skirt}
  output: {export: [npz]}
timeout: 600
jobs: 2
warm_up: %s
grid:
  garments[0].kind: [short_skirt, shorts]
  garments[0].sewing:
    normal: {}
    tight: {tolerance: 1.0e-5, max_iterations: 2}
"""


def _run(path, out, **kw):
    notes = []
    sw, rows = S.run_sweep(path, output=out, progress=False, echo=notes.append, **kw)
    return sw, rows, notes


@pytest.fixture(scope="module")
def pool(tmp_path_factory):
    d = tmp_path_factory.mktemp("sweep")
    f = d / "tiny.yaml"
    f.write_text(SWEEP % "false")
    sw, rows, notes = _run(f, d / "out")
    return f, d / "out", sw, rows, notes


def test_jobs_rows_and_failure_labels(pool):
    f, out, sw, rows, notes = pool
    assert [r["job"] for r in rows] == [j.id for j in sw.jobs] and len(rows) == 4
    by = {(r["garments[0].kind"], r["garments[0].sewing"]): r for r in rows}
    assert set(by) == {(k, s) for k in ("short_skirt", "shorts") for s in ("normal", "tight")}
    for kind in ("short_skirt", "shorts"):
        ok, bad = by[(kind, "normal")], by[(kind, "tight")]
        assert ok["status"] == "ok" and ok["failure"] == "" and ok["message"] == ""
        assert ok["frames"] == ok["frames_done"] == 2 and ok["particles"] > 100
        assert ok["in_colliders_max"] == 0 and ok["in_body_max"] is not None
        assert ok["strain_mean_pct"] > 0 and ok["strain_p99_pct"] >= ok["strain_mean_pct"]
        assert ok["crossings_self_max"] is not None and 0 < ok["seam_gap_mm"] < 4
        assert ok["wall_s"] > 0 and ok["frames_per_s"] > 0
        job = out / "jobs" / ok["job"]
        assert (job / ok["recording"]).is_file() and ok["recording"].endswith(".rrd")
        assert {Path(p).name for p in ok["exports"].split(";")} == {"tiny.garment.npz", "tiny.body.npz"}
        # the failed job: labelled, its sewing left as it was (geometry kept), the others went on
        assert bad["status"] == "failed" and bad["failure"] == "sewing"
        assert "sewing did not close seam" in bad["message"] and bad["seam_gap_mm"] > 0.01
        job = out / "jobs" / bad["job"]
        assert (job / bad["recording"]).is_file() and bad["recording"].endswith(".partial.rrd")
        g = np.load(job / "export" / "tiny.garment.npz")
        assert g["vertices_seq"].shape[0] == 1 and np.isfinite(g["vertices_seq"]).all()
        assert "partial" in json.loads(str(g["meta"]))["source"]
        assert "sewing" in (job / "log.txt").read_text()


def test_csv_and_parquet_read_back_equal(pool):
    import pyarrow.parquet as pq
    f, out, sw, rows, notes = pool
    parquet = pq.read_table(out / "table.parquet").to_pylist()
    csv_rows = S.read_csv_table(out / "table.csv")
    assert parquet == csv_rows == rows
    assert list(parquet[0]) == S.columns(sw)


def test_resume_skips_finished_jobs_and_retry_failed_reruns_the_failed(pool):
    f, out, sw, rows, notes = pool
    before = {r["job"]: (out / "jobs" / r["job"] / "row.json").read_text() for r in rows}
    sw2, rows2, notes2 = _run(f, out)
    assert "4 finished before, skipped; 0 to run" in notes2[-1]
    assert rows2 == rows
    assert {j: (out / "jobs" / j / "row.json").read_text() for j in before} == before
    sw3, rows3, notes3 = _run(f, out, retry_failed=True, jobs=2)
    assert "2 finished before, skipped; 2 to run" in notes3[-1]
    again = {r["job"]: r for r in rows3}
    for r in rows:
        if r["status"] == "ok":
            assert (out / "jobs" / r["job"] / "row.json").read_text() == before[r["job"]]
        else:   # ran again: the same failure, a new row
            assert again[r["job"]]["failure"] == "sewing"
            assert S.comparable([again[r["job"]]]) == S.comparable([r])


def test_same_table_on_a_local_ray_cluster(pool, tmp_path):
    pytest.importorskip("ray", reason="Ray is not installed (the optional extra: pip install -e '.[ray]')")
    f, out, sw, rows, notes = pool
    g = tmp_path / "tiny.yaml"
    g.write_text(SWEEP % "true")   # Ray's workers warm up on their first task
    sw2, rows2, notes2 = _run(g, tmp_path / "out", ray_address=None, jobs=2)
    assert [r["job"] for r in rows2] == [r["job"] for r in rows]
    assert S.comparable(rows2) == S.comparable(rows)


def test_a_job_past_its_timeout_is_labelled_and_the_sweep_goes_on(tmp_path):
    f = tmp_path / "slow.yaml"
    f.write_text(SWEEP.replace("timeout: 600", "timeout: 0.5").replace("jobs: 2", "jobs: 1") % "false")
    sw, rows, notes = _run(f, tmp_path / "out")
    assert len(rows) == 4   # every job has its row: none stopped the sweep
    for r in rows:
        assert r["status"] == "failed" and r["failure"] == "timeout", r
        assert "longer than 0.5 s" in r["message"]
        assert (tmp_path / "out" / "jobs" / r["job"] / "row.json").is_file()


def test_a_killed_worker_leaves_a_timeout_row_and_its_partial_recording(tmp_path):
    spec = {"id": "j-1", "dir": str(tmp_path / "j-1"), "labels": {"seed": "0"}, "timeout": 2.0}
    (tmp_path / "j-1").mkdir()
    (tmp_path / "j-1" / ".j-1.rrd.tmp-123").write_bytes(b"partial")
    row = S.timeout_row(spec, 14.2, "the worker was killed")
    assert row["failure"] == "timeout" and "killed" in row["message"]
    assert (tmp_path / "j-1" / "j-1.partial.rrd").read_bytes() == b"partial"
    assert json.loads((tmp_path / "j-1" / "row.json").read_text()) == row


def test_job_ids_are_stable_and_keys_parse():
    assert F.parse_key("garments[0].options.ease") == ["garments", 0, "options", "ease"]
    assert F.parse_key("character.body") == ["character", "body"]
    for bad in ("", "a..b", "garments[x]", "0abc"):
        with pytest.raises(ValueError):
            F.parse_key(bad)
    a = F.job_id(["tshirt", "0"], {"garments[0].kind": "tshirt", "seed": 0})
    assert a == F.job_id(["tshirt", "0"], {"seed": 0, "garments[0].kind": "tshirt"})
    assert a != F.job_id(["tshirt", "0"], {"garments[0].kind": "tshirt", "seed": 1})
    data = {"garments": [{"kind": "a"}]}
    F._set(data, ["garments", 0, "options", "ease"], 0.1, "garments[0].options.ease")
    assert data == {"garments": [{"kind": "a", "options": {"ease": 0.1}}]}
    with pytest.raises(ValueError, match="out of range"):
        F._set(data, ["garments", 2, "kind"], "b", "garments[2].kind")


BASE = ("base: {character: {source: procedural, clip: walk}, frames: {count: 2}, "
        "garments: [{type: pattern, name: g, kind: short_skirt}]}\n")


@pytest.mark.parametrize("text, fragment", [
    (BASE + "grid:\n  garments[0].kind: [short_skirt, tshirtt]\n",
     "bad.yaml:3:35: grid 'garments[0].kind' = 'tshirtt' (job tshirtt-"),
    (BASE + "grid:\n  garments[0].kind: [short_skirt, tshirtt]\n", "is not one of tshirt, short_skirt"),
    (BASE + "grid:\n  seed: [0, -1]\n", "grid 'seed' = -1 (job 1-"),
    (BASE + "grid:\n  garments[1].kind: [shorts]\n", "index 1 is out of range"),
    (BASE + "grid:\n  garments[0].options.eas: [0.1]\n", "not an option of kind 'short_skirt' (did you mean 'ease'?); options:"),
    (BASE + "grid:\n  character.clip: [walk, wlk]\n", "'wlk' is not a clip of 'procedural'"),
    (BASE + "grid:\n  seed: 3\n", "expected a non-empty list of values"),
    (BASE + "grid:\n  output.path: [x.rrd]\n", "set by the sweep"),
    (BASE + "gird:\n  seed: [1]\n", "bad.yaml:2:1: gird: unknown key 'gird'; did you mean 'grid'?"),
    (BASE + "timeout: -3\n", "timeout: -3.0 is out of range"),
    (BASE + "cases:\n  - {seed: 1}\n  - {sed: 2}\n", "cases[1] ('case1') 'sed' = 2"),
    ("base: nothere.yaml\n", "base: scene file not found"),
    ("grid: {seed: [1]}\n", "base: missing required key"),
    ("base: {}\ngrid: {seed: [1]\n", "YAML syntax error"),
])
def test_bad_sweep_files_are_one_line_exit_2_before_any_job(tmp_path, capsys, monkeypatch, text, fragment):
    from pipeline.cli import main
    monkeypatch.chdir(tmp_path)
    (tmp_path / "bad.yaml").write_text(text)
    code = main(["sweep", "bad.yaml", "-o", str(tmp_path / "out"), "-q"])
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: bad.yaml"), err
    assert fragment in lines[0], err
    assert not (tmp_path / "out").exists()   # checked before anything runs


def test_missing_ray_is_one_line(tmp_path, capsys, monkeypatch):
    import builtins
    real = builtins.__import__

    def no_ray(name, *a, **k):
        if name == "ray" or name.startswith("ray."):
            raise ImportError("No module named 'ray'")
        return real(name, *a, **k)
    monkeypatch.setattr(builtins, "__import__", no_ray)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "s.yaml").write_text(BASE + "grid: {seed: [1]}\n")
    from pipeline.cli import main
    assert main(["sweep", "s.yaml", "--ray", "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and 'pip install -e ".[ray]"' in err


@pytest.mark.skipif(os.environ.get("GARMENT_SWEEP_FULL") != "1",
                    reason="the 24-job example sweep on the pool and on Ray takes about 10 minutes on 2 cores; "
                           "set GARMENT_SWEEP_FULL=1 to run it")
def test_example_sweep_same_table_on_the_pool_and_on_ray(tmp_path, assets_dir):
    pytest.importorskip("ray", reason="Ray is not installed (the optional extra: pip install -e '.[ray]')")
    sw, rows, _ = _run(REPO / "scenes" / "sweep_example.yaml", tmp_path / "pool")
    sw2, rows2, _ = _run(REPO / "scenes" / "sweep_example.yaml", tmp_path / "ray", ray_address=None)
    assert len(rows) == len(sw.jobs) == 24
    assert S.comparable(rows2) == S.comparable(rows)


def test_a_simulation_stopped_midway_keeps_the_frames_it_did():
    """simulate(partial=...): what a run stopped from outside (a sweep's timeout) keeps."""
    from stages.garments.simple import rectangle_cloth
    from stages.garments.types import attach_indices, bind_pose, build_garment
    from stages.sim import SimParams, simulate
    from stages.sim.scenes import toy_character, toy_motion
    tet = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]) * 0.01 - 5.0
    ch = toy_character(tet, np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]], np.int32))
    mo = toy_motion(70)
    x, tri = rectangle_cloth(0.5, 0.5, 8, 8, center=(0, 1, 0), normal=(0, 0, 1))
    top = np.flatnonzero(np.isclose(x[:, 1], x[:, 1].max()))
    g = build_garment("flag", x, tri, attachments=[attach_indices(top, "root")], bind=bind_pose(ch, mo))
    params = SimParams(body_audit=False)
    full = simulate(ch, mo, None, None, [g], params)
    partial: dict = {}
    reached = []

    class Stop(BaseException):
        pass

    def progress(done, total):   # something that stops the run between two chunks
        reached.append(done)
        if done > 1:
            raise Stop
    with pytest.raises(Stop):
        simulate(ch, mo, None, None, [g], params, progress=progress, partial=partial)
    done = reached[-1]
    assert 1 < done < 70
    part = partial["result"]()
    assert part.garments[0].positions.shape[0] == done
    np.testing.assert_array_equal(part.garments[0].positions, full.garments[0].positions[:done])


def test_a_job_that_ignores_its_deadline_has_its_worker_killed_and_the_sweep_goes_on(tmp_path, monkeypatch):
    """The hard timeout: SIGALRM blocked in this process is blocked in the workers it spawns too, so
    the jobs' own deadline never fires, as in a job stuck in one long kernel call."""
    import signal
    monkeypatch.setattr(S, "_grace", lambda timeout: 1.0)
    f = tmp_path / "stuck.yaml"
    # the tight sewing never closes and goes on for 10,000 rounds: both jobs outlive the deadline on any
    # machine (with 2 rounds the tight job ended 'sewing' before the kill on a quiet one)
    f.write_text(SWEEP.replace("timeout: 600", "timeout: 1").replace("jobs: 2", "jobs: 1")
                 .replace("max_iterations: 2}", "max_iterations: 10000}")
                 .replace("  garments[0].kind: [short_skirt, shorts]\n", "  garments[0].kind: [short_skirt]\n") % "false")
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGALRM})
    try:
        sw, rows, notes = _run(f, tmp_path / "out")
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)
    assert len(rows) == 2   # the worker killed for the first job was replaced for the second
    for r in rows:
        assert r["failure"] == "timeout" and "killed" in r["message"], r
        assert json.loads((tmp_path / "out" / "jobs" / r["job"] / "row.json").read_text())["failure"] == "timeout"


def test_a_timeout_raised_inside_a_kernel_call_is_labelled_timeout():
    """Numba wraps an exception raised while it unpickles an object during a kernel call in
    SystemError ("returned a result with an exception set"); the deadline is still the cause."""
    from pipeline import sweep_job as J
    try:
        try:
            raise J.JobTimeout("the job ran longer than 0.5 s")
        except J.JobTimeout as inner:
            raise SystemError("CPUDispatcher(...) returned a result with an exception set") from inner
    except SystemError as err:
        wrapped = err
    assert J._failure(wrapped) == "timeout" and "0.5 s" in str(J._timeout_in(wrapped))
    assert J._failure(SystemError("something else")) == "crash"


def test_a_timeout_that_library_code_turned_into_another_error_is_still_a_timeout(tmp_path, monkeypatch):
    # numpy's structured-array comparison catches the deadline's exception and raises a TypeError
    # without chaining it: past the deadline, whatever stopped the job is the timeout
    import pipeline.run

    def swallowing_run(scene, **kw):
        try:
            while True:
                pass
        except BaseException:   # cleared, as C code clears it: the new error has no context
            pass
        raise TypeError("Cannot compare structured arrays unless they have a common dtype")

    monkeypatch.setattr(pipeline.run, "run_scene", swallowing_run)
    text = textwrap.dedent(SWEEP.split("timeout:")[0].replace("base:\n", ""))
    spec = {"id": "j-1", "text": text, "source": "slow.yaml[j-1]", "base_dir": str(tmp_path),
            "dir": str(tmp_path / "j-1"), "labels": {}, "timeout": 0.2}
    row = S.run_job(spec)
    assert row["status"] == "failed" and row["failure"] == "timeout", row
    assert "longer than 0.2 s" in row["message"]
