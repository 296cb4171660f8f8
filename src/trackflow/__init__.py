"""trackflow: ubiquitous 6-DoF tracking with error handling.

Poses ``T_a_b`` map frame b into frame a and carry a 6x6 covariance over
``(dt [m, frame a], dtheta [rad, right])``; see ``docs/conventions.md``.

``Pose`` and ``UncertainPose`` are imported on first use, so ``import trackflow`` (and the
command line's ``--help``) does not load numpy, scipy or numba.
"""

__version__ = "0.1.0"

__all__ = ["Pose", "UncertainPose", "__version__"]


def __getattr__(name: str):
    if name in ("Pose", "UncertainPose"):
        from . import math

        return getattr(math, name)
    raise AttributeError(f"module 'trackflow' has no attribute {name!r}")
