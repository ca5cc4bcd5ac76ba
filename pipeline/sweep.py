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

import copy
import csv
import hashlib
import json
import math
import os
import re
import sys
import time
from dataclasses import dataclass, field
from itertools import product
from pathlib import Path

import yaml

from pipeline.schema import REQUIRED, Field, SceneError, validate

FAILURES = ("sewing", "timeout", "diverged", "bad-input", "crash")

# the metrics row, in table order; the override columns (one per swept key) follow `job`
COLUMNS = ("job", "status", "failure", "message", "frames", "frames_done", "particles",
           "in_body_max", "in_colliders_max", "strain_mean_pct", "strain_p99_pct", "strain_p99_worst_pct",
           "crossings_self_max", "crossings_between_max", "seam_gap_mm", "fit_gap_cm", "floor_cm",
           "coverage_min_pct", "excess_p95_cm", "warnings",
           "wall_s", "frames_per_s", "sim_frames_per_s", "warm_up_s", "worker", "recording", "exports")
# columns that depend on the machine and its load, not on the job: left out when comparing tables
TIMING_COLUMNS = ("wall_s", "frames_per_s", "sim_frames_per_s", "warm_up_s", "worker")
INT_COLUMNS = ("frames", "frames_done", "particles", "in_body_max", "in_colliders_max", "crossings_self_max",
               "crossings_between_max", "warnings")
FLOAT_COLUMNS = ("strain_mean_pct", "strain_p99_pct", "strain_p99_worst_pct", "seam_gap_mm", "fit_gap_cm",
                 "floor_cm", "coverage_min_pct", "excess_p95_cm", "wall_s", "frames_per_s", "sim_frames_per_s",
                 "warm_up_s")


class SweepError(SceneError):
    """A bad sweep file or a combination that is not a valid scene: one line naming the file, the
    key, the bad value and what was expected (exit 2)."""


class JobTimeout(BaseException):
    """Raised inside a job at its deadline. A BaseException so that no `except Exception` in the
    stages swallows it."""


# ------------------------------------------------------------------ the sweep file

def _check_grid(g):
    if not isinstance(g, dict):
        return f"expected a mapping of dotted scene keys to lists of values, got {g!r}"
    for key, values in g.items():
        problem = _key_problem(key)
        if problem:
            return f"{key!r}: {problem}"
        if isinstance(values, dict):
            if not values:
                return f"{key!r}: expected at least one labelled value, got an empty mapping"
            for label in values:
                if not isinstance(label, (str, int)) or isinstance(label, bool):
                    return f"{key!r}: label {label!r}: expected a string"
        elif not isinstance(values, list) or not values:
            return (f"{key!r}: expected a non-empty list of values (or a mapping label: value), "
                    f"got {values!r}")
    return None


def _check_case(c):
    if not isinstance(c, dict) or not c:
        return f"expected a mapping of dotted scene keys to values (and an optional 'label'), got {c!r}"
    for key, value in c.items():
        if key == "label":
            if not isinstance(value, (str, int)) or isinstance(value, bool):
                return f"label: expected a string, got {value!r}"
            continue
        problem = _key_problem(key)
        if problem:
            return f"{key!r}: {problem}"
    return None


SWEEP_SPEC = {
    "base": Field("any", REQUIRED, "the base scene: a scene file (relative to the sweep file) or a scene mapping"),
    "name": Field("str", None, "sweep name; default: the sweep file's name without .yaml"),
    "output": Field("path", None, "results folder; default sweeps/<name> in the working folder"),
    "timeout": Field("float", 600.0, "seconds per job; null = none", lo=0.0, lo_open=True, nullable=True),
    "jobs": Field("int", None, "worker processes (default: every core)", lo=1, hi=4096),
    "warm_up": Field("bool", True, "each worker loads (or compiles) the numba kernels before its first job"),
    "grid": Field("any", {}, "dotted scene key -> list of values (or mapping label -> value); every combination",
                  check=_check_grid),
    "cases": Field("list", [], "override sets, each a mapping of dotted scene keys to values",
                   item=Field("any", check=_check_case)),
}

