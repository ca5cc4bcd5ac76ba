"""Compile the simulation's kernels in a second process while the first stages run (first run only).

On an empty numba cache the kernels of sewing, the simulation and the cloth audit take about half of
the first run's compiling, and the stages before them (rig, colliders, coverage, maps) keep one core
busy with their own. `BackgroundCompile` starts `python -m pipeline.kernel_warmup`, which measures
the collider coverage of a tiny character (one convex hull) and simulates a tiny scene (a 4 x 4
cloth over that hull, 2 frames) with the scene's simulation settings: that compiles the same
kernels with the same argument types and numba writes them to its cache. The run waits for it
before sewing, and its own calls then load them from the cache (the coverage kernels are compiled
first: that stage comes right after the colliders).

- Nothing starts when the simulation's kernel modules already have cache files (a warm run), or
  for a scene without garments.
- Results do not change: the cache holds what the run would have compiled itself (same source,
  flags and types); a kernel the tiny scene did not reach is compiled by the run as before.
- Cache files: numba replaces each file atomically; stages.jit serialises its index updates
  across processes (two processes adding signatures of one kernel at once).
- The child exits when the run does: the run terminates it on any exit (error, Ctrl-C), and the
  child stops itself when its parent is gone (a killed run).
"""
from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

# kernel groups (pipeline.kernel_cache) the tiny scene compiles
GROUPS = ("simulation", "cloth audit")
WATCH_PARENT_S = 0.5
SIMULATED = "simulation compiled"     # the child's line once sewing and simulation kernels are cached
# a compile that has not finished by then (never seen: about 25 s of CPU) is stopped and the run
# compiles what is missing itself, rather than waiting for ever
WAIT_LIMIT_S = 600


def warm_simulation(params, threads: int = 1, cloth_audit: bool = True, vertex_strain: bool = False,
                    layers=None, on_simulated=None) -> None:
    """Simulate a tiny scene with `params` on `threads` numba threads (and audit it): every kernel a
    scene's sewing, simulation and cloth audit call from Python, with the argument types they get.
    on_simulated: called between the simulation and the audit."""
    import numpy as np

    from stages.garments.simple import rectangle_cloth
    from stages.garments.types import build_garment
    from stages.jit import numba_threads
    from stages.maps.build import build_maps
    from stages.sim import simulate
    from stages.sim.scenes import convex_mesh, fibonacci_points, hull_set, toy_character, toy_motion

    mesh = convex_mesh(fibonacci_points(12, (0.2, 0.2, 0.2)))
    character = toy_character(mesh.vertices, mesh.faces)
    colliders = hull_set(mesh)
    maps = build_maps(colliders)
    x, tri = rectangle_cloth(0.3, 0.3, 4, 4, center=(0.0, 0.25, 0.0))
    cloths = [build_garment(f"cloth{i}", x + [0.0, 0.02 * i, 0.0], tri) for i in range(len(layers or [0]))]
    with numba_threads(threads):
        if params.cloth_collision:   # sewing simulates without the cloth phase: the step loop's other variant
            from dataclasses import replace
            simulate(character, toy_motion(2), colliders, maps, cloths[:1], replace(params, cloth_collision=False),
                     threads=threads)
        result = simulate(character, toy_motion(2), colliders, maps, cloths, params, threads=threads,
                          layers=None if layers is None else np.asarray(layers))
        if on_simulated is not None:
            on_simulated()
        if cloth_audit:
            from stages.sim.audit import audit_cloth
            audit_cloth(result, cloths, vertex_strain=vertex_strain)
        if params.body_audit:   # the run's body audit (pipeline.body_report): a sheet stood through the cloth
            from stages.sim.body_audit import BodyFrames, audit_body_crossings
            x = result.garments[0].positions
            body = (x[..., [0, 2, 1]] - x[..., [0, 2, 1]].mean(axis=1, keepdims=True) + x.mean(axis=1, keepdims=True))
            audit_body_crossings(result, BodyFrames(body.astype(np.float32), result.garments[0].triangles,
                                                    np.zeros(x.shape[1], np.int32), ("root",)))


