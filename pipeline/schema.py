"""A small declarative schema for scene files, with messages that name the key path.

A schema is a tree of `Field`s. `validate(spec, data)` walks the parsed YAML, fills defaults and
returns plain dicts / lists; the first problem raises `SceneError` with the key path
(`garments[1].pin.collider`), the bad value, what was expected and, where the YAML was parsed with
marks, the line and column.
"""
from __future__ import annotations

import difflib
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

REQUIRED = object()


class SceneError(ValueError):
    """A scene file problem: one line naming file, key path, bad value and what was expected."""


@dataclass(frozen=True)
class Field:
    """One scene key.

    kind: 'float' | 'int' | 'bool' | 'str' | 'vec3' | 'path' | 'section' | 'list' | 'union' | 'any'
      'union' picks the sub-schema in `variants` named by the value of `tag` (e.g. `type`).
    lo/hi: inclusive bounds for numbers (and list lengths for 'list'). lo_open: lower bound exclusive.
    """

    kind: str
    default: Any = REQUIRED
    doc: str = ""
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    choices: tuple = ()
    fields: dict = field(default_factory=dict)        # section
    item: "Field | None" = None                        # list
    tag: str = "type"                                  # union
    variants: dict = field(default_factory=dict)      # union: tag value -> fields dict
    tag_hints: dict = field(default_factory=dict)     # union: a tag value users write by mistake -> the fix
    length: int | None = None                          # fixed-length number lists ('vec3' is 3)
    # extra check: returns a problem, or (sub-key, problem) to name a key inside this one, or None
    check: Callable[[Any], "str | tuple[str, str] | None"] | None = None
    nullable: bool = False                             # null accepted (as None) though the default is not
    # section: keys left out stay out (no defaults filled), and keys it does not know are kept as they
    # are for the parent's `check` to name (a pattern's options: which are allowed depends on its kind)
    sparse: bool = False
    # legal but physically implausible: returns a warning (the run goes on) or None
    warn: Callable[[Any], str | None] | None = None


def plausible(lo: float | None, hi: float | None, why: str, *, norm: bool = False) -> Callable[[Any], str | None]:
    """A `Field.warn` for a value (or a vector's length, `norm`) outside [lo, hi]: legal, but not what
    a garment scene means; `why` says what to expect from it."""
    def warn(v):
        if v is None:
            return None
        x = math.sqrt(sum(c * c for c in v)) if norm else v
        if (lo is not None and x < lo) or (hi is not None and x > hi):
            what = f"length {x:.4g}" if norm else _describe(v)
            rng = (f"{lo:g} to {hi:g}" if lo is not None and hi is not None else
                   f"at most {hi:g}" if hi is not None else f"at least {lo:g}")
            return f"{what} is implausible (expected {rng}): {why}; running anyway"
        return None
    rng = (f"{lo:g} to {hi:g}" if lo is not None and hi is not None else
           f"above {hi:g}" if hi is not None else f"below {lo:g}")
    warn.text = f"warns {'outside ' if lo is not None and hi is not None else ''}{rng}{' (length)' if norm else ''}"
    return warn


def expand_path_vars(text: str) -> str:
    """Expand $VARS in a path; $GARMENT_ASSETS defaults to the shared assets folder when unset."""
    from pipeline.assets import ASSETS_ENV, assets_dir
    for form in ("${%s}" % ASSETS_ENV, "$" + ASSETS_ENV):
        text = text.replace(form, str(assets_dir()))
    return os.path.expandvars(text)


def _where(path: str) -> str:
    return path or "<top level>"


def _describe(v) -> str:
    s = repr(v)
    return s if len(s) <= 60 else s[:57] + "..."


class _Ctx:
    def __init__(self, source: str, marks: dict, base_dir: Path | None, notes: list | None = None):
        self.source, self.marks, self.base_dir, self.notes = source, marks, base_dir, notes

    def at(self, path: str, at_key: bool = False) -> str:
        mark = (self.marks.get("@" + path) if at_key else None) or self.marks.get(path)
        return f"{self.source}:{mark[0]}:{mark[1]}" if mark else self.source

    def fail(self, path: str, problem: str, *, at_key: bool = False):
        raise SceneError(f"{self.at(path, at_key)}: {_where(path)}: {problem}")


def validate(spec: dict, data, *, source: str = "<scene>", marks: dict | None = None,
             base_dir: Path | None = None, notes: list | None = None) -> dict:
    """Validate `data` against the top-level fields `spec`; return the filled-in dict. The `warn`
    lines of legal but implausible values go to `notes` when given (shown once every check passed:
    a scene with an error prints that one line), else to warnings.warn."""
    return _section(spec, data, "", _Ctx(source, marks or {}, base_dir, notes))


def _section(fields: dict, data, path: str, ctx: _Ctx, skip: tuple = (), sparse: bool = False) -> dict:
    if data is None:
        data = {}
    if not isinstance(data, dict):
        ctx.fail(path, f"expected a mapping of keys, got {_describe(data)}")
    out = {}
    for key in data:
        if not isinstance(key, str):
            ctx.fail(path, f"keys must be strings, got {_describe(key)}")
        if key not in fields and key not in skip and not sparse:
            near = difflib.get_close_matches(key, list(fields), n=1, cutoff=0.5)
            hint = f"; did you mean {near[0]!r}?" if near else f"; valid keys: {', '.join(fields)}"
            ctx.fail(_join(path, key), f"unknown key {key!r}{hint}", at_key=True)
    if sparse:
        out.update((k, v) for k, v in data.items() if k not in fields)
    for key, f in fields.items():
        sub = _join(path, key)
        if key in data:
            out[key] = _value(f, data[key], sub, ctx)
        elif sparse:
            continue
        elif f.default is REQUIRED:
            ctx.fail(sub, f"missing required key ({f.doc or f.kind})")
        else:
            out[key] = _value(f, f.default, sub, ctx) if f.kind in ("section", "list") and f.default is not None else f.default
    return out


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


