"""The manual's generated pages: the scene reference from `SCENE_SPEC` and the CLI reference from the
argument parser, so that neither can drift from the code.

`docs/hooks.py` (an mkdocs hook) adds both pages to every `mkdocs build`; `tests/test_docs.py` checks
that every scene key and every subcommand appears. Print one with
`python -m pipeline.reference scene|cli`.
"""
from __future__ import annotations

import argparse
import math
import sys

from pipeline.schema import REQUIRED, Field

SCENE_PAGE = "reference/scene.md"
CLI_PAGE = "reference/cli.md"


def _cell(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _num(v) -> str:
    if isinstance(v, float):
        if math.isfinite(v) and abs(v - round(v, 4)) > 1e-12:
            return f"{v:.4g}"
        return repr(round(v, 4))
    return repr(v)


def _type(f: Field) -> str:
    if f.kind == "list" and f.item is not None:
        inner = "garment" if f.item.kind == "union" and "pattern" in f.item.variants else \
                "obstacle" if f.item.kind == "union" else _type(f.item)
        return f"list of {f.length} {inner}" if f.length else f"list of {inner}"
    if f.kind == "vec3":
        return "[x, y, z]"
    if f.kind == "path":
        return "path"
    if f.kind == "any":
        return "any"
    return f.kind


def _default(f: Field) -> str:
    if f.default is REQUIRED:
        return "**required**"
    if f.kind == "section":
        return "—"
    if f.default is None:
        return "`null`"
    if isinstance(f.default, float):
        return f"`{_num(f.default)}`"
    if isinstance(f.default, bool):
        return "`true`" if f.default else "`false`"
    if isinstance(f.default, list):
        return "`[" + ", ".join(_num(x) for x in f.default) + "]`"
    return f"`{f.default!r}`".replace("'", "")


def _range(f: Field) -> str:
    parts = []
    if f.choices:
        parts.append(" | ".join(f"`{c}`" for c in f.choices))
    item = f.item if f.kind in ("list", "vec3") and f.item is not None and f.item.kind != "union" else None
    for g, what in ((f, ""), (item, "each ")):
        if g is None:
            continue
        if g.choices and g is not f:
            parts.append(what + " | ".join(f"`{c}`" for c in g.choices))
        if g.lo is not None or g.hi is not None:
            lo = "" if g.lo is None else (f"> {_num(g.lo)}" if g.lo_open else f"≥ {_num(g.lo)}")
            hi = "" if g.hi is None else f"≤ {_num(g.hi)}"
            parts.append(what + ", ".join(x for x in (lo, hi) if x))
    if f.nullable and f.default is not None:
        parts.append("or `null`")
    if f.warn is not None:
        parts.append(getattr(f.warn, "text", "warns when implausible"))
    return "; ".join(parts) or "—"


def _rows(fields: dict, prefix: str, out: list) -> None:
    for key, f in fields.items():
        path = f"{prefix}{key}"
        out.append(f"| `{path}` | {_cell(_type(f))} | {_cell(_default(f))} | {_cell(_range(f))} | {_cell(f.doc)} |")
        if f.kind == "section" and f.fields:
            _rows(f.fields, path + ".", out)


_HEAD = ["| key | type | default | range | meaning |", "| --- | --- | --- | --- | --- |"]


def scene_keys() -> list[str]:
    """Every key path of SCENE_SPEC as the reference names it (garment and obstacle keys per type)."""
    from pipeline.scene import OUTPUT_FIELDS, SCENE_SPEC
    keys: list[str] = []

    def walk(fields, prefix):
        for k, f in fields.items():
            keys.append(prefix + k)
            if f.kind == "section":
                walk(f.fields, prefix + k + ".")
            if f.kind == "list" and f.item is not None and f.item.kind == "union":
                for t, sub in f.item.variants.items():
                    walk(sub, f"{prefix}{k}[type={t}].")
    walk(SCENE_SPEC, "")
    walk(OUTPUT_FIELDS, "output.")
    return keys


def scene_reference() -> str:
    """The scene reference page (Markdown), generated from pipeline.scene.SCENE_SPEC."""
    from pipeline.scene import OUTPUT_FIELDS, SCENE_SPEC
    out = ["# Scene reference", "",
           "Generated from `SCENE_SPEC` in `pipeline/scene.py` at every build of this manual "
           "(`pipeline/reference.py`); it cannot drift from the code. Every key is optional unless its "
           "default says **required**. Lengths are metres, times seconds, Y is up; relative paths resolve "
           "against the scene file's folder, and `${GARMENT_ASSETS}` expands to the assets folder. "
           "`null` for a key marked *preset* takes the value of `simulation.preset`. See "
           "[Scenes](../guide/scenes.md) for how a scene is put together.", ""]
    top = {k: f for k, f in SCENE_SPEC.items() if k not in ("garments", "obstacles", "output")}
    out += ["## Top level, character, frames, colliders, simulation", ""] + _HEAD
    _rows(top, "", out)
    for key, title, text in (
            ("garments", "Garments", "`garments:` is a list; each item has a `type` that picks its keys."),
            ("obstacles", "Obstacles", "`obstacles:` is a list; each item has a `type` that picks its keys.")):
        f = SCENE_SPEC[key]
        out += ["", f"## {title}", "", text, ""] + _HEAD
        _rows({key: f}, "", out)
        out.append("")
        order = ("pattern", "garmentcode", "mesh", "tube", "rectangle") if key == "garments" else ()
        for t, sub in sorted(f.item.variants.items(), key=lambda kv: order.index(kv[0]) if kv[0] in order else 99):
            out += [f"### `{key}[]` with `type: {t}`", ""] + _HEAD
            _rows({"type": Field("str", REQUIRED, f"`{t}`")}, f"{key}[].", out)
            _rows(sub, f"{key}[].", out)
            out.append("")
    out += ["## Output", "",
            "`output:` is a path, or a mapping of the keys below.", ""] + _HEAD
    _rows({"output": SCENE_SPEC["output"]}, "", out)
    _rows(OUTPUT_FIELDS, "output.", out)
    out.append("")
    return "\n".join(out)


def _subparsers(parser: argparse.ArgumentParser):
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            helps = {c.dest: c.help for c in a._choices_actions}
            for name, sp in a.choices.items():
                yield name, helps.get(name, ""), sp


def subcommands() -> list[str]:
    from pipeline.cli import build_parser
    return [name for name, _, _ in _subparsers(build_parser())]


def _options(sp: argparse.ArgumentParser) -> list[str]:
    rows = ["| argument | meaning |", "| --- | --- |"]
    for a in sp._actions:
        if a.help == argparse.SUPPRESS or isinstance(a, argparse._HelpAction):
            continue
        if a.option_strings:
            name = ", ".join(a.option_strings)
            if a.nargs != 0:
                name += " " + (a.metavar or a.dest.upper())
        else:
            name = a.metavar or a.dest
        extra = ""
        if a.default not in (None, False, argparse.SUPPRESS) and a.option_strings:
            extra = f" (default `{a.default}`)" if f"default" not in (a.help or "") else ""
        rows.append(f"| `{_cell(name)}` | {_cell((a.help or '') + extra)} |")
    return rows


def cli_reference() -> str:
    """The CLI reference page (Markdown), generated from pipeline.cli.build_parser()."""
    from pipeline.cli import build_parser
    p = build_parser()
    out = ["# Command-line reference", "",
           "Generated from the argument parser in `pipeline/cli.py` at every build of this manual "
           "(`pipeline/reference.py`). Every command is `python -m pipeline COMMAND ...` (or `garment-sim "
           "COMMAND ...`). Exit codes: 0 done; 1 an unexpected error (a bug: one line naming the stage, "
           "`--debug` adds the traceback), or a matrix pair / sweep job failed; 2 bad input (one `error:` "
           "line, see [Troubleshooting](../troubleshooting.md)); 130 interrupted.", "",
           f"{p.description}", "", "| command | what it does |", "| --- | --- |"]
    subs = list(_subparsers(p))
    for name, help_, _ in subs:
        out.append(f"| [`{name}`](#{name}) | {_cell(help_)} |")
    for name, help_, sp in subs:
        out += ["", f"## {name}", "", f"{help_[:1].upper() + help_[1:]}.", "", "```text",
                sp.format_usage().strip().replace("usage: ", ""), "```", ""] + _options(sp)
    out.append("")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    which = (argv if argv is not None else sys.argv[1:]) or ["scene"]
    for w in which:
        print(scene_reference() if w == "scene" else cli_reference())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