def warm_coverage(threads: int = 1) -> None:
    """Measure a tiny character's coverage (stages.coverage): the collider coverage stage's kernels
    (the skinned-ball fit of the colliders stage uses them too), then the balls' pair search; compiled
    first (those stages run before sewing)."""
    import numpy as np

    from stages.coverage import measure_coverage
    from stages.hulls.balls_kernels import pairs_in_reach
    from stages.jit import numba_threads
    from stages.sim.scenes import convex_mesh, fibonacci_points, hull_set, toy_character, toy_motion

    mesh = convex_mesh(fibonacci_points(12, (0.2, 0.2, 0.2)))
    with numba_threads(threads):
        measure_coverage(toy_character(mesh.vertices, mesh.faces), toy_motion(2), hull_set(mesh), every=1,
                         interior_samples=200, surface_spacing=0.05)
    # the skinned balls' pair search (the colliders stage, after the hulls: 1.6 s of compiling)
    pairs_in_reach(np.zeros((2, 3, 3)), np.zeros((2, 4, 3)), np.full(3, 0.1), 0.05)


def _exit_with_parent(parent: int) -> None:
    """A daemon thread ending this process once `parent` is gone (a killed run leaves no compile behind)."""
    def watch():
        while os.getppid() == parent:
            time.sleep(WATCH_PARENT_S)
        os._exit(3)
    threading.Thread(target=watch, daemon=True).start()


def main() -> int:
    request = pickle.load(sys.stdin.buffer)
    _exit_with_parent(request.pop("parent"))
    # the run terminates this process on Ctrl-C (SIGINT reaches the whole process group as well)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if request.pop("coverage", False):
        warm_coverage(request["threads"])
    warm_simulation(**request, on_simulated=lambda: print(SIMULATED, flush=True))
    return 0


def cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:   # not on Linux
        return os.cpu_count() or 1


IDLE_SAMPLE = 0.25    # s: how long the CPUs are watched for an idle core


def _cpu_times() -> tuple[float, float] | None:
    """(idle, total) jiffies over all CPUs from /proc/stat (Linux), else None."""
    try:
        with open("/proc/stat") as f:
            v = [float(x) for x in f.readline().split()[1:]]
    except (OSError, ValueError):
        return None
    return v[3] + (v[4] if len(v) > 4 else 0.0), sum(v[:8])


def no_idle_core() -> bool:
    """No core is idle now: over IDLE_SAMPLE seconds the CPUs (this run included) were idle for less
    than 3/4 of a core. Measured on the shared 2-core machine at load 4.5-5 (2026-11-24): the second
    process made the first run slower (54.0 s against 49.5 s wall, 49.8 s against 45.5 s CPU): it
    only takes turns with the other jobs. Not the 1-minute load average: it stays above 1 for
    minutes after any work (a pip install, the previous run) while the cores are free (measured:
    27.3 s with the second process, then 48.7 and 49.3 s with the load average at 1.0-1.2 turning
    it off). Elsewhere (no /proc/stat) the load average decides."""
    import time
    a = _cpu_times()
    if a is None:
        try:
            return os.getloadavg()[0] > cores() - 1
        except (AttributeError, OSError):   # no load average (Windows)
            return False
    time.sleep(IDLE_SAMPLE)
    b = _cpu_times()
    if b is None or b[1] <= a[1]:
        return False
    total = b[1] - a[1]
    return (b[0] - a[0]) / total * (os.cpu_count() or 1) < 0.75


def needed() -> bool:
    """Whether the simulation's kernel modules have no numba cache yet (a first run), with an idle
    second core to compile on. GARMENT_BACKGROUND_COMPILE=0 turns it off (tools/compile_profile.py:
    every compile in one process), =1 starts it whatever the load."""
    flag = os.environ.get("GARMENT_BACKGROUND_COMPILE")
    if os.environ.get("NUMBA_DISABLE_JIT") == "1" or flag == "0":
        return False
    if cores() < 2:     # one core: the second process would only take turns with the run
        return False
    from pipeline.kernel_cache import uncompiled
    if uncompiled("simulation")[0] == 0:     # warm: no second process, and no 0.25 s CPU sample either
        return False
    return flag == "1" or not no_idle_core()


