"""`python -m pipeline inspect PATTERN_specification.json`: a GarmentCode pattern as the pipeline
reads it (issue 39): its panels (part, edges by kind, flat size, area), its stitches (the two edges'
lengths), its size as placed for its body, the body it was made for, and a PNG of the panels.

`describe_pattern(path)` returns the facts as a dict (what `--json` prints), `pattern_text(facts)`
formats them and `pattern_png(path, out)` draws the panels (pipeline.pattern_png).
"""
from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np

BODY_KEYS = ("height", "bust", "waist", "hips", "shoulder_w", "arm_pose_angle")


def _edge_key(st_side) -> str:
    return f"{st_side[0]}.{st_side[1]}"


def describe_pattern(path) -> dict:
    """The facts of a GarmentCode specification file; InputError naming the file when unreadable."""
    from pipeline.assets import assets_dir
    from stages.errors import InputError
    from stages.garments.garmentcode import edge_length, euler_xyz_to_R, loop_points, panel_part, read_pattern
    from stages.garments.garmentcode_place import DEFAULT_BODY, body_of
    gc = read_pattern(path)
    panels, placed = [], []
    for p in gc.panels:
        outline = loop_points(p)
        lo, hi = outline.min(axis=0), outline.max(axis=0)
        x, y = outline[:, 0], outline[:, 1]
        area = 0.5 * abs(float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)))
        panels.append({"name": p.name, "part": panel_part(p), "label": p.label or None,
                       "edges": len(p.edges), "edge_kinds": dict(Counter(e.kind for e in p.edges)),
                       "edge_labels": sorted({e.label for e in p.edges if e.label}),
                       "size_cm": [round(100 * float(v), 1) for v in hi - lo], "area_cm2": round(1e4 * area, 1)})
        xyz = np.c_[outline, np.zeros(len(outline))] @ euler_xyz_to_R(p.rotation_deg).T + p.translation
        placed.append(xyz)
    by_name = {p.name: p for p in gc.panels}
    stitches = []
    for s in gc.stitches:
        la = edge_length(by_name[s.a[0]], by_name[s.a[0]].edges[s.a[1]])
        lb = edge_length(by_name[s.b[0]], by_name[s.b[0]].edges[s.b[1]])
        stitches.append({"a": _edge_key(s.a), "b": _edge_key(s.b), "length_cm": [round(100 * la, 1), round(100 * lb, 1)],
                         "right_wrong": s.right_wrong})
    allp = np.concatenate(placed)
    try:
        body = body_of(path, assets_dir() / DEFAULT_BODY)
        made_for = {"source": body.source, **{k: body.values[k] for k in BODY_KEYS if k in body.values}}
    except InputError as err:
        made_for = {"source": None, "problem": f"{err.source}: {err.problem}"}
    return {"kind": "garmentcode pattern", "path": str(path), "name": gc.name, "units_in_meter": gc.units_in_meter,
            "panels": panels, "stitches": stitches,
            "edge_kinds": dict(Counter(e.kind for p in gc.panels for e in p.edges)),
            "fabric_area_m2": round(sum(p["area_cm2"] for p in panels) / 1e4, 3),
            "placed_size_cm": [round(100 * float(v), 1) for v in allp.max(axis=0) - allp.min(axis=0)],
            "made_for": made_for}


def pattern_text(f: dict) -> str:
    """The facts as the terminal shows them."""
    out = [f"{f['path']}: GarmentCode pattern {f['name']!r}, {len(f['panels'])} panels, {len(f['stitches'])} stitches",
           f"  edges: {', '.join(f'{n} {k}' for k, n in sorted(f['edge_kinds'].items()))}; fabric "
           f"{f['fabric_area_m2']} m^2; placed size {' x '.join(map(str, f['placed_size_cm']))} cm (x, y, z)"]
    b = f["made_for"]
    if b["source"] is None:
        out.append(f"  made for: unknown ({b['problem']})")
    else:
        out.append(f"  made for: {b['source']}: " + ", ".join(f"{k} {v:g}" for k, v in b.items() if k != "source"))
    out.append("  panels (part, edges, flat size cm, area cm^2, edge labels):")
    for p in f["panels"]:
        kinds = ", ".join(f"{n} {k}" for k, n in sorted(p["edge_kinds"].items()))
        labels = f"  [{', '.join(p['edge_labels'])}]" if p["edge_labels"] else ""
        out.append(f"    {p['name']:<24} {p['part']:<5} {kinds:<34} {p['size_cm'][0]:>6} x {p['size_cm'][1]:<6} "
                   f"{p['area_cm2']:>8}{labels}")
    out.append("  stitches (edge, edge, lengths cm):")
    for s in f["stitches"]:
        rw = "  right_wrong" if s["right_wrong"] else ""
        out.append(f"    {s['a']:<28} {s['b']:<28} {s['length_cm'][0]:>6} {s['length_cm'][1]:>6}{rw}")
    return "\n".join(out)


def pattern_png(path, out: Path) -> Path:
    """Draw the flat panels of a pattern (file order, left to right) to `out`."""
    from pipeline.pattern_png import panels_image, write_png
    from stages.garments.garmentcode import edge_points, loop_points, panel_part, read_pattern
    gc = read_pattern(path)
    sewn = {(s.a[0], s.a[1]) for s in gc.stitches} | {(s.b[0], s.b[1]) for s in gc.stitches}
    panels = [{"outline": loop_points(p), "part": panel_part(p),
               "stitched": [edge_points(p, e, np.linspace(0.0, 1.0, 33)) for i, e in enumerate(p.edges)
                            if (p.name, i) in sewn]} for p in gc.panels]
    write_png(out, panels_image(panels))
    return out
