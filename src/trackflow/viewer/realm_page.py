"""The page of ``trackflow view --realm NAME``: a distributed realm seen read-only.

:class:`RealmPage` draws what a realm watcher gathers (the plain snapshot of
:class:`trackflow.distributed.realm_watch.RealmWatch`; nothing here speaks Zenoh):

* the panel: every agent (alive or gone, how its links are protected, its sensors with their
  rates and stale flags, measured against declared attributes, its queries with their state,
  current path and answers published), the realm's union graph drawn like the live view's
  SRG (an edge green while its agent advertises it live, red when not, blue when static; the
  queries' current paths highlighted), and the realm's events newest first with their times
  (agents joining and leaving, sensors going down, queries re-planned or switched, with the
  agent's reason);
* the scene: each query's newest answer, ``T_source_target`` drawn from the query's source
  frame with its error ellipsoid (magnified like a live view's: ``magnify``).
"""

from __future__ import annotations

import html
import re
import time

import numpy as np

from ..math import Pose, UncertainPose
from .attributes_panel import render_attributes
from .graph_panel import COLOURS, EdgeStatus, render_panel
from .scene import PALETTE, PoseDrawing, Style
from .server import ViewServer

__all__ = ["RealmPage", "realm_panel"]

#: events listed on the page (the newest)
SHOWN_EVENTS = 12


def _clock(t_ns: int) -> str:
    """A host time as ``HH:MM:SS.mmm`` (local time)."""
    s = t_ns / 1e9
    return time.strftime("%H:%M:%S", time.localtime(s)) + f".{int(t_ns // 1_000_000) % 1000:03d}"


def _on_path(agents: dict) -> set[str]:
    """Edge names on the current path of some query of ``agents``."""
    out = set()
    for st in agents.values():
        for q in (st.get("queries") or {}).values():
            paths = q.get("paths") or []
            k = q.get("path", 0) or 0
            if 0 <= k < len(paths):
                out.update(re.findall(r"\[([^\]]+)\]", paths[k]))
    return out


def _agent_html(name: str, st: dict, edges: list[dict]) -> str:
    alive = st.get("alive", False)
    colour = COLOURS["live"] if alive else COLOURS["stale"]
    head = (f'<div style="font-size:12px;margin-top:6px"><b>{html.escape(name)}</b> '
            f'<span style="color:{colour}">{"alive" if alive else "gone"}</span>'
            f" (links: {html.escape(str(st.get('security', '?')))})</div>")  # fmt: skip
    rows = []
    for sensor, s in (st.get("inputs") or {}).items():
        stale = " STALE" if s.get("stale") else ""
        rows.append(f"{html.escape(sensor)} ({html.escape(str(s.get('protocol')))}): "
                    f"{s.get('rate_hz', 0):.1f} Hz{stale}")  # fmt: skip
    own = sorted(e["name"] for e in edges if e["agent"] == name and e["kind"] != "static")
    if own:
        live = {e["name"] for e in edges if e["agent"] == name and e["live"]}
        rows.append("advertises " + ", ".join(
            html.escape(e) + ("" if e in live else " (down)") for e in own))  # fmt: skip
    for q, qs in (st.get("queries") or {}).items():
        paths = qs.get("paths") or []
        k = qs.get("path", 0) or 0
        path = paths[k] if 0 <= k < len(paths) else "-"
        rows.append(f"query {html.escape(q)}: {html.escape(str(qs.get('state')))}, path "
                    f"{html.escape(path)}, published {qs.get('published', 0)}")  # fmt: skip
    if st.get("error"):
        rows.append(f"error: {html.escape(str(st['error']))}")
    body = "".join(f"<div>&nbsp;&nbsp;{r}</div>" for r in rows)
    attrs = st.get("attributes") or {}
    table = render_attributes({"attributes": attrs}) if attrs else ""
    return head + f'<div style="font-size:11px">{body}</div>' + table


