"""The demo's world: sensor characteristics, the true motion (a real recorded head motion,
smoothed), the true static frames, the SRG and the simulated sensors (thesis 2.3, fig. 7.2)."""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources

import numpy as np

from ..dataflow import SimulatedSensor
from ..errors import InputError
from ..graph import MotionSpec, SpatialRelationshipGraph
from ..math import Pose, UncertainPose, quat_exp, quat_make_continuous

__all__ = [
    "DemoConfig",
    "demo_frames",
    "demo_graph",
    "demo_sensors",
    "demo_truth",
    "load_demo_motion",
]


@dataclass(frozen=True)
class DemoConfig:
    """Sensor characteristics of the demo (seconds, metres, radians)."""

    seed: int = 7
    tracker_rate_hz: float = 60.0
    tracker_latency_s: float = 0.020
    tracker_sigma_pos: float = 0.0003
    tracker_sigma_ori: float = np.radians(0.05)
    camera_rate_hz: float = 30.0
    camera_latency_s: float = 0.050
    camera_stamp_offset_s: float = 0.030
    camera_sigma_pos: float = 0.002
    camera_sigma_ori: tuple[float, float, float] = (
        float(np.radians(1.0)),
        float(np.radians(1.0)),
        float(np.radians(0.3)),
    )
    camera_outlier_rate: float = 0.02
    query_rate_hz: float = 60.0
    aligned_offset_s: float = -0.100
    warmup_s: float = 1.0
    truth_lowpass_hz: float | None = 6.0
    # Process noise of the constant-velocity models, in MotionModel's order (position levels
    # 0..1, then orientation levels 0..1): white acceleration [m/s^2/sqrt(s)] and white angular
    # acceleration [rad/s^2/sqrt(s)]. Tuned on a different noise seed (11) for the smallest
    # prediction error to the sensor's latency, then moved ~3x away from the point where
    # consistent measurements start failing the 99.9 % gate (docs/dataflow.md).
    tracker_motion_noise: tuple[float, ...] = (0.0, 0.3, 0.0, 3.0)
    camera_motion_noise: tuple[float, ...] = (0.0, 1.5, 0.0, 1.0)


def load_demo_motion() -> tuple[np.ndarray, Pose]:
    """The shipped head-motion excerpt: times [s] (N,) and poses ``T_world_body`` (N,)."""
    text = resources.files("trackflow.data").joinpath("headset_optitrack.csv").read_text()
    rows = [line for line in text.splitlines() if line and not line.startswith(("#", "t,"))]
    d = np.array([[float(v) for v in r.split(",")] for r in rows])
    return d[:, 0], Pose(d[:, 1:4], d[:, 4:8], normalize=True)


def demo_truth(t_s: np.ndarray, poses: Pose, lowpass_hz: float | None = 6.0):
    """A smooth ground-truth motion ``truth(t) -> Pose`` through the recorded samples.

    The recording is first resampled on a uniform 120 Hz grid (cubic spline in position,
    rotation spline in orientation; this bridges its tracking gaps). With ``lowpass_hz`` the
    resampled motion is then low-passed (4th-order Butterworth run forwards and backwards, so
    without phase lag; quaternion components are filtered after making them sign-continuous and
    renormalised). The OptiTrack samples carry about 0.1 mm / 0.05 deg of jitter; splining
    through it gives accelerations of ~15 m/s^2 and ~400 rad/s^2 RMS that no head produces.
    At 6 Hz the smoothed motion stays within ~0.4 mm RMS of the raw samples while its
    acceleration drops to ~0.5 m/s^2 and ~4 rad/s^2 RMS (measured; ``docs/dataflow.md``).

    Parameters
    ----------
    t_s : ndarray (N,)
        Sample times [s], increasing.
    poses : Pose (N,)
        Recorded ``T_world_body``.
    lowpass_hz : float or None
        Cut-off frequency [Hz] (below 60 Hz); ``None`` keeps the raw spline.
    """
    from scipy.interpolate import CubicSpline
    from scipy.spatial.transform import Rotation, RotationSpline

    pos = CubicSpline(t_s, poses.position, axis=0)
    rot = RotationSpline(t_s, Rotation.from_quat(poses.quaternion))
    if lowpass_hz is not None:
        from scipy.signal import butter, filtfilt

        if not 0 < lowpass_hz < 60:
            raise InputError(f"lowpass_hz must be in (0, 60) Hz, got {lowpass_hz}")
        grid = np.arange(t_s[0], t_s[-1], 1.0 / 120.0)
        b, a = butter(4, lowpass_hz / 60.0)
        p = filtfilt(b, a, pos(grid), axis=0)
        q = filtfilt(b, a, quat_make_continuous(rot(grid).as_quat()), axis=0)
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        pos = CubicSpline(grid, p, axis=0)
        rot = RotationSpline(grid, Rotation.from_quat(q))
        t_lo, t_hi = grid[0], grid[-1]
    else:
        t_lo, t_hi = t_s[0], t_s[-1]

    def truth(t):
        t = np.clip(np.asarray(t, dtype=float), t_lo, t_hi)
        return Pose(pos(t), rot(t).as_quat(), normalize=True)

    return truth


