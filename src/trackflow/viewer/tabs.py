"""Each browser tab its own view: a view made for every page that connects to a server.

viser shows what is added to a server to every open page, and a control moved in one tab
moves in all. :class:`PerTab` gives each page its own view instead (made by a factory on the
page's :class:`~trackflow.viewer.server.ClientView`): its own time, play state, error
display, scene and camera. ``trackflow view RECORDING`` serves a recording this way
(:class:`~trackflow.viewer.recording.RecordingView` per tab)::

    tabs = PerTab(ViewServer(port=0), lambda page: RecordingView(track, server=page))

A view made for a page is closed when the page goes.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Protocol

from .server import ClientView, ViewServer

__all__ = ["PerTab", "TabView"]


class TabView(Protocol):
    """What :class:`PerTab` needs of a view: to be closed when its page goes."""

    def close(self) -> None: ...


class PerTab:
    """A view per connected page of ``server`` (module docstring).

    Parameters
    ----------
    server : ViewServer
        Its own panel shows ``note`` above each page's own.
    make : callable
        ``make(page: ClientView) -> TabView``, called on viser's callback pool when a page
        connects; an exception is shown on that page's status line.
    note : str
        The server-wide line shown to every page.
    """

    def __init__(
        self,
        server: ViewServer,
        make: Callable[[ClientView], TabView],
        note: str = "each tab has its own view",
    ):
        self.server = server
        self._make = make
        self._lock = threading.Lock()
        self._views: dict[int, TabView] = {}
        self._closed = False
        server.set_status(note)
        server.server.on_client_connect(self._open)
        server.server.on_client_disconnect(self._gone)

    @property
    def url(self) -> str:
        return self.server.url

    @property
    def views(self) -> dict[int, TabView]:
        """``{client id: view}`` of the pages open now."""
        with self._lock:
            return dict(self._views)

    def _open(self, client) -> None:
        page = ClientView(self.server, client)
        try:
            view = self._make(page)
        except Exception as exc:  # shown on the page that asked; the others go on
            page.set_status(f"**this view failed:** {type(exc).__name__}: {exc}")
            raise
        with self._lock:
            if not self._closed:
                self._views[client.client_id] = view
                return
        view.close()

    def _gone(self, client) -> None:
        with self._lock:
            view = self._views.pop(client.client_id, None)
        if view is not None:
            view.close()

    def close(self) -> None:
        """Close every page's view and the server."""
        with self._lock:
            self._closed = True
            views, self._views = list(self._views.values()), {}
        for view in views:
            view.close()
        self.server.close()
