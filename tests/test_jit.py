"""stages.jit: numba disk caching that follows the modules a kernel inlines."""
from __future__ import annotations

import stages.jit


def test_the_cache_hook_is_registered_on_this_numba():
    assert stages.jit.REGISTERED


def test_disk_cache_of_a_kernel_follows_the_modules_it_inlines(tmp_path):
    """A module listing NUMBA_CACHE_DEPENDS (as stages/sim/body_collide.py lists the maps kernels) recompiles
    when a listed module changes, and loads from the cache otherwise."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    (tmp_path / "dep_inlined.py").write_text(
        "from numba import njit\n\n@njit(cache=True, inline='always')\ndef f(x):\n    return x + 1.0\n")
    (tmp_path / "dep_user.py").write_text(
        "import stages.jit\nfrom numba import njit\nfrom dep_inlined import f\n"
        "NUMBA_CACHE_DEPENDS = ('dep_inlined',)\n\n@njit(cache=True)\ndef g(x):\n    return f(x)\n")
    repo = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(repo)]), "PYTHONDONTWRITEBYTECODE": "1"}

    def run():
        code = "import dep_user; v = dep_user.g(1.0); print(v, dep_user.g.stats.cache_hits.get(dep_user.g.signatures[0], 0))"
        out = subprocess.run([sys.executable, "-c", code], env=env, cwd=tmp_path, capture_output=True, text=True,
                             check=True)
        value, hits = out.stdout.split()
        return float(value), int(hits)

    assert run() == (2.0, 0)          # compiled and saved
    assert run() == (2.0, 1)          # loaded from the cache
    (tmp_path / "dep_inlined.py").write_text(
        "from numba import njit\n\n@njit(cache=True, inline='always')\ndef f(x):\n    return x + 2.0\n")
    assert run() == (3.0, 0)          # the inlined module changed: recompiled
