"""Calibration with uncertainty: clock offset, hand-eye, alignment, sensor noise, pivot.

Every estimator is a typed library function returning a typed result with a covariance in the
conventions of ``docs/conventions.md``; ``trackflow calibrate ...`` wraps them. Methods and
measured figures: ``docs/calibration.md``.
"""

from .clock_offset import ClockOffset, estimate_clock_offset
from .hand_eye import HandEyeResult, evaluate_hand_eye, hand_eye_residuals, solve_hand_eye

__all__ = [
    "ClockOffset",
    "HandEyeResult",
    "estimate_clock_offset",
    "evaluate_hand_eye",
    "hand_eye_residuals",
    "solve_hand_eye",
]
