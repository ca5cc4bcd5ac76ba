"""One job of a sweep, in a worker process: run the scene, label a failure, keep what exists, and
make the metrics row (columns: COLUMNS)."""
from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path

import yaml

from pipeline.schema import SceneError
from pipeline.sweep_file import job_scene

FAILURES = ("sewing", "timeout", "diverged", "bad-input", "crash")

# the metrics row, in table order; the override columns (one per swept key) follow `job`
COLUMNS = ("job", "status", "failure", "message", "frames", "frames_done", "particles",
           "in_body_max", "in_body_overlap_max", "in_colliders_max", "released_frames", "strain_mean_pct", "strain_p99_pct", "strain_p99_worst_pct",
           "crossings_self_max", "crossings_between_max", "body_edges_max", "body_edges_overlap_max", "seam_gap_mm", "fit_gap_cm", "floor_cm",
           "slide_cm", "coverage_min_pct", "excess_p95_cm", "warnings",
           "wall_s", "frames_per_s", "sim_frames_per_s", "warm_up_s", "peak_memory_mb", "worker", "recording", "exports")
# columns that depend on the machine and its load, not on the job: left out when comparing tables
TIMING_COLUMNS = ("wall_s", "frames_per_s", "sim_frames_per_s", "warm_up_s", "peak_memory_mb", "worker")
INT_COLUMNS = ("frames", "frames_done", "particles", "in_body_max", "in_body_overlap_max", "in_colliders_max",
               "released_frames", "crossings_self_max",
               "crossings_between_max", "body_edges_max", "body_edges_overlap_max", "warnings")
FLOAT_COLUMNS = ("strain_mean_pct", "strain_p99_pct", "strain_p99_worst_pct", "seam_gap_mm", "fit_gap_cm",
                 "floor_cm", "slide_cm", "coverage_min_pct", "excess_p95_cm", "wall_s", "frames_per_s", "sim_frames_per_s",
                 "warm_up_s", "peak_memory_mb")


class JobTimeout(BaseException):
    """Raised inside a job at its deadline. A BaseException so that no `except Exception` in the
    stages swallows it."""


# ------------------------------------------------------------------ one job (in a worker)

def _failure(err: BaseException) -> str:
    from pipeline.dressing import SewingError
    from stages.checks import ContractError
    from stages.errors import InputError
    from stages.sim import SimulationDiverged
    if _timeout_in(err) is not None:
        return "timeout"
    if isinstance(err, SewingError):
        return "sewing"
    if isinstance(err, SimulationDiverged):
        return "diverged"
    if isinstance(err, (SceneError, InputError, ContractError)):
        return "bad-input"
    return "crash"


def _timeout_in(err: BaseException | None) -> JobTimeout | None:
    """The JobTimeout that stopped the job: `err` itself, or the cause of an error it led to (raised
    inside numba's object unpickling during a kernel call, it comes out as SystemError "returned a
    result with an exception set" with the timeout as its cause). None when the deadline did not."""
    seen = set()
    while err is not None and id(err) not in seen:
        if isinstance(err, JobTimeout):
            return err
        seen.add(id(err))
        err = err.__cause__ or err.__context__
    return None


def _one_line(text: str, limit: int = 400) -> str:
    s = " ".join(str(text).split())
    return s if len(s) <= limit else s[:limit - 3] + "..."


