"""`python -m pipeline bench [hulls] [maps] [sim] [obstacles] [coverage]`: the stage benchmarks
(pipeline/benches/), with the machine.

Benchmarks are separate from the tests (no timing is asserted anywhere). stdout gets a short table
(what, figure, target: `pipeline.bench_table`); `--json FILE` also writes the full dict of figures to
FILE, `--json -` prints that dict instead of the table. Progress ("== sim ...") goes to stderr.
"""
from __future__ import annotations

import contextlib
import json
import os
import platform
import sys
import time

BENCHES = {
    "hulls": "pipeline.benches.hulls",
    "maps": "pipeline.benches.maps",
    "sim": "pipeline.benches.sim",
    "obstacles": "pipeline.benches.obstacles",
    "coverage": "pipeline.benches.coverage",
}


def machine() -> dict:
    load = os.getloadavg() if hasattr(os, "getloadavg") else None
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next(l.split(":", 1)[1].strip() for l in f if l.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(),
            "load_average": [round(x, 2) for x in load] if load else None}


def _jsonable(x):
    import numpy as np   # lazily: the CLI reads BENCHES for its help without loading numpy

    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    return x


def run_benchmarks(which, output: str | None = None) -> dict:
    import importlib
    names = list(BENCHES) if not which or "all" in which else list(which)
    unknown = [n for n in names if n not in BENCHES]
    if unknown:
        from pipeline.schema import SceneError
        raise SceneError(f"bench: unknown benchmark {unknown[0]!r}; choose from {', '.join(BENCHES)} or all")
    results = {"machine": machine()}
    for n in names:
        print(f"== {n} ...", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        with contextlib.redirect_stdout(sys.stderr):   # what a bench prints itself is progress
            results[n] = _jsonable(importlib.import_module(BENCHES[n]).run_benchmark())
        results[n]["bench_wall_s"] = round(time.perf_counter() - t0, 2)
    if output == "-":
        print(json.dumps(results, indent=2), flush=True)
    else:
        from pipeline.bench_table import table
        print(table(results), flush=True)
        for n in names:
            if isinstance(results[n], dict) and "table" in results[n]:   # a bench's own table (markdown)
                print(f"\n{n}:\n{results[n]['table']}", flush=True)
        if output:
            with open(output, "w") as f:
                json.dump(results, f, indent=2)
    return results
