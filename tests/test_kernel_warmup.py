"""pipeline.kernel_warmup: the first run compiles the simulation's kernels in a second process.

- the tiny scene compiles every kernel signature the default scene's sewing, simulation and cloth
  audit call from Python (else the run would compile them again after waiting);
- nothing starts on a warm cache; a killed or interrupted run leaves no compile process behind.
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

from pipeline import kernel_cache, kernel_warmup

REPO = Path(__file__).resolve().parents[1]

# prints {kernel: [signatures]} of every numba dispatcher in stages.sim / stages.maps that gained a
# signature while `body` ran (the dispatchers called from Python: loading from the cache adds one)
_SIGNATURES = """
import json, sys
import stages.sim, stages.sim.simulate, stages.sim.audit, stages.maps.build, stages.coverage.kernels
from numba.core.registry import CPUDispatcher

def dispatchers():
    seen = {}
    for name, mod in list(sys.modules.items()):
        if name.startswith(("stages.sim", "stages.maps", "stages.affine", "stages.coverage")):
            for v in vars(mod).values():
                if isinstance(v, CPUDispatcher):
                    seen[id(v)] = v
    from stages.jit import _PARALLEL
    for v in _PARALLEL.values():
        seen[id(v)] = v
    return list(seen.values())

def snapshot():
    return {f"{d.py_func.__module__}.{d.py_func.__qualname__}": {str(s) for s in d.signatures} for d in dispatchers()}

before = snapshot()
{body}
after = snapshot()
print(json.dumps({k: sorted(v - before.get(k, set())) for k, v in after.items() if v - before.get(k, set())}))
"""

_REAL_RUN = """
from pipeline.run import run_scene
from pipeline.scene import load_scene
state = {{}}
def on_stage(name):
    if name.startswith("collider coverage"):
        global before
        before = snapshot()
run_scene(load_scene("scenes/default.yaml"), output={out!r}, frames=3, progress=False, on_stage=on_stage)
"""

_WARMUP = """
from pipeline.run import background_warmup
from pipeline.scene import load_scene
from pipeline.kernel_warmup import warm_coverage, warm_simulation
bg = background_warmup(load_scene("scenes/default.yaml"), True)
request = dict(bg.request)
if request.pop("coverage"):
    warm_coverage(request["threads"])
warm_simulation(**request)
"""


def _signatures(body: str) -> dict:
    out = subprocess.run([sys.executable, "-c", _SIGNATURES.replace("{body}", body)], cwd=REPO,
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_the_tiny_scene_compiles_what_the_default_scene_calls_after_the_colliders(tmp_path):
    """Every kernel signature the default scene calls from the coverage stage on (3 frames) is one
    the warm-up calls too: with the warm-up's cache the run compiles nothing after the colliders."""
    # the warm-up first: a signature it misses is one the run then compiles or loads itself
    warm = _signatures(_WARMUP)
    real = _signatures(_REAL_RUN.format(out=str(tmp_path / "r.rrd")))
    assert real, "the run called no simulation kernel from Python?"
    missing = {k: sorted(set(v) - set(warm.get(k, []))) for k, v in real.items() if set(v) - set(warm.get(k, []))}
    assert not missing, f"the warm-up does not compile: {missing}"


def test_no_background_compile_on_a_warm_cache_one_core_or_when_turned_off(monkeypatch):
    monkeypatch.delenv("NUMBA_DISABLE_JIT", raising=False)
    monkeypatch.delenv("GARMENT_BACKGROUND_COMPILE", raising=False)
    monkeypatch.setattr(kernel_cache, "uncompiled", lambda stage: (3, 3))
    monkeypatch.setattr(kernel_warmup, "cores", lambda: 2)
    monkeypatch.setattr(kernel_warmup, "no_idle_core", lambda: False)
    assert kernel_warmup.needed()
    monkeypatch.setattr(kernel_warmup, "no_idle_core", lambda: True)     # a loaded machine
    assert not kernel_warmup.needed()
    monkeypatch.setenv("GARMENT_BACKGROUND_COMPILE", "1")                 # asked for all the same
    assert kernel_warmup.needed()
    monkeypatch.setenv("GARMENT_BACKGROUND_COMPILE", "0")
    assert not kernel_warmup.needed()
    monkeypatch.delenv("GARMENT_BACKGROUND_COMPILE")
    monkeypatch.setattr(kernel_warmup, "cores", lambda: 1)
    assert not kernel_warmup.needed()
    monkeypatch.setattr(kernel_warmup, "cores", lambda: 2)
    monkeypatch.setattr(kernel_cache, "uncompiled", lambda stage: (0, 3))
    with kernel_warmup.BackgroundCompile({"threads": 1}) as bg:
        assert not bg.started and not bg.running()
        assert bg.wait() is None
    with kernel_warmup.BackgroundCompile(None) as bg:    # a run that did not ask for it
        assert not bg.started