_KEY_PART = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)((?:\[\d+\])*)")
SWEEP_SET = ("output", "output.path", "output.export_dir")   # the sweep places every job's files


def parse_key(key: str) -> list:
    """'garments[0].options.ease' -> ['garments', 0, 'options', 'ease']; ValueError when malformed."""
    if not isinstance(key, str) or not key:
        raise ValueError("expected a dotted scene key such as 'seed' or 'garments[0].kind'")
    out: list = []
    for part in key.split("."):
        m = _KEY_PART.fullmatch(part)
        if not m:
            raise ValueError(f"{part!r} is not a key name or name[index] (expected a dotted scene key such as "
                             f"'garments[0].kind')")
        out.append(m.group(1))
        out += [int(i) for i in re.findall(r"\[(\d+)\]", m.group(2))]
    return out


def _key_problem(key) -> str | None:
    try:
        parse_key(key)
    except ValueError as e:
        return str(e)
    if key in SWEEP_SET:
        return "set by the sweep (each job writes into its own folder); override 'output.export' instead"
    return None


def _slug(text: str, limit: int = 24) -> str:
    s = re.sub(r"[^A-Za-z0-9_.-]+", "-", str(text)).strip("-.")
    return (s or "x")[:limit]


def _label(value, index: int) -> str:
    if isinstance(value, (str, int, float, bool)) or value is None:
        return str(value)
    if isinstance(value, dict) and isinstance(value.get("path"), str):   # a character or mesh file
        return Path(value["path"]).stem
    if isinstance(value, dict) and isinstance(value.get("kind"), str):
        return value["kind"]
    return f"v{index}"


def job_id(labels: list[str], overrides: dict) -> str:
    """The labels of the job's values (readable) plus a hash of the override values (stable: the
    same overrides give the same id in any run, on any machine)."""
    digest = hashlib.sha1(json.dumps(overrides, sort_keys=True, default=str).encode()).hexdigest()[:8]
    head = "_".join(_slug(x) for x in labels)[:80] or "base"
    return f"{head}-{digest}"


@dataclass
class Job:
    """One combination. overrides: dotted key -> value (applied in order); labels: dotted key -> the
    value's label; blame: dotted key -> (where in the sweep file, 'line:col' or '')."""

    id: str
    overrides: dict
    labels: dict
    blame: dict
    text: str = ""          # the job's scene (YAML), as the recording stores it
    source: str = ""        # how messages name the job's scene
    dir: str = ""           # OUT/jobs/<id>
    formats: list = field(default_factory=list)

    def spec(self, base_dir: Path, timeout: float | None) -> dict:
        """What a worker needs (picklable, plain)."""
        return {"id": self.id, "text": self.text, "source": self.source, "base_dir": str(base_dir),
                "dir": self.dir, "labels": dict(self.labels), "timeout": timeout}


@dataclass
class Sweep:
    path: Path
    name: str
    out: Path
    base_path: Path | None
    base_dir: Path
    base_data: dict
    timeout: float | None
    workers: int | None
    warm_up: bool
    keys: list          # the label columns: 'case' (with cases), then the grid keys
    jobs: list          # Job, in expansion order


def _marks_of(text: str) -> dict:
    from pipeline.scene import _marks
    marks: dict = {}
    node = yaml.compose(text, Loader=yaml.SafeLoader)
    if node is not None:
        _marks(node, "", marks)
    return marks


def _at(path: Path, marks: dict, key: str) -> str:
    m = marks.get(key) or marks.get("@" + key)
    return f"{path}:{m[0]}:{m[1]}" if m else str(path)


