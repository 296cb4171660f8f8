"""The thesis's demo setup (section 2.3, figure 7.2) driven by a real recorded motion.

Frames: projector ``P``, outside-in tracker ``A`` (ART-like), tracked target ``T`` rigidly
mounted on a hand-held camera ``C``, and a marker ``M`` lying still on the table. Edges:

* ``P -> A`` static (the projector is calibrated to the tracker),
* ``A -> T`` measured by the tracker: 60 Hz, low noise, 20 ms latency,
* ``T -> C`` static, estimated from data first (section 7.4.1),
* ``C -> M`` measured by the ARToolKit-like camera: 30 Hz, noisy orientation, 50 ms latency,
  occasional wrong detections, and host-side timestamps 30 ms late (the constant time offset
  of section 9.2.2, known from calibration),
* ``A -> M`` static, the surveyed marker location used only to estimate ``T -> C``.

The target moves like the shipped head-motion excerpt. Because the marker does not move, the
true ``T_P_M`` is constant, so every wobble of the computed relationship is error - exactly the
experiment of section 9.2.2. Three dataflows answer the query ``P -> M`` at 60 Hz:

* naive: the newest measurement of each sensor chained as it is (no time alignment);
* aligned: Kalman filters interpolate both sensors to one common time 100 ms in the past;
* predicted: the same filters predict both sensors to the present (the real-time output).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from ..graph import MotionSpec, Query, SpatialRelationshipGraph
from ..math import Pose, UncertainPose, quat_angle, quat_exp, quat_make_continuous
from ._planner import plan_query
from ._sources import SimulatedSensor

__all__ = [
    "DemoConfig",
    "demo_frames",
    "demo_graph",
    "demo_json",
    "demo_sensors",
    "demo_truth",
    "load_demo_motion",
    "run_demo",
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
            raise ValueError(f"lowpass_hz must be in (0, 60) Hz, got {lowpass_hz}")
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


def pose_errors(estimate: Pose, truth: Pose) -> tuple[np.ndarray, np.ndarray]:
    """Position error [m] and rotation angle error [rad] of each estimate."""
    dp = np.linalg.norm(estimate.position - truth.position, axis=-1)
    dq = quat_angle(truth.quaternion, estimate.quaternion)
    return dp, dq


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")


def run_demo(
    out: str | Path = "out/demo.png",
    cfg: DemoConfig | None = None,
    filter_factory=None,
    plot: bool = True,
) -> dict:
    """Run the demo; return the error summary (mm, degrees) and write the plot.

    Returns
    -------
    dict
        ``{"naive": {"pos_rms_mm", "ori_rms_deg"}, "aligned": {...}, "predicted": {...},
        "static_edge_error": {"pos_mm", "ori_deg"}, "plot": path}`` plus, under ``"details"``,
        counts and the estimated edge.
    """
    cfg = cfg or DemoConfig()
    t_rec, poses = load_demo_motion()
    truth = demo_truth(t_rec, poses, cfg.truth_lowpass_hz)
    t0, t1 = float(t_rec[0]), float(t_rec[-1])
    fixed = demo_frames(truth, t0, t1)

    # 1. Estimate the static target->camera edge from data (7.4.1): T<-A . A->M . C<-M into a
    #    static estimator, the unknown edge itself excluded from the search.
    unknown = UncertainPose(Pose.identity(), np.eye(6))
    g0 = demo_graph(cfg, fixed, unknown)
    q_cal = Query("T", "C", static=True, exclude=("target_camera",), name="calibration")
    cal_plan = plan_query(g0, q_cal)
    net, sink = cal_plan.build(
        demo_sensors(cfg, truth, fixed, t0, t1), filter_factory=filter_factory
    )
    net.run()
    est = sink.get(int(t1 * 1e9))
    cal_rejections = {n: st["rejections"] for n, st in net.stats().items() if st["rejections"]}
    if est is None:
        raise RuntimeError("the static edge could not be estimated: no accepted measurements")
    T_T_C_est = est.pose
    e_pos, e_ori = pose_errors(T_T_C_est.pose, fixed["T_T_C"])

    # 2. Track P -> M with the estimated calibration: the naive chain in a network of its own;
    #    the aligned and the predicted query in one network sharing the sensors' filters (a
    #    filter's state does not depend on who asks it, so sharing changes no result).
    graph = demo_graph(cfg, fixed, T_T_C_est)
    truth_PM = fixed["T_P_A"] @ fixed["T_A_M"]
    variants = {
        "naive": (False, 0.0),
        "aligned": (True, cfg.aligned_offset_s),
        "predicted": (True, 0.0),
    }
    result: dict = {}
    series = {}
    details = {"static_edge": {}, "rejections": {"calibration": cal_rejections}}
    sinks = {}
    nets = {}
    shared = None
    for label, (align, offset) in variants.items():
        q = Query(
            "P",
            "M",
            mode="push",
            rate_hz=cfg.query_rate_hz,
            time_offset_s=offset,
            exclude=("marker",),
            name=label,
        )
        plan = plan_query(graph, q, align=align)
        if not align:
            sensors = demo_sensors(cfg, truth, fixed, t0, t1)
            nets[label], sinks[label] = plan.build(sensors, filter_factory=filter_factory)
            continue
        if shared is None:
            sensors = demo_sensors(cfg, truth, fixed, t0, t1)
            details["camera_wrong_detections"] = int(sensors["artoolkit"].outliers.sum())
        shared, sinks[label] = plan.build(
            sensors, filter_factory=filter_factory, network=shared, prefix=f"{label}_"
        )
        nets[label] = shared
    for net in {id(n): n for n in nets.values()}.values():
        net.run()
    for label in variants:
        a = sinks[label].arrays()
        keep = a["t_ns"] * 1e-9 >= t0 + cfg.warmup_s
        est_pose = Pose(a["position"][keep], a["quaternion"][keep], normalize=True)
        dp, dq = pose_errors(
            est_pose,
            Pose(
                np.broadcast_to(truth_PM.position, est_pose.position.shape),
                np.broadcast_to(truth_PM.quaternion, est_pose.quaternion.shape),
            ),
        )
        result[label] = {"pos_rms_mm": _rms(dp) * 1e3, "ori_rms_deg": float(np.degrees(_rms(dq)))}
        series[label] = (a["t_ns"][keep] * 1e-9 - t0, dp * 1e3, np.degrees(dq))
        # this query's own components (prefixed) and the shared sources and filters
        others = tuple(f"{o}_" for o in variants if o != label)
        details["rejections"][label] = {
            n.removeprefix(f"{label}_"): st["rejections"]
            for n, st in nets[label].stats().items()
            if st["rejections"] and not n.startswith(others)
        }
    result["static_edge_error"] = {
        "pos_mm": float(e_pos) * 1e3,
        "ori_deg": float(np.degrees(e_ori)),
    }
    path = Path(out)
    if plot:
        _plot(series, path, result)
    result["plot"] = str(path)
    details["static_edge"] = {
        "position_m": T_T_C_est.position.tolist(),
        "quaternion_xyzw": T_T_C_est.quaternion.tolist(),
        "sigma_mm": (np.sqrt(np.diag(T_T_C_est.covariance)[:3]) * 1e3).tolist(),
    }
    result["details"] = details
    return result


def _plot(series, path: Path, result) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path.parent.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    for label, (t, dp, dq) in series.items():
        r = result[label]
        axes[0].plot(t, dp, lw=0.8, label=f"{label} (RMS {r['pos_rms_mm']:.1f} mm)")
        axes[1].plot(t, dq, lw=0.8, label=f"{label} (RMS {r['ori_rms_deg']:.2f} deg)")
    axes[0].set_ylabel("position error [mm]")
    axes[1].set_ylabel("orientation error [deg]")
    axes[1].set_xlabel("time [s]")
    axes[0].set_title("projector -> marker (marker at rest: truth is constant)")
    for ax in axes:
        ax.legend(loc="upper right", fontsize=8)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def demo_json(result: dict) -> str:
    """The stable one-line JSON of ``trackflow demo --json`` (without ``details``)."""
    keys = ("naive", "aligned", "predicted", "static_edge_error", "plot")
    return json.dumps({k: result[k] for k in keys})
