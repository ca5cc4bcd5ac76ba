"""`python -m pipeline sweep SWEEP.yaml`: many runs of one base scene, one per combination of
overrides, on a local process pool or on a Ray cluster, with a metrics table (CSV and Parquet).

A sweep file:

    base: walk_tshirt_skirt.yaml      # the base scene: a file (relative to the sweep file) or a mapping
    name: my_sweep                    # default: the sweep file's name
    output: sweeps/my_sweep           # results folder (default sweeps/<name>; -o overrides)
    timeout: 600                      # seconds per job (null: none)
    jobs: null                        # workers (default: every core; --jobs overrides)
    warm_up: true                     # each worker compiles / loads the numba kernels before its first job
    grid:                             # every combination of these (dotted scene keys)
      garments[0].kind: [tshirt, short_skirt]
      seed: [0, 1]
      character:                      # a mapping gives each value a label (used in the job id)
        builtin: {source: procedural, clip: walk}
    cases:                            # a list of override sets, each combined with every grid point
      - {label: fast, simulation.substeps: 10}

Each job is the base scene with its overrides applied (a dotted key replaces that value: `seed`,
`character`, `character.body.height`, `garments[0].options.ease`, `garments[1].density`, ...).
Its id is the labels of its values plus a hash of the override values, so a rerun finds the jobs
already done: finished jobs are skipped (failed ones too, unless `--retry-failed`).

Results: `OUT/jobs/<id>/` holds the job's recording (`<id>.rrd`), its exports (`export/`, the base
scene's `output.export`), `row.json` (its metrics row) and `log.txt` (its warnings and errors); a
failed job keeps whatever exists: the recording up to the failure (`<id>.partial.rrd`) and the
geometry of the frames it reached (`export/`, npz at least). `OUT/table.csv` and
`OUT/table.parquet` hold one row per finished job (columns: `COLUMNS`).

Failure labels: sewing (a seam did not close), timeout, diverged (the cloth blew up), bad-input
(a user error a run would exit 2 on), crash (any other exception, or the worker process died).

Timeouts: the job's own process raises at the deadline (between two kernel calls) and keeps what
exists; a job that does not stop within a grace period (stuck in one long kernel) has its worker
killed and replaced.
"""
from __future__ import annotations

import csv
import json
import math
import os
import sys
import time
from pathlib import Path


from pipeline.sweep_file import Sweep, SweepError, load_sweep, validate_jobs
from pipeline.sweep_job import (COLUMNS, FLOAT_COLUMNS, INT_COLUMNS, TIMING_COLUMNS, _one_line, crash_row, run_job,
                                timeout_row, warm_up, warm_up_timeout_row)

# ------------------------------------------------------------------ the table

def columns(sw: Sweep) -> list[str]:
    return ["job"] + [k for k in sw.keys if k not in COLUMNS] + [c for c in COLUMNS if c != "job"]


def table_rows(sw: Sweep, rows: dict) -> list[dict]:
    """The finished jobs' rows in the sweep's job order, every column present (None when absent)."""
    cols = columns(sw)
    out = []
    for job in sw.jobs:
        r = rows.get(job.id)
        if r is None:
            continue
        row = {c: r.get(c) for c in cols}
        for c in INT_COLUMNS:
            row[c] = None if row[c] is None else int(row[c])
        for c in FLOAT_COLUMNS:
            row[c] = None if row[c] is None else float(row[c])
        for c in cols:   # text columns: '' when empty (a CSV cell cannot tell '' from null)
            if c not in INT_COLUMNS and c not in FLOAT_COLUMNS:
                row[c] = "" if row[c] is None else str(row[c])
        out.append(row)
    return out


def arrow_schema(cols: list[str]):
    import pyarrow as pa
    return pa.schema([(c, pa.int64() if c in INT_COLUMNS else pa.float64() if c in FLOAT_COLUMNS else pa.string())
                      for c in cols])


