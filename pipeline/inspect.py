"""`python -m pipeline inspect ASSET.glb|ASSET.gltf|ASSET.bvh|builtin`: what a character file holds, as
the pipeline reads it: the joint tree, the clips, the mesh size, the units and up axis taken, and
which joints the garments will anchor on (`stages.rig.humanoid.humanoid_joints`).

`describe(path)` returns the facts as a dict (what `--json` prints); `text(facts)` formats them.
A file that cannot be read raises `InputError` naming it (the CLI prints one line, exit 2).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

BUILTIN = "builtin"
SUFFIXES = (".glb", ".gltf", ".bvh")


def load_asset(path: str):
    """(Character, kind) from a .glb/.gltf/.bvh file, or the built-in procedural character."""
    from stages.errors import InputError
    if str(path) == BUILTIN:
        from stages.rig.procedural import procedural_character
        return procedural_character(), "builtin"
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix not in SUFFIXES:
        raise InputError(p, f"not a character file: expected {', '.join(SUFFIXES)} or '{BUILTIN}'")
    from stages.input_files import file_problem
    problem = file_problem(p, "character file")
    if problem:
        raise InputError(p, problem)
    if suffix == ".bvh":
        from stages.rig.bvh_character import load_bvh_character
        return load_bvh_character(p), "bvh"
    from stages.rig.gltf import load_gltf
    return load_gltf(p), "gltf"


def _tree(names, parents) -> list:
    """Depth-first (joint index, depth) pairs: parents[j] < j, children in index order."""
    kids: dict[int, list] = {}
    for j, p in enumerate(parents):
        kids.setdefault(int(p), []).append(j)
    out, stack = [], [(r, 0) for r in reversed(kids.get(-1, []))]
    while stack:
        j, d = stack.pop()
        out.append((j, d))
        stack += [(c, d + 1) for c in reversed(kids.get(j, []))]
    return out


def bone_mapping(character) -> dict:
    """Each humanoid part -> {"joints": [names] or None, "found": 'name' | 'shape' | 'missing'};
    plus "needs": garment kind -> the parts it anchors on that are missing."""
    from stages.garments.anchors import ANCHORS, QUADRUPED_KINDS
    from stages.rig.humanoid import humanoid_joints
    h = humanoid_joints(character)
    names = character.joint_names
    parts = {}
    for kind in ("arm", "leg"):
        for side in ("l", "r"):
            part = f"{kind}_{side}"
            # a chain, or a limb of one or two joints (a trouser leg or a sleeve is placed on the points
            # measured on its skin)
            chain = h.limb(kind, side) or h.short.get(part)
            parts[part] = {"joints": None if chain is None else [names[j] for j in chain],
                           "found": "missing" if chain is None else h.found.get(part, "shape"),
                           "why": h.why.get(part, "")}
    for part in ("chest", "neck", "head"):
        j = getattr(h, part)
        # the spine parts are placed by the skeleton's shape (where the arms branch off), a neck by its
        # name where no arms are found
        parts[part] = {"joints": None if j < 0 else [names[j]],
                       "found": "missing" if j < 0 else h.found.get(part, "shape") if part == "neck" else "shape",
                       "why": h.why.get(part, "")}
    # a skirt's anchor: both legs, of any number of joints
    parts["hips"] = {"joints": None if h.hips < 0 else [names[h.hips]],
                     "found": "missing" if h.hips < 0 else "shape", "why": h._why("hips")}
    missing = {p for p, v in parts.items() if v["found"] == "missing"}
    needs = {kind: sorted(set(anchors) & missing) for kind, anchors in ANCHORS.items() if set(anchors) & missing}
    from stages.garments.quadruped import front_legs
    legs = front_legs(character, h)
    if legs:   # four legs: a cape is a blanket over the back, the biped kinds are refused
        needs = {kind: ["a biped"] for kind in ANCHORS if kind not in QUADRUPED_KINDS}
        parts["front legs"] = {"joints": [", ".join(names[j] for j in legs)], "found": "shape", "why": ""}
    return {"parts": parts, "missing": sorted(missing), "garments_blocked": needs,
            "anchors": {k: list(v) for k, v in ANCHORS.items()}}


def _units(character, kind: str, path: str) -> dict:
    if kind == "gltf":  # the loader's notes say what it took and why (stages.rig.gltf_nodes.choose_units)
        up = next((n for n in character.notes if n.startswith("up axis")), "up axis: file +Y")
        units = next((n for n in character.notes if n.startswith("units:")), "units: metres (glTF convention), scale 1")
        return {"lengths": units.split(":", 1)[1].strip(), "up_axis": up.split(":", 1)[1].strip(),
                "notes": [n for n in character.notes if not n.startswith(("up axis", "units:"))]}
    if kind == "bvh":
        from stages.rig.bvh import parse_bvh
        data = parse_bvh(path)
        return {"lengths": "file units taken as metres, scale 1 (BVH has no unit)",
                "up_axis": "file +Y (BVH convention, not detected)",
                "notes": [f"frame time {data.frame_time:.6g} s ({1.0 / data.frame_time:.4g} Hz), "
                          f"{len(data.channels)} joints ({int(np.sum(data.end_site))} end sites), "
                          f"{sum(len(c) for c in data.channels)} channels",
                          "mesh: a skin generated around the skeleton (BVH holds no mesh), bound in the "
                          "neutral pose, lifted to stand on y = 0"] + list(character.notes)}
    return {"lengths": "metres", "up_axis": "+Y (built in)", "notes": list(character.notes)}


def describe(path: str) -> dict:
    """Everything `inspect` shows, as plain JSON-able values."""
    character, kind = load_asset(path)
    v = character.vertices
    names, parents = character.joint_names, np.asarray(character.parents)
    clips = []
    for c in character.clips:
        clips.append({"name": c.name, "duration_s": round(c.duration, 6), "frames": int(c.times.size),
                      "interpolation": c.interpolation, "loop": bool(c.loop)})
    tree = [{"index": j, "name": names[j], "parent": None if parents[j] < 0 else names[parents[j]], "depth": d}
            for j, d in _tree(names, parents)]
    lo, hi = v.min(axis=0), v.max(axis=0)
    return {
        "file": str(path), "kind": kind, "name": character.name,
        "mesh": {"vertices": int(v.shape[0]), "triangles": int(character.triangles.shape[0]),
                 "primitives": int(np.unique(character.primitive_ids).size),
                 "height_m": round(float(hi[1] - lo[1]), 4),
                 "bounds_m": [[round(float(x), 4) for x in lo], [round(float(x), 4) for x in hi]]},
        "units": _units(character, kind, path),
        "joints": {"count": int(len(names)), "root": names[character.root_joint], "tree": tree},
        "clips": clips,
        "humanoid": bone_mapping(character),
    }


def text(facts: dict) -> str:
    m, u, h = facts["mesh"], facts["units"], facts["humanoid"]
    lines = [f"{facts['file']}: {facts['kind']} character {facts['name']!r}",
             f"mesh: {m['vertices']} vertices, {m['triangles']} triangles, {m['primitives']} primitive(s), "
             f"height {m['height_m']:.3f} m",
             f"units: {u['lengths']}; up axis: {u['up_axis']}"]
    lines += [f"  {n}" for n in u["notes"]]
    lines.append(f"clips ({len(facts['clips'])}):")
    lines += [f"  {c['name']}: {c['duration_s']:.3f} s, {c['frames']} frames ({c['interpolation']}"
              f"{', loops' if c['loop'] else ''})" for c in facts["clips"]] or ["  (none: rest pose only)"]
    lines.append(f"joints ({facts['joints']['count']}, root {facts['joints']['root']}):")
    lines += [f"  {'  ' * t['depth']}{t['name']}" for t in facts["joints"]["tree"]]
    lines.append("garment anchors (stages.rig.humanoid):")
    for part, p in h["parts"].items():
        what = " > ".join(p["joints"]) if p["joints"] else "-"
        how = {"name": "by name", "shape": "by the skeleton's shape", "missing": "MISSING"}[p["found"]]
        lines.append(f"  {part:<6} {what}  ({how})")
        if p.get("why") and p["found"] == "missing":
            lines.append(f"         {p['why']}")
    if "front legs" in h["parts"]:
        lines.append("  four legs: a cape is dressed as a blanket over the back, pinned along the spine")
    if h["garments_blocked"]:
        for kind, parts in h["garments_blocked"].items():
            if parts == ["a biped"]:
                lines.append(f"  garment {kind!r} cannot be dressed: needs a biped")
                continue
            lines.append(f"  garment {kind!r} cannot be dressed: needs {', '.join(h['anchors'][kind])}; "
                         f"missing {', '.join(parts)}")
    else:
        lines.append("  every garment kind can anchor")
    return "\n".join(lines)
