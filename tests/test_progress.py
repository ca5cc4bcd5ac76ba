"""Progress of the long stages: the stages' progress(done, total) callbacks, the progress line, the
"compiling kernels (first run only)" note and the stage lines of `run` on stderr."""
from __future__ import annotations

import io
import os
import subprocess
import sys
from pathlib import Path

from pipeline import kernel_cache
from pipeline.progress import Progress
from stages.coverage.measure import measure_coverage
from stages.hulls.fit import fit_character
from tests.toy_rig import bend_motion, bent_tube

REPO = Path(__file__).resolve().parent.parent


def test_progress_callback_takes_a_growing_total():
    s = io.StringIO()   # not a terminal: a line at every tenth
    p = Progress(1, "colliders", unit="hulls", stream=s)
    for k in range(1, 5):
        p(k, 4)
    p(5, 10)
    p.close()
    lines = s.getvalue().splitlines()
    assert lines[0].startswith("colliders: 1/4 hulls") and lines[-1].startswith("colliders: 5/10 hulls")
    assert p.total == 10


def test_disabled_progress_writes_nothing():
    s = io.StringIO()
    p = Progress(3, "x", stream=s, enabled=False)
    p(1, 3)
    p.close()
    assert s.getvalue() == ""


def test_collider_fit_and_coverage_report_their_counts():
    c = bent_tube()
    motion = bend_motion(c, [0.0, 30.0, 60.0])
    calls = []
    _, cs = fit_character(c, motion.joint_world, progress=lambda done, total: calls.append((done, total)))
    assert calls and calls[-1][0] == calls[-1][1]   # ends complete
    assert len(cs.hulls) <= calls[-1][1] <= len(cs.hulls) + len(cs.spheres)
    assert all(0 <= d <= t for d, t in calls) and [d for d, _ in calls] == sorted(d for d, _ in calls)
    frames = []
    measure_coverage(c, motion, cs, frames=[0, 1, 2], interior_samples=2000,
                     progress=lambda done, total: frames.append((done, total)))
    assert frames == [(1, 3), (2, 3), (3, 3)]


def _fake_stages(tmp_path, monkeypatch):
    pkg = tmp_path / "stages" / "sim"
    pkg.mkdir(parents=True)
    (pkg / "kern.py").write_text("@njit(cache=True)\ndef f(x):\n    return x\n")
    (pkg / "plain.py").write_text("def g():\n    pass\n")
    monkeypatch.setattr(kernel_cache, "STAGES_DIR", tmp_path / "stages")
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.delenv("NUMBA_DISABLE_JIT", raising=False)
    kernel_cache.kernel_modules.cache_clear()
    return pkg


def test_compile_note_until_the_cache_index_exists(tmp_path, monkeypatch):
    pkg = _fake_stages(tmp_path, monkeypatch)
    try:
        assert kernel_cache.uncompiled("simulation") == (1, 1)   # plain.py defines no kernel
        assert kernel_cache.uncompiled("cloth audit") == (0, 0)  # no audit_kernels.py here
        note = kernel_cache.compile_note("simulation")
        assert note is not None and note.startswith("compiling kernels, first run only: about ")
        assert kernel_cache.compile_note("no such stage") is None
        (pkg / "__pycache__").mkdir()
        (pkg / "__pycache__" / "kern.f-1.py311.nbi").write_bytes(b"")
        assert kernel_cache.uncompiled("simulation") == (0, 1)
        assert kernel_cache.compile_note("simulation") is None
    finally:
        kernel_cache.kernel_modules.cache_clear()


