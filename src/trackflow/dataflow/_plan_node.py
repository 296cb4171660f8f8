"""One component of a query's plan, before it is built: what the planner
(:mod:`._planner`) lays out and what adds to a plan (:func:`._inertial.attach_imus`) inserts."""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["PlanNode"]


@dataclass
class PlanNode:
    """One component of a plan: ``kind`` in {source, kalman, latest, static, inversion,
    inference, switch, sampler, recorder, pull sink}; ``inputs`` are ``(node_id,
    "push"|"pull")``."""

    id: str
    kind: str
    params: dict = field(default_factory=dict)
    inputs: list[tuple[str, str]] = field(default_factory=list)
    why: str = ""

    def label(self) -> str:
        p = self.params
        if self.kind == "kalman":
            m = p["motion"]
            model = "static" if m.static else f"n_dp={m.n_dp}, n_do={m.n_do}"
            return f"kalman ({p['role']}; {model})"
        if self.kind == "sampler":
            return f"sampler ({p['rate_hz']:g} Hz, offset {p['offset_ns'] * 1e-6:+g} ms)"
        if self.kind == "source":
            return f"source ({p['edge']})"
        if self.kind == "switch":
            return f"switch ({len(p['sensors'])} paths, hold {p['hold_ns'] * 1e-9:g} s)"
        return self.kind