def write_table(sw: Sweep, rows: dict) -> tuple[Path, Path]:
    """OUT/table.csv and OUT/table.parquet (each written to a temporary name, then renamed)."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    cols = columns(sw)
    data = table_rows(sw, rows)
    sw.out.mkdir(parents=True, exist_ok=True)
    csv_path, pq_path = sw.out / "table.csv", sw.out / "table.parquet"
    tmp = csv_path.with_name(f".table.csv.tmp-{os.getpid()}")
    with open(tmp, "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=cols)
        w.writeheader()
        for r in data:
            w.writerow({c: "" if r[c] is None else repr(r[c]) if isinstance(r[c], float) else r[c] for c in cols})
    os.replace(tmp, csv_path)
    tmp = pq_path.with_name(f".table.parquet.tmp-{os.getpid()}")
    pq.write_table(pa.Table.from_pylist(data, schema=arrow_schema(cols)), tmp)
    os.replace(tmp, pq_path)
    return csv_path, pq_path


def read_csv_table(path: Path) -> list[dict]:
    """The CSV back as typed rows, as `table_rows` gives them (an empty number cell is None)."""
    out = []
    with open(path, newline="", encoding="utf-8") as fh:
        for r in csv.DictReader(fh):
            row = {}
            for c, v in r.items():
                if c not in INT_COLUMNS and c not in FLOAT_COLUMNS:
                    row[c] = v
                elif v == "":
                    row[c] = None
                elif c in INT_COLUMNS:
                    row[c] = int(v)
                else:
                    row[c] = float(v)
            out.append(row)
    return out


def comparable(rows: list[dict]) -> list[dict]:
    """Rows without the machine-dependent columns (TIMING_COLUMNS), NaN as None: what two runs of
    the same sweep (pool and Ray, or two machines) must agree on."""
    out = []
    for r in rows:
        out.append({c: (None if isinstance(v, float) and math.isnan(v) else v) for c, v in r.items()
                    if c not in TIMING_COLUMNS})
    return out


def read_rows(sw: Sweep) -> dict:
    """job id -> its row.json, for the jobs of this sweep that have one."""
    rows = {}
    for job in sw.jobs:
        p = Path(job.dir) / "row.json"
        if p.is_file():
            try:
                rows[job.id] = json.loads(p.read_text())
            except (OSError, ValueError):
                pass   # a torn file: the job runs again
    return rows


# ------------------------------------------------------------------ progress over jobs

class JobProgress:
    """One line per finished job when not on a terminal; a bar redrawn in place on one."""

    def __init__(self, total: int, stream=None, enabled: bool = True):
        self.total, self.done, self.failed = total, 0, 0
        self.stream = stream or sys.stderr
        self.enabled = enabled and total > 0
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.t0 = time.perf_counter()

    def note(self, text: str) -> None:
        if self.enabled:
            self.stream.write(("\r\033[K" if self.tty else "") + text + "\n")
            self.stream.flush()
            self.draw()

    def update(self, row: dict) -> None:
        self.done += 1
        self.failed += row.get("status") != "ok"
        if not self.enabled:
            return
        status = "ok" if row.get("status") == "ok" else f"FAILED ({row.get('failure')}: {_one_line(row.get('message', ''), 160)})"
        line = f"job {self.done}/{self.total} {row['job']}: {status}, {row.get('wall_s') or 0:.1f} s"
        if self.tty:
            self.stream.write("\r\033[K" + line + "\n")
            self.draw()
        else:
            self.stream.write(self.text() + "  " + line + "\n")
        self.stream.flush()

    def text(self) -> str:
        el = time.perf_counter() - self.t0
        eta = el / self.done * (self.total - self.done) if self.done else float("nan")
        width = 30
        fill = int(width * self.done / max(self.total, 1))
        return (f"sweep [{'#' * fill}{'.' * (width - fill)}] {self.done}/{self.total} jobs, {self.failed} failed, "
                f"{el:.0f} s" + (f", about {eta:.0f} s left" if self.done and self.done < self.total else ""))

    def draw(self) -> None:
        if self.enabled and self.tty:
            self.stream.write("\r\033[K" + self.text())
            self.stream.flush()

    def close(self) -> None:
        if self.enabled and self.tty:
            self.stream.write("\n")
            self.stream.flush()


# ------------------------------------------------------------------ running: process pool

def _grace(timeout: float) -> float:
    return min(120.0, max(10.0, 0.25 * timeout))


def _worker_main(conn, warm_spec, env: dict) -> None:   # pragma: no cover - runs in the child process
    import signal
    signal.signal(signal.SIGINT, signal.SIG_IGN)   # the parent handles Ctrl-C and stops the workers
    os.environ.update(env)
    warm = warm_up(warm_spec) if warm_spec is not None else None
    conn.send(("ready", warm))
    first = True
    while True:
        try:
            spec = conn.recv()
        except EOFError:
            return
        if spec is None:
            return
        t0 = time.perf_counter()
        try:
            row = run_job(spec, warm_up_s=warm if first else None)
        except BaseException as e:   # noqa: BLE001  (run_job answers for the job; this is its last resort)
            row = crash_row(spec, time.perf_counter() - t0, f"the job runner failed: {type(e).__name__}: {e}")
        first = False
        conn.send(("row", row))


WORKER_ENV = {"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}


def kernels_cold() -> bool:
    """Whether some stage's numba kernels have no cache yet (the first run compiles them)."""
    from pipeline.kernel_cache import STAGE_PACKAGES, uncompiled
    return any(uncompiled(stage)[0] for stage in STAGE_PACKAGES if stage != "obstacles")


