"""Prediction-error evaluation and automatic Kalman filter tuning (PoseTool, thesis 8.1, 9.2.1).

A recording is checked once into a :class:`Trajectory` (times, positions, quaternions, gap
threshold) that every step takes. ``evaluate_recording`` tunes on the first part of it and
scores the tuned Kalman predictor, linear extrapolation and no prediction on the rest (thesis
tables 9.2-9.5); each is a :class:`Predictor`. ``evaluate_with_imu`` adds an IMU-aided
predictor (``kalman_imu``) on a thinned pose stream. See ``docs/posetool.md`` and
``docs/inertial.md``.
"""

from ._baselines import LinearPredictor, NoPredictor, predict_linear, predict_none
from ._compare import ALIGNMENTS, CompareSettings, associate, compare_trajectories
from ._compare_result import CompareResult, ErrorSeries, Stats
from ._evaluate import PREDICTORS, PredictionReport, evaluate_predictors
from ._inertial import (
    IMU_PREDICTORS,
    ORIGINS,
    ImuSamples,
    InertialPredictor,
    evaluate_with_imu,
    tune_inertial,
)
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
from ._pairs import DELTA_UNITS, POSE_RELATIONS, rpe_pairs
from ._prediction import Prediction, Predictor, predict_kalman
from ._predictor import (
    KalmanPredictor,
    PartwisePredictor,
    TwistARPredictor,
    default_predictor,
    estimate_noise,
)
from ._results import ResultsComparison, compare_results, load_result
from ._shrinkage import (
    ShrunkPredictor,
    apply_shrinkage,
    change_factors,
    fit_shrinkage,
    shrinkage_factors,
)
from ._stream_ops import (
    check_stream,
    downsample_stream,
    load_transform,
    merge_streams,
    motion_filter_stream,
    sync_streams,
    transform_stream,
)
from ._targets import default_gap, interpolate_poses, scored_mask
from ._thinned import TrackerTrajectory, predict_from_last_pose, thin_poses
from ._trajectory import Trajectory
from ._tuning import LEARNED_ORDERS, TuneResult, evaluate_recording, tune_model
from ._warmup import compile_kernels

__all__ = [
    "compile_kernels",
    "IMU_PREDICTORS",
    "ORIGINS",
    "ImuSamples",
    "InertialPredictor",
    "TrackerTrajectory",
    "evaluate_with_imu",
    "thin_poses",
    "predict_from_last_pose",
    "tune_inertial",
    "change_factors",
    "ALIGNMENTS",
    "CompareResult",
    "CompareSettings",
    "DELTA_UNITS",
    "ErrorSeries",
    "POSE_RELATIONS",
    "rpe_pairs",
    "check_stream",
    "compare_results",
    "load_result",
    "ResultsComparison",
    "downsample_stream",
    "load_transform",
    "merge_streams",
    "motion_filter_stream",
    "sync_streams",
    "transform_stream",
    "Stats",
    "ShrunkPredictor",
    "apply_shrinkage",
    "fit_shrinkage",
    "shrinkage_factors",
    "associate",
    "compare_trajectories",
    "LEARNED_ORDERS",
    "PREDICTORS",
    "ErrorStats",
    "FilterRun",
    "KalmanPredictor",
    "LinearPredictor",
    "NoPredictor",
    "PartwisePredictor",
    "Prediction",
    "PredictionReport",
    "Predictor",
    "TuneResult",
    "Trajectory",
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
