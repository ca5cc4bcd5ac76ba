"""`python -m pipeline matrix --corpus`: every character and clip in the assets folder, dressed the
way a user writes a scene (the character, its clip, a start inside the clip, the garments; no tuning
keys), run as a sweep (pipeline.sweep: the process pool, a recording per pair) and judged against
the targets a user checks.

Characters: the built-in one and every .glb / .gltf / .bvh file at the top of the assets folder
(GARMENT_ASSETS, default ../shared/assets), found by listing it, so a file dropped there is in the
next check. A pair is a clip and a garment kind: every clip is worn at least once and every kind
the character can wear at least once (clips and kinds dealt round-robin; `full`: every clip with
every kind), plus one layered outfit (a T-shirt over shorts) per character that can wear both. A
kind the character cannot wear is a row with the one line `run` would print. Each scene starts at
START_SHARE of its clip.

GarmentCode patterns (issue 39): every `*_specification.json` under the assets folder's
garmentcode/ (examples and sampled designs) is dressed on every character, one scene each, its clip
dealt round-robin, as a `type: garmentcode` garment with nothing but its path (`patterns`: only
these names; `kinds=[]`: the patterns alone).

A pair passes when the run exits 0 and, after frame 0: at most IN_BODY_MAX of the particles inside
the body at every frame, no cloth edge through cloth, no body-mesh edge through the cloth at any
frame after the blend-in (pipeline.body_report; the dressing matrix reports that figure without
failing on it), strain p99 at the last frame at most STRAIN_P99_MAX, every sewn garment's seams closed to
SEAM_GAP_MAX before they were joined, and no garment slid off the body (SLIDE_MAX: its waistband or
collar, else its highest particles, at most that much farther from the skin they were dressed on at
any frame; a top with nothing to hold it slid down the body, through the floor before there was one
and onto it since), and its process peaked at most MEMORY_MAX_MB of resident memory. A hem that reaches the floor (a long skirt on a short character) rests on the
simulation's floor and is judged by the other figures.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import yaml

START_SHARE = 0.4        # scenes start 40 % into their clip: neither its first frame nor the rest pose
IN_BODY_MAX = 0.005      # share of a garment's particles inside the body, worst frame after frame 0
STRAIN_P99_MAX = 10.0    # %, last frame, worst garment
SEAM_GAP_MAX = 2.0       # mm, the largest seam gap the sewing left before joining the seams (issue 39)
SLIDE_MAX = 10.0         # cm: a garment whose waistband / collar moved farther than this off its skin slid off
MEMORY_MAX_MB = 2048.0   # a run's peak resident memory (its process: imports and kernels included; issue 37)
CHARACTER_FILES = (".glb", ".gltf", ".bvh")
OUTFIT = ("tshirt", "shorts")   # worn together: the T-shirt over the shorts


@dataclass
class CorpusCharacter:
    """One character of the corpus: its label, the scene's `character` mapping, its clips
    ((name, duration s), or none), the kinds it can wear and why it cannot wear the others."""
    label: str
    spec: dict
    clips: list = field(default_factory=list)
    wears: list = field(default_factory=list)
    refused: dict = field(default_factory=dict)     # kind -> one line
    refused_patterns: str = ""                      # why no GarmentCode pattern fits it ('': they do)


def assets_dir() -> Path:
    from pipeline.assets import assets_dir as shared
    return Path(shared())


def character_specs(assets: Path) -> list[tuple[str, dict]]:
    """(label, scene `character` mapping) of the built-in character and every character file."""
    out = [("builtin", {"source": "procedural", "clip": "walk"})]
    if assets.is_dir():
        for p in sorted(assets.iterdir()):
            if p.is_file() and p.suffix.lower() in CHARACTER_FILES:
                src = "bvh" if p.suffix.lower() == ".bvh" else "gltf"
                out.append((p.stem, {"source": src, "path": str(p.resolve())}))
    return out


def survey(label: str, spec: dict, kinds) -> CorpusCharacter:
    """Load the character as a scene would and find its clips and the kinds it can wear."""
    from pipeline.run import load_character
    from pipeline.scene import parse_scene_text
    from stages.errors import InputError
    from stages.garments.anchors import require_anchors, require_human
    from stages.rig.humanoid import humanoid_joints
    out = CorpusCharacter(label, dict(spec))
    scene = parse_scene_text(yaml.safe_dump({"character": {**spec, "clip": "rest"}}), source=f"corpus:{label}")
    character = load_character(scene)
    out.clips = [(c.name, float(c.duration)) for c in character.clips]
    joints = humanoid_joints(character)
    try:
        require_human(character, "GarmentCode patterns", joints)
    except InputError as err:
        out.refused_patterns = f"GarmentCode patterns cannot be dressed on {character.name!r}: {' '.join(err.problem.split())}"
    for kind in kinds:
        try:
            require_anchors(kind, character, f"garment {kind!r}", joints)
            out.wears.append(kind)
        except InputError as err:
            out.refused[kind] = f"{kind!r} cannot be dressed on {character.name!r}: {' '.join(err.problem.split())}"
    return out


def _slug(text: str) -> str:
    """The case label as the sweep keeps it (pipeline.sweep_file._slug leaves this one unchanged)."""
    from pipeline.sweep_file import _slug as sweep_slug
    return sweep_slug(text, 40).rstrip("-.") or "x"


def pattern_files(root: Path, names=None) -> list[Path]:
    """The GarmentCode patterns under `root` (**/*_specification.json), sorted; names: only these
    (the file name without _specification.json)."""
    found = sorted(root.rglob("*_specification.json")) if root.is_dir() else []
    if names:
        unknown = [n for n in names if n not in {pattern_name(p) for p in found}]
        if unknown:
            from pipeline.schema import SceneError
            raise SceneError(f"matrix --corpus --pattern: {', '.join(map(repr, unknown))} not found in {root}; "
                             f"patterns: {', '.join(pattern_name(p) for p in found)}")
        found = [p for p in found if pattern_name(p) in names]
    return found


def pattern_name(path: Path) -> str:
    return path.name[:-len("_specification.json")]


def pattern_cases(c: CorpusCharacter, patterns: list[Path]) -> list[dict]:
    """One scene per GarmentCode pattern on the character, its clips dealt round-robin (none on a
    character that is not a human: c.refused_patterns)."""
    if c.refused_patterns:
        return []
    clips = c.clips or [("rest", 0.0)]
    return [_case(c, *clips[i % len(clips)], [{"type": "garmentcode", "name": _slug(pattern_name(p)),
                                               "path": str(p.resolve())}], f"gc-{pattern_name(p)}")
            for i, p in enumerate(patterns)]


def cases_of(c: CorpusCharacter, *, full: bool = False, kinds=None, outfit: bool = True) -> list[dict]:
    """The sweep cases of one character: (clip, kind) pairs of the kinds it wears (of `kinds`, None:
    all) and, with `outfit`, the layered outfit."""
    clips = c.clips or [("rest", 0.0)]
    wears = [k for k in c.wears if kinds is None or k in kinds]
    pairs = []
    if wears and full:
        pairs = [(clip, kind) for clip in clips for kind in wears]
    elif wears:
        n = max(len(clips), len(wears))
        pairs = [(clips[i % len(clips)], wears[i % len(wears)]) for i in range(n)]
    out = []
    for (clip, duration), kind in pairs:
        out.append(_case(c, clip, duration, [{"type": "pattern", "name": kind, "kind": kind}], kind))
    if outfit and all(k in c.wears for k in OUTFIT):
        clip, duration = clips[0]
        # listed inner first: the shorts are layer 0, the T-shirt over them layer 1 (the list's order)
        out.append(_case(c, clip, duration, [{"type": "pattern", "name": k, "kind": k} for k in OUTFIT[::-1]],
                         "outfit"))
    return out


LABEL_MAX = 40   # characters of a case label the sweep keeps (pipeline.sweep_file)


def case_label(character: str, clip: str, what: str) -> str:
    """CHARACTER-CLIP-WHAT within LABEL_MAX, WHAT (the kind or gc-PATTERN) kept whole: the clip is left
    out where it repeats the character's name (a BVH file's one clip) and the front is shortened first.
    Cut at the end, the CMU walk's two dresses and two skirts were each one label in the table."""
    what = _slug(what)
    front = character if clip == character else f"{character}-{clip}"
    room = LABEL_MAX - len(what) - 1
    return _slug(f"{front[:max(room, 1)].rstrip('-.')}-{what}") if room > 0 else what[:LABEL_MAX]


def unique_labels(cases: list[dict]) -> list[dict]:
    """The cases with a label repeated (two names alike for their first LABEL_MAX characters) told
    apart by -2, -3, ... at its end."""
    seen, out = {}, []
    for k in cases:
        label = k["label"]
        seen[label] = seen.get(label, 0) + 1
        if seen[label] > 1:
            tail = f"-{seen[label]}"
            label = k["label"][:LABEL_MAX - len(tail)].rstrip("-.") + tail
        out.append(dict(k, label=label))
    return out


def _case(c: CorpusCharacter, clip: str, duration: float, garments: list, what: str) -> dict:
    start = round(START_SHARE * duration, 3)
    return {"label": case_label(c.label, clip, what), "character": {**c.spec, "clip": clip},
            "frames.start": start, "garments": garments}


def write_sweep(folder: Path, cases: list[dict], frames: int, timeout: float) -> Path:
    """The corpus as a sweep file in `folder` (what `python -m pipeline sweep` would run)."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "corpus.yaml"
    doc = {"name": "corpus", "output": str(folder.resolve()), "timeout": timeout,
           "base": {"frames": {"count": frames}}, "cases": cases}
    path.write_text("# written by `python -m pipeline matrix --corpus`: minimal scenes, no tuning keys\n"
                    + yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")
    return path


def verdict(row: dict) -> list[str]:
    """Why a corpus row fails its targets (empty: it passes)."""
    if row.get("status") != "ok":
        return [f"{row.get('failure') or row.get('status')}: {' '.join(str(row.get('message') or '').split())}"]
    out = []
    particles = row.get("particles") or 0
    if row.get("in_body_max") is not None and particles and row["in_body_max"] > IN_BODY_MAX * particles:
        out.append(f"{row['in_body_max']} of {particles} particles in the body ({100 * row['in_body_max'] / particles:.2f} %)")
    cross = (row.get("crossings_self_max") or 0) + (row.get("crossings_between_max") or 0)
    if cross:
        out.append(f"{cross} cloth edges through cloth")
    if row.get("body_edges_max"):
        out.append(f"{row['body_edges_max']} body edges through the cloth in a frame after the blend-in")
    if row.get("strain_p99_pct") is not None and row["strain_p99_pct"] > STRAIN_P99_MAX:
        out.append(f"strain p99 {row['strain_p99_pct']:.1f} % at the last frame")
    if row.get("seam_gap_mm") is not None and row["seam_gap_mm"] > SEAM_GAP_MAX:
        out.append(f"seams {row['seam_gap_mm']:.1f} mm open when joined")
    if row.get("slide_cm") is not None and row["slide_cm"] > SLIDE_MAX:
        out.append(f"slid {row['slide_cm']:.0f} cm off where it was dressed (waistband / collar from its skin)")
    if row.get("peak_memory_mb") is not None and row["peak_memory_mb"] > MEMORY_MAX_MB:
        out.append(f"peak memory {row['peak_memory_mb']:.0f} MB (limit {MEMORY_MAX_MB:.0f} MB)")
    return out


def run_corpus(folder: Path, *, frames: int = 30, characters: list[str] | None = None,
               kinds: list[str] | None = None, full: bool = False, jobs: int | None = None,
               timeout: float = 900.0, patterns: list[str] | None = None, with_patterns: bool = True,
               pattern_dir: Path | None = None, echo=print) -> list[dict]:
    """Survey the characters, run their pairs as a sweep in `folder`; rows (the sweep's, plus
    `character`, `pair`, `verdict`), the refused pairs included. kinds: the built-in kinds (None:
    all, []: none); patterns: only these GarmentCode patterns; with_patterns False: none of them;
    pattern_dir: the patterns of this folder instead of the assets folder's garmentcode/ (a user's own)."""
    from pipeline.matrix import KINDS
    from pipeline.sweep import run_sweep
    unknown = [k for k in kinds or () if k not in KINDS and k != "outfit"]
    if unknown:
        from pipeline.schema import SceneError
        raise SceneError(f"matrix --corpus --garment: {', '.join(map(repr, unknown))} is not a built-in kind; "
                         f"expected one of: {', '.join(map(repr, KINDS + ('outfit',)))}")
    outfit = kinds is None or "outfit" in kinds         # the layered outfit: --garment outfit asks for it alone
    kinds = [k for k in (KINDS if kinds is None else kinds) if k != "outfit"]
    asked = list(kinds)
    kinds += [k for k in OUTFIT if outfit and k not in kinds]
    if pattern_dir is not None and not Path(pattern_dir).is_dir():
        from pipeline.schema import SceneError
        raise SceneError(f"matrix --corpus --patterns: {pattern_dir}: no such folder; expected a folder holding "
                         f"GarmentCode *_specification.json files (in subfolders or not)")
    root = Path(pattern_dir) if pattern_dir is not None else assets_dir() / "garmentcode"
    gc_files = pattern_files(root, patterns) if with_patterns else []
    if pattern_dir is not None and with_patterns and not gc_files:
        from pipeline.schema import SceneError
        raise SceneError(f"matrix --corpus --patterns: {pattern_dir}: no *_specification.json file in it or below it")
    specs = character_specs(assets_dir())
    if characters:
        unknown = [n for n in characters if n not in {label for label, _ in specs}]
        if unknown:
            from pipeline.schema import SceneError
            raise SceneError(f"matrix --corpus --character: {', '.join(map(repr, unknown))} not found; "
                             f"characters: {', '.join(label for label, _ in specs)}")
        specs = [(label, s) for label, s in specs if label in characters]
    cases, refused = [], []
    for label, spec in specs:
        try:
            c = survey(label, spec, kinds)
        except Exception as err:   # a file the loader refuses: one row, the line a run prints
            refused.append({"character": label, "pair": "(loading)", "status": "refused",
                            "verdict": [" ".join(str(err).split())]})
            continue
        echo(f"{label}: {len(c.clips)} clip(s), wears {', '.join(c.wears) or 'no built-in kind'}"
             f"{f' and {len(gc_files)} GarmentCode pattern(s)' if gc_files and not c.refused_patterns else ''}")
        cases += [dict(k, _character=label) for k in cases_of(c, full=full, kinds=asked, outfit=outfit)
                  + pattern_cases(c, gc_files)]
        refused += [{"character": label, "pair": kind, "status": "refused", "verdict": [why]}
                    for kind, why in c.refused.items() if kind in asked]
        if gc_files and c.refused_patterns:
            refused.append({"character": label, "pair": f"{len(gc_files)} GarmentCode patterns", "status": "refused",
                            "verdict": [c.refused_patterns]})
    cases = unique_labels(cases)
    by_label = {k["label"]: k.pop("_character") for k in cases}
    rows = []
    if cases:
        path = write_sweep(folder, cases, frames, timeout)
        _, got = run_sweep(path, jobs=jobs, progress=True, echo=echo)
        for r in got:
            r = dict(r)
            r["character"] = by_label.get(r.get("case"), "?")
            r["pair"] = r.get("case", "")
            r["verdict"] = verdict(r)
            rows.append(r)
    return rows + refused


def table(rows: list[dict]) -> str:
    """The corpus as a user reads it: one line per pair, pass or the reasons it fails."""
    head = ["character", "pair", "result", "in body (max %)", "crossings", "body edges through cloth",
            "body edges where the body meets itself (not judged)",
            "strain p99 last (%)", "seam gap (mm)", "fit gap (cm)", "peak memory (MB)"]
    out = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]

    def num(v, fmt):
        return "" if v is None else format(v, fmt)
    for r in rows:
        p = r.get("particles") or 0
        body = 100 * r["in_body_max"] / p if r.get("in_body_max") is not None and p else None
        cross = None if r.get("crossings_self_max") is None else r["crossings_self_max"] + (r.get("crossings_between_max") or 0)
        result = "pass" if not r["verdict"] else "FAIL: " + "; ".join(r["verdict"])
        out.append("| " + " | ".join([r["character"], r["pair"], result.replace("|", "/"), num(body, ".2f"),
                                      num(cross, "d"), num(r.get("body_edges_max"), "d"),
                                      num(r.get("body_edges_overlap_max"), "d"),
                                      num(r.get("strain_p99_pct"), ".1f"),
                                      num(r.get("seam_gap_mm"), ".1f"), num(r.get("fit_gap_cm"), ".1f"),
                                      num(r.get("peak_memory_mb"), ".0f")]) + " |")
    passed = sum(not r["verdict"] for r in rows)
    out += ["", f"{passed} of {len(rows)} pairs pass"]
    return "\n".join(out)


def default_folder() -> Path:
    return Path(os.environ.get("GARMENT_CORPUS_DIR", "sweeps/corpus"))
