"""Events travelling through a dataflow network and per-component statistics."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ..math import UncertainPose

__all__ = ["ComponentStats", "Measurement"]


class Measurement(NamedTuple):
    """A pose event (an immutable named tuple: cheap to make once per event).

    Parameters
    ----------
    t_ns : int
        Time at which the pose is valid [integer ns, the network's clock].
    pose : UncertainPose
        ``T_a_b`` of the edge the event belongs to, covariance over ``(dt, dtheta)`` with
        ``t_true = t + dt``, ``R_true = R Exp(dtheta)``.
    origin_ns : int
        Sensor timestamp of the newest raw measurement that contributed; delivery latency is
        measured from it.
    path : int
        Which of the query's candidate paths produced an answer: 0 the preferred one, ``k``
        its ``k``-th fallback (:class:`trackflow.dataflow.PathSwitch`); 0 everywhere else.
    broken : str
        The query requirement an answer does not meet, with its figure ("" if it meets them
        all or the query requires nothing; :class:`trackflow.graph.Requirements`).
    """

    t_ns: int
    pose: UncertainPose
    origin_ns: int
    path: int = 0
    broken: str = ""


@dataclass
class ComponentStats:
    """Counters of one component.

    ``events_in`` / ``events_out`` count pushed events and answered pulls; ``rejections``
    counts dropped inputs or unanswerable requests by reason; ``latencies_ns`` holds, for
    sinks, the delivery clock minus the origin sensor timestamp of every delivered event.
    """

    events_in: int = 0
    events_out: int = 0
    rejections: dict[str, int] = field(default_factory=dict)
    latencies_ns: list[int] = field(default_factory=list)

    def reject(self, reason: str) -> None:
        self.rejections[reason] = self.rejections.get(reason, 0) + 1

    @property
    def rejected(self) -> int:
        return sum(self.rejections.values())

    def summary(self) -> dict:
        """Plain dict: counts, rejections by reason and latency percentiles in ms."""
        out = {
            "events_in": self.events_in,
            "events_out": self.events_out,
            "rejections": dict(sorted(self.rejections.items())),
        }
        if self.latencies_ns:
            lat = np.asarray(self.latencies_ns, dtype=float) * 1e-6
            out["latency_ms"] = {
                "p50": float(np.percentile(lat, 50)),
                "p99": float(np.percentile(lat, 99)),
                "max": float(lat.max()),
            }
        return out
