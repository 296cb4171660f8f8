"""The learned increment filter: a Kalman filter on a vector autoregression of body-frame pose
increments (model and fit in ``model``, compiled loop in ``kernels``; ``docs/filters.md``)."""

from .model import TwistARModel, TwistARResult, body_increments, excitation_ratios, run_twist_ar

__all__ = ["TwistARModel", "TwistARResult", "body_increments", "excitation_ratios", "run_twist_ar"]