def _metrics(state: dict, err: BaseException | None) -> dict:
    """The row's figures from what the run left in `state` (a failed run: what it reached)."""
    import numpy as np
    r: dict = {}
    result = state.get("result")
    if result is None and err is not None:
        result = getattr(err, "partial", None) if not isinstance(getattr(err, "partial", None), tuple) else None
        if result is None and callable(state.get("sim", {}).get("result")):
            result = state["sim"]["result"]()    # the frames simulated before the stop
        state["partial_result"] = result
    motion = state.get("motion")
    r["frames"] = int(len(motion.times)) if motion is not None else None
    r["frames_done"] = int(len(result.times)) if result is not None else 0
    garments = state.get("garments")
    r["particles"] = int(sum(g.n_particles for g in garments)) if garments else None
    if result is not None and len(result.times):
        body = np.asarray(result.penetrations_body)
        r["in_body_max"] = int(body[1:].max(initial=0)) if (body >= 0).all() else None
        r["in_body_overlap_max"] = int(np.asarray(result.penetrations_body_overlap)[1:].max(initial=0))
        r["in_colliders_max"] = int(np.asarray(result.penetrations_colliders)[1:].max(initial=0))
        if result.released is not None:
            r["released_frames"] = int((np.asarray(result.released) > 0).sum())
    audit = state.get("audit")
    if audit is not None and audit.garments:
        r["strain_mean_pct"] = float(max(g.strain_mean[-1] for g in audit.garments) * 100)
        r["strain_p99_pct"] = float(max(g.strain_p99[-1] for g in audit.garments) * 100)
        r["strain_p99_worst_pct"] = float(max(np.max(g.strain_p99[1:], initial=g.strain_p99[0]) for g in audit.garments) * 100)
        r["crossings_self_max"] = int(np.sum([g.crossings_self for g in audit.garments], axis=0)[1:].max(initial=0))
        r["crossings_between_max"] = int(np.asarray(audit.crossings_between)[1:].max(initial=0))
    crossings = state.get("body_crossings")
    if crossings is not None:   # body edges through the cloth (all garments), worst frame after the blend-in
        from pipeline.body_report import body_edges_max
        r["body_edges_max"] = body_edges_max(crossings)
        r["body_edges_overlap_max"] = body_edges_max(crossings, in_overlap=True)
    builds = state.get("builds") or {}
    gaps = [float(log.gap_max[-1]) for log, _ in builds.values()]
    if err is not None and isinstance(getattr(err, "partial", None), tuple):   # a SewingError: its garment
        gaps.append(float(err.partial[1].gap_max[-1]))
    if gaps:
        r["seam_gap_mm"] = max(gaps) * 1000
    fits = state.get("fits")
    if fits:
        gaps = [f.fit_gap_median for f in fits if math.isfinite(f.fit_gap_median)]
        r["fit_gap_cm"] = max(gaps, key=abs) * 100 if gaps else None
        r["floor_cm"] = float(min(f.floor_clearance.min() for f in fits) * 100)
        slides = [float(f.slide[1:].max(initial=0.0)) for f in fits if f.slide.size]
        r["slide_cm"] = max(slides) * 100 if slides else None
    coverage = state.get("coverage")
    if coverage is not None:   # the collider-fit audit (the one figure the seed moves: its sample points)
        t = coverage.totals()
        r["coverage_min_pct"] = float(t["coverage_min"] * 100)
        r["excess_p95_cm"] = float(t["excess_p95"] * 100)
    summary = state.get("summary")
    if summary is not None:
        sim = next((s for s in summary.stages if s.name == "simulation"), None)
        if sim is not None and result is not None:
            r["sim_frames_per_s"] = len(result.times) / max(sim.seconds, 1e-9)
    return r


