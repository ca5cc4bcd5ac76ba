"""`python -m pipeline bench [hulls] [maps] [sim] [obstacles] [coverage]`: the stage benchmarks, with the machine.

Benchmarks are separate from the tests (no timing is asserted anywhere); figures are printed as
JSON and optionally written to a file.
"""
from __future__ import annotations

import json
import os
import platform
import sys
import time

import numpy as np

BENCHES = {
    "hulls": "stages.hulls.bench",
    "maps": "stages.maps.bench",
    "sim": "stages.sim.bench",
    "obstacles": "stages.obstacles.bench",
    "coverage": "stages.coverage.bench",
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
        results[n] = _jsonable(importlib.import_module(BENCHES[n]).run_benchmark())
        results[n]["bench_wall_s"] = round(time.perf_counter() - t0, 2)
        print(json.dumps({n: results[n]}, indent=2), flush=True)
        if "table" in results[n]:       # a bench's own summary table (markdown)
            print(results[n]["table"], flush=True)
    if output:
        with open(output, "w") as f:
            json.dump(results, f, indent=2)
    return results
