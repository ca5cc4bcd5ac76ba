"""Where numba's compile time goes: run a pipeline command in-process with a listener on numba's
compile events and print, per kernel, the compiled signatures and the exclusive compile time
(the time of its own compilation minus that of the kernels it compiled on the way).

    python tools/compile_profile.py [--top N] [--json FILE] -- run scenes/default.yaml -q

Clear the cache first for a cold figure (numba writes *.nbi / *.nbc into the __pycache__ folders
beside the modules): `find stages -name '*.nbi' -o -name '*.nbc' | xargs rm -f`. With a warm cache
the table lists only what numba had to compile (a stale or missing cache entry).
`run` compiles the simulation's kernels in a second process on a first run (pipeline.kernel_warmup);
this tool turns that off (GARMENT_BACKGROUND_COMPILE=0) so that every compile is counted here.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections import defaultdict

from numba.core import event

sys.path.insert(0, os.getcwd())     # the tree it is run from (not the installed one)


class _Exclusive(event.Listener):
    def __init__(self):
        self.stack = []          # [name, start, child time]
        self.dispatchers = {}
        self.rows = defaultdict(lambda: {"exclusive_s": 0.0, "inclusive_s": 0.0, "llvm_s": 0.0, "signatures": []})

    def on_start(self, ev):
        d = ev.data["dispatcher"]
        name = f"{d.py_func.__module__}.{d.py_func.__qualname__}"
        self.stack.append([name, time.perf_counter(), 0.0, ev.data.get("args")])
        self.dispatchers[name] = d

    def on_end(self, ev):
        name, t0, child, args = self.stack.pop()
        dt = time.perf_counter() - t0
        row = self.rows[name]
        row["exclusive_s"] += dt - child
        # a recursive compile of the same kernel (its own signature twice) counts once inclusive
        row["inclusive_s"] += dt
        row["signatures"].append(str(args))
        if self.stack:
            self.stack[-1][2] += dt


class _LLVMShare(event.Listener):
    """LLVM time (numba's llvm lock held) charged to the kernel being compiled."""

    def __init__(self, compiles):
        self.compiles = compiles
        self.depth = 0

    def on_start(self, ev):
        if self.depth == 0:
            self.t0 = time.perf_counter()
        self.depth += 1

    def on_end(self, ev):
        self.depth -= 1
        if self.depth == 0 and self.compiles.stack:
            self.compiles.rows[self.compiles.stack[-1][0]]["llvm_s"] += time.perf_counter() - self.t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--top", type=int, default=40)
    ap.add_argument("--json")
    ap.add_argument("--passes", type=int, default=0, help="numba pass times of the N slowest kernels")
    ap.add_argument("command", nargs=argparse.REMAINDER)
    a = ap.parse_args(argv)
    cmd = a.command[1:] if a.command[:1] == ["--"] else a.command
    os.environ.setdefault("GARMENT_BACKGROUND_COMPILE", "0")    # every compile in this process
    listener = _Exclusive()
    event.register("numba:compile", listener)
    llvm = event.TimingListener()       # the part of it spent in LLVM (optimisation, code generation)
    event.register("numba:llvm_lock", llvm)
    event.register("numba:llvm_lock", _LLVMShare(listener))
    from pipeline.cli import main as cli_main
    t0 = time.perf_counter()
    rc = cli_main(cmd)
    wall = time.perf_counter() - t0
    rows = sorted(listener.rows.items(), key=lambda kv: -kv[1]["exclusive_s"])
    total = sum(r["exclusive_s"] for _, r in rows)
    print(f"\nwall {wall:.1f} s, compiling {total:.1f} s in {sum(len(r['signatures']) for _, r in rows)} "
          f"compilations of {len(rows)} kernels; LLVM {llvm.duration if llvm.done else 0.0:.1f} s of it", file=sys.stderr)
    print(f"{'exclusive s':>11} {'LLVM s':>7} {'n':>3}  kernel", file=sys.stderr)
    for name, r in rows[:a.top]:
        print(f"{r['exclusive_s']:11.2f} {r['llvm_s']:7.2f} {len(r['signatures']):3d}  {name}", file=sys.stderr)
    if a.passes:
        for name, _ in rows[:a.passes]:
            times = defaultdict(float)
            for cres in listener.dispatchers[name].overloads.values():
                for pipeline, passes in cres.metadata.get("pipeline_times", {}).items():
                    for pname, t in passes.items():
                        times[pname.split("_", 1)[-1]] += t.init + t.run + t.finalize
            top = sorted(times.items(), key=lambda kv: -kv[1])[:6]
            print(f"  {name}: " + ", ".join(f"{k} {v:.2f}" for k, v in top), file=sys.stderr)
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"wall_s": wall, "compile_s": total, "kernels": dict(rows)}, f, indent=1)
    return rc


if __name__ == "__main__":
    sys.exit(main())
