"""The viser server every view runs on: loopback by default, Z up, one status line."""

from __future__ import annotations

import contextlib
import io

import numpy as np

from ..optional import require

__all__ = ["SECONDS_AXIS", "ViewServer"]

#: uPlot ``scales`` for plots over seconds of a run (uPlot reads x as Unix time by default).
SECONDS_AXIS = {"x": {"time": False}}


def _refuse_share(*_args, **_kwargs) -> None:
    """Stands in for ``ViserServer.request_share_url``: sharing is never started."""
    return None


class ViewServer:
    """A viser server bound to ``host:port`` (``port=0``: a free port) with a status line.

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
        self.status = self.gui.add_markdown("starting", order=-100)

    @property
    def url(self) -> str:
        """``http://host:port/`` of the page (loopback shown as 127.0.0.1)."""
        host = self.server.get_host()
        return (
            f"http://{'127.0.0.1' if host in ('0.0.0.0', '') else host}:{self.server.get_port()}/"
        )

    def set_status(self, text: str) -> None:
        """Replace the status line (tests and snapshots wait for its text)."""
        self.status.content = text

    def look_at(self, center, extent: float) -> None:
        """Place the initial camera so a box of size ``extent`` [m] around ``center`` fits."""
        c = np.asarray(center, float)
        e = max(float(extent), 0.05)
        back = np.array([1.0, -1.2, 0.8])
        back /= np.linalg.norm(back)
        right = np.cross(-back, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        # the control panel covers the right of the page: aim right of the centre so the
        # scene sits in the free left part
        target = c + 0.3 * e * right
        self.server.initial_camera.position = tuple(target + 1.5 * e * back)
        self.server.initial_camera.look_at = tuple(target)
        self.server.initial_camera.up = (0.0, 0.0, 1.0)

    def close(self) -> None:
        with contextlib.redirect_stdout(io.StringIO()):
            self.server.stop()
