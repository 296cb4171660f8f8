"""Calibration with uncertainty: clock offset, hand-eye, alignment, sensor noise, pivot.

A stored hand-eye calibration is reused in a new session by :func:`refit_calibration` (X kept,
the world transform and the clock offset refitted).

Every estimator is a typed library function returning a typed result with a covariance in the
conventions of ``docs/conventions.md``; ``trackflow calibrate ...`` wraps them. Methods and
measured figures: ``docs/calibration.md``.
"""

from .alignment import AlignmentResult, align_trajectories, fit_alignment
from .clock_offset import StreamClockOffset, estimate_clock_offset
from .fragment import sensor_update, static_edge, write_fragment
from .hand_eye import (
    HandEyeResult,
    evaluate_hand_eye,
    evaluate_with_world_fit,
    hand_eye_residuals,
    solve_hand_eye,
)
from .noise import NoiseResult, sensor_noise
from .online_offset import OnlineClockOffset, replay_online_offset, rigid_pairs
from .pivot import PivotResult, pivot_calibration
from .reuse import REFIT_CHOICES, refit_calibration

__all__ = [
    "OnlineClockOffset",
    "rigid_pairs",
    "replay_online_offset",
    "AlignmentResult",
    "HandEyeResult",
    "NoiseResult",
    "PivotResult",
    "StreamClockOffset",
    "align_trajectories",
    "fit_alignment",
    "estimate_clock_offset",
    "sensor_noise",
    "evaluate_hand_eye",
    "evaluate_with_world_fit",
    "hand_eye_residuals",
    "pivot_calibration",
    "REFIT_CHOICES",
    "refit_calibration",
    "sensor_update",
    "solve_hand_eye",
    "static_edge",
    "write_fragment",
]
