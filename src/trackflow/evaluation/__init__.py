"""Prediction-error evaluation and automatic Kalman filter tuning (PoseTool, thesis 8.1, 9.2.1).

``evaluate_recording`` tunes on the first part of a recording and scores the tuned Kalman
predictor, linear extrapolation and no prediction on the rest (thesis tables 9.2-9.5).
See ``docs/posetool.md``.
"""

from ._baselines import predict_linear, predict_none
from ._compare import ALIGNMENTS, CompareResult, Stats, associate, compare_trajectories, umeyama
from ._evaluate import PREDICTORS, PredictionReport, evaluate_predictors
from ._metrics import ErrorStats, error_stats, pose_errors
from ._model_file import (
    FilterRun,
    filter_stream,
    load_model,
    predictor_from_dict,
    predictor_to_dict,
    save_model,
)
from ._ops import infer_streams, invert_stream, scale_covariance, shift_stream, stream_info
from ._predictor import (
    KalmanPredictor,
    PartwisePredictor,
    TwistARPredictor,
    default_predictor,
    estimate_noise,
    predict_kalman,
)
from ._targets import default_gap, interpolate_poses, scored_mask
from ._tuning import LEARNED_ORDERS, TuneResult, evaluate_recording, tune_model

__all__ = [
    "ALIGNMENTS",
    "CompareResult",
    "Stats",
    "associate",
    "compare_trajectories",
    "umeyama",
    "LEARNED_ORDERS",
    "PREDICTORS",
    "ErrorStats",
    "FilterRun",
    "KalmanPredictor",
    "PartwisePredictor",
    "PredictionReport",
    "TuneResult",
    "TwistARPredictor",
    "default_gap",
    "default_predictor",
    "error_stats",
    "estimate_noise",
    "evaluate_predictors",
    "evaluate_recording",
    "filter_stream",
    "load_model",
    "predictor_from_dict",
    "predictor_to_dict",
    "save_model",
    "interpolate_poses",
    "pose_errors",
    "predict_kalman",
    "predict_linear",
    "predict_none",
    "scored_mask",
    "scale_covariance",
    "shift_stream",
    "stream_info",
    "infer_streams",
    "invert_stream",
    "tune_model",
]