def run_pool(specs: list[dict], workers: int, warm_spec: dict | None, on_row, on_note=None) -> None:
    """Run `specs` on `workers` processes of our own (spawned), so that one job can be killed at
    its timeout without stopping the others; a dead worker is replaced. on_row(row) per finished job."""
    import multiprocessing as mp
    from multiprocessing.connection import wait
    ctx = mp.get_context("spawn")
    pending = list(specs)
    n = max(1, min(workers, len(pending)))
    live: list[dict] = []

    def start():
        a, b = ctx.Pipe()
        proc = ctx.Process(target=_worker_main, args=(b, warm_spec, WORKER_ENV), daemon=True)
        proc.start()
        b.close()
        live.append({"proc": proc, "conn": a, "spec": None, "t0": None, "ready": False, "started": time.perf_counter()})

    def stop(w, how="kill"):
        try:
            (w["proc"].kill if how == "kill" else w["proc"].terminate)()
        except Exception:
            pass
        w["proc"].join(5)
        w["conn"].close()
        live.remove(w)

    # a cold numba cache: one worker compiles first, the others then load its cache
    stagger = warm_spec is not None and n > 1 and kernels_cold()
    if stagger and on_note:
        on_note("numba kernels not compiled yet: one worker compiles them first (about 90 s on 2 cores), "
                "then the others start")
    start()
    if not stagger:
        for _ in range(n - 1):
            start()
    try:
        while pending or any(w["spec"] is not None for w in live):
            for w in live:
                if w["ready"] and w["spec"] is None and pending:
                    w["spec"], w["t0"] = pending.pop(0), time.perf_counter()
                    w["conn"].send(w["spec"])
            now = time.perf_counter()
            deadlines = [w["t0"] + w["spec"]["timeout"] + _grace(w["spec"]["timeout"])
                         for w in live if w["spec"] is not None and w["spec"].get("timeout")]
            if pending and pending[0].get("timeout"):   # workers still warming up: bounded by the same timeout
                deadlines += [w["started"] + pending[0]["timeout"] + _grace(pending[0]["timeout"])
                              for w in live if not w["ready"]]
            wait_s = max(0.0, min(deadlines) - now) if deadlines else None
            ready = wait([w["conn"] for w in live] + [w["proc"].sentinel for w in live], timeout=wait_s)
            for w in list(live):
                if w["conn"] in ready:
                    try:
                        kind, payload = w["conn"].recv()
                    except (EOFError, OSError):
                        kind, payload = "dead", None
                    if kind == "ready":
                        w["ready"] = True
                        if stagger:
                            stagger = False
                            for _ in range(min(n, len(pending) + 1) - len(live)):
                                start()
                        continue
                    if kind == "row":
                        w["spec"] = None
                        on_row(payload)
                        if payload.get("failure") == "timeout":
                            # stopped mid-way (perhaps inside numba's lazy imports or registries): the
                            # process is not trusted with another job
                            stop(w)
                            if pending:
                                start()
                        continue
                if w["proc"].sentinel in ready or not w["proc"].is_alive():
                    code = w["proc"].exitcode
                    if w["spec"] is not None:
                        on_row(crash_row(w["spec"], time.perf_counter() - w["t0"],
                                         f"the worker process died (exit code {code}"
                                         f"{', signal ' + str(-code) if code is not None and code < 0 else ''}) "
                                         f"while running the job"))
                    elif not w["ready"]:
                        raise RuntimeError(f"a sweep worker process died while starting (exit code {code})")
                    stop(w)
                    if pending:
                        start()
            now = time.perf_counter()
            for w in list(live):
                s = w["spec"]
                if s is not None and s.get("timeout") and now > w["t0"] + s["timeout"] + _grace(s["timeout"]):
                    stop(w)
                    on_row(timeout_row(s, now - w["t0"], "the worker was killed"))
                    if pending:
                        start()
                elif (not w["ready"] and pending and pending[0].get("timeout")
                      and now > w["started"] + pending[0]["timeout"] + _grace(pending[0]["timeout"])):
                    stop(w)   # a warm-up past the timeout: the job it was to run is the one timed out
                    on_row(warm_up_timeout_row(pending.pop(0), now - w["started"]))
                    if pending:
                        start()
            if stagger and not live and pending:   # the compiling worker died
                start()
    finally:
        for w in list(live):
            try:
                if w["spec"] is None and w["proc"].is_alive():
                    w["conn"].send(None)
                    w["proc"].join(10)
            except Exception:
                pass
            if w["proc"].is_alive():
                w["proc"].kill()
                w["proc"].join(5)


