"""The live view's tabs and its draw loop (run in the view process).

One :class:`~trackflow.viewer.server.ViewServer` serves the page; every browser tab that
connects gets its own :class:`~trackflow.viewer.live_scene.LiveScene` on its
:class:`~trackflow.viewer.server.ClientView` (:class:`~trackflow.viewer.tabs.PerTab`), with
its own controls: a control moved in one tab changes that tab only. What the tabs share is
:class:`~trackflow.viewer.live_state.LiveState`, updated once per draw tick: the poses read
from the board, the bodies' paths (kept while no tab is open), and what the dataflow process
owns - the prediction offset (a slider moved in one tab moves it for every tab) and the
rejections, clock offsets and attributes it sends.

The Python API (:class:`~trackflow.viewer.live.LiveView`) speaks to every tab at once: a
setting applies to every open tab and becomes the default of tabs opened later; a report is
the oldest open tab's (or, with none open, what a new tab would start from).
"""

from __future__ import annotations

import sys
import threading
import time
import traceback
from collections.abc import Callable

from .board import Board
from .decor import grid_spec
from .edges import ViewLayout
from .live_scene import SETTINGS, LiveScene, default_settings
from .live_state import LiveState, scene_box
from .scene import Style
from .server import ClientView, ViewServer
from .tabs import PerTab

__all__ = ["IDLE_RATE_HZ", "LiveTabs"]

#: Frames per second drawn while no browser is connected (keeps trails and plots current).
IDLE_RATE_HZ = 2.0
#: The line every tab shows above its own.
NOTE = "each tab has its own live view; the prediction offset is shared by all"


