"""The layout rules of the code (docs/architecture.md): stages never import `pipeline`; the shared
geometry queries (stages/geometry) import no stage package; no module is over 600 lines; no import
circle among the modules of `stages` or of `pipeline`.

Imports are read from the source (every `import` statement, those inside functions too: a lazy
import still ties the two modules together), so nothing here imports the code it checks.
"""
from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
MAX_LINES = 600


def module_files() -> dict[str, Path]:
    """Dotted module name -> file, for the packages stages and pipeline."""
    out = {}
    for top in ("stages", "pipeline"):
        for path in sorted((REPO / top).rglob("*.py")):
            parts = path.relative_to(REPO).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def imported_modules(name: str, path: Path, known: dict) -> set[str]:
    """The modules of `known` that `name` (at `path`) imports, and the packages whose __init__ such an
    import runs first (the ones `name` is not itself inside)."""
    is_package = path.name == "__init__.py"
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        targets = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                here = name.split(".") if is_package else name.split(".")[:-1]
                here = here[:len(here) - (node.level - 1)]
                base = ".".join(here + ([base] if base else []))
            # `from package import module` imports the module; `from module import name` the module
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names]
        for target in targets:
            while target and target not in known:
                target = target.rpartition(".")[0]
            parts = target.split(".")
            for k in range(1, len(parts) + 1):
                dep = ".".join(parts[:k])
                inside = name == dep or name.startswith(dep + ".")
                if dep in known and not inside:
                    found.add(dep)
    return found


def import_graph() -> dict[str, set[str]]:
    known = module_files()
    return {name: imported_modules(name, path, known) for name, path in known.items()}


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index, low, stack, on_stack, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_checks_see_a_lazy_circle_and_a_stage_importing_pipeline(tmp_path, monkeypatch):
    """The checks below pass only if they can fail: a planted pair of modules importing each other
    (one of them inside a function) is a cycle; a stage importing pipeline is seen."""
    pkg = tmp_path / "stages" / "demo"
    pkg.mkdir(parents=True)
    (tmp_path / "stages" / "__init__.py").write_text("")
    (tmp_path / "pipeline").mkdir()
    (tmp_path / "pipeline" / "__init__.py").write_text("")
    (tmp_path / "pipeline" / "run.py").write_text("")
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from stages.demo import b\n")
    (pkg / "b.py").write_text("def f():\n    from stages.demo.a import g\n    from pipeline.run import x\n")
    monkeypatch.setattr(sys.modules[__name__], "REPO", tmp_path)
    graph = import_graph()
    assert import_cycles(graph) == [["stages.demo.a", "stages.demo.b"]]
    assert "pipeline.run" in graph["stages.demo.b"]


def test_no_stage_imports_pipeline():
    graph = import_graph()
    bad = {m: sorted(d for d in deps if d.split(".")[0] == "pipeline")
           for m, deps in graph.items() if m.split(".")[0] == "stages"}
    assert {m: d for m, d in bad.items() if d} == {}


def test_the_geometry_layer_imports_no_stage_package():
    """stages/geometry is the bottom layer: it may use the plain modules of `stages` (checks, jit,
    affine, ...) and itself, nothing a stage defines."""
    graph = import_graph()
    packages = {m.split(".")[1] for m in graph if m.count(".") >= 2 and m.startswith("stages.")}
    bad = {m: sorted(d for d in deps if d.count(".") >= 1 and d.split(".")[1] in packages - {"geometry"})
           for m, deps in graph.items() if m.startswith("stages.geometry")}
    assert {m: d for m, d in bad.items() if d} == {}


def test_no_import_circle():
    assert import_cycles(import_graph()) == []


@pytest.mark.parametrize("top", ["stages", "pipeline", "tests", "tools"])
def test_no_module_over_600_lines(top):
    long = {str(p.relative_to(REPO)): n for p in sorted((REPO / top).rglob("*.py"))
            if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert long == {}

