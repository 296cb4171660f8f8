"""Filter factories: the pose filter the dataflow builds for a relationship's motion.

The dataflow (:class:`trackflow.dataflow.KalmanFilter`) builds one filter per sensor with
``filter_factory(motion, history_s)``, where ``motion`` describes the relationship's motion
(:class:`MotionSpecLike`, met by :class:`trackflow.graph.MotionSpec`), and talks to it through
:class:`trackflow.filters.PoseFilter`. :func:`make_filter` is the default (the thesis's pose
Kalman filter); :func:`relative_motion_factory` and :func:`quaternion_space_factory` build the
seed papers' filters.

Process noise from a motion spec: the seed filters are constant-velocity models driven by white
linear / angular acceleration of spectral densities ``q_a`` [m^2/s^3] and ``q_alpha``
[rad^2/s^3]. A scalar or ``(position, orientation)`` motion noise ``(s_p, s_o)`` means
``q_a = s_p^2``, ``q_alpha = s_o^2`` (exactly what it means to :class:`MotionModel` for
``n_dp = n_do = 1``); a full per-level tuple uses its velocity-level entries. The factories take
explicit ``q_a`` / ``q_alpha`` instead. A static motion has no seed-filter counterpart: the
factories then return :func:`make_filter`'s filter (a static model: recursive least squares).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Protocol

from ..errors import InputError
from .derivative import MotionModel, PoseKalmanFilter
from .quaternion_space.streaming import QuaternionSpacePoseFilter
from .relative_motion.streaming import RelativeMotionPoseFilter

__all__ = [
    "MotionSpecLike",
    "constant_velocity_densities",
    "filter_noise",
    "make_filter",
    "quaternion_space_factory",
    "relative_motion_factory",
]


class MotionSpecLike(Protocol):
    """What a factory reads of a relationship's motion (:class:`trackflow.graph.MotionSpec`)."""

    static: bool
    n_dp: int
    n_do: int
    noise: float | tuple[float, ...]


def filter_noise(motion: MotionSpecLike) -> tuple[float, ...] | None:
    """Per-level process noise for :class:`MotionModel` from a motion spec.

    A scalar or a pair ``(position, orientation)`` drives the highest derivative level of
    each part (white-noise spectral densities, lower levels zero); a full tuple of
    ``(n_dp + 1) + (n_do + 1)`` values is passed unchanged.
    """
    noise = motion.noise
    levels = (motion.n_dp + 1, motion.n_do + 1)
    if isinstance(noise, (int, float)):
        noise = (float(noise), float(noise))
    noise = tuple(float(v) for v in noise)
    if len(noise) == sum(levels):
        return noise
    if len(noise) != 2:
        raise InputError(
            f"motion noise must be a scalar, a (position, orientation) pair or {sum(levels)} "
            f"values, got {noise}"
        )
    return (0.0,) * motion.n_dp + (noise[0],) + (0.0,) * motion.n_do + (noise[1],)


def make_filter(motion: MotionSpecLike, history_s: float) -> PoseKalmanFilter:
    """A :class:`PoseKalmanFilter` for a relationship's motion model (the default factory)."""
    if motion.static:
        model = MotionModel.static()
    else:
        model = MotionModel(motion.n_dp, motion.n_do, noise=filter_noise(motion))
    return PoseKalmanFilter(model, history=history_s)


def constant_velocity_densities(motion) -> tuple[float, float]:
    """``(q_a, q_alpha)`` [m^2/s^3, rad^2/s^3] of a constant-velocity model from a MotionSpec.

    Scalar ``s`` -> ``(s^2, s^2)``; pair ``(s_p, s_o)`` -> ``(s_p^2, s_o^2)``; a full tuple of
    ``(n_dp + 1) + (n_do + 1)`` per-level values -> its velocity-level entries squared.
    """
    noise = motion.noise
    if isinstance(noise, (int, float)):
        noise = (float(noise), float(noise))
    noise = tuple(float(v) for v in noise)
    if len(noise) == 2:
        s_p, s_o = noise
    elif len(noise) == motion.n_dp + motion.n_do + 2 and motion.n_dp >= 1 and motion.n_do >= 1:
        s_p, s_o = noise[1], noise[motion.n_dp + 2]
    else:
        raise InputError(
            f"motion noise {noise} cannot drive a constant-velocity seed filter: give a scalar, "
            "a (position, orientation) pair, or per-level values with n_dp, n_do >= 1"
        )
    if not (math.isfinite(s_p) and math.isfinite(s_o) and s_p >= 0 and s_o >= 0):
        raise InputError(f"motion noise must be finite and >= 0, got {noise}")
    return s_p * s_p, s_o * s_o


def _seed_factory(filter_class, q_a: float | None, q_alpha: float | None, options) -> Callable:
    def factory(motion, history_s: float):
        if motion.static:
            return make_filter(motion, history_s)
        qa, qal = constant_velocity_densities(motion)
        return filter_class(
            qa if q_a is None else q_a,
            qal if q_alpha is None else q_alpha,
            history=history_s,
            **options,
        )

    return factory


def relative_motion_factory(
    q_a: float | None = None, q_alpha: float | None = None, **options
) -> Callable:
    """A ``filter_factory(motion, history_s)`` building :class:`RelativeMotionPoseFilter`.

    ``q_a`` / ``q_alpha`` default to :func:`constant_velocity_densities` of each relationship's
    motion spec; ``options`` go to the constructor. Static motions get :func:`make_filter`.
    Build one factory and pass the same object to every plan, so that networks can share a
    sensor's filter (they compare factories by identity).
    """
    return _seed_factory(RelativeMotionPoseFilter, q_a, q_alpha, options)


def quaternion_space_factory(
    q_a: float | None = None, q_alpha: float | None = None, **options
) -> Callable:
    """A ``filter_factory(motion, history_s)`` building :class:`QuaternionSpacePoseFilter`
    (same rules as :func:`relative_motion_factory`)."""
    return _seed_factory(QuaternionSpacePoseFilter, q_a, q_alpha, options)
