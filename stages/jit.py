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


def _lock_cache_saves() -> bool:
    """Serialise numba's cache saves across processes (a lock on the cache folder).

    numba adds an entry by reading the kernel's index, picking the first free data file number and
    writing both back: two processes adding signatures of one kernel at once (the run and its
    background compile, pipeline.kernel_warmup) could lose an index entry or, both picking the
    same number, leave an entry naming the other's machine code. Each file is replaced atomically,
    so loads need no lock."""
    try:
        import fcntl

        from numba.core import caching
        plain = caching.IndexDataCacheFile.save
    except (ImportError, AttributeError):   # no flock (Windows) or other numba internals
        return False
    if getattr(plain, "_locked", False):
        return True

    def save(self, key, data):
        fd = os.open(self._cache_path, os.O_RDONLY)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            return plain(self, key, data)
        finally:
            os.close(fd)    # releases the lock
    save._locked = True
    caching.IndexDataCacheFile.save = save
    return True


SAVES_LOCKED = _lock_cache_saves()


def _plain_slice_errors() -> bool:
    """numba's CPU error for an array assigned to a slice of another shape ("cannot assign slice of
    shape (3,) from input of shape (4,)") formats the shapes with numba's string functions, which it
    compiles (str of ints, join, f-strings: 3-5 s of CPU) the first time a process compiles any
    kernel with such an assignment. The message of numba's generic target ("cannot assign slice
    from input of different size") raises the same ValueError and needs no strings compiled."""
    try:
        from numba.core.registry import cpu_target
        from numba.np import arrayobj
        cpu_only = arrayobj.ol_raise_with_shape_context_cpu
        plain = arrayobj.ol_raise_with_shape_context_generic
        typing = cpu_target.typing_context
        typing.refresh()
        templates = typing.resolve_value_type(arrayobj.raise_with_shape_context).templates
    except (ImportError, AttributeError):   # another numba: its own message, compiled as before
        return False
    for t in templates:
        if getattr(t, "_overload_func", None) is cpu_only:
            t._overload_func = staticmethod(plain)
    return True


PLAIN_SLICE_ERRORS = _plain_slice_errors()


# -- serial and parallel variants of one kernel ------------------------------------------------------
# numba compiles a `parallel=True` kernel several times slower than the same loop as plain code (the
# parfor passes and the outlined gufunc; the collision kernel: ~26 s against a few), and with one
# thread the parallel form buys nothing. A kernel with prange loops is therefore compiled serially
# (prange is range) under its own name, and in parallel only when a caller asks for more threads.
# numba names its cache files after the function's qualified name and line, and its cache index does
# not tell the two compilations apart, so the parallel one is a copy of the function renamed
# `<name>_parallel` (its own cache files).
import types as _types

_PARALLEL = {}      # id(serial dispatcher) -> parallel dispatcher


def _renamed(func, name, globals_=None):
    """A copy of the plain function `func` named `name` (and its qualified name), over `globals_`."""
    f = _types.FunctionType(func.__code__, func.__globals__ if globals_ is None else globals_, name,
                            func.__defaults__, func.__closure__)
    f.__qualname__ = func.__qualname__.rpartition(func.__name__)[0] + name
    f.__module__ = func.__module__
    f.__doc__ = func.__doc__
    f.__kwdefaults__ = func.__kwdefaults__
    return f


def serial_and_parallel(**options):
    """Decorator for a kernel with prange loops: njit(**options) of it without `parallel` (the
    returned dispatcher, the one its callers use by default), and njit(parallel=True, **options) of a
    copy named `<name>_parallel`, lazily compiled, which `parallel(kernel)` returns."""
    from numba import njit

    def wrap(func):
        serial = njit(**options)(func)
        _PARALLEL[id(serial)] = njit(parallel=True, **options)(_renamed(func, func.__name__ + "_parallel"))
        return serial
    return wrap