def _number(f: Field, v, path: str, ctx: _Ctx, kind: str):
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        hint = ""
        if isinstance(v, str):
            try:
                float(v)   # YAML 1.1 reads 1e4 (no '.', no exponent sign) as text
                hint = f" (YAML reads it as text: write it as {float(v):.1e})"
            except ValueError:
                pass
        ctx.fail(path, f"expected {'an integer' if kind == 'int' else 'a number'}, got {_describe(v)}{hint}")
    if kind == "int" and not float(v).is_integer():
        ctx.fail(path, f"expected an integer, got {_describe(v)}")
    if not math.isfinite(v):
        ctx.fail(path, f"expected a finite number, got {_describe(v)}")
    v = int(v) if kind == "int" else float(v)
    if f.lo is not None and (v <= f.lo if f.lo_open else v < f.lo):
        ctx.fail(path, f"{_describe(v)} is out of range: expected {'>' if f.lo_open else '>='} {f.lo}"
                 + (f" and <= {f.hi}" if f.hi is not None else ""))
    if f.hi is not None and v > f.hi:
        ctx.fail(path, f"{_describe(v)} is out of range: expected <= {f.hi}"
                 + (f" and {'>' if f.lo_open else '>='} {f.lo}" if f.lo is not None else ""))
    return v


def _value(f: Field, v, path: str, ctx: _Ctx):
    if v is None and (f.default is None or f.nullable):
        return None
    k = f.kind
    if k in ("float", "int"):
        out = _number(f, v, path, ctx, k)
    elif k == "bool":
        if not isinstance(v, bool):
            ctx.fail(path, f"expected true or false, got {_describe(v)}")
        out = v
    elif k in ("str", "path"):
        if not isinstance(v, str) or not v:
            ctx.fail(path, f"expected a{' file path' if k == 'path' else ' string'}, got {_describe(v)}")
        if f.choices and v not in f.choices:
            near = difflib.get_close_matches(v, [str(c) for c in f.choices], n=1, cutoff=0.5)
            hint = f" (did you mean {near[0]!r}?)" if near else ""
            ctx.fail(path, f"{_describe(v)} is not one of {', '.join(map(str, f.choices))}{hint}")
        out = v
        if k == "path":
            p = Path(expand_path_vars(v)).expanduser()
            out = str(p if p.is_absolute() or ctx.base_dir is None else (ctx.base_dir / p))
    elif k == "vec3" or (k == "list" and f.item is not None and f.item.kind in ("float", "int") and f.length):
        n = 3 if k == "vec3" else f.length
        if not isinstance(v, (list, tuple)) or len(v) != n:
            ctx.fail(path, f"expected a list of {n} numbers, got {_describe(v)}")
        item = f.item or Field("float")
        out = [_number(item, x, f"{path}[{i}]", ctx, item.kind) for i, x in enumerate(v)]
    elif k == "section":
        out = _section(f.fields, v, path, ctx, sparse=f.sparse)
    elif k == "list":
        if not isinstance(v, list):
            ctx.fail(path, f"expected a list, got {_describe(v)}")
        if f.lo is not None and len(v) < f.lo:
            ctx.fail(path, f"expected at least {int(f.lo)} items, got {len(v)}")
        if f.hi is not None and len(v) > f.hi:
            ctx.fail(path, f"expected at most {int(f.hi)} items, got {len(v)}")
        out = [_value(f.item, x, f"{path}[{i}]", ctx) for i, x in enumerate(v)]
    elif k == "union":
        if not isinstance(v, dict):
            ctx.fail(path, f"expected a mapping with a {f.tag!r} key, got {_describe(v)}")
        if f.tag not in v:
            ctx.fail(_join(path, f.tag), f"missing required key (one of {', '.join(f.variants)})")
        tag = v[f.tag]
        if not isinstance(tag, str) or tag not in f.variants:
            near = difflib.get_close_matches(str(tag), list(f.variants), n=1, cutoff=0.5)
            hint = f" (did you mean {near[0]!r}?)" if near else ""
            if isinstance(tag, str) and tag in f.tag_hints:
                hint = f" ({f.tag_hints[tag]})"
            ctx.fail(_join(path, f.tag), f"{_describe(tag)} is not one of {', '.join(f.variants)}{hint}")
        out = _section(f.variants[tag], v, path, ctx, skip=(f.tag,))
        out[f.tag] = tag
    elif k == "any":
        out = v
    else:  # pragma: no cover - a schema bug, not user input
        raise AssertionError(f"unknown field kind {k!r}")
    if f.check is not None:
        problem = f.check(out)
        if isinstance(problem, tuple):
            ctx.fail(_join(path, problem[0]), problem[1])
        if problem:
            ctx.fail(path, problem)
    if f.warn is not None:
        note = f.warn(out)
        if note:
            line = f"{ctx.at(path)}: {_where(path)}: {note}"
            if ctx.notes is not None:
                ctx.notes.append(line)
            else:
                import warnings
                warnings.warn(line, stacklevel=2)
    return out
