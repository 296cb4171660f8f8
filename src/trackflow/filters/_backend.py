"""Backend selection for the filter kernels in ``_core.py``.

``kernels()`` returns a namespace with the kernel functions for the active
``trackflow.math`` backend: the plain-Python/NumPy module, or a second copy of the same source
whose functions are compiled with ``numba.njit(cache=True)`` (compiled lazily on first call;
the on-disk cache lives where ``trackflow.math`` put ``NUMBA_CACHE_DIR``).
"""

from __future__ import annotations

import importlib.util
import sys
import types

from trackflow.math import get_backend, numba_available

from . import _core

__all__ = ["kernels"]

_jit_module: types.ModuleType | None = None
# error_model="numpy": division by zero gives inf/nan like NumPy (caught by the divergence
# checks) instead of a raising branch in every inner loop.
_OPTIONS = {"cache": True, "error_model": "numpy"}


def _load_jit() -> types.ModuleType:
    import numba

    name = "trackflow.filters._core_jit"
    spec = importlib.util.spec_from_file_location(name, _core.__file__)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod  # numba's on-disk cache re-imports the module by name
    spec.loader.exec_module(mod)
    for name in _core.KERNELS:
        setattr(mod, name, numba.njit(**_OPTIONS)(getattr(mod, name)))
    return mod


def kernels() -> types.ModuleType:
    """Kernel namespace for the active backend (``trackflow.math.get_backend()``)."""
    global _jit_module
    if get_backend() != "numba" or not numba_available():
        return _core
    if _jit_module is None:
        _jit_module = _load_jit()
    return _jit_module
