"""The one seam for trackflow's optional dependencies.

Every module trackflow can run without (numba, zenoh, viser, playwright, matplotlib, rosbags)
is imported through :func:`require`, at the place and time it is needed (a command that does
not use it never imports it). Without the module the user reads what needs it and the pip
extra that installs it, a :class:`~trackflow.errors.MissingExtraError`::

    zenoh = require("zenoh", extra="distributed", feature="trackflow agent")
    # trackflow agent needs the Python package 'zenoh', which is not installed:
    # pip install 'trackflow[distributed]'

The extras are those of ``pyproject.toml``: ``fast`` (numba), ``plot`` (matplotlib), ``ros``
(rosbags), ``distributed`` (eclipse-zenoh), ``viewer`` (viser, playwright).
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
import types

from .errors import MissingExtraError

__all__ = ["EXTRAS", "available", "pyplot", "require"]

#: top-level module -> the extra of trackflow that installs it
EXTRAS = {
    "numba": "fast",
    "matplotlib": "plot",
    "rosbags": "ros",
    "zenoh": "distributed",
    "viser": "viewer",
    "playwright": "viewer",
}


def require(module: str, extra: str | None = None, feature: str | None = None) -> types.ModuleType:
    """Import ``module`` (a dotted name) or raise :class:`MissingExtraError` naming the extra.

    Parameters
    ----------
    module : str
        The module to import (``"zenoh"``, ``"matplotlib.pyplot"``).
    extra : str, optional
        trackflow's pip extra that installs it (default: from :data:`EXTRAS`).
    feature : str, optional
        What needs it, for the message (default: ``"this feature"``).

    Returns
    -------
    module
        The imported module.

    Raises
    ------
    MissingExtraError
        The module (or its package) is not installed. An ``ImportError`` raised inside an
        installed package (a broken install) is passed on as it is.
    """
    top = module.split(".")[0]
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        missing = getattr(exc, "name", None)
        parts = module.split(".")
        ours = {".".join(parts[: i + 1]) for i in range(len(parts))}
        if missing not in ours:
            raise
        raise MissingExtraError(
            top, extra or EXTRAS.get(top, "all"), feature or "this feature"
        ) from None


def available(module: str) -> bool:
    """Whether ``module`` can be imported, without importing it (``None`` in ``sys.modules``,
    a module blocked on purpose, counts as missing)."""
    top = module.split(".")[0]
    if top in sys.modules:
        return sys.modules[top] is not None
    try:
        return importlib.util.find_spec(top) is not None
    except (ImportError, ValueError):
        return False


def pyplot(feature: str = "plots"):
    """``matplotlib.pyplot`` on the file-only ``Agg`` backend (no window, no display needed),
    or :class:`MissingExtraError` naming the ``plot`` extra."""
    matplotlib = require("matplotlib", extra="plot", feature=feature)
    matplotlib.use("Agg")
    return require("matplotlib.pyplot", extra="plot", feature=feature)
