"""Distributed ubiquitous tracking on Eclipse Zenoh (thesis chapter 2, DWARF-style agents).

Agents advertise their fragment of the spatial relationship graph (liveliness token per edge,
fragment queryable), run each sensor's filter next to the sensor and publish its states in a
versioned binary encoding
(:mod:`trackflow.distributed.wire`, ``docs/wire.md``), assemble the union graph, plan their
queries with the single-process planner and re-plan when sensors come and go. Remote stamps
are mapped with a measured clock offset whose uncertainty enters the covariance
(:mod:`trackflow.distributed.clock`). See ``docs/distributed.md``.

Needs the ``eclipse-zenoh`` package (``pip install trackflow[distributed]``); importing
this package works without it, opening an agent does not.
"""

from .agent import Agent, QueryState, RemoteSource, remote_get, run_agent
from .clock import time_error_covariance, twist_between
from .config import AgentConfig, load_agent, zenoh_config
from .fragment import (
    edge_from_dict,
    edge_to_dict,
    fragment_json,
    fragment_stale,
    parse_fragment,
)
from .replica import RemoteFilter, RemoteGet, StatePublisher
from .wire import (
    Rejections,
    StateSample,
    WireError,
    WireSample,
    decode,
    decode_state,
    encode,
    encode_state,
)

__all__ = [
    "Agent",
    "AgentConfig",
    "QueryState",
    "Rejections",
    "RemoteFilter",
    "RemoteGet",
    "RemoteSource",
    "StatePublisher",
    "StateSample",
    "WireError",
    "WireSample",
    "decode",
    "decode_state",
    "edge_from_dict",
    "edge_to_dict",
    "encode",
    "encode_state",
    "fragment_json",
    "fragment_stale",
    "load_agent",
    "parse_fragment",
    "remote_get",
    "run_agent",
    "time_error_covariance",
    "twist_between",
    "zenoh_config",
]
