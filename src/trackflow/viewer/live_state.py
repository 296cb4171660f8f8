"""What every tab of the live view shares: the network's state read from the board once per
view frame, and the history of the bodies' paths.

The view process draws one :class:`~trackflow.viewer.live_scene.LiveScene` per browser tab
(:mod:`trackflow.viewer.live_loop`), each with its own controls. What does not depend on a
tab's controls is worked out here, once per draw tick, for all of them:

* the poses on the board, with a query's answer held (grey) once it stands on no live data,
  every body's colour and how long it has been without data;
* what the dataflow process sends over the pipe (rejections, clock offsets, measured
  attributes) and the prediction offset, which the dataflow process owns: one for all tabs;
* every body placed in an anchor frame, with its trail and its whole path. The history is kept
  per anchor frame, in that frame (each point where the body was in the anchor at its time),
  for the default anchor always (also while no page is open: a tab opened later shows the
  whole path so far) and for every anchor an open tab draws in. An anchor no tab draws in
  any more is forgotten; a tab that changes to an anchor without history starts it afresh;
* the scene's extent in each anchor once its frames are placed (the grid is laid under it)
  and, with ``auto_scale``, the glyph size it implies (one for all tabs);
* the recent error sizes of every sensor (the time plots).
"""

from __future__ import annotations

import dataclasses
import math
import threading
from collections import deque

import numpy as np

from .batch import BodyFrame
from .board import Board, BoardPose
from .edges import EdgeLayout, EdgeMonitor, QueryLayout, ViewLayout
from .graph_panel import classify
from .legend import sigma_sizes
from .placement import place_frames, to_world
from .scene import GREY, PALETTE

__all__ = ["PATH_POINTS", "Anchored", "LiveState", "scene_box"]

#: Points kept of a body's whole path (halved, every other one, when full).
PATH_POINTS = 4000
#: Seconds after the first two frames were placed that a scene is framed with what is placed.
SETTLE_S = 2.0
#: Error sizes kept per sensor for the time plots (one every ``PLOT_PERIOD_S``).
SIGMA_POINTS = 300
PLOT_PERIOD_S = 0.5


def scene_box(places: dict[str, tuple], bodies: list) -> tuple[np.ndarray, np.ndarray]:
    """The bounding box ``(lo, hi)`` (3,) of the placed frames and the drawn bodies."""
    pts = np.array([p for _, p in places.values()] + [b.position for b in bodies if b])
    return pts.min(axis=0), pts.max(axis=0)


@dataclasses.dataclass
class Anchored:
    """The bodies of one draw tick placed in one anchor frame.

    Attributes
    ----------
    places : dict frame -> (quaternion (4,), position (3,))
        ``T_anchor_frame`` of every frame reachable from the anchor.
    bodies : list of BodyFrame or None
        Every body of :attr:`LiveState.bodies` in the anchor frame (None: not drawn).
    trails : list of ndarray (N, 3) or None
        Each body's recent points (its fading trail).
    settled : bool
        Whether the scene in this anchor can be framed (its frames are placed).
    """

    places: dict
    bodies: list
    trails: list
    settled: bool


class _History:
    """One anchor's trails and paths, and when its frames were first placed."""

    def __init__(self):
        self.trails: dict[str, list] = {}
        self.paths: dict[str, list] = {}
        self.first_placed: float | None = None
        self.settled = False


