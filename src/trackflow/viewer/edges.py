"""What the view knows of a network: its layout and its edges' states.

:class:`ViewLayout` describes the scene (frames, edges, queries and their board slots) as
plain, picklable data for the view process; :class:`EdgeMonitor` turns the board, the network
clock and the counted rejections into the graph panel's edge states - one function for the
view process and for :meth:`trackflow.viewer.LiveView.edge_statuses`. Imports no dataflow:
the view process loads only what it draws with.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..math import UncertainPose
from .board import Board
from .graph_panel import EdgeStatus, classify

__all__ = ["EdgeLayout", "EdgeMonitor", "QueryLayout", "ViewLayout", "default_anchor"]

#: Frame names taken for the room (the default anchor of the view), in this order.
WORLD_NAMES = ("world", "room", "map", "w", "odom")


@dataclass
class EdgeLayout:
    """One SRG edge of the view: a static value or a board slot (its sensor's tap)."""

    name: str
    source: str
    target: str
    static: bool
    slot: int | None = None
    value: UncertainPose | None = None  # static edges
    rate_hz: float = math.inf
    offset_ms: float = math.nan  # the edge's known timestamp offset
    max_extrapolation_s: float = math.inf  # its filter answers no further past its data


@dataclass
class QueryLayout:
    """One query: its path (edge names) and the board slots of its answer and prediction;
    ``error`` names why it has no path."""

    name: str
    source: str
    target: str
    path_edges: tuple[str, ...] = ()
    now_slot: int | None = None
    ahead_slot: int | None = None
    error: str = ""
    rate_hz: float = math.inf  # answers per second (a pull query: the view's rate)
    paths: tuple[tuple[str, ...], ...] = ()  # the edges of each of its paths (fusion: several)

    def max_extrapolation_s(self, edges: dict[str, EdgeLayout]) -> float:
        """How far past its sensors' data an answer may be: the smallest limit of the
        filters on its paths (their ``max_extrapolation_ns``)."""
        limits = [edges[n].max_extrapolation_s for n in self.path_edges if n in edges]
        return min(limits, default=math.inf)


@dataclass
class ViewLayout:
    """Everything the view process needs to know of the network (picklable).

    ``root`` is the anchor frame the scene is drawn in (:func:`default_anchor` unless the
    user chose one)."""

    frames: list[str]
    root: str
    edges: list[EdgeLayout]
    queries: list[QueryLayout]
    n_slots: int


def default_anchor(frames: list[str], edges: list[EdgeLayout], near: str | None = None) -> str:
    """The frame a scene is drawn in by default: the room, not a moving body.

    The first of: a frame named like the room (:data:`WORLD_NAMES`, any case), a root of the
    SRG (a frame that is the source of an edge and the target of none), the first frame;
    among those, one connected to ``near`` (the first query's source) when there is one.
    """
    linked = {near} if near else set()
    grow = bool(linked)
    while grow:
        grow = False
        for e in edges:
            if (e.source in linked) != (e.target in linked):
                linked |= {e.source, e.target}
                grow = True
    reach = [f for f in frames if not linked or f in linked] or list(frames)
    lower = {f.lower(): f for f in reach}
    for name in WORLD_NAMES:
        if name in lower:
            return lower[name]
    targets = {e.target for e in edges}
    roots = [f for f in reach if f not in targets and any(e.source == f for e in edges)]
    return (roots or reach)[0]


@dataclass
class _EdgeMemory:
    gated_seen: int = 0
    gated_at: float = -math.inf
    rate_count: int = 0
    rate_wall: float = 0.0
    rate_est: float = math.nan


@dataclass
class EdgeMonitor:
    """Edge states for the graph panel from the board (rates are measured over >= 1 s of
    wall time between calls; "gated" holds for 1 s after a new filter rejection)."""

    layout: ViewLayout
    board: Board
    memory: dict[str, _EdgeMemory] = field(default_factory=dict)

    def statuses(
        self,
        now_ns: int,
        rejections: dict[str, dict[str, int]],
        offsets_ms: dict[str, float] | None = None,
        selected_query: str | None = None,
    ) -> list[EdgeStatus]:
        """Every edge's :class:`EdgeStatus`, then one "no path" entry per unplannable query.

        Parameters
        ----------
        now_ns : int
            The network clock.
        rejections : dict edge -> {reason: count}
            Counted rejections of the edge's source and filter (and its tracker, live).
        offsets_ms : dict edge -> float, optional
            A measured clock offset replacing the edge's configured stamp offset (live).
        """
        now_wall = time.perf_counter()
        lay, board = self.layout, self.board
        q = next((q for q in lay.queries if q.name == selected_query), None)
        on_path = set(q.path_edges) if q else set()
        used = {n for qq in lay.queries for n in qq.path_edges} if lay.queries else None
        out = []
        for e in lay.edges:
            if e.static:
                out.append(
                    EdgeStatus(e.name, e.source, e.target, "static", on_path=e.name in on_path)
                )
                continue
            mem = self.memory.setdefault(e.name, _EdgeMemory())
            rej = dict(rejections.get(e.name, {}))
            gated = rej.get("filter rejected update", 0)
            if gated > mem.gated_seen:
                mem.gated_seen, mem.gated_at = gated, now_wall
            elif gated < mem.gated_seen:  # a new run
                mem.gated_seen = gated
            age = lat = None
            if e.slot is not None:
                count = board.count(e.slot)
                age = (now_ns - board.arrival_ns(e.slot)) * 1e-9 if count else None
                if now_wall - mem.rate_wall >= 1.0 or count < mem.rate_count:
                    if mem.rate_wall > 0 and count >= mem.rate_count:
                        mem.rate_est = (count - mem.rate_count) / (now_wall - mem.rate_wall)
                    mem.rate_count, mem.rate_wall = count, now_wall
                _, lats, _ = board.read_ring(e.slot, 50)
                lat = float(np.median(lats)) * 1e-6 if len(lats) else None
            state = classify(
                static=False,
                used=used is None or e.name in used,
                age_s=age,
                rate_hz=e.rate_hz,
                gated_recently=now_wall - mem.gated_at < 1.0,
            )
            offset = (offsets_ms or {}).get(e.name, e.offset_ms)
            out.append(
                EdgeStatus(e.name, e.source, e.target, state, mem.rate_est,
                           math.nan if lat is None else lat, offset, rej, e.name in on_path)
            )  # fmt: skip
        for qq in lay.queries:
            if qq.error:
                out.append(EdgeStatus(qq.name, qq.source, qq.target, "no path"))
        return out