def _partial_geometry(state: dict, err: BaseException, job_dir: Path, formats: list, scene) -> tuple[list, str]:
    """A failed job's geometry: every garment over the frames simulated (or as built / as the sewing
    left it, at frame 0) and the body over the same frames; the scene's formats plus npz."""
    import numpy as np

    from pipeline import export
    motion, skinned, character = state.get("motion"), state.get("skinned"), state.get("character")
    if motion is None or skinned is None or character is None:
        return [], "no geometry (the run stopped before the character was skinned)"
    result = state.get("result") or state.get("partial_result")
    meshes = []
    builds = dict(state.get("builds") or {})
    if result is not None and len(result.times):
        f = len(result.times)
        for track in result.garments:
            meshes.append(export.AnimatedMesh(track.name, "garment", np.asarray(track.positions, np.float32),
                                              np.asarray(track.triangles, np.int32)))
        what = f"{f} simulated frame(s)"
    else:
        f = 1
        garments = list(state.get("garments") or [])
        partial = getattr(err, "partial", None)
        if isinstance(partial, tuple):   # SewingError: the garment as the sewing left it
            garments.append(partial[0])
            builds[partial[0].name] = (partial[1], partial[2])
        root0 = motion.root_translation[0]
        for g in garments:
            meshes.append(export.AnimatedMesh(g.name, "garment", (np.asarray(g.positions) + root0)[None].astype(np.float32),
                                              np.asarray(g.triangles, np.int32)))
        what = ("frame 0 of the garments as built" + (" (unsewn)" if isinstance(partial, tuple) else "")
                if garments else "the body only (no garment was built)")
        if not garments:
            f = len(motion.times)
    for m in meshes:   # UVs as export.from_run gives them
        try:
            m.uv, m.uv_faces = export.garment_uv(m.name, m.faces, builds)
        except Exception:   # a failed job's garment as it was left: exported without UVs
            pass
    body = (np.asarray(skinned[:f]) + motion.root_translation[:f, None, :]).astype(np.float32)
    meshes.append(export.AnimatedMesh("body", "body", body, np.asarray(character.triangles, np.int32)))
    times = np.asarray(motion.times[:f], np.float64)
    data = export.ExportData(meshes, times, np.arange(f, dtype=np.int64), 1.0 / float(scene["simulation"]["dt"]),
                             f"{scene.path} (partial: {what})", scene_name=scene.name)
    fmts = list(dict.fromkeys(["npz"] + [x for x in formats if x in export.FORMATS]))
    paths = []
    for fmt in fmts:
        try:
            paths += export.write(data, [fmt], job_dir / "export")
        except Exception as e:   # a writer that cannot take this (e.g. a missing extra): keep the others
            what += f"; {fmt} not written ({type(e).__name__}: {_one_line(e, 120)})"
    return paths, what


def _write_json(path: Path, data: dict) -> None:
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    tmp.write_text(json.dumps(data, indent=1, default=_json_default))
    os.replace(tmp, path)


def _json_default(o):
    import numpy as np
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return float(o)
    if isinstance(o, Path):
        return str(o)
    return str(o)


