"""IMUs in the dataflow (thesis 10.3.3): an IMU is an attribute of a body frame.

A setup lists IMUs with the body frame they are mounted on::

    imus:
      - {name: box_imu, body: T, recording: imu0.csv, quaternion: [0, 0, 0, 1],
         lever_arm: [0, 0, 0], mode: strapdown, latency_ms: 1,
         noise: {gyro: 2e-3, accel: 2e-2, gyro_bias: 2e-5, accel_bias: 3e-3}}

The planner's filter behind every pose sensor measuring ``T_x_body`` becomes an
:class:`InertialKalmanFilter`: the sensor's poses correct it and the IMU's samples (played by an
:class:`ImuPlayer`) drive it. It answers pulls at any later time (between IMU samples and
ahead of the last one) and pushes a pose at every IMU sample, so push queries through that
sensor get IMU-rate answers.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np

from ..errors import ConfigError
from ..filters import ImuExtrinsics, ImuNoise, InertialFilter, InertialModel
from ._events import Measurement
from ._plan_node import PlanNode
from ._processing import KalmanFilter
from ._sources import RecordingPlayer

__all__ = ["ImuPlayer", "ImuSample", "ImuSpec", "InertialKalmanFilter", "attach_imus", "parse_imus"]


class ImuSample(NamedTuple):
    """An IMU event: time [ns], gyro [rad/s] (3,), specific force [m/s^2] (3,), sensor frame."""

    t_ns: int
    gyro: np.ndarray
    accel: np.ndarray


@dataclass(frozen=True)
class ImuSpec:
    """An IMU mounted on a body frame of the setup.

    Attributes
    ----------
    name : str
    body : str
        The frame it is mounted on (pose sensors measuring ``T_x_body`` get it).
    model : InertialModel
        Filter settings, including ``T_body_imu`` (``model.extrinsics``).
    recording : Path or None
        IMU file (``trackflow.io.read_imu``) to play.
    latency_ns : int
        Delay from IMU timestamp to availability [ns].
    clock_offset_ns : int
        Added to the IMU's time stamps to put them on the trackers' clock [ns].
    """

    name: str
    body: str
    model: InertialModel = field(default_factory=InertialModel)
    recording: Path | None = None
    latency_ns: int = 0
    clock_offset_ns: int = 0


class ImuPlayer(RecordingPlayer):
    """Plays an :class:`trackflow.io.ImuStream` into the network as :class:`ImuSample` events."""

    kind = "imu player"

    def __init__(self, name: str, stream, latency_ns: int = 0, clock_offset_ns: int = 0):
        t = stream.t_ns + int(clock_offset_ns)
        n = len(t)
        # the base class schedules by t_ns and latency; the pose arrays are placeholders
        super().__init__(
            name, t, np.zeros((n, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)), np.eye(6),
            latency_ns,
        )  # fmt: skip
        self.gyro = stream.gyro
        self.accel = stream.accel

    def deliver(self, index: int) -> None:
        self.stats.events_in += 1
        t = int(self.t_ns[index])
        if self._last_t is not None and t <= self._last_t:
            self.stats.reject("timestamp backwards")
            return
        self._last_t = t
        self.emit(ImuSample(t, self.gyro[index], self.accel[index]))


class _InertialAdapter:
    """``update_pose``/``predict`` in seconds around :class:`InertialFilter`."""

    def __init__(self, model: InertialModel):
        self.f = InertialFilter(model)

    def update_pose(self, t: float, pose) -> bool:
        return self.f.update_pose(t, pose)

    def predict(self, t: float):
        return self.f.predict(t)


class InertialKalmanFilter(KalmanFilter):
    """The filter behind a pose sensor whose body carries an IMU (see module docstring).

    Pose measurements arrive as :class:`Measurement` (port 0), IMU samples as
    :class:`ImuSample` (any port). IMU samples before the first pose, or older than the
    filter state, are counted rejections. Every accepted IMU sample after the first pose
    pushes the filtered pose at its time.
    """

    kind = "inertial kalman"

    def __init__(self, name, motion, imu: ImuSpec, **kwargs):
        self.imu = imu
        kwargs["filter_factory"] = lambda motion, history_s: _InertialAdapter(imu.model)
        super().__init__(name, motion, **kwargs)

    def same_filter(self, other) -> bool:
        return (
            isinstance(other, InertialKalmanFilter)
            and other.imu == self.imu
            and (self.motion == other.motion and self.stamp_offset_ns == other.stamp_offset_ns)
        )

    def push(self, m, port: int = 0) -> None:
        if not isinstance(m, ImuSample):
            super().push(m, port)
            return
        self.stats.events_in += 1
        f = self.filter.f
        t = m.t_ns * 1e-9
        try:
            f.update_imu(t, m.gyro, m.accel)
        except ValueError:
            self.stats.reject("IMU sample out of order or invalid")
            return
        if self.last_t is None:
            return  # no pose yet: the sample only primes the input hold
        self.last_t = max(self.last_t, m.t_ns)
        pose = f.predict(t)
        self.emit(Measurement(m.t_ns, pose, m.t_ns))

    def describe(self) -> str:
        return (
            f"inertial kalman {self.name} ({self.role}; IMU {self.imu.name} on "
            f"{self.imu.body}, {self.imu.model.mode})"
        )


def parse_imus(src: str, items, base_dir: Path | None, err) -> dict[str, ImuSpec]:
    """:class:`ImuSpec` per name from a setup's ``imus:`` list; ``err(item, msg)`` makes the
    error naming the file and line."""
    allowed = {
        "name", "body", "recording", "quaternion", "lever_arm", "mode", "noise", "gravity",
        "latency_ms", "clock_offset_ms", "gravity_sigma",
    }  # fmt: skip
    out: dict[str, ImuSpec] = {}
    for i, item in enumerate(items or []):
        what = f"imus[{i}]"
        if not isinstance(item, dict):
            raise err(item, f"{what} must be a mapping")
        unknown = set(item) - allowed
        if unknown:
            raise err(item, f"{what}: unknown keys {sorted(unknown)} (allowed: {sorted(allowed)})")
        for key in ("name", "body"):
            if key not in item:
                raise err(item, f"{what}: missing key {key!r}")
        try:
            noise = item.get("noise", {})
            if not isinstance(noise, dict):
                raise ConfigError("noise must be a mapping of gyro/accel/gyro_bias/accel_bias")
            kw = {}
            if "gravity" in item:
                kw["gravity"] = np.asarray(item["gravity"], dtype=float)
            if "gravity_sigma" in item:
                kw["gravity_sigma"] = float(item["gravity_sigma"])
            model = InertialModel(
                mode=str(item.get("mode", "strapdown")),
                noise=ImuNoise(**{k: float(v) for k, v in noise.items()}),
                extrinsics=ImuExtrinsics(
                    np.asarray(item.get("quaternion", [0, 0, 0, 1]), dtype=float),
                    np.asarray(item.get("lever_arm", [0, 0, 0]), dtype=float),
                ),
                **kw,
            )
        except (TypeError, ValueError) as exc:
            raise err(item, f"{what}: {exc}") from exc
        rec = item.get("recording")
        path = None
        if rec is not None:
            path = Path(str(rec))
            path = path if path.is_absolute() or base_dir is None else base_dir / path
        name = str(item["name"])
        if name in out:
            raise err(item, f"{what}: duplicate IMU name {name!r}")
        out[name] = ImuSpec(
            name, str(item["body"]), model, path,
            int(round(float(item.get("latency_ms", 0.0)) * 1e6)),
            int(round(float(item.get("clock_offset_ms", 0.0)) * 1e6)),
        )  # fmt: skip
    return out


def attach_imus(plan, graph, imus: dict[str, ImuSpec]):
    """Put each IMU into the plan's filters behind the pose sensors measuring its body.

    Every ``kalman`` node of a measured edge ``x -> body`` gets ``params["imu"]`` and a push
    input from an ``imu source`` node (one per IMU). Returns the plan (changed in place).
    """
    by_body = {}
    for spec in imus.values():
        if spec.body in by_body:
            raise ConfigError(
                f"two IMUs on body {spec.body!r}: {by_body[spec.body].name}, {spec.name}"
            )
        graph.check_frame(spec.body)
        by_body[spec.body] = spec
    added = {}
    for node in list(plan.nodes):
        if node.kind != "kalman" or "edge" not in node.params:
            continue
        edge = graph.edge(node.params["edge"])
        spec = by_body.get(edge.target)
        if spec is None:
            continue
        if spec.name not in added:
            src = PlanNode(
                f"src_imu_{spec.name}", "imu source", {"imu": spec.name},
                why=f"IMU {spec.name} on body {spec.body}",
            )  # fmt: skip
            plan.nodes.insert(plan.nodes.index(node), src)
            added[spec.name] = src.id
        node.params["imu"] = spec
        node.inputs.append((added[spec.name], "push"))
        node.why += f"; IMU {spec.name} drives it between poses (IMU-rate answers)"
    return plan
