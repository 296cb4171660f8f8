"""The viser server every view runs on (loopback by default, Z up, one status line), and one
page's own view on it.

A view draws on a :class:`ViewServer` (every open page shows the same: one panel, one
scene) or on a :class:`ClientView` (one page's own panel, scene and camera: each browser tab
its own state). Both keep the pages' cameras the same way (:class:`Pages`): a home camera
(what a page is moved to when the view frames its content) and the camera each page last
reported.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io

import numpy as np

from ..errors import InputError
from ..optional import require
from .camera import DEFAULT_FOV, FRAMING_FOV, Camera, frame_points

__all__ = ["SECONDS_AXIS", "ClientView", "Pages", "ViewServer", "linked_cursor", "span_axis"]

#: uPlot ``scales`` for plots over seconds of a run (uPlot reads x as Unix time by default).
SECONDS_AXIS = {"x": {"time": False}}


def span_axis(t0_s: float, t1_s: float) -> dict:
    """:data:`SECONDS_AXIS` spanning ``[t0_s, t1_s]`` whatever the data: the plots of one
    view then share one time span (a current-time line and a click map alike in each)."""
    return {"x": {**SECONDS_AXIS["x"], "range": [float(t0_s), max(float(t1_s), t0_s + 1e-3)]}}


def linked_cursor(key: str) -> dict:
    """uPlot ``cursor`` options that link the plots given the same ``key``: hovering one
    shows the cursor, at the same time, in all of them."""
    return {"sync": {"key": key, "scales": ("x", None)}}


def _refuse_share(*_args, **_kwargs) -> None:
    """Stands in for ``ViserServer.request_share_url``: sharing is never started."""
    return None


class Pages:
    """The cameras of a view's pages: its home camera (``_home``: ``position``, ``look_at``,
    ``up``, ``fov``; viser's initial camera for a whole server) and the camera each page
    last reported. Subclasses give ``_home`` and :meth:`_pages`, and call
    :meth:`watch_page` for every page they show."""

    _home: object

    def _init_pages(self) -> None:
        self._cameras: dict[int, Camera] = {}  # client id -> the camera it last reported
        self._camera_hooks: list = []

    def _pages(self) -> dict:
        """``{client id: client handle}`` of the pages this view moves."""
        raise NotImplementedError  # pragma: no cover

    def _add_status(self) -> None:
        self.status = self.gui.add_markdown("starting", order=-100)

    def _clear_view(self) -> None:
        """Remove the view's scene nodes, controls and camera hooks; a new status line."""
        self.scene.reset()
        self.gui.reset()
        self._add_status()
        self._camera_hooks.clear()

    def set_status(self, text: str) -> None:
        """Replace the status line (tests and snapshots wait for its text)."""
        self.status.content = text

    def atomic(self):
        """A context in which the messages to the pages are applied together (viser's
        ``atomic``: a frame's nodes move at once)."""
        raise NotImplementedError  # pragma: no cover

    def _forget_client(self, client) -> None:
        self._cameras.pop(client.client_id, None)

    def watch_page(self, client) -> None:
        """Follow a page's camera (a viser ``ClientHandle``): its first report moves it to
        the home camera, every report is kept and calls the :meth:`on_camera` hooks."""

        def seen(camera, cid=client.client_id) -> None:
            # A page reports its camera as it starts, possibly before it applied the initial
            # camera (the client's default, looking at the origin), or having applied only
            # part of it (the client takes the initial camera once, at the first of its
            # messages: its position with the default point to look at). Its first report
            # moves it to the home camera explicitly, so every page starts there.
            if cid not in self._cameras:
                self._move_home(client)
            self._cameras[cid] = Camera.from_client(camera)
            for hook in list(self._camera_hooks):
                hook()

        client.camera.on_update(seen)
        # viser counts a page as connected at its first camera report and hands that report
        # to the camera callbacks at once, while the connect callbacks (which watch the
        # page) run later on its thread pool: the first report can pass before ``seen`` is
        # there, and a page whose camera then stays still would never be moved home. A page
        # that has reported is seen here (twice at worst, which moves nothing further).
        if client.camera.update_timestamp > 0.0:
            seen(client.camera)

    @property
    def has_browser_camera(self) -> bool:
        """Whether a connected page has reported its camera."""
        return bool(self._cameras)

    def on_camera(self, hook) -> None:
        """Call ``hook()`` whenever a page reports a moved camera (labels are laid out anew)."""
        self._camera_hooks.append(hook)

    def reset_cameras(self) -> None:
        """Move the camera of every connected page to the home camera (a page that has not
        reported its camera yet goes there at its first report)."""
        for cid, client in self._pages().items():
            if self._can_move(cid, client):
                self._move_home(client)

    def _can_move(self, cid: int, client) -> bool:
        """Whether a page's camera can be moved now (it reported one)."""
        return cid in self._cameras

    def _move_home(self, client) -> None:
        home = self._home
        client.camera.fov = float(home.fov)
        client.camera.position = np.asarray(home.position, float)
        client.camera.look_at = np.asarray(home.look_at, float)

    def _set_home(self, position, look_at) -> None:
        self._home.position = tuple(float(x) for x in position)
        self._home.look_at = tuple(float(x) for x in look_at)
        self._home.up = (0.0, 0.0, 1.0)
        self._home_moved()

    def _home_moved(self) -> None:
        """The home camera moved (a whole server's pages opened later take it)."""

    def look_at(self, center, extent: float) -> None:
        """Place the home camera so a box of size ``extent`` [m] around ``center`` fits."""
        c = np.asarray(center, float)
        e = max(float(extent), 0.05)
        back = np.array([1.0, -1.2, 0.8])
        back /= np.linalg.norm(back)
        right = np.cross(-back, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        # the control panel covers the right of the page: aim right of the centre so the
        # scene sits in the free left part
        target = c + 0.3 * e * right
        # 1.5 extents away at three.js's 75 degrees; the same view through the longer lens
        dist = 1.5 * e * np.tan(0.5 * DEFAULT_FOV) / np.tan(0.5 * FRAMING_FOV)
        self._set_home(target + dist * back, target)

    def place_camera(self, position, look_at, move_browsers: bool = False) -> None:
        """The home camera at ``position`` (3,) looking at ``look_at`` (3,) [m, scene
        frame], z up; with ``move_browsers`` the connected pages' cameras too."""
        p, t = np.asarray(position, float), np.asarray(look_at, float)
        if p.shape != (3,) or t.shape != (3,) or not np.all(np.isfinite([*p, *t])):
            raise InputError(f"a camera needs two finite points, got {position}, {look_at}")
        if np.linalg.norm(p - t) < 1e-6:
            raise InputError("the camera's position and the point it looks at are the same")
        self._set_home(p, t)
        if move_browsers:
            self.reset_cameras()

    def frame(self, points, coverage: float = 0.14, centre=None) -> np.ndarray:
        """Aim the home camera at ``centre`` (default: the middle of ``points`` (N, 3)) so
        that the points' bounding box covers ``coverage`` of the page
        (:func:`camera.frame_points`); returns the point it looks at (3,)."""
        position, look_at = frame_points(points, coverage, fov=FRAMING_FOV, centre=centre)
        self._set_home(position, look_at)
        return look_at

    def camera(self) -> Camera:
        """The camera of the first page that reported one, else the home camera (on the
        default canvas)."""
        for cam in list(self._cameras.values()):
            return cam
        home = self._home
        return Camera.looking_at(home.position, home.look_at, fov=float(home.fov))

    def looked_at(self) -> np.ndarray:
        """The point the first page with a camera looks at, else the home camera's."""
        clients = self._pages()
        for cid in list(self._cameras):
            if cid in clients:
                return np.asarray(clients[cid].camera.look_at, float)
        return np.asarray(self._home.look_at, float)

    def follow(self, look_at) -> None:
        """Move every connected page's camera (and the home camera) so that it looks at
        ``look_at`` (3,), keeping its direction and distance (the user may orbit and zoom
        while it follows): a followed body stays where it is on the page.

        Each camera is moved from where its page last reported it, to the absolute target,
        so a report that crossed the previous move on the wire costs nothing."""
        target = np.asarray(look_at, float)
        if not np.all(np.isfinite(target)):
            return
        for cid, client in self._pages().items():
            cam = self._cameras.get(cid)
            if cam is None:  # not reported yet: the handle has no state
                continue
            d = target - np.asarray(client.camera.look_at, float)
            if np.linalg.norm(d) > 1e-6:
                client.camera.position = np.asarray(client.camera.position, float) + d
                # where it is now (labels are laid out for it before the page reports back)
                self._cameras[cid] = dataclasses.replace(cam, position=cam.position + d)
        home = self._home
        d = target - np.asarray(home.look_at, float)
        if np.linalg.norm(d) > 1e-6:
            home.position = tuple(np.asarray(home.position, float) + d)
            home.look_at = tuple(target)


class ViewServer(Pages):
    """A viser server bound to ``host:port`` (``port=0``: a free port) with a status line;
    every page shows the same panel and scene, and its home camera is viser's initial
    camera (what a page opened later starts with).

    viser serves only its own client page (its bundled ``index.html``) and the websocket of
    that page; nothing else is reachable. The default host is ``127.0.0.1``: pass
    ``host="0.0.0.0"`` deliberately to open the view to the network.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 8080, title: str = "trackflow"):
        viser = require("viser", extra="viewer", feature="the viewer")
        # viser prints a banner (and "Server stopped") on stdout whatever ``verbose`` says;
        # stdout belongs to the command (``--json`` output), so the banner is dropped
        with contextlib.redirect_stdout(io.StringIO()):
            self.server = viser.ViserServer(host=host, port=int(port), label=title, verbose=False)
        self.scene, self.gui = self.server.scene, self.server.gui
        # viser can publish a page through its share service (a tunnel to an outside server) when
        # a client asks; this view serves only its own page on the bound address: no share
        # button, and a share request from a client is refused (the handler looks the method up
        # on the instance at call time).
        self.server.request_share_url = _refuse_share
        self.gui.configure_theme(control_width="large", show_share_button=False)
        self.scene.set_up_direction("+z")
        # no shadows: an error view draws no sun, a shadow on the floor reads as another glyph,
        # and the three shadow passes per frame cost software WebGL a quarter of its time to
        # a settled picture
        self.scene.configure_default_lights(True, cast_shadow=False)
        # a longer lens than three.js's 75 degrees: a body framed close is not distorted
        self.server.initial_camera.fov = float(FRAMING_FOV)
        self._home = self.server.initial_camera
        self._add_status()
        self._init_pages()
        self.server.on_client_connect(self.watch_page)
        self.server.on_client_disconnect(self._forget_client)

    def _pages(self) -> dict:
        return self.server.get_clients()

    def atomic(self):
        return self.server.atomic()

    def clear(self) -> None:
        """Remove every scene node, control and camera hook (the status line stays): the
        server can show another view to the pages already open, which keep their WebGL
        context (a new page costs software WebGL its shaders again)."""
        self._clear_view()

    @property
    def url(self) -> str:
        """``http://host:port/`` of the page (loopback shown as 127.0.0.1)."""
        host = self.server.get_host()
        return (
            f"http://{'127.0.0.1' if host in ('0.0.0.0', '') else host}:{self.server.get_port()}/"
        )

    def close(self) -> None:
        with contextlib.redirect_stdout(io.StringIO()):
            self.server.stop()


@dataclasses.dataclass
class _Home:
    """A page's own home camera (as viser's initial camera holds a server's)."""

    position: tuple
    look_at: tuple
    up: tuple
    fov: float


class ClientView(Pages):
    """One page's own view on a :class:`ViewServer` ``host``: the page's own panel (with its
    status line), scene and camera, so that each browser tab keeps its own state. What the
    server shows to every page stays; :meth:`close` removes only this page's part.

    Parameters
    ----------
    host : ViewServer
    client : viser.ClientHandle
        The page (from ``host.server.on_client_connect``).
    """

    def __init__(self, host: ViewServer, client):
        self.host, self.client = host, client
        self.scene, self.gui = client.scene, client.gui
        ic = host.server.initial_camera
        up = (0.0, 0.0, 1.0) if ic.up is None else tuple(ic.up)  # None: the scene's up
        self._home = _Home(tuple(ic.position), tuple(ic.look_at), up, float(ic.fov))
        self._add_status()
        self._init_pages()
        self.watch_page(client)  # a page that reported before goes to this view's home now

    def _pages(self) -> dict:
        return {self.client.client_id: self.client}

    def atomic(self):
        return self.client.atomic()

    def _can_move(self, cid: int, client) -> bool:
        return client.camera.update_timestamp > 0.0  # viser holds the page's camera

    def _home_moved(self) -> None:
        # the page is open already: it goes there now (or at its first report)
        self.reset_cameras()

    def clear(self) -> None:
        """Remove this page's scene nodes, controls and camera hooks (the status stays; a
        page that has gone has nothing to remove)."""
        if self.client.client_id not in self.host.server.get_clients():
            self._camera_hooks.clear()
            return
        self._clear_view()

    @property
    def url(self) -> str:
        return self.host.url

    def close(self) -> None:
        """Remove this page's part (the server runs on)."""
        self.clear()