class LiveTabs:
    """The live view of the view process: a server, a scene per tab, the shared state and
    the loop that draws them (module docstring).

    Parameters
    ----------
    layout : ViewLayout
    board : Board
    host, port : str, int
        Where the page is served (``port=0``: a free port).
    rate_hz : float
        Draw ticks per second while a page is open (``IDLE_RATE_HZ`` while none is).
    style : Style, optional
        How poses are drawn; default: glyphs sized to the scene once it is framed.
    send : callable, optional
        ``send(message)`` to the dataflow process (``("offset", seconds)``).
    anchor : str, optional
        The frame tabs draw in first (default the layout's root).

    Attributes
    ----------
    frames_sent : int
        Draw ticks done (also written to the board's header, with the pages connected).
    draw_errors : int
        Exceptions raised while drawing (each kind is written to stderr, with its traceback,
        the first time, and shown on the status line of the tab it happened in); the other
        tabs, and the next tick, draw on.
    """

    def __init__(
        self, layout: ViewLayout, board: Board, host: str = "127.0.0.1", port: int = 8080,
        rate_hz: float = 30.0, style: Style | None = None,
        send: Callable[[tuple], None] | None = None, anchor: str | None = None,
    ):  # fmt: skip
        self.board, self.rate_hz = board, float(rate_hz)
        self._style = style or Style(axes_length=0.08, magnify=1.0)
        self.state = LiveState(
            layout, board, rate_hz, self._style.axes_length, auto_scale=style is None,
            trail_s=self._style.trail_s,
        )  # fmt: skip
        self._send = send or (lambda msg: None)
        self._lock = threading.Lock()
        self._defaults = default_settings(layout, self._style, anchor)
        self.frames_sent = self.draw_errors = 0
        self._errors_told: set[tuple[str, str]] = set()
        self.server = ViewServer(host, port, title="trackflow live")
        self.server.look_at((0.3, 0.0, 0.2), 1.2)
        self.tabs = PerTab(self.server, self._open, note=NOTE)

    @property
    def url(self) -> str:
        return self.server.url

    def _open(self, page: ClientView) -> LiveScene:
        with self._lock:
            settings = dict(self._defaults)
        return LiveScene(page, self.state, self._style, settings, self.share_offset)

    def scenes(self) -> list[LiveScene]:
        """The open tabs' scenes, the oldest first."""
        return list(self.tabs.views.values())

    def clients(self) -> int:
        """Pages connected to the server."""
        return len(self.server.server.get_clients())

    # -- the Python API and the shared offset ----------------------------------------------------
    def apply(self, **kw) -> None:
        """Set settings (:data:`~trackflow.viewer.live_scene.SETTINGS`, ``offset_s``) in
        every open tab and as the default of tabs opened later; ``offset_s`` is the shared
        prediction offset (the dataflow process has moved its samplers already)."""
        unknown = set(kw) - set(SETTINGS) - {"offset_s"}
        if unknown:
            raise KeyError(f"no live view setting {sorted(unknown)}; one of {SETTINGS}")
        if "offset_s" in kw:
            self.state.offset_s = float(kw["offset_s"])
        with self._lock:
            if kw.get("anchor", self.state.layout.root) in self.state.layout.frames:
                self._defaults.update((k, v) for k, v in kw.items() if k != "offset_s")
        for scene in self.scenes():
            scene.apply(**kw)

    def share_offset(self, offset_s: float) -> None:
        """A tab's prediction slider moved: the offset for every tab, the dataflow process's
        samplers moved, every tab's slider shows it."""
        self.state.offset_s = float(offset_s)
        self._send(("offset", float(offset_s)))
        for scene in self.scenes():
            scene.apply(offset_s=offset_s)

    def report(self) -> dict:
        """The oldest open tab's :meth:`LiveScene.report`; with none open, what a new tab
        starts from (its anchor, the bodies, the grid of the anchor's scene; no labels)."""
        for scene in self.scenes():
            return {"draw_errors": self.draw_errors, **scene.report()}
        with self._lock:
            anchor = self._defaults["anchor"]
        seen = self.state.anchored(anchor)
        grid = grid_spec(*scene_box(seen.places, seen.bodies)).text if seen.settled else None
        return {
            "draw_errors": self.draw_errors,
            "anchor": anchor,
            "browser_camera": False,
            "bodies": self.state.body_reports(),
            "grid": grid,
            "labels": [],
            "camera": None,
        }

    # -- drawing ---------------------------------------------------------------------------------
    def tick(self) -> None:
        """One draw tick: the shared state once (in the default anchor and every tab's),
        then every open tab's scene."""
        scenes = self.scenes()
        with self._lock:
            anchors = {self._defaults["anchor"]} | {s.anchor for s in scenes}
        try:
            self.state.tick(anchors, time.perf_counter())
        except Exception as exc:  # reported; the next tick reads the board afresh
            self._drawing_failed(exc, None)
            return
        for scene in scenes:
            try:
                scene.render_frame()
            except Exception as exc:  # reported; the other tabs draw on
                self._drawing_failed(exc, scene)
        self.frames_sent += 1
        self.board.frames_sent = self.frames_sent

    def _drawing_failed(self, exc: Exception, scene: LiveScene | None) -> None:
        """Count a drawing error, tell stderr the first of each kind (with its traceback)
        and show it on the tab it happened in: a view that stops drawing says so and why."""
        self.draw_errors += 1
        where = "reading the board" if scene is None else "drawing a tab"
        key = (where, f"{type(exc).__name__}: {exc}")
        if key not in self._errors_told:
            self._errors_told.add(key)
            text = "".join(traceback.format_exception(exc))
            print(f"trackflow view: {where} failed ({key[1]}):\n{text}", file=sys.stderr,
                  flush=True)  # fmt: skip
        if scene is not None:
            scene.show_error(key[1])

    def loop(self, stop: threading.Event) -> None:
        """Tick at ``rate_hz`` (``IDLE_RATE_HZ`` while no page is connected) until ``stop``."""
        nxt = time.perf_counter()
        while not stop.is_set():
            delay = nxt - time.perf_counter()
            if delay > 0 and stop.wait(delay):
                break
            start = time.perf_counter()
            self.tick()
            clients = self.clients()
            self.board.clients = clients
            period = 1.0 / (self.rate_hz if clients else min(self.rate_hz, IDLE_RATE_HZ))
            nxt += period
            if nxt < start - 0.25:  # far behind (a busy machine): start afresh, no burst
                nxt = start + period

    def close(self) -> None:
        """Close every tab's scene and the server."""
        self.tabs.close()
