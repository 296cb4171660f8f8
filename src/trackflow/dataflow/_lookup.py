"""``lookup``: the pose of one frame in another at a time, from a setup and its recordings."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError, PlanError
from ..graph import Query
from ..math import UncertainPose, quat_to_matrix
from ._setup import Setup
from ._sources import NO_ORIGIN

__all__ = ["LookupResult", "lookup", "rpy_deg"]


def rpy_deg(quaternion) -> np.ndarray:
    """Roll, pitch, yaw [deg] of ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (fixed axes x, y, z).

    This is the convention of ROS's tf2 (``getRPY``); pitch is in [-90, 90] degrees.
    """
    r = quat_to_matrix(np.asarray(quaternion, float))
    pitch = np.arcsin(np.clip(-r[..., 2, 0], -1.0, 1.0))
    roll = np.arctan2(r[..., 2, 1], r[..., 2, 2])
    yaw = np.arctan2(r[..., 1, 0], r[..., 0, 0])
    return np.degrees(np.stack([roll, pitch, yaw], axis=-1))


@dataclass(frozen=True)
class LookupResult:
    """``T_source_target`` at ``t_ns`` with its covariance and the age of its newest input.

    Attributes
    ----------
    source, target : str
    t_ns : int
        Time the pose is valid at [ns, the recordings' clock].
    pose : UncertainPose
        Covariance over ``(dt [m, frame source], dtheta [rad, frame target])``.
    age_ns : int or None
        ``t_ns`` minus the sensor timestamp of the newest measurement used (``None`` for a
        chain of static edges only).
    path : str
        The path the planner chose.
    """

    source: str
    target: str
    t_ns: int
    pose: UncertainPose
    age_ns: int | None
    path: str

    def as_dict(self) -> dict:
        sig = np.sqrt(np.clip(np.diag(self.pose.covariance), 0.0, None))
        return {
            "source": self.source,
            "target": self.target,
            "t_s": self.t_ns * 1e-9,
            "position_m": np.asarray(self.pose.position).tolist(),
            "quaternion_xyzw": np.asarray(self.pose.quaternion).tolist(),
            "rpy_deg": rpy_deg(self.pose.quaternion).tolist(),
            "sigma_position_mm": (sig[:3] * 1e3).tolist(),
            "sigma_rotation_deg": np.degrees(sig[3:]).tolist(),
            "age_ms": None if self.age_ns is None else self.age_ns * 1e-6,
            "path": self.path,
        }


def lookup(setup: Setup, source: str, target: str, t_ns: int | None = None) -> LookupResult:
    """``T_source_target`` at ``t_ns`` from ``setup`` (its statics and sensor recordings).

    The planner's pull dataflow for the query is built on the setup's recordings
    (``Setup.players``) and run up to ``t_ns``; the result is what an application pulling at
    that moment would get (time-aligned by the sensors' Kalman filters). ``t_ns`` defaults to
    the latest common time of the recordings on the path, the earliest of their last samples
    (like tf2's "latest common time"; 0 when every edge on the path is static).

    Raises
    ------
    ValueError
        Unknown frames, no path, a measured edge on the path without a recording, or no
        answer at ``t_ns`` (e.g. before the first measurement); messages name the setup.
    """
    for frame in (source, target):
        try:
            setup.graph.check_frame(frame)
        except ValueError as exc:
            raise PlanError(f"{setup.source}: {exc}") from None
    plan = setup.plan(Query(source, target, mode="pull", name=f"{source}->{target}"))
    measured = sorted({n.params["edge"] for n in plan.nodes if n.kind == "source"})
    missing = [e for e in measured if e not in setup.recordings]
    if missing:
        raise PlanError(
            f"{setup.source}: the path {plan.paths[0]} uses sensor(s) {missing} without a "
            "'recording:' in the setup"
        )
    players = {k: v for k, v in setup.players().items() if k in measured}
    if t_ns is None:
        t_ns = min((int(p.t_ns[-1]) for p in players.values()), default=0)
    net, sink = plan.build(players)
    if players:
        net.run(until_ns=int(t_ns))
    m = sink.get(int(t_ns))
    if m is None:
        raise InputError(
            f"{setup.source}: no estimate of T_{source}_{target} at {t_ns * 1e-9:.9f} s "
            "(before the first measurement, or in a gap of a sensor)"
        )
    age = None if m.origin_ns == NO_ORIGIN else int(t_ns) - int(m.origin_ns)
    return LookupResult(source, target, int(t_ns), m.pose, age, str(plan.paths[0]))