def with_parallel_calls(kernel):
    """For a serial kernel that calls (through module globals) kernels with a parallel variant:
    the same kernel compiled over globals where each such callee is its parallel variant, named
    `<name>_parallel` (registered, so a caller of this one can be switched the same way)."""
    from numba import njit
    g = dict(kernel.py_func.__globals__)
    swapped = {k: _PARALLEL[id(v)] for k, v in g.items() if id(v) in _PARALLEL}
    if not swapped:
        raise ValueError(f"{kernel.py_func.__qualname__} calls no kernel with a parallel variant")
    g.update(swapped)
    options = {k: v for k, v in kernel.targetoptions.items() if k not in ("nopython", "boundscheck")}
    options["cache"] = type(kernel._cache).__name__ != "NullCache"
    par = njit(**options)(_renamed(kernel.py_func, kernel.py_func.__name__ + "_parallel", g))
    _PARALLEL[id(kernel)] = par
    if id(kernel) in _OPT_LEVELS:
        _OPT_LEVELS[id(par)] = _OPT_LEVELS[id(kernel)]
    return par


def parallel(kernel):
    """The parallel variant of a kernel (serial_and_parallel / with_parallel_calls); the kernel
    itself when it has none."""
    return _PARALLEL.get(id(kernel), kernel)


def for_threads(kernel, threads: int):
    """The variant of `kernel` to run with `threads` numba threads: serial for 1, else parallel."""
    return parallel(kernel) if threads > 1 else kernel


def threaded(kernel):
    """The variant of `kernel` for numba's current thread count (numba.set_num_threads)."""
    import numba
    return for_threads(kernel, numba.get_num_threads())


class numba_threads:
    """Context manager: numba's thread count set to `threads` (at most NUMBA_NUM_THREADS) inside,
    restored after; kernels called through `threaded` then take their serial variant for 1."""

    def __init__(self, threads: int):
        self.threads = threads

    def __enter__(self):
        import numba
        self.old = numba.get_num_threads()
        numba.set_num_threads(max(1, min(int(self.threads), numba.config.NUMBA_NUM_THREADS)))
        return self

    def __exit__(self, *exc):
        import numba
        numba.set_num_threads(self.old)
        return False


# -- LLVM optimisation level per kernel ------------------------------------------------------------
# numba optimises a kernel's LLVM module at NUMBA_OPT (3), then again the module with every kernel
# it calls linked in, at every level of a call chain: a thin caller of big, already optimised
# kernels (the step loop over the phases) or a deep chain run once per hull (the simplification)
# pays O3 over all of its callees' code again. `opt_level(n)` compiles one kernel's own module at
# level n; every other kernel (its callees too) keeps the default. numba reads config.OPT when it
# builds its pass managers, so the level is set around the kernel's compile (numba's compile lock
# serialises compiles). The level changes no result: without fastmath, LLVM's passes keep IEEE
# semantics at every level.
_OPT_LEVELS = {}      # id(dispatcher) -> LLVM level


def _install_opt_levels() -> bool:
    from numba.core import config, dispatcher
    base = dispatcher.Dispatcher
    if getattr(base.compile, "_opt_levels", False):
        return True
    default = config.OPT
    plain = base.compile

    def compile(self, sig):
        level = _OPT_LEVELS.get(id(self))
        old = config.OPT
        config.OPT = default if level is None else config._OptLevel(level)
        try:
            return plain(self, sig)
        finally:
            config.OPT = old
    compile._opt_levels = True
    compile.__doc__ = plain.__doc__
    base.compile = compile
    return True


def opt_level(level: int):
    """Decorator above @njit / @serial_and_parallel (both variants): LLVM level for this kernel."""
    def wrap(kernel):
        _install_opt_levels()
        _OPT_LEVELS[id(kernel)] = level
        par = _PARALLEL.get(id(kernel))
        if par is not None:
            _OPT_LEVELS[id(par)] = level
        return kernel
    return wrap