def _alive(pid: int) -> bool:
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except FileNotFoundError:
        return False
    return "\nState:\tZ" not in status      # a zombie has exited


def _wait_gone(pid: int, seconds: float = 10.0) -> bool:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if not _alive(pid):
            return True
        time.sleep(0.1)
    return False


def _children(pid: int) -> list[int]:
    try:
        return [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except FileNotFoundError:
        return []


_START_AND_SLEEP = """
import time
from pipeline.kernel_warmup import BackgroundCompile
from stages.sim import SimParams
bg = BackgroundCompile(dict(params=SimParams.preset("default"), threads=1)).__enter__()
print(bg.proc.pid if bg.started else -1, flush=True)
time.sleep(120)
"""


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs Linux /proc")
@pytest.mark.skipif(kernel_warmup.cores() < 2, reason="one core: no background compile")
def test_a_killed_run_leaves_no_compile_process(tmp_path):
    """The run is killed (SIGKILL: no cleanup at all): its compile process notices and exits."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}   # empty: the compile starts
    env["GARMENT_BACKGROUND_COMPILE"] = "1"     # whatever the machine's load
    parent = subprocess.Popen([sys.executable, "-c", _START_AND_SLEEP], cwd=REPO, env=env, stdout=subprocess.PIPE,
                              text=True)
    try:
        child = int(parent.stdout.readline())
        assert child > 0, "no background compile started on an empty cache"
        assert _alive(child)
        parent.kill()
        parent.wait(10)
        assert _wait_gone(child), "the compile process outlived its killed parent"
    finally:
        if parent.poll() is None:
            parent.kill()


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs Linux /proc")
@pytest.mark.skipif(kernel_warmup.cores() < 2, reason="one core: no background compile")
def test_ctrl_c_stops_the_run_and_its_compile_process(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    env["GARMENT_BACKGROUND_COMPILE"] = "1"     # whatever the machine's load
    out = tmp_path / "r.rrd"
    # Ctrl-C as from a terminal: a test session started in the background (`cmd &`, nohup) has SIGINT
    # ignored, the run would inherit that and finish (seen in a CI run started that way)
    run = subprocess.Popen([sys.executable, "-m", "pipeline", "run", "scenes/default.yaml", "-q", "-o", str(out)],
                           cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                           preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        child = None
        end = time.monotonic() + 60
        while child is None and time.monotonic() < end and run.poll() is None:
            kids = _children(run.pid)
            child = kids[0] if kids else None
            time.sleep(0.05)
        assert child is not None, "no background compile started on an empty cache"
        time.sleep(1.0)
        # Python ignores a KeyboardInterrupt raised inside a finalizer (__del__, of which numba's
        # compile runs many): as a user would, press Ctrl-C again until the run stops
        end = time.monotonic() + 90
        while run.poll() is None and time.monotonic() < end:
            run.send_signal(signal.SIGINT)
            try:
                run.wait(3)
            except subprocess.TimeoutExpired:
                pass
        _, err = run.communicate(timeout=30)
        assert run.returncode == 130, err[-2000:]
        assert _wait_gone(child, 2.0), "the compile process outlived the interrupted run"
        assert not out.exists()
    finally:
        if run.poll() is None:
            run.kill()


@pytest.mark.skipif(kernel_warmup.cores() < 2, reason="one core: no background compile")
def test_a_compile_that_does_not_finish_in_time_is_stopped(tmp_path, monkeypatch):
    """The run stops waiting after WAIT_LIMIT_S (then compiles for itself), with a warning, once."""
    import warnings

    from stages.sim import SimParams
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))     # empty: the compile starts
    monkeypatch.setenv("GARMENT_BACKGROUND_COMPILE", "1")
    monkeypatch.setattr(kernel_warmup, "WAIT_LIMIT_S", 0.5)
    with kernel_warmup.BackgroundCompile(dict(params=SimParams.preset("default"), threads=1)) as bg:
        assert bg.started
        with pytest.warns(RuntimeWarning, match="did not finish"):
            bg.wait_simulation()
        assert not bg.running() and not bg.simulated
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            bg.wait()          # already reported: no second warning


@pytest.mark.parametrize("idle_share,cpus,busy", [(0.5, 2, False), (0.3, 2, True), (0.05, 4, True), (0.25, 4, False)])
def test_an_idle_core_is_read_from_the_cpu_counters(monkeypatch, idle_share, cpus, busy):
    """no_idle_core from two /proc/stat samples: idle jiffies / total x CPUs below 3/4 of a core."""
    samples = iter([(0.0, 0.0), (idle_share * 1000.0, 1000.0)])
    monkeypatch.setattr(kernel_warmup, "_cpu_times", lambda: next(samples))
    monkeypatch.setattr(kernel_warmup, "IDLE_SAMPLE", 0.0)
    monkeypatch.setattr(kernel_warmup.os, "cpu_count", lambda: cpus)
    assert kernel_warmup.no_idle_core() is busy
