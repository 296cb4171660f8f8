"""trackflow: ubiquitous 6-DoF tracking with error handling.

Poses ``T_a_b`` map frame b into frame a and carry a 6x6 covariance over
``(dt [m, frame a], dtheta [rad, right])``; see ``docs/conventions.md``.
"""

from .math import Pose, UncertainPose

__version__ = "0.1.0"

__all__ = ["Pose", "UncertainPose", "__version__"]
