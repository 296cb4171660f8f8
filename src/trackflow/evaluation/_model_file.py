"""The model file that ``tune`` writes and ``filter`` reads: any predictor family, as JSON.

A model file holds one predictor of the evaluation (``KalmanPredictor`` on derivative motion
models, ``TwistARPredictor`` on a learned increment model, or ``PartwisePredictor`` combining
two of them), completely: a learned model keeps its coefficients, so ``filter --model`` runs
exactly the filter that ``tune`` chose. Layout::

    {"trackflow_model": 1, "predictor": {...}, "tuning": {...optional summary...}}

``predictor`` is ``{"family": "derivative", "n_dp", "n_do", "noise", "kind", "pos_sigma",
"ori_sigma", "gate_probability"}``, ``{"family": "twist_ar", "dt", "coefficients" (L x 6 x 6),
"noise" (6 x 6), "twist_covariance" (6 x 6), "pos_sigma", "ori_sigma"}`` or ``{"family":
"partwise", "position": {...}, "orientation": {...}}``; units are metres, radians and seconds.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ConfigError, InputError
from ..filters import MotionModel, TwistARModel, run_filter, run_twist_ar
from ..io import PoseStream, atomic_output
from ..math import Pose, UncertainPose
from ._predictor import KalmanPredictor, PartwisePredictor, TwistARPredictor

__all__ = [
    "MODEL_FILE_VERSION",
    "FilterRun",
    "filter_stream",
    "load_model",
    "predictor_from_dict",
    "predictor_to_dict",
    "save_model",
]

MODEL_FILE_VERSION = 1
#: Most time derivatives a model file may keep per part (the tuning tries 1..3; the setups'
#: motion models allow 0..3).
MAX_DERIVATIVES = 3


def predictor_to_dict(pred) -> dict:
    """Complete plain-data form of a predictor (JSON serialisable, learned coefficients kept)."""
    if isinstance(pred, KalmanPredictor):
        return pred.as_dict()
    if isinstance(pred, TwistARPredictor):
        m = pred.model
        return {
            "family": "twist_ar",
            "dt": float(m.dt),
            "coefficients": np.asarray(m.coefficients).tolist(),
            "noise": np.asarray(m.noise).tolist(),
            "twist_covariance": np.asarray(m.twist_covariance).tolist(),
            "pos_sigma": float(pred.pos_sigma),
            "ori_sigma": float(pred.ori_sigma),
        }
    if isinstance(pred, PartwisePredictor):
        return {
            "family": "partwise",
            "position": predictor_to_dict(pred.position),
            "orientation": predictor_to_dict(pred.orientation),
        }
    raise InputError(f"not a predictor: {type(pred).__name__}")


def _field(d: dict, key: str, where: str):
    if key not in d:
        raise ConfigError(f"{where}: missing field {key!r}")
    return d[key]


def predictor_from_dict(d: dict, where: str = "model"):
    """Inverse of :func:`predictor_to_dict`; ``ValueError`` naming ``where`` and the field."""
    if not isinstance(d, dict):
        raise ConfigError(f"{where}: expected an object, got {type(d).__name__}")
    family = _field(d, "family", where)
    try:
        if family == "derivative":
            counts = {k: _field(d, k, where) for k in ("n_dp", "n_do")}
            for k, v in counts.items():
                if not isinstance(v, int) or isinstance(v, bool) or not -1 <= v <= MAX_DERIVATIVES:
                    raise InputError(
                        f"{k} must be an integer in -1..{MAX_DERIVATIVES} (derivatives in the "
                        f"state), got {v!r}"
                    )
            model = MotionModel(
                counts["n_dp"],
                counts["n_do"],
                noise=[float(v) for v in _field(d, "noise", where)],
                kind=str(d.get("kind", "white_noise")),
            )
            g = d.get("gate_probability", 0.999)
            return KalmanPredictor(
                model,
                float(_field(d, "pos_sigma", where)),
                float(_field(d, "ori_sigma", where)),
                None if g is None else float(g),
            )
        if family == "twist_ar":
            model = TwistARModel(
                float(_field(d, "dt", where)),
                np.asarray(_field(d, "coefficients", where), dtype=float),
                np.asarray(_field(d, "noise", where), dtype=float),
                np.asarray(d["twist_covariance"], dtype=float) if "twist_covariance" in d else None,
            )
            return TwistARPredictor(
                model, float(_field(d, "pos_sigma", where)), float(_field(d, "ori_sigma", where))
            )
        if family == "partwise":
            return PartwisePredictor(
                predictor_from_dict(_field(d, "position", where), f"{where}.position"),
                predictor_from_dict(_field(d, "orientation", where), f"{where}.orientation"),
            )
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: {exc}") from None
    raise ConfigError(f"{where}: unknown family {family!r} (derivative, twist_ar or partwise)")


def save_model(path, pred, tuning: dict | None = None, overwrite: bool = False) -> None:
    """Write a model file (atomic; an existing file only with ``overwrite``)."""
    doc = {"trackflow_model": MODEL_FILE_VERSION, "predictor": predictor_to_dict(pred)}
    if tuning:
        doc["tuning"] = tuning
    with atomic_output(path, overwrite=overwrite) as tmp:
        tmp.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")


def load_model(path):
    """Read a model file written by :func:`save_model` (``tune --output``)."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{path}:{exc.lineno}: not a JSON model file ({exc.msg})") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a JSON model file (not UTF-8 text)") from None
    if not isinstance(doc, dict) or doc.get("trackflow_model") != MODEL_FILE_VERSION:
        raise ConfigError(
            f"{path}: not a trackflow model file (write one with trackflow tune --output)"
        )
    return predictor_from_dict(doc.get("predictor"), str(path))