def realm_panel(snap: dict) -> str:
    """The panel's HTML of a realm snapshot (module docstring)."""
    agents = snap.get("agents") or {}
    on_path = _on_path(agents)
    edges = []
    for e in snap.get("edges") or []:
        state = "static" if e["kind"] == "static" else ("live" if e["live"] else "stale")
        edges.append(EdgeStatus(e["name"], e["source"], e["target"], state,
                                on_path=e["name"] in on_path))  # fmt: skip
    out = [f'<div style="font-size:12px"><b>realm {html.escape(str(snap.get("realm")))}</b>: '
           f"{sum(1 for a in agents.values() if a.get('alive'))} agent(s) alive</div>"]  # fmt: skip
    out += [_agent_html(name, st, snap.get("edges") or []) for name, st in sorted(agents.items())]
    if edges:
        out.append(render_panel(list(snap.get("frames") or []), edges))
    events = list(snap.get("events") or [])[-SHOWN_EVENTS:][::-1]
    if events:
        out.append('<div style="font-size:12px;margin-top:6px"><b>events</b></div>')
        out += [f'<div style="font-size:11px">{_clock(ev["t_ns"])} '
                f"{html.escape(ev['text'])}</div>" for ev in events]  # fmt: skip
    rej = snap.get("rejections") or {}
    if rej:
        out.append(f'<div style="font-size:11px">rejected: {html.escape(str(rej))}</div>')
    return "".join(out)


class RealmPage:
    """A viser page of a realm (module docstring). Call :meth:`show` with each snapshot.

    Parameters
    ----------
    host, port : str, int
        Where the page is served (loopback by default; ``port=0``: a free one).
    realm : str
        The realm's name (the page's title).
    magnify : float
        Ellipsoids drawn this many times their size (sub-millimetre errors are invisible at
        room scale).
    """

    #: an answer is drawn at most this often [s] (the page is a monitor: software WebGL on a
    #: loaded machine falls behind a 60 Hz query, and the panel's text waits behind it)
    answer_period_s = 1.0
    #: the panel's moving figures are sent at most this often [s] (events at once)
    panel_period_s = 2.0

    def __init__(self, host: str = "127.0.0.1", port: int = 8080, realm: str = "",
                 magnify: float = 100.0):  # fmt: skip
        self.view = ViewServer(host, port, title=f"trackflow realm {realm}")
        self.style = Style(magnify=float(magnify), axes_length=0.1, show_orientation=False)
        self.panel = self.view.gui.add_html("")
        self._html = ""
        self._change: tuple = ()
        self._html_at = 0.0
        self._drawings: dict[str, PoseDrawing] = {}
        self._drawn: dict[str, tuple] = {}  # answer -> (its time, when it was drawn)
        self._status = ""
        self._framed = False

    @property
    def url(self) -> str:
        return self.view.url

    def show(self, snap: dict) -> None:
        """Draw a snapshot (:meth:`RealmWatch.snapshot`)."""
        text = realm_panel(snap)
        now = time.monotonic()
        # a change of the realm (an event, an agent or sensor up or down) goes out at once;
        # the figures that move all the time (rates, answers published) every few seconds:
        # each update makes the page lay the whole panel out again
        alive = sorted(a for a, st in (snap.get("agents") or {}).items() if st.get("alive"))
        live = [e["live"] for e in snap.get("edges") or ()]
        shown = [(e["t_ns"], e["text"]) for e in list(snap.get("events") or ())[-SHOWN_EVENTS:]]
        change = (*shown, *live, *alive)  # (the watch keeps a bounded list: not its length)
        if text != self._html and (
            change != self._change or now - self._html_at >= self.panel_period_s
        ):
            self._html, self._change, self._html_at = text, change, now
            self.panel.content = text
        now = time.monotonic()
        for key, a in sorted((snap.get("answers") or {}).items()):
            last = self._drawn.get(key)
            if last is not None and (last[0] == a["t_ns"] or now - last[1] < self.answer_period_s):
                continue  # nothing new, or drawn recently: each drawing is a dozen messages
            self._drawn[key] = (a["t_ns"], now)
            d = self._drawings.get(key)
            if d is None:
                colour = PALETTE[len(self._drawings) % len(PALETTE)]
                path = "/realm/" + key.replace("/", "_")
                d = self._drawings[key] = PoseDrawing(self.view.scene, path, colour, self.style)
            pose = UncertainPose(Pose(a["position"], a["quaternion"], normalize=True),
                                 np.asarray(a["covariance"], float))  # fmt: skip
            d.update(pose)
            if not self._framed:  # the first answer: the camera on it, a metre around it
                self.view.look_at(pose.position, 1.0)
                self.view.reset_cameras()
                self._framed = True
        agents = snap.get("agents") or {}
        alive = sum(1 for a in agents.values() if a.get("alive"))
        status = f"realm {snap.get('realm')}: {alive} agent(s) alive"
        if status != self._status:
            self._status = status
            self.view.set_status(status)

    def close(self) -> None:
        self.view.close()