def load_sweep(path: str | os.PathLike, output: str | os.PathLike | None = None) -> Sweep:
    """Read a sweep file and expand it into jobs; every problem is a SweepError (one line, file, key,
    value, what was expected). Does not validate the jobs' scenes (`validate_jobs`)."""
    from pipeline.scene import _UniqueKeyLoader
    p = Path(path)
    if not p.is_file():
        raise SweepError(f"{p}: sweep file not found" if not p.exists() else f"{p}: is a folder, expected a .yaml sweep file")
    try:
        text = p.read_text(encoding="utf-8")
        data = yaml.load(text, Loader=_UniqueKeyLoader)
        marks = _marks_of(text)
    except yaml.MarkedYAMLError as e:
        m = e.problem_mark or e.context_mark
        raise SweepError(f"{p}:{m.line + 1}:{m.column + 1}: YAML syntax error: {e.problem or e}" if m
                         else f"{p}: YAML syntax error: {e}") from None
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as e:
        raise SweepError(f"{p}: cannot read the sweep file ({type(e).__name__}: {e})") from None
    if not isinstance(data, dict):
        raise SweepError(f"{p}: expected a mapping with 'base:' and 'grid:' and/or 'cases:', got {data!r}")
    try:
        s = validate(SWEEP_SPEC, data, source=str(p), marks=marks, base_dir=p.resolve().parent)
    except SweepError:
        raise
    except SceneError as e:
        raise SweepError(str(e)) from None
    name = s["name"] or p.stem
    if not re.fullmatch(r"[A-Za-z0-9_.-]+", name):
        raise SweepError(f"{_at(p, marks, 'name')}: name: {name!r} must use only letters, digits, '_', '-' and '.'")

    # the base scene, raw (the overrides apply to what the file says, before defaults)
    base = s["base"]
    if isinstance(base, str):
        from pipeline.schema import expand_path_vars
        bp = Path(expand_path_vars(base)).expanduser()
        bp = bp if bp.is_absolute() else p.resolve().parent / bp
        if not bp.is_file():
            raise SweepError(f"{_at(p, marks, 'base')}: base: scene file not found: {bp}")
        from pipeline.scene import load_scene
        load_scene(bp)   # the base alone must be a valid scene (its own file, line and column)
        base_data = yaml.safe_load(bp.read_text(encoding="utf-8"))
        base_path, base_dir = bp, bp.parent
    elif isinstance(base, dict):
        base_data, base_path, base_dir = copy.deepcopy(base), None, p.resolve().parent
    else:
        raise SweepError(f"{_at(p, marks, 'base')}: base: expected a scene file path or a scene mapping, got {base!r}")

    # grid axes: (key, [(label, value, mark key)])
    axes = []
    for key, values in s["grid"].items():
        if isinstance(values, dict):
            vals = [(_slug(str(lab), 40), v, f"grid.{key}.{lab}") for lab, v in values.items()]
        else:
            vals = [(_label(v, i), v, f"grid.{key}[{i}]") for i, v in enumerate(values)]
        axes.append((key, vals))
    cases = []
    for i, c in enumerate(s["cases"]):
        label = _slug(str(c.get("label", f"case{i}")), 40)
        items = [(k, v) for k, v in c.items() if k != "label"]
        for k, _ in items:
            if k in s["grid"]:
                raise SweepError(f"{_at(p, marks, f'cases[{i}].{k}')}: cases[{i}].{k}: also a grid key; "
                                 f"expected each key in the grid or in the cases, not both")
        cases.append((label, items, i))

    keys = (["case"] if cases else []) + [k for k, _ in axes]   # the table's columns of the job's labels
    jobs, seen = [], {}
    for case in (cases or [None]):
        for point in product(*[vals for _, vals in axes]):
            overrides, labels, blame, names = {}, {}, {}, []
            if case is not None:
                label, items, ci = case
                names.append(label)
                labels["case"] = label
                for k, v in items:
                    overrides[k] = v
                    blame[k] = (_at(p, marks, f"cases[{ci}].{k}"), f"cases[{ci}] ({label!r}) {k!r}")
            for (key, _), (lab, value, mk) in zip(axes, point):
                overrides[key], labels[key] = value, lab
                blame[key] = (_at(p, marks, mk), f"grid {key!r}")
                names.append(lab)
            jid = job_id(names, overrides)
            if jid in seen:
                raise SweepError(f"{p}: two combinations are the same job ({jid}): {seen[jid]} and {overrides}; "
                                 f"expected every combination to differ")
            seen[jid] = overrides
            jobs.append(Job(jid, overrides, labels, blame))

    out = Path(output) if output is not None else Path(s["output"]) if s["output"] else Path("sweeps") / name
    sw = Sweep(path=p, name=name, out=out, base_path=base_path, base_dir=base_dir, base_data=base_data,
               timeout=s["timeout"], workers=s["jobs"], warm_up=s["warm_up"], keys=keys, jobs=jobs)
    for job in jobs:
        _compose(sw, job)
    return sw