# ------------------------------------------------------------------ running: Ray

_RAY_WARM: dict = {}


def _ray_job(spec: dict, warm_spec: dict | None) -> dict:   # pragma: no cover - runs in a Ray worker
    """A Ray task: the worker's first task warms the numba kernels (once per worker process)."""
    warm = None
    if warm_spec is not None and not _RAY_WARM:
        _RAY_WARM["s"] = warm = warm_up(warm_spec)
    return run_job(spec, warm_up_s=warm)


RAY_MISSING = ("--ray: Ray is not installed; install the extra: pip install -e \".[ray]\" "
               "(or pip install \"ray>=2\")")


def run_ray(specs: list[dict], address: str | None, workers: int, warm_spec: dict | None, on_row, on_note=None) -> None:
    """The same jobs as Ray tasks: on the cluster at `address`, or on a local one (`workers` CPUs)
    when it is None. At most as many tasks in flight as the cluster has CPUs, so each starts when
    submitted and its timeout counts from there; a task past its timeout and grace is cancelled
    with force (its worker killed)."""
    try:
        import ray
    except ImportError:
        raise SweepError(RAY_MISSING) from None
    import logging
    started_here = not ray.is_initialized()
    if started_here:
        kw = dict(include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR,
                  runtime_env={"env_vars": dict(WORKER_ENV)})
        if address:
            ray.init(address=address, **kw)
        else:
            ray.init(num_cpus=workers, **kw)
    if on_note:
        on_note(f"ray: {'cluster ' + address if address else 'local cluster'}, "
                f"{int(ray.cluster_resources().get('CPU', 0))} CPUs")
    try:
        remote = ray.remote(num_cpus=1, max_retries=0)(_ray_job)
        slots = max(1, int(ray.cluster_resources().get("CPU", workers)) if address else workers)
        pending = list(specs)
        flight: dict = {}   # ref -> (spec, t0)
        # a worker's first task also warms the kernels: its hard deadline allows for that
        warm_allow = (600.0 if kernels_cold() else 120.0) if warm_spec is not None else 0.0
        firsts = slots
        while pending or flight:
            while pending and len(flight) < slots:
                s = pending.pop(0)
                allow = warm_allow if firsts > 0 else 0.0
                firsts -= 1
                flight[remote.remote(s, warm_spec)] = (s, time.perf_counter(), allow)
            now = time.perf_counter()
            deadlines = [t0 + s["timeout"] + _grace(s["timeout"]) + allow
                         for s, t0, allow in flight.values() if s.get("timeout")]
            wait_s = max(0.0, min(deadlines) - now) if deadlines else None
            done, _ = ray.wait(list(flight), num_returns=1, timeout=wait_s)
            for ref in done:
                s, t0, _ = flight.pop(ref)
                try:
                    on_row(ray.get(ref))
                except Exception as e:   # the worker died (a crash) or the task raised
                    on_row(crash_row(s, time.perf_counter() - t0, f"ray: {type(e).__name__}: {_one_line(e, 300)}"))
            now = time.perf_counter()
            for ref, (s, t0, allow) in list(flight.items()):
                if s.get("timeout") and now > t0 + s["timeout"] + _grace(s["timeout"]) + allow:
                    ray.cancel(ref, force=True)
                    flight.pop(ref)
                    on_row(timeout_row(s, now - t0, "the Ray task was cancelled (its worker killed)"))
    finally:
        if started_here:
            ray.shutdown()


# ------------------------------------------------------------------ the command

def default_workers() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:   # pragma: no cover - not Linux
        return os.cpu_count() or 1


# a pool worker's peak memory: scenes/default.yaml at 30 frames peaked at 443 MB RSS (2026-11-29)
WORKER_BYTES = 450 * 1024 ** 2