@dataclass(frozen=True)
class FilterRun:
    """Filtered (or predicted) poses of a recording and how the filter fared.

    Attributes
    ----------
    stream : PoseStream
        ``T_source_target`` at the input times, with 6x6 covariances over ``(dt, dtheta)``.
    nis : ndarray, shape (N,)
        Normalised innovation squared per measurement (NaN where none was formed); 6 degrees of
        freedom for derivative filters on whole poses.
    rejected : int
        Measurements the outlier gate refused.
    resets : int
        Times the filter started again (divergence, repeated gating; not the first sample).
    noise_scale : tuple of float
        Variance factor applied to the predictor's measurement and process noise by the
        calibration (one per filter: position and orientation for a partwise predictor).
    predictor : object
        The predictor that produced ``stream`` (after calibration).
    dof : int
        Degrees of freedom of ``nis`` (6 for a whole pose, 3 + 3 for two independent parts,
        more when a learned part measures the whole pose).
    """

    stream: PoseStream
    nis: np.ndarray
    rejected: int
    resets: int
    noise_scale: tuple[float, ...] = (1.0,)
    predictor: object = None
    dof: int = 6

    def nis_band(self, probability: float = 0.99) -> tuple[float, float, float]:
        """Mean NIS and its two-sided ``probability`` band for the number of measurements.

        Under a consistent filter the mean of ``n`` NIS values of ``dof`` degrees of freedom
        lies in ``chi2(n dof) / n`` at the given probability.
        """
        from scipy.stats import chi2

        v = self.nis[np.isfinite(self.nis)]
        n = max(len(v), 1)
        lo, hi = chi2.ppf([(1 - probability) / 2, (1 + probability) / 2], self.dof * n) / n
        return float(np.mean(v)) if len(v) else float("nan"), float(lo), float(hi)


def scale_noise(pred, k: float):
    """``pred`` with every noise variance (measurement and process) multiplied by ``k``.

    For a linear Kalman filter this leaves the gain and so the estimates unchanged and scales
    every covariance and the inverse NIS by ``k``; the error-state filters here are close to
    linear over one step, so the means change only through the outlier gate.
    """
    if not (np.isfinite(k) and k > 0):
        raise InputError(f"noise scale must be > 0, got {k!r}")
    r = float(np.sqrt(k))
    if isinstance(pred, KalmanPredictor):
        m = pred.model
        model = MotionModel(m.n_dp, m.n_do, noise=np.asarray(m.noise) * r, kind=m.kind)
        return KalmanPredictor(model, pred.pos_sigma * r, pred.ori_sigma * r,
                               pred.gate_probability)  # fmt: skip
    if isinstance(pred, TwistARPredictor):
        m = pred.model
        model = TwistARModel(m.dt, m.coefficients, np.asarray(m.noise) * k,
                             np.asarray(m.twist_covariance) * k)  # fmt: skip
        return TwistARPredictor(model, pred.pos_sigma * r, pred.ori_sigma * r)
    raise InputError(f"cannot scale {type(pred).__name__}")


