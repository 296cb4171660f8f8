"""Names of a package imported from its modules on first use (PEP 562): a command that needs
one part of a package does not load the others (the viewer's process, a realm's watcher)."""

from __future__ import annotations

import importlib
from collections.abc import Callable


def lazy_names(package: str, where: dict[str, str]) -> tuple[Callable, Callable]:
    """``(__getattr__, __dir__)`` for ``package`` (its ``__name__``) whose public names live
    in the modules ``where`` gives (name -> module, relative to the package). A name is
    imported on first access and then kept in the package's namespace."""
    names = sorted(where)

    def __getattr__(name: str):
        module = where.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        pkg = importlib.import_module(package)
        value = getattr(importlib.import_module(f".{module}", package), name)
        setattr(pkg, name, value)
        return value

    def __dir__() -> list[str]:
        return names

    return __getattr__, __dir__
