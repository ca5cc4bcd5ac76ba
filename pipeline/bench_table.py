"""The short table `bench` prints: one row per headline figure (what, figure, target), from the
full results dict (`--json FILE` writes that dict; `--json -` prints it instead of the table).

A figure a bench did not produce (skipped, asset missing, an older bench) is left out; targets are
the issues' and the papers' (docs/benchmarks.md), '-' where there is none.
"""
from __future__ import annotations


def _get(d, *keys):
    for k in keys:
        if not isinstance(d, dict) or k not in d:
            return None
        d = d[k]
    return d


def _num(x, fmt: str = ",.0f") -> str:
    return format(x, fmt) if isinstance(x, (int, float)) else str(x)


def rows(results: dict) -> list[tuple[str, str, str]]:
    out = []
    hulls = results.get("hulls")
    if isinstance(hulls, dict):
        for key, r in hulls.items():
            if key.startswith("paper_body") and isinstance(r, dict) and "faces_simplified" in r:
                out.append((f"hulls: paper-like body ({key[len('paper_body_'):]}) raw -> simplified faces",
                            f"{r['faces_raw']} -> {r['faces_simplified']} in {r['seconds']:.3f} s", "224 -> 116 (paper)"))
        r = hulls.get("cesium_man_delta0.01_min40")
        if isinstance(r, dict) and "seconds_warm" in r:
            out.append(("hulls: CesiumMan colliders, delta 0.01 (warm)", f"{r['seconds_warm']:.3f} s", "-"))
    summary = _get(results, "maps", "summary")
    if isinstance(summary, dict):
        for label, r in summary.items():
            out.append((f"maps: {label} inside + response", f"{r['collide_qps'] / 1e6:.2f} M queries/s", "-"))
    sim = results.get("sim")
    if isinstance(sim, dict):
        for key, r in sim.items():
            if isinstance(r, dict) and "steps_per_s" in r:
                target = {"drape_default": ">= 500 frames/s (issue 15)",
                          "walk_tshirt_skirt_default": ">= 200 frames/s with cloth collision (issue 15)"}.get(key, "-")
                cc = ", cloth collision on" if r.get("cloth_collision") else ""
                out.append((f"sim: {key.replace('_', ' ')} ({r.get('preset', '')}{cc}, 1 thread)",
                            f"{r['frames_per_s']:,.0f} frames/s, {r['steps_per_s']:,.0f} sub-steps/s", target))
            elif isinstance(r, dict) and "skipped" in r:
                out.append((f"sim: {key}", f"skipped: {r['skipped']}", "-"))
        on, off = sim.get("walk_tshirt_skirt_default"), sim.get("walk_tshirt_skirt_default-off")
        if isinstance(on, dict) and isinstance(off, dict) and off.get("frames_per_s"):
            out.append(("sim: walk tshirt skirt, frames/s with cloth collision on / off",
                        f"{on['frames_per_s'] / off['frames_per_s']:.2f}", ">= 0.5 (issue 41)"))
    ob = results.get("obstacles")
    if isinstance(ob, dict) and "steps_per_s_total" in ob:
        out.append(("obstacles: cloth on a table, steps/s", _num(ob["steps_per_s_total"]), "-"))
        out.append(("obstacles: candidate pairs per traversal (brute force)",
                    f"{_num(ob['candidate_pairs_per_traversal'])} ({_num(ob['brute_pairs_per_pass'])})", "-"))
    cov = results.get("coverage")
    if isinstance(cov, dict):
        for name, per in cov.items():
            for mode, r in (per.items() if isinstance(per, dict) else ()):
                if isinstance(r, dict) and "coverage_min_pct" in r:
                    out.append((f"coverage: {name} {mode}", f"{r['coverage_min_pct']:.2f} %, excess p95 "
                                f"{r['excess_p95_cm']:.1f} cm", "100 % covered"))
    for name, r in results.items():
        if name != "machine" and isinstance(r, dict) and "bench_wall_s" in r:
            out.append((f"{name}: bench wall time", f"{r['bench_wall_s']:.1f} s", "-"))
    return out


def table(results: dict) -> str:
    m = results.get("machine") or {}
    head = (f"machine: {m.get('cpu', '?')}, {m.get('cores', '?')} cores, python {m.get('python', '?')}, "
            f"load average {m.get('load_average')}")
    body = rows(results)
    w = max([len("what")] + [len(r[0]) for r in body])
    f = max([len("figure")] + [len(r[1]) for r in body])
    lines = [head, f"{'what':<{w}}  {'figure':<{f}}  target", f"{'-' * w}  {'-' * f}  ------"]
    lines += [f"{a:<{w}}  {b:<{f}}  {c}" for a, b, c in body]
    return "\n".join(lines)