def _set(data, parts: list, value, key: str):
    """Set data[parts] = value; a missing mapping on the way is created, a list index must exist."""
    cur = data
    for i, part in enumerate(parts):
        last = i == len(parts) - 1
        where = key if last else "".join(f"[{q}]" if isinstance(q, int) else f".{q}" for q in parts[:i + 1]).lstrip(".")
        if isinstance(part, int):
            if not isinstance(cur, list):
                raise ValueError(f"{where}: the base scene has no list here to index with [{part}]")
            if part >= len(cur):
                raise ValueError(f"{where}: index {part} is out of range: the base scene's list has {len(cur)} "
                                 f"item(s), expected 0 to {len(cur) - 1}")
        else:
            if not isinstance(cur, dict):
                raise ValueError(f"{where}: the base scene has no mapping here to set {part!r} in")
            if not last and cur.get(part) is None:
                if isinstance(parts[i + 1], int):
                    raise ValueError(f"{where}: not in the base scene (expected a list to index with [{parts[i + 1]}])")
                cur[part] = {}
        if last:
            cur[part] = copy.deepcopy(value)
        else:
            cur = cur[part]


def _compose(sw: Sweep, job: Job) -> None:
    """The job's scene text (base + overrides + its output paths), its folder and export formats."""
    data = copy.deepcopy(sw.base_data) if isinstance(sw.base_data, dict) else {}
    for key, value in job.overrides.items():
        try:
            _set(data, parse_key(key), value, key)
        except ValueError as e:
            at, what = job.blame[key]
            raise SweepError(f"{at}: {what} = {_short(value)} (job {job.id}): {e}") from None
    out = data.get("output")
    formats = list(out.get("export") or []) if isinstance(out, dict) else []
    job.dir = str((sw.out / "jobs" / job.id).resolve())
    data["output"] = {"path": str(Path(job.dir) / f"{job.id}.rrd"), "export": formats,
                      "export_dir": str(Path(job.dir) / "export")}
    job.formats = formats
    head = f"# sweep {sw.path} job {job.id}: " + json.dumps(job.overrides, default=str)
    job.text = head + "\n" + yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=110)
    job.source = f"{sw.path}[{job.id}]"


def _short(v) -> str:
    s = json.dumps(v, default=str) if not isinstance(v, str) else repr(v)
    return s if len(s) <= 80 else s[:77] + "..."


def job_scene(text: str, source: str, base_dir: str | Path):
    """The Scene of a job's YAML (validated as any scene; messages name `source`)."""
    from pipeline.scene import Scene, scene_from_data
    data = yaml.safe_load(text)
    sc = scene_from_data(data, text=text, source=source, base_dir=Path(base_dir), default_name="sweep")
    return Scene(path=Path(source), name=sc.name, text=text, settings=sc.settings, export=sc.export)


def _blame(job: Job, message: str) -> SweepError:
    """A job's scene error as a sweep error: the override responsible (file:line:col, key, value)."""
    msg = " ".join(str(message).split())
    rest = msg[len(job.source) + 2:] if msg.startswith(job.source + ": ") else msg
    keypath = rest.split(": ", 1)[0].split(" ")[0]
    for key in reversed(list(job.overrides)):
        if (keypath == key or keypath.startswith((key + ".", key + "["))
                or key.startswith((keypath + ".", keypath + "["))):
            at, what = job.blame[key]
            return SweepError(f"{at}: {what} = {_short(job.overrides[key])} (job {job.id}): {rest}")
    given = ", ".join(f"{k}={_short(v)}" for k, v in job.overrides.items())
    return SweepError(f"{job.source.split('[')[0]}: job {job.id} ({given or 'the base scene'}): {rest}")


