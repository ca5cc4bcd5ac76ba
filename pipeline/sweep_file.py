"""The sweep file of `python -m pipeline sweep` (format in pipeline/sweep.py): parsing, the jobs
it gives (one per combination of overrides), and their validation before anything runs."""
from __future__ import annotations

import copy
import hashlib
import json
import math
import os
import re
from dataclasses import dataclass, field
from itertools import product
from pathlib import Path

import yaml

from pipeline.schema import REQUIRED, Field, SceneError, validate


class SweepError(SceneError):
    """A bad sweep file or a combination that is not a valid scene: one line naming the file, the
    key, the bad value and what was expected (exit 2)."""


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
SWEEP_SET = ("output", "output.path", "output.export_dir")
MAX_JOBS = 10_000   # jobs a sweep file may expand to: each is a run and a table row   # the sweep places every job's files


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


def _marks_of(node) -> dict:
    from pipeline.scene import _marks
    marks: dict = {}
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
    from stages.input_files import read_text_file
    from stages.safe_yaml import load_checked
    p = Path(path)
    text = read_text_file(p, "sweep file", SweepError)   # stat first: a FIFO or device is refused unopened
    try:
        data, node = load_checked(text, str(p), SweepError, loader=_UniqueKeyLoader)
        marks = _marks_of(node)
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
        from stages.input_files import file_problem
        problem = file_problem(bp, "scene file")   # stat only: a FIFO is never opened
        if problem:
            raise SweepError(f"{_at(p, marks, 'base')}: base: {problem}: {bp}")
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

    total = max(len(cases), 1) * math.prod(len(vals) for _, vals in axes)
    if total > MAX_JOBS:   # counted before any job is made: a grid of 10^10 would fill the memory first
        sizes = " x ".join([str(len(cases))] * bool(cases) + [str(len(vals)) for _, vals in axes])
        raise SweepError(f"{_at(p, marks, 'grid')}: grid: {sizes} = {total:,} jobs, more than {MAX_JOBS:,}; "
                         f"expected a smaller grid (or several sweeps)")
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
    return Scene(path=Path(source), name=sc.name, text=text, settings=sc.settings, export=sc.export, notes=sc.notes)


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
    from pipeline.preflight import check_references, preflight
    from pipeline.run import load_character
    from pipeline.dressing import check_pattern
    from stages.errors import InputError
    import warnings
    characters: dict = {}
    noted: dict = {}   # a warning the jobs' scenes share: once, with the jobs it applies to
    for job in sw.jobs:
        try:
            scene = job_scene(job.text, job.source, sw.base_dir)
            for text in scene.notes:
                noted.setdefault(text.split(": ", 1)[-1] if text.startswith(job.source) else text, []).append(job.id)
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
    for text, ids in noted.items():
        jobs = "every job" if len(ids) == len(sw.jobs) else f"jobs {', '.join(ids[:4])}" + (
            f" (+{len(ids) - 4} more)" if len(ids) > 4 else "")
        warnings.warn(f"{sw.path}: {text} ({jobs})", stacklevel=2)


def _check_anchors(scene, character) -> None:
    from stages.errors import InputError
    from stages.garments.anchors import ANCHORS, require_anchors, require_human
    from stages.rig.humanoid import humanoid_joints
    joints = None
    for i, g in enumerate(scene["garments"]):
        if g["type"] == "garmentcode":
            joints = joints or humanoid_joints(character)
            try:
                require_human(character, f"garment {g['name']!r}", joints)
            except InputError as err:
                raise SceneError(f"{scene.path}: garments[{i}] ({g['name']!r}, GarmentCode) cannot be dressed on "
                                 f"{character.name!r}: {err.problem}") from None
            continue
        if g["type"] != "pattern" or not ANCHORS.get(g["kind"]):
            continue
        joints = joints or humanoid_joints(character)
        try:
            require_anchors(g["kind"], character, f"garment {g['name']!r}", joints)
        except InputError as err:
            raise SceneError(f"{scene.path}: garments[{i}].kind: {g['kind']!r} cannot be dressed on "
                             f"{character.name!r}: {err.problem}") from None