class BackgroundCompile:
    """`with BackgroundCompile(request) as bg:` ... `bg.wait_simulation()` before sewing,
    `bg.wait()` before the cloth audit. request: warm_simulation's keyword arguments. Starts nothing when
    `needed()` is false; `bg.started` says whether it did."""

    def __init__(self, request: dict, estimate_s: float = 0.0):
        self.request, self.estimate_s = request, estimate_s
        self.proc = None
        self.log = None
        self.simulated = False
        self.reported = False     # the exit code seen (and a failure warned about)
        self.t0 = time.perf_counter()

    @property
    def started(self) -> bool:
        return self.proc is not None

    def __enter__(self):
        if self.request is None or not needed():
            return self
        root = str(Path(__file__).resolve().parent.parent)   # the tree this pipeline runs from
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH")) if p))
        self.log = tempfile.TemporaryFile()
        self.proc = subprocess.Popen([sys.executable, "-m", "pipeline.kernel_warmup"], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=self.log, env=env, cwd=root)
        try:
            self.proc.stdin.write(pickle.dumps(dict(self.request, parent=os.getpid())))
            self.proc.stdin.close()
        except OSError:     # the child died at start: the run compiles for itself
            pass
        self.t0 = time.perf_counter()
        return self

    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def seconds_left(self) -> float:
        return max(1.0, self.estimate_s - (time.perf_counter() - self.t0))

    def simulation_ready(self) -> bool:
        """Whether the sewing and simulation kernels are cached (the child said so or has ended)."""
        if self.proc is None or self.simulated:
            return True
        if self.proc.poll() is not None:
            return True
        import select
        try:
            return bool(select.select([self.proc.stdout], [], [], 0)[0])    # its line is there to read
        except (OSError, ValueError):   # no select on pipes (Windows): say "waiting"
            return False

    def wait_simulation(self) -> None:
        """Wait until the sewing and simulation kernels are cached (the audit's may still compile,
        while the run sews and simulates)."""
        if self.proc is None or self.simulated:
            return
        import select
        try:
            ready = select.select([self.proc.stdout], [], [], WAIT_LIMIT_S)[0]
        except (OSError, ValueError):   # no select on pipes (Windows): read without a limit
            ready = True
        if not ready:
            self._give_up()
            return
        line = self.proc.stdout.readline()      # b"" when the child ended (then wait() reports)
        self.simulated = line.decode(errors="replace").strip() == SIMULATED
        if not self.simulated:
            self.wait()

    def _give_up(self) -> None:
        import warnings
        self._stop()
        self.reported = True
        warnings.warn(f"the background kernel compile did not finish in {WAIT_LIMIT_S} s; the run compiles its "
                      "kernels itself", RuntimeWarning, stacklevel=3)

    def _stop(self) -> None:
        if self.running():
            self.proc.terminate()
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()

    def wait(self) -> int | None:
        """Wait for the compile; its exit code (None: none started). A failure is not an error: the
        run compiles what is missing itself, and a warning shows the child's last line."""
        if self.proc is None:
            return None
        if self.reported:
            return self.proc.returncode
        try:
            rc = self.proc.wait(WAIT_LIMIT_S)
        except subprocess.TimeoutExpired:
            self._give_up()
            return self.proc.returncode
        self.reported = True
        if rc != 0:
            import warnings
            self.log.seek(0)
            last = (self.log.read().decode(errors="replace").strip().splitlines() or ["no output"])[-1]
            warnings.warn(f"the background kernel compile failed (exit {rc}: {last}); the run compiles "
                          "its kernels itself", RuntimeWarning, stacklevel=2)
        return rc

    def __exit__(self, *exc):
        self._stop()
        if self.proc is not None:
            self.proc.stdout.close()
        if self.log is not None:
            self.log.close()
        return False


if __name__ == "__main__":
    sys.exit(main())
