"""Whether a stage's numba kernels still have to be compiled (the first run after an install or
an edit), so the run can say "compiling kernels (first run only)" instead of going silent.

numba writes one index file (`<module>.<function>-<line>.py311.nbi`) per cached kernel beside the
module, in `__pycache__` (or under $NUMBA_CACHE_DIR). A module that defines `cache=True` kernels
and has no index file at all has not been compiled yet. This is a module-level test: a module
half compiled (a kernel a scene did not use before) is not seen; nor is a cache numba finds stale
(an edited source), which it recompiles.

ESTIMATE_S: seconds each stage spent compiling on the 2-core development machine (cold run of
scenes/default.yaml minus the warm one, docs/decisions.md "Start-up"; colliders: the hull chain and the
winding kernels, 12 s CPU; cloth collision: its kernels' first call on an empty cache, 29 s CPU,
2026-11-23); the message scales it by the share of the stage's modules that are not compiled.
`run` compiles the garments / simulation / cloth audit kernels in a second process while the
earlier stages run (pipeline.kernel_warmup), so on a first run those stages are not silent waits.
"""
from __future__ import annotations

import os
import re
from functools import lru_cache
from pathlib import Path

STAGES_DIR = Path(__file__).resolve().parent.parent / "stages"

# stage (as run_scene announces it) -> where its kernels are, as paths under stages/: a package
# ('sim': its own modules, not its subpackages), a module ('geometry/kdop'), or '-' and a path: not that
# one. tests/test_progress.py checks that every entry exists and every kernel module is named.
# a package's entry covers its own modules, not its subpackages (sim/cloth_contact)
_SIM_ONLY = ("sim", "-sim/audit_kernels", "-sim/body_audit_kernels")
STAGE_PACKAGES = {
    "rig": ("rig",),
    # skinning (rig) is compiled by the rig stage
    "colliders": ("hulls", "coverage", "geometry/winding", "geometry/skin_distance"),
    "collider coverage": ("coverage", "geometry/winding", "geometry/skin_distance"),
    "obstacles": ("obstacles", "geometry/kdop"),
    # sewing runs the simulation, without the cloth audit or cloth collision; placement and fit ask the skin
    "garments": _SIM_ONLY + ("geometry/winding", "geometry/skin_distance"),
    "simulation": _SIM_ONLY + ("geometry/winding",),          # the body audit's winding number
    "cloth collision": ("sim/cloth_contact", "-sim/cloth_contact/bench", "geometry/kdop"),   # only scenes that turn it on
    "cloth audit": ("sim/audit_kernels",),
    "body audit": ("sim/body_audit_kernels",),
}
# body audit: its one kernel on an empty cache, 2.6 s (1 thread) / 3.5 s (2), 2026-11-28 (issue 38)
ESTIMATE_S = {"rig": 1, "colliders": 12, "collider coverage": 3, "obstacles": 5, "garments": 16,
              "simulation": 5, "cloth audit": 4, "cloth collision": 29, "body audit": 3}
# the second process compiling sewing, simulation and cloth audit kernels (pipeline.kernel_warmup):
# the coverage and simulation kernels, 22 s of CPU on a cold cache (the audit's 3 s more, compiled
# while the run sews and simulates), 2026-11-23 (issue 19)
BACKGROUND_ESTIMATE_S = 22

_CACHED = re.compile(r"cache\s*=\s*True")


@lru_cache(maxsize=None)
def kernel_modules(package: str) -> tuple[Path, ...]:
    """The modules of stages/<package> (a folder; not its subfolders) that define cached numba kernels."""
    return tuple(p for p in sorted((STAGES_DIR / package).glob("*.py")) if _CACHED.search(p.read_text()))


def _cache_dirs(module: Path) -> list[Path]:
    user = os.environ.get("NUMBA_CACHE_DIR")
    if user:   # numba then uses only that folder, mirroring the source folder under it
        return [Path(user) / module.parent.resolve().relative_to(module.parent.resolve().anchor)]
    return [module.parent / "__pycache__"]


def is_compiled(module: Path) -> bool:
    """Any numba index file for `module`'s kernels."""
    return any(any(d.glob(f"{module.stem}.*.nbi")) for d in _cache_dirs(module) if d.is_dir())


def entry_modules(entry: str) -> set:
    """The modules with cached kernels at one STAGE_PACKAGES path ('-' stripped): a package's, or the module's."""
    path = entry.lstrip("-")
    if (STAGES_DIR / path).is_dir():
        return set(kernel_modules(path))
    folder, _, stem = path.rpartition("/")
    return {m for m in kernel_modules(folder) if m.stem == stem}


def stage_modules(stage: str) -> set:
    """The modules with cached kernels that `stage` calls (STAGE_PACKAGES)."""
    mods, drop = set(), set()
    for entry in STAGE_PACKAGES.get(stage, ()):
        (drop if entry.startswith("-") else mods).update(entry_modules(entry))
    return mods - drop


def _stamp(stage: str) -> Path:
    user = os.environ.get("NUMBA_CACHE_DIR")
    return (Path(user) if user else STAGES_DIR / "__pycache__") / f"ran-{stage.replace(' ', '_')}.stamp"


def mark_ran(*stages: str) -> None:
    """Remember that these stages ran to the end: the kernels they call are compiled. A module
    whose kernels a scene never calls (cloth contact's continuous-collision kernels on a slow
    clip) keeps no numba index, and was counted as uncompiled on every run."""
    for st in stages:
        path = _stamp(st)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.touch()
        except OSError:   # a read-only install: the module-level test alone
            pass


def _ran_since_edit(stage: str, mods: set) -> bool:
    """The stage ran to the end after its kernel modules were last changed."""
    try:
        ran = _stamp(stage).stat().st_mtime
        return all(m.stat().st_mtime <= ran for m in mods)
    except OSError:
        return False


def uncompiled(stage: str) -> tuple[int, int]:
    """(modules of the stage's kernels without a numba cache, modules with kernels); none once the
    stage has run to the end since its modules were edited (mark_ran)."""
    mods = stage_modules(stage)
    if mods and _ran_since_edit(stage, mods):
        return 0, len(mods)
    return sum(not is_compiled(m) for m in mods), len(mods)


def compile_note(stage: str, *more: str) -> str | None:
    """'compiling kernels, first run only: about N s' when the stage's kernels (and those of the
    `more` kernel groups it runs, e.g. 'cloth collision') are not cached."""
    if os.environ.get("NUMBA_DISABLE_JIT") == "1":
        return None
    est = 0.0
    for st in (stage, *more):
        missing, total = uncompiled(st)
        if missing:
            est += ESTIMATE_S.get(st, 5) * missing / total
    if not est:
        return None
    return f"compiling kernels, first run only: about {max(1, round(est))} s on 2 cores"