class LiveState:
    """The shared state of the live view's tabs (module docstring), updated by :meth:`tick`.

    Parameters
    ----------
    layout : ViewLayout
    board : Board
    rate_hz : float
        The view rate (the trail keeps ``trail_s`` of it).
    axes_length : float
        The glyph size [m] until the scene is framed.
    auto_scale : bool
        Size the glyphs to the scene once it is framed (axes a tenth of its extent).
    trail_s : float
        Length of the fading trail [s].

    Attributes
    ----------
    bodies : list of EdgeLayout or QueryLayout
        What is drawn: every sensor with a board slot, then every query with answers.
    colours : list of (r, g, b)
        Each body's own colour.
    offset_s : float
        The prediction offset (set by the dataflow process's samplers).
    rejections, offsets_ms, attributes
        The dataflow process's latest ``stats`` and ``attributes`` messages.
    """

    def __init__(
        self, layout: ViewLayout, board: Board, rate_hz: float, axes_length: float = 0.08,
        auto_scale: bool = True, trail_s: float = 2.0,
    ):  # fmt: skip
        self.layout, self.board, self.rate_hz = layout, board, float(rate_hz)
        self.axes_length, self.auto_scale, self.trail_s = axes_length, auto_scale, trail_s
        self.monitor = EdgeMonitor(layout, board)
        self.bodies: list[EdgeLayout | QueryLayout] = [
            e for e in layout.edges if not e.static and e.slot is not None
        ]
        self.bodies += [q for q in layout.queries if q.now_slot is not None]
        self.colours = [PALETTE[k % len(PALETTE)] for k in range(len(self.bodies))]
        self.offset_s = 0.0
        self.rejections: dict[str, dict[str, int]] = {}
        self.offsets_ms: dict[str, float] = {}
        #: measured attributes and queries' paths from the main process (attributes_panel)
        self.attributes: dict | None = None
        self.now_ns = 0
        self.now_wall = 0.0
        self.poses: dict[str, BoardPose | None] = {}
        self._lock = threading.RLock()
        self._edges = {e.name: e for e in layout.edges}
        self._statics = [
            (e.source, e.target, e.value.quaternion, e.value.position)
            for e in layout.edges
            if e.static and e.value is not None
        ]
        self._held: dict[str, BoardPose] = {}  # a query's newest usual answer (held if stale)
        self._aheads: dict[str, deque] = {}  # how far its recent answers were extrapolated
        self._over: dict[str, float] = {}  # a query held (no live path): for how long [s]
        self._ages: list[float | None] = [None] * len(self.bodies)
        self._grey_after: dict[str, float] = {}
        self._histories: dict[str, _History] = {}
        self._anchored: dict[str, Anchored] = {}  # this tick's, by anchor
        self._sigmas: dict[str, deque] = {}
        self._sigma_wall = -math.inf

    # -- the tick --------------------------------------------------------------------------------
    def tick(self, anchors, now_wall: float) -> None:
        """Read the board (poses, held answers, colours, error sizes) and place the bodies in
        every frame of ``anchors`` (extending their histories); the histories of other
        anchors are forgotten."""
        with self._lock:
            self.now_wall = now_wall
            self.now_ns, _ = self.board.clock()
            poses = {b.name: self._read(b) for b in self.bodies}
            self._hold_extrapolated(poses, self.now_ns)
            self.poses = poses
            self._note_ages(self.now_ns, poses)
            if now_wall - self._sigma_wall >= PLOT_PERIOD_S:
                self._sigma_wall = now_wall
                self._note_sigmas(poses)
            self._anchored = {}
            keep = set(anchors)
            for gone in set(self._histories) - keep:
                del self._histories[gone]
            for anchor in keep:
                self.anchored(anchor)

    def anchored(self, anchor: str) -> Anchored:
        """This tick's bodies in ``anchor`` (placed now if no tick placed them: an anchor's
        history starts with its first use)."""
        with self._lock:
            got = self._anchored.get(anchor)
            if got is None:
                hist = self._histories.setdefault(anchor, _History())
                places = self.place_frames(anchor, self.poses)
                bodies, trails = self._collect(places, self.poses, hist)
                self._settle(hist, places, bodies)
                got = Anchored(places, bodies, trails, hist.settled)
                self._anchored[anchor] = got
            return got

    def path(self, anchor: str, name: str) -> np.ndarray | None:
        """Body ``name``'s whole path so far in ``anchor`` (N, 3), None if under two points."""
        with self._lock:
            hist = self._histories.get(anchor)
            path = None if hist is None else hist.paths.get(name)
            return np.array(path) if path and len(path) > 1 else None

    def sigma_ring(self, edge: str) -> np.ndarray | None:
        """Sensor ``edge``'s recent ``(t [s], position [mm], orientation [deg])`` 1-sigma
        sizes (N, 3), None if under two."""
        with self._lock:
            ring = self._sigmas.get(edge)
            return np.array(ring) if ring is not None and len(ring) >= 2 else None

    # -- what every tab shows alike --------------------------------------------------------------
    def age(self, k: int) -> float | None:
        """How long body ``k`` has been without data while drawn grey (None: not grey)."""
        return self._ages[k] if k < len(self._ages) else None

    def colour(self, k: int) -> tuple:
        """Body ``k``'s colour now: grey while its data stopped."""
        return GREY if self.age(k) is not None else self.colours[k]

    def grey_after(self, name: str) -> float | None:
        """How long body ``name`` was without data when it was first drawn grey."""
        return self._grey_after.get(name)

    def body_reports(self) -> list[dict]:
        """Every body's name, kind, colour and times without data, as plain data."""
        with self._lock:
            return [
                {
                    "name": b.name,
                    "kind": "sensor" if isinstance(b, EdgeLayout) else "query",
                    "grey": self.age(k) is not None,
                    "no_data_s": self.age(k),
                    "grey_after_s": self._grey_after.get(b.name),
                    "extrapolated_s": self._over.get(b.name),
                    "colour": list(self.colour(k)),
                }  # fmt: skip
                for k, b in enumerate(self.bodies)
            ]

    # -- reading the board -----------------------------------------------------------------------
    def _read(self, b: EdgeLayout | QueryLayout) -> BoardPose | None:
        return self.board.read_pose(b.slot if isinstance(b, EdgeLayout) else b.now_slot)

    def read_poses(self) -> dict[str, BoardPose | None]:
        """Every body's newest pose on the board, by name (none held back)."""
        return {b.name: self._read(b) for b in self.bodies}

    def _hold_extrapolated(self, poses: dict[str, BoardPose | None], now_ns: int) -> None:
        """A query's answer is drawn only while it stands on data: while one of its paths has
        no stale sensor (the panel's "stale": no event for three periods and 250 ms), and
        within its filters' extrapolation limit (``max_extrapolation``) past that path's data.
        Otherwise the last answer drawn stays, grey - not one extrapolated on, with its
        ellipsoid ballooning, until the filters refuse."""
        for b in self.bodies:
            pose = poses.get(b.name)
            if not isinstance(b, QueryLayout) or pose is None:
                continue
            ahead = self._extrapolation(b, pose)
            without = self._path_stale_s(b, now_ns)
            if without is not None or ahead > b.max_extrapolation_s(self._edges) + 1e-9:
                self._over[b.name] = max(without or 0.0, ahead)
                poses[b.name] = self._held.get(b.name)
            else:
                self._over.pop(b.name, None)
                # the answer to hold when the data stop: the newest one extrapolated as far
                # as answers usually are (not one of the last, already ballooning, ones)
                hist = self._aheads.setdefault(b.name, deque(maxlen=64))
                hist.append(ahead)
                if ahead <= float(np.median(hist)) + self._slack(b):
                    self._held[b.name] = pose

    def _slack(self, q: QueryLayout) -> float:
        """Two periods of the slowest sensor on ``q``'s paths, and 5 ms [s]."""
        rates = [self._edges[n].rate_hz for n in q.path_edges if n in self._edges]
        periods = [1.0 / r for r in rates if 0 < r < math.inf]
        return 2.0 * max(periods, default=0.0) + 0.005

    def _path_stale_s(self, q: QueryLayout, now_ns: int) -> float | None:
        """None while some path of ``q`` has no stale sensor; else how long its best path
        has been without data [s] (network time since its stalest sensor's last event)."""
        best = None
        for path in q.paths or (q.path_edges,):
            worst = 0.0
            for name in path:
                e = self._edges.get(name)
                if e is None or e.static or e.slot is None:
                    continue
                n = self.board.count(e.slot)
                age = (now_ns - self.board.arrival_ns(e.slot)) * 1e-9 if n else math.inf
                state = classify(static=False, used=True, age_s=None if not n else age,
                                 rate_hz=e.rate_hz, gated_recently=False)  # fmt: skip
                if state == "stale":
                    worst = max(worst, age)
            if worst == 0.0:
                return None
            best = worst if best is None else min(best, worst)
        return best

    def _extrapolation(self, q: QueryLayout, pose: BoardPose) -> float:
        """How far ``pose`` [s] lies past the data of the query's best path (a path's data
        is as new as its stalest sensor's newest event)."""
        newest = None
        for path in q.paths or (q.path_edges,):
            times = []
            for name in path:
                e = self._edges.get(name)
                if e is not None and not e.static and e.slot is not None:
                    times.append(self.board.last_event_ns(e.slot))
            if not times:
                return 0.0  # a path of static values: no extrapolation
            if None in times:
                continue
            t = min(times)
            newest = t if newest is None else max(newest, t)
        return math.inf if newest is None else (pose.t_ns - newest) * 1e-9

    def _note_ages(self, now_ns: int, poses: dict[str, BoardPose | None]) -> None:
        """Each body grey once its data stopped (no event for three periods and at least
        250 ms of network time, the edges' "stale"): how long it has been, and how long it
        was when first drawn grey."""
        ages = []
        for b in self.bodies:
            slot = b.slot if isinstance(b, EdgeLayout) else b.now_slot
            count = self.board.count(slot)
            age = (now_ns - self.board.arrival_ns(slot)) * 1e-9 if count else None
            stale = poses.get(b.name) is not None and (
                classify(static=False, used=True, age_s=age, rate_hz=b.rate_hz,
                         gated_recently=False) == "stale"
            )  # fmt: skip
            if b.name in self._over:  # answers, but past the data: held, grey
                stale, age = True, max(age or 0.0, self._over[b.name])
            if stale:
                self._grey_after.setdefault(b.name, age)
            else:
                self._grey_after.pop(b.name, None)
            ages.append(age if stale else None)
        self._ages = ages

    def _note_sigmas(self, poses: dict[str, BoardPose | None]) -> None:
        """Every sensor's 1-sigma error sizes, when its pose is a new one."""
        for b in self.bodies:
            pose = poses.get(b.name)
            if not isinstance(b, EdgeLayout) or pose is None:
                continue
            ring = self._sigmas.setdefault(b.name, deque(maxlen=SIGMA_POINTS))
            t = pose.t_ns * 1e-9
            if not ring or ring[-1][0] != t:
                ring.append((t, *sigma_sizes(pose.covariance, 1.0)))

    # -- placing ---------------------------------------------------------------------------------
    def place_frames(self, anchor: str, poses: dict[str, BoardPose | None]) -> dict[str, tuple]:
        """Placement ``T_anchor_frame`` as ``(quaternion (4,), position (3,))`` of every
        frame reachable from ``anchor`` through static values and the sensors' ``poses``."""
        values = list(self._statics)
        for e in self.layout.edges:
            p = None if e.static else poses.get(e.name)
            if p is not None:
                values.append((e.source, e.target, p.quaternion, p.position))
        return place_frames(anchor, values)

    def bodies_in(self, places: dict[str, tuple], poses: dict[str, BoardPose | None]):
        """Every body's pose (and its query's prediction while an offset is set) in the
        frame ``places`` are given in: a list of :class:`BodyFrame` or None."""
        todo = []  # (body index, frame placement, pose, prediction or None)
        for k, b in enumerate(self.bodies):
            pose = poses.get(b.name)
            if pose is not None and b.source in places:
                todo.append((k, places[b.source], pose, self._ahead(b, pose)))
        bodies: list[BodyFrame | None] = [None] * len(self.bodies)
        if not todo:
            return bodies
        fq = np.array([t[1][0] for t in todo])
        fp = np.array([t[1][1] for t in todo])
        world = to_world(fq, fp, [t[2] for t in todo])
        has = [i for i, t in enumerate(todo) if t[3] is not None]
        pred = to_world(fq[has], fp[has], [todo[i][3] for i in has]) if has else None
        row = {i: j for j, i in enumerate(has)}
        for i, (k, *_rest) in enumerate(todo):
            ghost = None
            if pred is not None and i in row:
                j = row[i]
                ghost = (pred[0][j], pred[1][j], pred[2][j])
            bodies[k] = BodyFrame(world[0][i], world[1][i], world[2][i], predicted=ghost)
        return bodies

    def _ahead(self, b, pose: BoardPose) -> BoardPose | None:
        """A query's prediction made with ``pose`` (an unanswered pull leaves the previous
        one on the board), while an offset is set and the answer is not held."""
        if not isinstance(b, QueryLayout) or b.ahead_slot is None or self.offset_s <= 0:
            return None
        if b.name in self._over:
            return None
        ahead = self.board.read_pose(b.ahead_slot)
        due = pose.t_ns + round(self.offset_s * 1e9)
        if ahead is None or abs(ahead.t_ns - due) > 1_000_000:
            return None
        return ahead

    def _collect(self, places: dict[str, tuple], poses, hist: _History):
        """The bodies in the anchor of ``places``, each drawn one extending its trail and
        (at 1 % of an axis moved) its whole path in ``hist``."""
        bodies = self.bodies_in(places, poses)
        keep = max(2, int(self.trail_s * self.rate_hz))
        step = 0.01 * self.axes_length
        trails: list[np.ndarray | None] = [None] * len(self.bodies)
        for k, body in enumerate(bodies):
            if body is None:
                continue
            name, p = self.bodies[k].name, body.position
            trail = hist.trails.setdefault(name, [])
            trail.append(p)
            del trail[:-keep]
            trails[k] = np.array(trail)
            path = hist.paths.setdefault(name, [])
            if not path or np.linalg.norm(p - path[-1]) > step:
                path.append(p)
                if len(path) > PATH_POINTS:
                    del path[1::2]
        return bodies, trails

    def _settle(self, hist: _History, places: dict[str, tuple], bodies: list) -> None:
        """An anchor's scene can be framed once every frame is placed (or ``SETTLE_S`` after
        the first two were, with what is placed); the first framed sizes the glyphs."""
        if hist.settled:
            return
        if len(places) < len(self.layout.frames):
            if len(places) < 2:
                return
            if hist.first_placed is None:
                hist.first_placed = self.now_wall
            if self.now_wall - hist.first_placed < SETTLE_S:
                return
        hist.settled = True
        if self.auto_scale:
            lo, hi = scene_box(places, bodies)
            extent = max(float(np.max(hi - lo)), 0.3)
            self.axes_length = float(np.clip(0.1 * extent, 0.02, 0.5))
            self.auto_scale = False
