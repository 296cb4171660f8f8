"""Running the demo: estimate the target->camera edge from data, then answer ``P -> M`` with
the naive, the time-aligned and the predicting dataflow, and score them against the truth."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..dataflow import plan_query
from ..errors import StateError
from ..graph import Query
from ..math import Pose, UncertainPose, quat_angle
from . import simulation as sim
from .report import plot_errors

__all__ = ["pose_errors", "run_demo"]

#: the three dataflows answering P -> M: (time-aligned, time offset [s] or None = the config's)
_VARIANTS = {"naive": (False, 0.0), "aligned": (True, None), "predicted": (True, 0.0)}


def pose_errors(estimate: Pose, truth: Pose) -> tuple[np.ndarray, np.ndarray]:
    """Position error [m] and rotation angle error [rad] of each estimate."""
    dp = np.linalg.norm(estimate.position - truth.position, axis=-1)
    dq = quat_angle(truth.quaternion, estimate.quaternion)
    return dp, dq


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")


@dataclass(frozen=True)
class _World:
    """The true motion, the true static frames and the time span of one demo run."""

    cfg: sim.DemoConfig
    truth: object
    fixed: dict
    t0: float
    t1: float

    @classmethod
    def make(cls, cfg: sim.DemoConfig) -> _World:
        t_rec, poses = sim.load_demo_motion()
        truth = sim.demo_truth(t_rec, poses, cfg.truth_lowpass_hz)
        t0, t1 = float(t_rec[0]), float(t_rec[-1])
        return cls(cfg, truth, sim.demo_frames(truth, t0, t1), t0, t1)

    def sensors(self) -> dict:
        """Fresh simulated sensors (the same seed gives the same data every time)."""
        return sim.demo_sensors(self.cfg, self.truth, self.fixed, self.t0, self.t1)


def _estimate_static_edge(world: _World, filter_factory) -> tuple[UncertainPose, dict]:
    """The static target->camera edge from data (7.4.1): ``T<-A . A->M . C<-M`` into a static
    estimator, the unknown edge itself excluded from the search. Returns the estimate and the
    rejections per component."""
    unknown = UncertainPose(Pose.identity(), np.eye(6))
    g0 = sim.demo_graph(world.cfg, world.fixed, unknown)
    q_cal = Query("T", "C", static=True, exclude=("target_camera",), name="calibration")
    net, sink = plan_query(g0, q_cal).build(world.sensors(), filter_factory=filter_factory)
    net.run()
    est = sink.get(int(world.t1 * 1e9))
    rejections = {n: st["rejections"] for n, st in net.stats().items() if st["rejections"]}
    if est is None:
        raise StateError("the static edge could not be estimated: no accepted measurements")
    return est.pose, rejections


def _track(world: _World, T_T_C: UncertainPose, filter_factory) -> tuple[dict, dict, int]:
    """Build and run the three ``P -> M`` dataflows with the estimated calibration: the naive
    chain in a network of its own; the aligned and the predicted query in one network sharing
    the sensors' filters (a filter's state does not depend on who asks it, so sharing changes
    no result). Returns ``(sinks, networks, wrong camera detections)`` by variant."""
    cfg = world.cfg
    graph = sim.demo_graph(cfg, world.fixed, T_T_C)
    sinks, nets, shared, wrong = {}, {}, None, 0
    for label, (align, offset) in _VARIANTS.items():
        offset = cfg.aligned_offset_s if offset is None else offset
        q = Query("P", "M", mode="push", rate_hz=cfg.query_rate_hz, time_offset_s=offset,
                  exclude=("marker",), name=label)  # fmt: skip
        plan = plan_query(graph, q, align=align)
        if not align:
            nets[label], sinks[label] = plan.build(world.sensors(), filter_factory=filter_factory)
            continue
        if shared is None:
            sensors = world.sensors()
            wrong = int(sensors["artoolkit"].outliers.sum())
        shared, sinks[label] = plan.build(
            sensors, filter_factory=filter_factory, network=shared, prefix=f"{label}_"
        )
        nets[label] = shared
    for net in {id(n): n for n in nets.values()}.values():
        net.run()
    return sinks, nets, wrong


def _score(world: _World, sinks: dict, nets: dict) -> tuple[dict, dict, dict]:
    """RMS errors against the constant true ``T_P_M`` after the warm-up, the error series for
    the plot, and each variant's rejections (its own components and the shared ones)."""
    truth_PM = world.fixed["T_P_A"] @ world.fixed["T_A_M"]
    result, series, rejections = {}, {}, {}
    for label in _VARIANTS:
        a = sinks[label].arrays()
        keep = a["t_ns"] * 1e-9 >= world.t0 + world.cfg.warmup_s
        est = Pose(a["position"][keep], a["quaternion"][keep], normalize=True)
        shape = est.position.shape
        true = Pose(np.broadcast_to(truth_PM.position, shape),
                    np.broadcast_to(truth_PM.quaternion, est.quaternion.shape))  # fmt: skip
        dp, dq = pose_errors(est, true)
        result[label] = {"pos_rms_mm": _rms(dp) * 1e3, "ori_rms_deg": float(np.degrees(_rms(dq)))}
        series[label] = (a["t_ns"][keep] * 1e-9 - world.t0, dp * 1e3, np.degrees(dq))
        others = tuple(f"{o}_" for o in _VARIANTS if o != label)
        rejections[label] = {
            n.removeprefix(f"{label}_"): st["rejections"]
            for n, st in nets[label].stats().items()
            if st["rejections"] and not n.startswith(others)
        }
    return result, series, rejections


def run_demo(
    out: str | Path = "out/demo.png",
    cfg: sim.DemoConfig | None = None,
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
    world = _World.make(cfg or sim.DemoConfig())
    T_T_C_est, cal_rejections = _estimate_static_edge(world, filter_factory)
    e_pos, e_ori = pose_errors(T_T_C_est.pose, world.fixed["T_T_C"])
    sinks, nets, wrong = _track(world, T_T_C_est, filter_factory)
    result, series, rejections = _score(world, sinks, nets)
    result["static_edge_error"] = {
        "pos_mm": float(e_pos) * 1e3,
        "ori_deg": float(np.degrees(e_ori)),
    }
    path = Path(out)
    if plot:
        plot_errors(series, path, result)
    result["plot"] = str(path)
    result["details"] = {
        "static_edge": {
            "position_m": T_T_C_est.position.tolist(),
            "quaternion_xyzw": T_T_C_est.quaternion.tolist(),
            "sigma_mm": (np.sqrt(np.diag(T_T_C_est.covariance)[:3]) * 1e3).tolist(),
        },
        "rejections": {"calibration": cal_rejections, **rejections},
        "camera_wrong_detections": wrong,
    }
    return result
