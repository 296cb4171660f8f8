"""Dataflow runtime: components with push/pull ports, a scheduler, a planner and setups.

Timestamps are integer nanoseconds; poses are ``T_a_b`` with covariance over
``(dt, dtheta)`` (``t_true = t + dt``, ``R_true = R Exp(dtheta)``), see
``docs/conventions.md``. IMUs on body frames (setup key ``imus``) drive the filters behind
those bodies' pose sensors (``docs/inertial.md``).
"""

from ..filters import make_filter  # the default filter factory, re-exported for plans
from ..scheduler import (
    SAMPLE,
    TICK,
    Arrival,
    EventSource,
    Scheduler,
    Ticker,
    TimedSource,
    WallTime,
    calm_gc,
    collect_due,
    stop_signals,
)
from ._attributes import MeasuredAttributes
from ._bank import KalmanBank
from ._component import Component
from ._events import ComponentStats, Measurement
from ._failover import KEPT_EVENTS, PathSwitch, SwitchEvent
from ._inertial import ImuPlayer, ImuSample, ImuSpec, InertialKalmanFilter
from ._inputs import (
    NETWORK_PROTOCOLS,
    InputSpec,
    PoseFeed,
    feed_factory,
    parse_input,
    register_feed,
)
from ._lookup import LookupResult, lookup, rpy_deg
from ._network import Network
from ._online_spec import OnlineOffsetSpec
from ._planner import Plan, PlanNode, plan_query
from ._processing import Inference, Inversion, KalmanFilter, LatestValue, Sampler
from ._ros2spec import ROS2_INPUT_TYPES, ROS2_OUTPUT_TYPES, Ros2Link, Ros2Output
from ._setup import Setup, load_setup, parse_setup
from ._sinks import LONG_RUN_KEEP, CallbackSink, PullSink, Recorder, keep_newest
from ._sources import (
    BACKLOG_NS,
    NO_ORIGIN,
    PlayerSource,
    RecordingPlayer,
    SimulatedSensor,
    StaticPose,
)
from ._static_loops import StaticLoops
from ._warmup import warm_up

__all__ = [
    "BACKLOG_NS",
    "ROS2_INPUT_TYPES",
    "ROS2_OUTPUT_TYPES",
    "Ros2Link",
    "Ros2Output",
    "NO_ORIGIN",
    "SAMPLE",
    "TICK",
    "Arrival",
    "EventSource",
    "PlayerSource",
    "Scheduler",
    "Ticker",
    "TimedSource",
    "WallTime",
    "calm_gc",
    "collect_due",
    "stop_signals",
    "warm_up",
    "CallbackSink",
    "LONG_RUN_KEEP",
    "keep_newest",
    "Component",
    "ComponentStats",
    "ImuPlayer",
    "ImuSample",
    "ImuSpec",
    "Inference",
    "InertialKalmanFilter",
    "InputSpec",
    "NETWORK_PROTOCOLS",
    "PoseFeed",
    "feed_factory",
    "register_feed",
    "Inversion",
    "KalmanBank",
    "KalmanFilter",
    "LatestValue",
    "LookupResult",
    "MeasuredAttributes",
    "Measurement",
    "Network",
    "KEPT_EVENTS",
    "PathSwitch",
    "Plan",
    "PlanNode",
    "PullSink",
    "RecordingPlayer",
    "Recorder",
    "Sampler",
    "OnlineOffsetSpec",
    "Setup",
    "StaticLoops",
    "SimulatedSensor",
    "StaticPose",
    "SwitchEvent",
    "load_setup",
    "lookup",
    "rpy_deg",
    "make_filter",
    "parse_input",
    "parse_setup",
    "plan_query",
]