def _rot(axis, deg) -> np.ndarray:
    a = np.asarray(axis, dtype=float)
    return quat_exp(a / np.linalg.norm(a) * np.radians(deg))


def demo_frames(truth, t0: float, t1: float) -> dict[str, Pose]:
    """True static relationships: target->camera, marker placement, projector."""
    T_T_C = Pose([0.03, -0.05, 0.02], _rot([1, 2, 0.5], 12.0))
    ts = np.linspace(t0, t1, 50)
    cams = truth(ts) @ T_T_C
    mid = cams[len(ts) // 2]
    # The marker lies 0.6 m in front of the camera's mid pose, facing it.
    T_A_M = mid @ Pose([0.02, 0.01, 0.6], _rot([0, 1, 0.1], 170.0))
    T_P_A = Pose([0.1, 2.0, -0.3], _rot([1, 0, 0], 90.0))
    return {"T_T_C": T_T_C, "T_A_M": T_A_M, "T_P_A": T_P_A}


def demo_graph(cfg: DemoConfig, fixed: dict[str, Pose], T_T_C: UncertainPose):
    """The demo SRG with the given target->camera calibration."""
    tracker_motion = MotionSpec(static=False, n_dp=1, n_do=1, noise=cfg.tracker_motion_noise)
    camera_motion = MotionSpec(static=False, n_dp=1, n_do=1, noise=cfg.camera_motion_noise)
    g = SpatialRelationshipGraph()
    g.add_static("projector", "P", "A", fixed["T_P_A"], np.diag([1e-8] * 3 + [1e-8] * 3))
    g.add_measured(
        "art",
        "A",
        "T",
        latency_s=cfg.tracker_latency_s,
        rate_hz=cfg.tracker_rate_hz,
        covariance=np.diag([cfg.tracker_sigma_pos**2] * 3 + [cfg.tracker_sigma_ori**2] * 3),
        motion=tracker_motion,
    )
    g.add_static("target_camera", "T", "C", T_T_C.pose, T_T_C.covariance)
    g.add_measured(
        "artoolkit",
        "C",
        "M",
        latency_s=cfg.camera_latency_s,
        rate_hz=cfg.camera_rate_hz,
        confidence=1.0 - cfg.camera_outlier_rate,
        covariance=np.diag([cfg.camera_sigma_pos**2] * 3 + [s**2 for s in cfg.camera_sigma_ori]),
        motion=camera_motion,
        stamp_offset_s=cfg.camera_stamp_offset_s,
    )
    g.add_static("marker", "A", "M", fixed["T_A_M"], np.diag([1e-8] * 3 + [1e-8] * 3))
    return g


def demo_sensors(cfg: DemoConfig, truth, fixed, t0: float, t1: float) -> dict[str, SimulatedSensor]:
    """Fresh simulated sensors; the same seed gives bit-identical data."""
    rng = np.random.default_rng(cfg.seed)
    T_T_C, T_A_M = fixed["T_T_C"], fixed["T_A_M"]

    def camera_truth(t):
        return (truth(t) @ T_T_C).inverse() @ T_A_M

    art = SimulatedSensor(
        "art",
        truth,
        rate_hz=cfg.tracker_rate_hz,
        latency_s=cfg.tracker_latency_s,
        sigma_pos=cfg.tracker_sigma_pos,
        sigma_ori=cfg.tracker_sigma_ori,
        rng=rng,
        start_s=t0,
        end_s=t1,
    )
    cam = SimulatedSensor(
        "artoolkit",
        camera_truth,
        rate_hz=cfg.camera_rate_hz,
        latency_s=cfg.camera_latency_s,
        sigma_pos=cfg.camera_sigma_pos,
        sigma_ori=cfg.camera_sigma_ori,
        rng=rng,
        start_s=t0 + 0.011,
        end_s=t1,
        stamp_offset_s=cfg.camera_stamp_offset_s,
        outlier_rate=cfg.camera_outlier_rate,
    )
    return {"art": art, "artoolkit": cam}