def validate_jobs(sw: Sweep, echo=None) -> None:
    """Every combination's scene checked before any job runs: the scene schema, the pattern kinds and
    options, mesh files and pinned indices, the export formats (and their extras), and against the
    character (loaded once per distinct character): clip and joint names, the joints each pattern
    garment anchors on. (Sizing, placing and sewing are left to the jobs: they need the colliders.)"""
    from pipeline import export
    from pipeline.run import check_pattern, check_references, load_character, preflight
    from stages.errors import InputError
    characters: dict = {}
    for job in sw.jobs:
        try:
            scene = job_scene(job.text, job.source, sw.base_dir)
            for i, g in enumerate(scene["garments"]):
                if g["type"] == "pattern":
                    check_pattern(scene, i)
            preflight(scene, None, create=False)
            if job.formats:
                export.check_formats(job.formats, where=f"{job.source}: output.export")
            ckey = json.dumps([scene["character"]], sort_keys=True, default=str)
            if ckey not in characters:
                if echo:
                    echo(f"checking character {scene['character']['source']} "
                         f"{Path(scene['character']['path']).name if scene['character']['path'] else ''}".rstrip())
                characters[ckey] = load_character(scene)
            character = characters[ckey]
            check_references(scene, character)
            _check_anchors(scene, character)
        except SceneError as e:
            if isinstance(e, export.ExportError) and "pip install" in str(e):
                raise SweepError(f"{sw.path}: {' '.join(str(e).split())}") from None
            raise _blame(job, str(e)) from None
        except InputError as e:
            raise _blame(job, f"{job.source}: {e}") from None


def _check_anchors(scene, character) -> None:
    from stages.errors import InputError
    from stages.garments.library import ANCHORS
    from stages.rig.humanoid import humanoid_joints
    joints = None
    for i, g in enumerate(scene["garments"]):
        if g["type"] != "pattern" or not ANCHORS.get(g["kind"]):
            continue
        joints = joints or humanoid_joints(character)
        try:
            joints.require(ANCHORS[g["kind"]], f"garment {g['name']!r}")
        except InputError as err:
            raise SceneError(f"{scene.path}: garments[{i}].kind: {g['kind']!r} cannot be dressed on "
                             f"{character.name!r}: {err.problem}") from None


# ------------------------------------------------------------------ one job (in a worker)

def _failure(err: BaseException) -> str:
    from pipeline.run import SewingError
    from stages.checks import ContractError
    from stages.errors import InputError
    from stages.sim import SimulationDiverged
    if isinstance(err, JobTimeout):
        return "timeout"
    if isinstance(err, SewingError):
        return "sewing"
    if isinstance(err, SimulationDiverged):
        return "diverged"
    if isinstance(err, (SceneError, InputError, ContractError)):
        return "bad-input"
    return "crash"


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
        r["in_colliders_max"] = int(np.asarray(result.penetrations_colliders)[1:].max(initial=0))
    audit = state.get("audit")
    if audit is not None and audit.garments:
        r["strain_mean_pct"] = float(max(g.strain_mean[-1] for g in audit.garments) * 100)
        r["strain_p99_pct"] = float(max(g.strain_p99[-1] for g in audit.garments) * 100)
        r["strain_p99_worst_pct"] = float(max(np.max(g.strain_p99[1:], initial=g.strain_p99[0]) for g in audit.garments) * 100)
        r["crossings_self_max"] = int(np.sum([g.crossings_self for g in audit.garments], axis=0)[1:].max(initial=0))
        r["crossings_between_max"] = int(np.asarray(audit.crossings_between)[1:].max(initial=0))
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
    for m in meshes:   # UVs of pattern garments (as export.from_run)
        if m.name in builds:
            try:
                from stages.garments.sewing import merge_pairs
                build = builds[m.name][1]
                uv, uvf = export.pattern_uv(build)
                remap = merge_pairs(uv.shape[0], np.asarray(build.seam_pairs))
                if uvf.shape == m.faces.shape and np.array_equal(remap[uvf], m.faces):
                    m.uv, m.uv_faces = uv, uvf
            except Exception:
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


