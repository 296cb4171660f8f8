"""The one backend seam of trackflow: NumPy reference code or numba-compiled copies of it.

Every hot loop in trackflow is written once, as plain Python on NumPy arrays, in a *kernel
source* module: a module that lists its kernel functions in ``KERNELS`` and the kernel sources
it calls in ``KERNEL_SOURCES`` (module names). :func:`kernels` returns, for the active backend,

* ``"numpy"``: the kernel source module itself (the reference path), or
* ``"numba"``: a second copy of the same source whose ``KERNELS`` are wrapped in
  ``numba.njit(cache=True)``, with every name it imported from another kernel source rebound to
  that source's compiled copy, so compiled code only ever calls compiled code. A source may
  also list in ``KERNELS_INLINE`` kernels that numba inlines into their compiled callers
  (``inline="always"``; still callable on their own): glue functions that pass many arrays on,
  whose reference counting (two atomic operations per array argument and call) would otherwise
  cost more than their arithmetic. Inlining changes no operation, hence no result. A source
  may add numba options for all its kernels in ``KERNEL_OPTIONS`` (``{"nogil": True}`` for
  kernels that run beside other threads).

Nothing is compiled at import: numba itself is imported when the first compiled copy is made,
and each function compiles (or loads from the on-disk cache) on its first call, so a command
compiles only the kernels it runs.

The cache lives in ``$NUMBA_CACHE_DIR`` when the user set it (numba's own rule), else in a
per-user directory (``$XDG_CACHE_HOME/trackflow/numba`` or ``~/.cache/trackflow/numba``); this
is scoped to trackflow's functions, and no environment variable of the process is changed.
numba checks only a function's own source file for staleness, so each compiled copy also
records a fingerprint of all the kernel sources it depends on and drops its cached entries when
any of them changed.

Each kernel compiles one machine-code *specialisation* per combination of argument types, and
numba's types include an array's layout (contiguous or strided) and whether it is writeable.
Drivers pass their array inputs through :func:`frozen` (C-contiguous, float64, read-only) and
give the kernels contiguous output buffers, so a kernel has one specialisation whatever arrays
the caller holds, and the one ``trackflow compile`` made ahead of time is the one every command
finds in the cache.

The backend is chosen once at import (``TRACKFLOW_BACKEND=numpy`` forces NumPy) and can be
switched for a block of code with :func:`use_backend`, which always restores the previous one.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib
import importlib.util
import os
import sys
import tempfile
import types
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..optional import require

__all__ = [
    "SELECTED",
    "cache_is_warm",
    "frozen",
    "get_backend",
    "kernels",
    "numba_available",
    "numpy_reason",
    "set_backend",
    "set_notice",
    "use_backend",
]

_PACKAGE_DIR = str(Path(__file__).resolve().parents[1])
# error_model="numpy": division by zero gives inf/nan like NumPy (caught by the divergence
# checks) instead of a raising branch in every inner loop.
_JIT_OPTIONS = {"cache": True, "error_model": "numpy"}


def frozen(array, dtype=float):
    """A C-contiguous, read-only view of ``array`` as ``dtype`` (a copy only when needed).

    The one argument form of every array a driver passes into a kernel (see the module notes:
    one compiled specialisation per kernel). The caller's array is never made read-only; one that
    already is frozen (read-only, C-contiguous, of ``dtype``) is returned as it is.
    """
    if type(array) is np.ndarray:
        flags = array.flags
        if not flags.writeable and flags.c_contiguous and array.dtype == dtype:
            return array  # already frozen: as it is
        view = np.ascontiguousarray(array, dtype=dtype).view()  # never the caller's array
    else:
        view = np.array(array, dtype=dtype)  # a new array of a sequence
    view.flags.writeable = False
    return view


@functools.cache
def numba_available() -> bool:
    """Whether the compiled backend can be used (numba is installed; not imported here)."""
    return importlib.util.find_spec("numba") is not None


def _initial_backend() -> str:
    if os.environ.get("TRACKFLOW_BACKEND", "").lower() == "numpy" or not numba_available():
        return "numpy"
    return "numba"


_backend = _initial_backend()


def get_backend() -> str:
    """The active backend name, ``"numba"`` or ``"numpy"``."""
    return _backend


def set_backend(name: str) -> None:
    """Select ``"numba"`` or ``"numpy"`` for all following calls (prefer :func:`use_backend`)."""
    global _backend
    if name not in ("numba", "numpy"):
        raise InputError(f"unknown backend {name!r}; use 'numba' or 'numpy'")
    if name == "numba" and not numba_available():
        raise InputError("numba backend requested but numba is not installed: pip install numba")
    _backend = name


@contextlib.contextmanager
def use_backend(name: str):
    """Context manager selecting a backend and restoring the previous one afterwards."""
    old = _backend
    set_backend(name)
    try:
        yield
    finally:
        set_backend(old)


def kernels(source: types.ModuleType) -> types.ModuleType:
    """The kernels of the kernel source module ``source`` for the active backend."""
    if _backend != "numba":
        if _notice is not None:
            _notice("numpy", source.__name__)
        return source
    return _compiled(source.__name__)


#: :func:`numpy_reason` when the code chose the NumPy backend (``use_backend``), not the user
SELECTED = "the numpy backend was selected"


def numpy_reason() -> str:
    """Why the NumPy backend is active, for a user: numba missing, the environment variable,
    or :data:`SELECTED`."""
    if not numba_available():
        return "numba is not installed"
    if os.environ.get("TRACKFLOW_BACKEND", "").lower() == "numpy":
        return "TRACKFLOW_BACKEND=numpy"
    return SELECTED


# -- compiled copies ---------------------------------------------------------------------------


def cache_root() -> str:
    """Directory of trackflow's numba cache (see the module docstring)."""
    user = os.environ.get("NUMBA_CACHE_DIR")
    if user:
        return user
    return _default_cache_root()


