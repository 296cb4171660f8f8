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

from .._lazy import lazy_names

# Imported on first use (PEP 562): a realm's watcher or status command needs the wire and the
# key space, not the agent's whole runtime (the planner, the filters, the live inputs), and
# starts seconds sooner without it.
_WHERE = {
    **dict.fromkeys(("Agent", "QueryState", "RemoteSource", "remote_get", "run_agent"), "agent"),
    **dict.fromkeys(("time_error_covariance", "twist_between"), "clock"),
    **dict.fromkeys(("AgentConfig", "load_agent", "zenoh_config"), "config"),
    **dict.fromkeys(
        ("edge_from_dict", "edge_to_dict", "fragment_json", "fragment_stale", "parse_fragment"),
        "fragment",
    ),
    **dict.fromkeys(("RemoteFilter", "RemoteGet", "StatePublisher"), "replica"),
    **dict.fromkeys(
        (
            "Rejections",
            "StateSample",
            "WireError",
            "WireSample",
            "decode",
            "decode_state",
            "encode",
            "encode_state",
        ),
        "wire",
    ),
}


__getattr__, __dir__ = lazy_names(__name__, _WHERE)

__all__ = sorted(_WHERE)