def _worker_name() -> str:
    import socket
    return f"{socket.gethostname()}:{os.getpid()}"


def run_job(spec: dict, warm_up_s: float | None = None) -> dict:
    """Run one job in this process: its recording, exports and metrics row (also written to
    `<dir>/row.json`). Never raises for a failed job: the row says what failed."""
    import contextlib
    import io
    import signal
    import threading
    import traceback
    import warnings

    from pipeline import where
    from pipeline.run import run_scene
    job_dir = Path(spec["dir"])
    job_dir.mkdir(parents=True, exist_ok=True)
    row = {"job": spec["id"], **spec["labels"]}
    state: dict = {}
    log = io.StringIO()
    t0 = time.perf_counter()
    err: BaseException | None = None
    scene = None
    timeout = spec.get("timeout")
    alarm = bool(timeout) and threading.current_thread() is threading.main_thread() and hasattr(signal, "setitimer")
    old_handler = None
    armed = [True]

    def on_alarm(signum, frame):
        # raised again every second until the job stops: library code that catches everything (rtree's
        # library finder prints "unexpected error" and goes on) may swallow one
        if armed[0]:
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
            if _failure(e) == "crash":
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
            row["message"] = _one_line(f"{text} (stopped in stage {stage!r})")
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
    """The row of a job whose worker was killed (no answer after the timeout and its grace): the
    parent writes it, renaming the job's temporary recording (whatever the worker had written)."""
    job_dir = Path(spec["dir"])
    job_dir.mkdir(parents=True, exist_ok=True)
    partial = job_dir / f"{spec['id']}.partial.rrd"
    for tmp in sorted(job_dir.glob(f".{spec['id']}.rrd.tmp-*")):
        os.replace(tmp, partial)
    row = {"job": spec["id"], **spec["labels"], "status": "failed", "failure": "timeout",
           "message": _one_line(f"timeout: {how} after {seconds:.0f} s (the job ran longer than {spec['timeout']:g} s "
                                f"and did not stop at the deadline: stuck in one long kernel call)"),
           "frames_done": 0, "recording": os.path.relpath(partial, job_dir) if partial.exists() else "",
           "exports": "", "wall_s": seconds}
    _write_json(job_dir / "row.json", row)
    return row


def crash_row(spec: dict, seconds: float, what: str) -> dict:
    job_dir = Path(spec["dir"])
    job_dir.mkdir(parents=True, exist_ok=True)
    partial = job_dir / f"{spec['id']}.partial.rrd"
    for tmp in sorted(job_dir.glob(f".{spec['id']}.rrd.tmp-*")):
        os.replace(tmp, partial)
    row = {"job": spec["id"], **spec["labels"], "status": "failed", "failure": "crash",
           "message": _one_line(what), "frames_done": 0,
           "recording": os.path.relpath(partial, job_dir) if partial.exists() else "", "exports": "",
           "wall_s": seconds}
    _write_json(job_dir / "row.json", row)
    return row


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
                              "crossings self / between", "seam gap (mm)"])
    out = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    for r in rows:
        status = "ok" if r["status"] == "ok" else f"{r['failure']}: {_one_line(r['message'] or '', 120)}"
        strain = (f"{_fmt(r['strain_mean_pct'], '.2f')} / {_fmt(r['strain_p99_pct'], '.1f')}"
                  if r["strain_mean_pct"] is not None else "")
        cross = (f"{_fmt(r['crossings_self_max'])} / {_fmt(r['crossings_between_max'])}"
                 if r["crossings_self_max"] is not None else "")
        cells = ([r["job"]] + [_fmt(r.get(k)) for k in keys]
                 + [status, _fmt(r["wall_s"], ".1f"), _fmt(r["frames_per_s"], ".1f"), _fmt(r["in_body_max"]),
                    _fmt(r["in_colliders_max"]), strain, cross, _fmt(r["seam_gap_mm"], ".1f")])
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
