"""numba disk caching that follows the modules a kernel inlines.

numba keeps a cached kernel while the source file that defines it is unchanged; it does not look at
the files of the kernels it inlines or calls (stages/sim/body_collide.py inlines the maps' hull query), so
an edit there would leave the simulation running the old code from its cache. A module that defines
`NUMBA_CACHE_DEPENDS` (module names) before its first `@njit(cache=True)` gets a cache stamp covering
those modules' sources too. Import this module (for its side effect) before defining such kernels.

This hooks numba's cache locators (`numba.core.caching`, internal API, checked on numba 0.68). If
they are not there, caching works as plain numba does (only the defining file is checked) and a
warning says so.
"""
from __future__ import annotations

import functools
import hashlib
import importlib.util
import os
import warnings


@functools.lru_cache(maxsize=None)
def _source_digest(path: str, mtime: float, size: int) -> bytes:
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).digest()


class _DependentSource:
    """Cache locator mixin: the stamp is the base locator's (own source) plus the listed modules'."""

    @classmethod
    def from_function(cls, py_func, py_file):
        deps = py_func.__globals__.get("NUMBA_CACHE_DEPENDS")
        if not deps:
            return None
        self = super().from_function(py_func, py_file)
        if self is not None:
            self._dep_files = tuple(importlib.util.find_spec(d).origin for d in deps)
        return self

    def get_source_stamp(self):
        deps = []
        for path in self._dep_files:
            st = os.stat(path)
            deps.append(_source_digest(path, st.st_mtime, st.st_size))
        return (super().get_source_stamp(), *deps)


def _register_dependent_locators() -> bool:
    """Put dependency-aware variants of numba's source-file locators first (same order), once."""
    try:
        from numba.core import caching
        locators = caching.CacheImpl._locator_classes
        plain_file = (caching.UserProvidedCacheLocator, caching.InTreeCacheLocator, caching.UserWideCacheLocator)
    except (ImportError, AttributeError) as e:  # a numba without these internals
        warnings.warn(f"numba cache stamps will not follow inlined modules ({e}); after editing a kernel "
                      "module, clear __pycache__ to be safe", RuntimeWarning, stacklevel=2)
        return False
    if not any(issubclass(c, _DependentSource) for c in locators):
        bases = [c for c in locators if c in plain_file]
        locators[:0] = [type(f"Dependent{b.__name__}", (_DependentSource, b), {}) for b in bases]
    return True


REGISTERED = _register_dependent_locators()