def test_a_stage_that_ran_to_the_end_is_not_compiling_again(tmp_path, monkeypatch):
    """A module whose kernels the scene never calls keeps no numba index (cloth contact's CCD on a slow
    clip): once the stage ran to the end, the note stops, until a kernel module is edited."""
    pkg = _fake_stages(tmp_path, monkeypatch)
    try:
        assert kernel_cache.compile_note("simulation") is not None
        kernel_cache.mark_ran("simulation")
        assert kernel_cache.uncompiled("simulation") == (0, 1)
        assert kernel_cache.compile_note("simulation") is None
        assert kernel_cache.compile_note("garments") is not None      # stamps are per stage
        stamp = kernel_cache._stamp("simulation").stat().st_mtime
        os.utime(pkg / "kern.py", (stamp + 10, stamp + 10))             # edited after the run
        assert kernel_cache.uncompiled("simulation") == (1, 1)
    finally:
        kernel_cache.kernel_modules.cache_clear()


def test_compile_note_follows_numba_cache_dir(tmp_path, monkeypatch):
    pkg = _fake_stages(tmp_path, monkeypatch)
    try:
        cache = tmp_path / "cache"
        monkeypatch.setenv("NUMBA_CACHE_DIR", str(cache))
        mirrored = cache / pkg.resolve().relative_to(pkg.resolve().anchor)
        mirrored.mkdir(parents=True)
        assert kernel_cache.compile_note("garments") is not None
        (mirrored / "kern.f-1.py311.nbi").write_bytes(b"")
        assert kernel_cache.compile_note("garments") is None
    finally:
        kernel_cache.kernel_modules.cache_clear()


def test_every_announced_stage_knows_its_kernel_modules():
    for stage in kernel_cache.STAGE_PACKAGES:
        assert stage in kernel_cache.ESTIMATE_S
        assert kernel_cache.stage_modules(stage), stage
    sim = {m.stem for m in kernel_cache.stage_modules("simulation")}
    assert "integrate" in sim and "audit_kernels" not in sim
    assert {m.stem for m in kernel_cache.stage_modules("cloth audit")} == {"audit_kernels"}


def test_run_shows_a_line_per_stage_and_the_sewing_and_simulation_progress(tmp_path):
    scene = tmp_path / "s.yaml"
    scene.write_text((REPO / "scenes" / "default.yaml").read_text())
    r = subprocess.run([sys.executable, "-m", "pipeline", "run", str(scene), "--frames", "6", "-o", str(tmp_path / "o.rrd")],
                       cwd=tmp_path, env=dict(os.environ), capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    err = r.stderr.splitlines()
    # on a first run a line says the simulation kernels compile in a second process
    starts = [l.split(" ")[0] for l in err if l.endswith(" ...") and not l.startswith("simulation kernels ")]
    assert starts == ["rig", "colliders", "collider", "maps", "garments", "simulation", "cloth", "body"], err
    assert any(l.startswith("colliders: ") and " hulls " in l for l in err), err
    assert any(l.startswith("collider coverage: ") and " frames " in l for l in err), err
    assert any(l.startswith("sewing skirt (stops when the seams close): ") and " iterations " in l for l in err), err
    assert any(l.startswith("simulation: ") for l in err), err


def test_stage_packages_name_existing_paths_and_every_kernel_module():
    """STAGE_PACKAGES names modules by path: a moved module must be renamed there too (an entry that
    names nothing is a stale one), and a kernel module beside the named ones that no stage names would
    compile unannounced."""
    stages = kernel_cache.STAGES_DIR
    for stage, entries in kernel_cache.STAGE_PACKAGES.items():
        for entry in entries:
            path = entry.lstrip("-")
            assert (stages / path).is_dir() or (stages / f"{path}.py").is_file(), (stage, entry)
    named = set().union(*(kernel_cache.stage_modules(s) for s in kernel_cache.STAGE_PACKAGES))
    dropped = {m for s, entries in kernel_cache.STAGE_PACKAGES.items() for e in entries if e.startswith("-")
               for m in kernel_cache.entry_modules(e)}
    folders = {(stages / e.lstrip("-")).parent if not (stages / e.lstrip("-")).is_dir() else stages / e.lstrip("-")
               for entries in kernel_cache.STAGE_PACKAGES.values() for e in entries}
    every = {p for f in folders for p in f.glob("*.py") if "cache=True" in p.read_text().replace(" ", "")}
    assert every - named - dropped == set()   # each folder a stage draws kernels from is accounted for