@functools.cache
def _default_cache_root() -> str:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    for root in (Path(base), Path(tempfile.gettempdir())):
        d = root / "trackflow" / "numba"
        try:
            d.mkdir(parents=True, exist_ok=True)
            if os.access(d, os.W_OK):
                return str(d)
        except OSError:
            continue
    return tempfile.mkdtemp(prefix="trackflow-numba-")


def _source_closure(name: str, seen: dict[str, str] | None = None) -> dict[str, str]:
    """``{module name: source file}`` of a kernel source and every source it depends on."""
    seen = {} if seen is None else seen
    if name not in seen:
        mod = importlib.import_module(name)
        seen[name] = mod.__file__
        for dep in getattr(mod, "KERNEL_SOURCES", ()):
            _source_closure(dep, seen)
    return seen


def _fingerprint(name: str) -> str:
    h = hashlib.sha256()
    for mod, path in sorted(_source_closure(name).items()):
        h.update(mod.encode())
        h.update(Path(path).read_bytes())
    return h.hexdigest()


@functools.cache
def _locator_class():
    """A numba cache locator for trackflow's own functions (installed once)."""
    from numba.core import caching

    # numba >= 0.61 made these public; 0.60 (the declared floor) has the underscored names
    base = getattr(caching, "UserProvidedCacheLocator", None) or caching._UserProvidedCacheLocator
    impl = getattr(caching, "CacheImpl", None) or caching._CacheImpl

    class TrackflowCacheLocator(base):
        def __init__(self, py_func, py_file):
            self._py_file = py_file
            self._lineno = py_func.__code__.co_firstlineno
            self._cache_path = os.path.join(cache_root(), self.get_suitable_cache_subpath(py_file))

        @classmethod
        def from_function(cls, py_func, py_file):
            if os.environ.get("NUMBA_CACHE_DIR") or not os.path.abspath(py_file).startswith(
                _PACKAGE_DIR
            ):
                return None  # numba's own rules
            if not os.path.exists(py_file):
                return None
            return cls(py_func, py_file)

    impl._locator_classes.insert(0, TrackflowCacheLocator)
    return TrackflowCacheLocator


def install_cache_locator() -> None:
    """Route the on-disk cache of every numba function of trackflow (kernel sources and any
    module decorating its own functions) to trackflow's cache directory, once per process.

    Called when this module is imported, so that functions compiled at import time and those
    compiled later through :func:`kernels` use the same place.
    """
    if numba_available():
        _locator_class()


def _drop_stale_cache(name: str, path: str) -> None:
    """Remove cached machine code of ``path`` if a kernel source it depends on changed."""
    locator = _locator_class()
    cache_dir = Path(cache_root()) / locator.get_suitable_cache_subpath(path)
    stamp = cache_dir / f"{Path(path).stem}.sources.sha256"
    fingerprint = _fingerprint(name)
    try:
        if stamp.read_text() == fingerprint:
            return
    except OSError:
        pass
    with contextlib.suppress(OSError):
        cache_dir.mkdir(parents=True, exist_ok=True)
        for f in cache_dir.glob(f"{Path(path).stem}.*.nb[ic]"):
            f.unlink(missing_ok=True)
        stamp.write_text(fingerprint)


_notice = None  # called with (event, kernel source name); see set_notice


def set_notice(callback) -> None:
    """Call ``callback(event, source_name)`` when the user may wait for the kernels.

    ``event`` is ``"compile"`` before a kernel source with an empty cache is compiled, and
    ``"numpy"`` each time a kernel source is handed out on the NumPy backend (the slow
    reference path). The command line uses it to say why a run waits or crawls, once; the
    library stays silent. ``None`` removes it.
    """
    global _notice
    _notice = callback


def cache_is_warm(source: types.ModuleType) -> bool:
    """Whether compiled code of ``source`` (a kernel source module) is in the cache."""
    if not numba_available():
        return False
    path = source.__file__
    cache_dir = Path(cache_root()) / _locator_class().get_suitable_cache_subpath(path)
    stamp = cache_dir / f"{Path(path).stem}.sources.sha256"
    try:
        fresh = stamp.read_text() == _fingerprint(source.__name__)
    except OSError:
        return False
    return fresh and any(cache_dir.glob(f"{Path(path).stem}.*.nbi"))


@functools.cache
def _compiled(name: str) -> types.ModuleType:
    numba = require("numba", extra="fast", feature="the compiled backend")

    source = importlib.import_module(name)
    deps = {dep: (importlib.import_module(dep), _compiled(dep)) for dep in source.KERNEL_SOURCES}
    if _notice is not None and not cache_is_warm(source):
        _notice("compile", name)
    _drop_stale_cache(name, source.__file__)
    jit_name = f"{name}__compiled"
    spec = importlib.util.spec_from_file_location(jit_name, source.__file__)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[jit_name] = mod  # numba's on-disk cache re-imports the module by name
    spec.loader.exec_module(mod)
    for plain, jit in deps.values():
        for kernel in plain.KERNELS:
            for attr, value in list(vars(mod).items()):
                if value is getattr(plain, kernel):
                    setattr(mod, attr, getattr(jit, kernel))
    inline = set(getattr(source, "KERNELS_INLINE", ()))
    base = dict(_JIT_OPTIONS, **getattr(source, "KERNEL_OPTIONS", {}))
    for kernel in source.KERNELS:
        options = dict(base, inline="always") if kernel in inline else base
        setattr(mod, kernel, numba.njit(**options)(getattr(mod, kernel)))
    return mod


install_cache_locator()