def _dof(pred) -> int:
    """Measurement dimension of one filter (position-only / orientation-only parts: 3)."""
    if isinstance(pred, KalmanPredictor) and min(pred.model.n_dp, pred.model.n_do) < 0:
        return 3
    return 6


def _run_part(pred, t, p, q, horizon: float):
    """(position, quaternion, covariance, nis, rejected, resets) of one predictor."""
    if isinstance(pred, KalmanPredictor):
        res = run_filter(
            t, pred.measurements(p, q), pred.model, (horizon,),
            gate_probability=pred.gate_probability,
        )  # fmt: skip
        out = res.predictions[horizon] if horizon > 0 else res.filtered
        st = res.stats
        return (out.position, out.quaternion, out.covariance, res.nis,
                int(st["rejected_gate"]), int(st["resets"]))  # fmt: skip
    if horizon > 0:
        raise InputError(
            "the learned (twist_ar) model predicts means only; filter with --horizon 0, "
            "or tune with --learned-orders none for predictions with covariances"
        )
    res = run_twist_ar(t, p, q, pred.model, pred.pos_sigma, pred.ori_sigma)
    return res.position, res.quaternion, res.covariance, res.nis, 0, max(res.restarts - 1, 0)


def _calibrated(pred, t, p, q, horizon: float, calibrate: bool):
    """Run one filter; with ``calibrate`` once more with its noise scaled to mean NIS = dof."""
    out = _run_part(pred, t, p, q, horizon)
    if not calibrate:
        return pred, 1.0, out
    nis = out[3][np.isfinite(out[3])]
    if not nis.size:
        return pred, 1.0, out
    k = float(np.mean(nis)) / _dof(pred)
    if not k > 0:  # a recording that never moves nor shows noise: nothing to calibrate by
        return pred, 1.0, out
    pred = scale_noise(pred, k)
    return pred, k, _run_part(pred, t, p, q, horizon)


def filter_stream(
    stream: PoseStream, pred, horizon: float = 0.0, calibrate: bool = False
) -> FilterRun:
    """Run ``pred`` (any family) over ``stream``; predictions ``horizon`` seconds ahead if > 0.

    A partwise predictor takes the position (and its 3x3 covariance block) from its position
    filter and the orientation from its orientation filter; the cross-covariance between the
    two is zero, as the filters are independent.

    With ``calibrate`` each filter's noise (measurement and process together, see
    :func:`scale_noise`) is scaled so that its mean NIS over the recording equals its
    measurement dimension, and the filter is run again: the reported covariances then match the
    size of the innovations actually seen (a covariance-matching step on the recording itself).
    """
    t = (stream.t_ns - stream.t_ns[0]).astype(float) * 1e-9
    p = np.asarray(stream.position, float)
    q = np.asarray(stream.quaternion, float)
    if isinstance(pred, PartwisePredictor):
        pa, ka, a = _calibrated(pred.position, t, p, q, horizon, calibrate)
        pb, kb, b = _calibrated(pred.orientation, t, p, q, horizon, calibrate)
        cov = np.zeros((len(t), 6, 6))
        cov[:, :3, :3] = a[2][:, :3, :3]
        cov[:, 3:, 3:] = b[2][:, 3:, 3:]
        pos, quat = a[0], b[1]
        nis, dof = a[3] + b[3], _dof(pa) + _dof(pb)
        rejected, resets = a[4] + b[4], a[5] + b[5]
        scales, used = (ka, kb), PartwisePredictor(pa, pb)
    else:
        used, k, (pos, quat, cov, nis, rejected, resets) = _calibrated(
            pred, t, p, q, horizon, calibrate
        )
        scales, dof = (k,), _dof(used)
    poses = UncertainPose(Pose(pos, quat), np.array(cov))
    out = PoseStream.from_poses(stream.source, stream.target, stream.t_ns, poses)
    return FilterRun(out, np.asarray(nis, float), rejected, resets, scales, used, dof)