def reset_peak_memory() -> bool:
    """Start the process's peak resident memory (VmHWM) afresh, so that the next peak_memory_mb is
    one job's (a pool worker runs many). What earlier jobs freed is handed back to the system first
    (glibc's malloc_trim): kept, it counted in the next job's peak (1.75 GB against 0.83 GB for the
    same run alone). Linux only (/proc/self/clear_refs); False elsewhere."""
    import ctypes
    import gc
    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):   # not glibc: the peak may include what earlier jobs freed
        pass
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def peak_memory_mb() -> float | None:
    """The process's peak resident memory since the last reset_peak_memory (VmHWM, MB); None where
    /proc is not there. The worker's imports and kernels are in it: a `run` carries them too."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return None


def _worker_name() -> str:
    import socket
    return f"{socket.gethostname()}:{os.getpid()}"


# what a run imports, loaded before a job's deadline is armed: a timeout raised inside an import
# leaves a half-initialised module (numba.core.types) behind, and the job could not even write its
# row (the pool also replaces a worker after a timeout: numba loads registries lazily too)
RUN_MODULES = ("numba", "rerun", "trimesh", "pipeline.run", "pipeline.logs", "pipeline.export", "pipeline.blueprint",
               "stages.rig.gltf", "stages.rig.bvh_character", "stages.rig.procedural", "stages.rig.capsule_skin", "stages.rig.skinning",
               "stages.rig.humanoid", "stages.hulls.fit", "stages.maps", "stages.coverage", "stages.garments.library",
               "stages.garments.placement", "stages.garments.sewing", "stages.garments.types", "stages.garments.fit",
               "stages.obstacles", "stages.sim", "stages.sim.audit")


def run_job(spec: dict, warm_up_s: float | None = None) -> dict:
    """Run one job in this process: its recording, exports and metrics row (also written to
    `<dir>/row.json`). Never raises for a failed job: the row says what failed."""
    import contextlib
    import io
    import signal
    import threading
    import traceback
    import warnings

    import importlib

    from pipeline import where
    from pipeline.run import run_scene
    for name in RUN_MODULES:
        importlib.import_module(name)
    job_dir = Path(spec["dir"])
    job_dir.mkdir(parents=True, exist_ok=True)
    row = {"job": spec["id"], **spec["labels"]}
    state: dict = {}
    log = io.StringIO()
    peak_known = reset_peak_memory()
    t0 = time.perf_counter()
    err: BaseException | None = None
    scene = None
    timeout = spec.get("timeout")
    alarm = bool(timeout) and threading.current_thread() is threading.main_thread() and hasattr(signal, "setitimer")
    old_handler = None
    armed, fired = [True], [False]

    def on_alarm(signum, frame):
        # raised again every second until the job stops: library code that catches everything (rtree's
        # library finder prints "unexpected error" and goes on) may swallow one
        if armed[0]:
            fired[0] = True
            raise JobTimeout(f"the job ran longer than {timeout:g} s")

    with warnings.catch_warnings(record=True) as caught, contextlib.redirect_stdout(log), \
            contextlib.redirect_stderr(log):
        warnings.simplefilter("always")
        try:
            if alarm:
                old_handler = signal.signal(signal.SIGALRM, on_alarm)
                signal.setitimer(signal.ITIMER_REAL, float(timeout), 1.0)
            where.reset(spec["source"])
            scene = job_scene(spec["text"], spec["source"], spec["base_dir"])
            run_scene(scene, progress=False, state=state, keep_partial=job_dir / f"{spec['id']}.partial.rrd")
        except BaseException as e:   # noqa: BLE001  (a failed job is a row, never the end of the sweep)
            armed[0] = False
            if isinstance(e, KeyboardInterrupt):
                raise
            err = e
            if fired[0] and _timeout_in(e) is None:
                # raised inside C code that replaced the timeout by an error of its own (numpy's
                # structured-array comparison raises TypeError): past the deadline, it is the timeout
                err = JobTimeout(f"the job ran longer than {timeout:g} s")
                err.__cause__ = e
            if _failure(err) == "crash":
                log.write(f"{where.current()}\n" + traceback.format_exc())
        finally:
            armed[0] = False
            if alarm:
                signal.setitimer(signal.ITIMER_REAL, 0.0)
                signal.signal(signal.SIGALRM, old_handler or signal.SIG_DFL)
    try:
        row.update(_metrics(state, err))
    except Exception as e:   # metrics of a broken run: keep the failure, note this
        log.write(f"metrics: {type(e).__name__}: {e}\n")
    if err is None:
        row.update(status="ok", failure="", message="")
        summary = state["summary"]
        row["exports"] = ";".join(os.path.relpath(p, job_dir) for p in summary.exports)
        row["recording"] = os.path.relpath(job_dir / f"{spec['id']}.rrd", job_dir)
    else:
        kind = _failure(err)
        stage = where.current()["stage"]
        text = " ".join(str(err).split())
        if text.startswith(spec["source"] + ": "):   # the row names the job already
            text = text[len(spec["source"]) + 2:]
        if kind == "crash":
            text = f"{type(err).__name__}: {text} (in stage {stage!r})"
        row.update(status="failed", failure=kind, message=_one_line(text))
        if kind == "timeout":
            row["message"] = _one_line(f"{_timeout_in(err)} (stopped in stage {stage!r})")
        if scene is not None:
            try:
                paths, what = _partial_geometry(state, err, job_dir, scene.export["formats"], scene)
            except Exception as e:   # keeping geometry must not hide the failure
                paths, what = [], f"geometry not kept ({type(e).__name__}: {e})"
            row["exports"] = ";".join(os.path.relpath(p, job_dir) for p in paths)
            log.write(f"kept: {what}\n")
        partial = job_dir / f"{spec['id']}.partial.rrd"
        row["recording"] = os.path.relpath(partial, job_dir) if partial.exists() else ""
    row["wall_s"] = time.perf_counter() - t0
    done = row.get("frames_done") or 0
    row["frames_per_s"] = done / row["wall_s"] if done else None
    row["warm_up_s"] = warm_up_s
    row["peak_memory_mb"] = peak_memory_mb() if peak_known else None
    row["worker"] = _worker_name()
    row["warnings"] = len(caught)
    for w in caught:
        log.write(f"warning: {w.message}\n")
    if err is not None:
        log.write(f"error ({row['failure']}): {err}\n")
    (job_dir / "log.txt").write_text(log.getvalue())
    _write_json(job_dir / "row.json", row)
    return row


def warm_up(spec: dict) -> float:
    """Load (or compile) the numba kernels a job uses by running it for 2 frames into a scratch
    folder; returns the seconds it took. A warm-up that fails has still compiled what it reached."""
    import contextlib
    import io
    import shutil
    import tempfile
    import warnings
    t0 = time.perf_counter()
    scratch = Path(tempfile.mkdtemp(prefix="sweep-warm-"))
    try:
        data = yaml.safe_load(spec["text"])
        frames = data.get("frames") if isinstance(data.get("frames"), dict) else {}
        data["frames"] = {**frames, "count": 2}
        data["output"] = {"path": str(scratch / "warm.rrd"), "export": [], "export_dir": None}
        text = yaml.safe_dump(data, sort_keys=False)
        from pipeline.run import run_scene
        with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()), \
                contextlib.redirect_stderr(io.StringIO()):
            warnings.simplefilter("ignore")
            try:
                run_scene(job_scene(text, spec["source"] + " (warm-up)", spec["base_dir"]), progress=False)
            except Exception:
                pass
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return time.perf_counter() - t0


def timeout_row(spec: dict, seconds: float, how: str) -> dict:
    """The row of a job whose worker was killed (no answer after the timeout and its grace)."""
    return _lost_worker_row(spec, seconds, "timeout", f"timeout: {how} after {seconds:.0f} s (the job ran longer than "
                            f"{spec['timeout']:g} s and did not stop at the deadline: stuck in one long kernel call)")


def warm_up_timeout_row(spec: dict, seconds: float) -> dict:
    """The row of the job a worker was to start with when its warm-up (loading or compiling the numba
    kernels) outlasted the job timeout: the timeout bounds the job's whole wait, warm-up included."""
    return _lost_worker_row(spec, seconds, "timeout", f"timeout: the worker's warm-up (loading or compiling the "
                            f"numba kernels) took more than the job timeout of {spec['timeout']:g} s; the worker "
                            f"was killed after {seconds:.0f} s (raise 'timeout', or run one job first to fill the "
                            f"kernel cache)")


def crash_row(spec: dict, seconds: float, what: str) -> dict:
    """The row of a job whose worker died or could not run it."""
    return _lost_worker_row(spec, seconds, "crash", what)


def _lost_worker_row(spec: dict, seconds: float, failure: str, message: str) -> dict:
    """A failed job's row written by the parent (its worker gave none): the job's temporary recording
    (whatever the worker had written) becomes its partial one."""
    job_dir = Path(spec["dir"])
    job_dir.mkdir(parents=True, exist_ok=True)
    partial = job_dir / f"{spec['id']}.partial.rrd"
    for tmp in sorted(job_dir.glob(f".{spec['id']}.rrd.tmp-*")):
        os.replace(tmp, partial)
    row = {"job": spec["id"], **spec["labels"], "status": "failed", "failure": failure,
           "message": _one_line(message), "frames_done": 0,
           "recording": os.path.relpath(partial, job_dir) if partial.exists() else "", "exports": "",
           "wall_s": seconds}
    _write_json(job_dir / "row.json", row)
    return row