def memory_capped_workers(workers: int, sw) -> int:
    """At most as many pool workers as the available memory holds (WORKER_BYTES each), with a warning
    saying so: 64 workers asked on a 23 GB machine were killed by the kernel, not refused."""
    import warnings

    from pipeline.preflight import available_memory
    free = available_memory()
    cap = max(1, free // WORKER_BYTES) if free is not None else workers
    if workers > cap:
        warnings.warn(f"{sw.path}: jobs: {workers} workers need about {workers * WORKER_BYTES / 1024 ** 3:.1f} GB of "
                      f"memory, more than the {free / 1024 ** 3:.1f} GB available: running {cap} workers", stacklevel=2)
        return int(cap)
    return workers


def run_sweep(path, *, output=None, jobs: int | None = None, ray_address: str | None | bool = False,
              retry_failed: bool = False, progress: bool = True, echo=None) -> tuple[Sweep, list[dict]]:
    """Load, validate every combination, run the jobs not finished yet, write the table. Returns the
    sweep and the table rows (every finished job of this sweep, in job order).

    ray_address: False = the local process pool; None or '' = a local Ray cluster; else its address."""
    echo = echo or (lambda *a: None)
    sw = load_sweep(path, output)
    if ray_address is not False:   # a missing Ray is said before any work
        try:
            import ray  # noqa: F401
        except ImportError:
            raise SweepError(RAY_MISSING) from None
    validate_jobs(sw, echo=echo)
    rows = read_rows(sw)
    todo = [j for j in sw.jobs if j.id not in rows or (retry_failed and rows[j.id].get("status") != "ok")]
    skipped = len(sw.jobs) - len(todo)
    workers = jobs or sw.workers or default_workers()
    if ray_address is False:
        workers = memory_capped_workers(workers, sw)
    echo(f"sweep {sw.name}: {len(sw.jobs)} jobs ({skipped} finished before, skipped; {len(todo)} to run) "
         f"-> {sw.out}" + (f", {min(workers, len(todo))} workers" if todo and ray_address is False else ""))
    import shutil
    for j in todo:   # a job that runs again starts from an empty folder
        if Path(j.dir).exists():
            shutil.rmtree(j.dir)
    sw.out.mkdir(parents=True, exist_ok=True)
    (sw.out / "sweep.yaml").write_text(sw.path.read_text(encoding="utf-8"))
    specs = [j.spec(sw.base_dir, sw.timeout) for j in todo]
    warm_spec = specs[0] if (specs and sw.warm_up) else None
    bar = JobProgress(len(specs), enabled=progress)

    def on_row(row: dict) -> None:
        rows[row["job"]] = row
        bar.update(row)
        write_table(sw, rows)

    try:
        if specs:
            if ray_address is False:
                run_pool(specs, workers, warm_spec, on_row, on_note=bar.note)
            else:
                run_ray(specs, ray_address or None, workers, warm_spec, on_row, on_note=bar.note)
    finally:
        bar.close()
        write_table(sw, rows)
    return sw, table_rows(sw, rows)


def _fmt(v, spec: str = "") -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return ""
    return format(v, spec) if spec else str(v)


def summary_text(sw: Sweep, rows: list[dict]) -> str:
    """The table as a user reads it (markdown), then where the files are."""
    keys = [k for k in sw.keys if k not in COLUMNS]
    head = (["job"] + keys + ["status", "wall (s)", "frames/s", "in body", "in colliders", "strain mean / p99 (%)",
                              "crossings self / between", "body edges through cloth", "seam gap (mm)"])
    out = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    for r in rows:
        status = "ok" if r["status"] == "ok" else f"{r['failure']}: {_one_line(r['message'] or '', 120)}"
        strain = (f"{_fmt(r['strain_mean_pct'], '.2f')} / {_fmt(r['strain_p99_pct'], '.1f')}"
                  if r["strain_mean_pct"] is not None else "")
        cross = (f"{_fmt(r['crossings_self_max'])} / {_fmt(r['crossings_between_max'])}"
                 if r["crossings_self_max"] is not None else "")
        cells = ([r["job"]] + [_fmt(r.get(k)) for k in keys]
                 + [status, _fmt(r["wall_s"], ".1f"), _fmt(r["frames_per_s"], ".1f"), _fmt(r["in_body_max"]),
                    _fmt(r["in_colliders_max"]), strain, cross, _fmt(r.get("body_edges_max")),
                    _fmt(r["seam_gap_mm"], ".1f")])
        out.append("| " + " | ".join(cells) + " |")
    ok = sum(r["status"] == "ok" for r in rows)
    failed = {}
    for r in rows:
        if r["status"] != "ok":
            failed[r["failure"]] = failed.get(r["failure"], 0) + 1
    out.append("")
    out.append(f"{ok} of {len(sw.jobs)} jobs ok" + (", failed: " + ", ".join(f"{n} {k}" for k, n in failed.items())
                                                     if failed else "")
               + (f", {len(sw.jobs) - len(rows)} not run" if len(rows) < len(sw.jobs) else ""))
    out.append(f"table: {sw.out / 'table.csv'}, {sw.out / 'table.parquet'}; jobs: {sw.out / 'jobs'}/<job>/")
    return "\n".join(out)

