"""What ``trackflow view`` runs: a setup live, or a recording on a timeline; or one snapshot."""

from __future__ import annotations

import dataclasses
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from ..dataflow import Network, Plan, Setup, load_setup
from ..errors import InputError, ServiceError
from .live import LiveView, attach_view
from .simulate import setup_sources

__all__ = ["SetupRun", "ViewOptions", "is_setup", "serve", "start_setup"]


@dataclass
class ViewOptions:
    """Options of :func:`serve` (the command line's flags)."""

    host: str = "127.0.0.1"
    port: int = 8080
    at_s: float | None = None
    sigma: int = 1
    offset_s: float = 0.0
    query: str | None = None
    format: str | None = None
    clean: bool = False
    duration_s: float = 120.0
    rate_hz: float = 30.0
    seed: int = 0
    magnify: float | None = None
    posetool: bool = False
    tune_fraction: float = 0.5
    anchor: str | None = None
    repeat: bool = True
    #: a recording's camera: ``(position, look_at)`` [m, its source frame]; None: framed
    camera: tuple | None = None
    #: a snapshot without the control panel
    no_panel: bool = False


def is_setup(path: str | Path) -> bool:
    """A YAML file is a setup; anything else is read as a recording."""
    return Path(path).suffix.lower() in (".yaml", ".yml")


class SetupRun:
    """A setup's network running on the wall clock in a background thread, with its view.

    The network plans every query of the setup (queries without a path are listed in the
    view's panel as "no path"), plays recordings or simulated sensors for ``duration_s`` and
    starts over until :meth:`close` (with ``repeat=False`` it stops at the end).
    """

    def __init__(self, setup: Setup, opts: ViewOptions):
        self.setup = setup
        self.network = Network()
        sources = setup_sources(setup, opts.duration_s, opts.seed)
        plans: dict[str, tuple[Plan, str]] = {}
        errors: dict[str, str] = {}
        for name, q in setup.queries.items():
            try:
                plan = setup.plan(q)
            except ValueError as exc:
                errors[name] = str(exc)
                continue
            prefix = f"{name}:"
            plan.build(sources, network=self.network, prefix=prefix)
            plans[name] = (plan, prefix)
        if not plans and not sources:
            raise InputError(f"{setup.source}: nothing to show (no sensors and no queries)")
        for name, player in sources.items():  # sensors no query uses still run and show
            if name not in self.network.components:
                self.network.add(player)
        self.view: LiveView = attach_view(
            self.network, setup, plans, host=opts.host, port=opts.port, rate_hz=opts.rate_hz,
            errors=errors, anchor=opts.anchor,
        )  # fmt: skip
        self.repeat = opts.repeat
        if opts.query:
            if opts.query not in plans:
                raise InputError(f"{setup.source}: no plannable query {opts.query!r}")
            self.view.selected_query = opts.query
        self.view.set_sigma(opts.sigma)
        self.view.set_offset(opts.offset_s)
        if opts.magnify is not None:
            self.view.set_magnify(opts.magnify)
        self._stop = threading.Event()
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, daemon=True, name="trackflow-network")
        self._thread.start()

    def _run(self) -> None:
        try:
            self.network.run(realtime=True, stop=self._stop, repeat=self.repeat)
        except (ValueError, RuntimeError) as exc:  # reported by serve()
            self.error = exc

    def wait_network_time(self, t_s: float, timeout_s: float) -> None:
        """Block until the network clock passed ``t_s`` seconds (bounded by ``timeout_s``)."""
        end = time.monotonic() + timeout_s
        while self.network.clock.now_ns * 1e-9 < t_s:
            if self.error is not None:
                raise ServiceError(f"the network stopped: {self.error}")
            if time.monotonic() > end:
                raise ServiceError(f"the network did not reach t = {t_s} s in {timeout_s} s")
            time.sleep(0.02)

    def close(self, timeout_s: float = 10.0) -> None:
        """Stop the view and the network (its run ends at the next event)."""
        self._stop.set()
        self.view.close()
        self._thread.join(timeout=timeout_s)


def start_setup(path, opts: ViewOptions) -> SetupRun:
    """Start a setup's network with a view (see :class:`SetupRun`): ``path`` is a YAML setup
    file or a :class:`~trackflow.dataflow.Setup` already made (the command line makes one of a
    realm's agent files)."""
    setup = path if isinstance(path, Setup) else load_setup(path)
    setup.refuse_online_offsets("trackflow view")
    return SetupRun(setup, opts)


def serve(target, opts: ViewOptions, snapshot=None, size=(1280, 800)) -> Path | None:
    """Serve the view of ``target`` (a setup file or :class:`~trackflow.dataflow.Setup`, or a
    recording) until interrupted, or, with ``snapshot``, render one frame to that PNG through
    headless Chromium and return its path."""
    from .browser import snapshot as take

    setup = isinstance(target, Setup) or is_setup(target)
    if opts.anchor is not None and not setup:
        raise InputError("--anchor applies to a setup; a recording is drawn in its source frame")
    if opts.camera is not None and (setup or opts.posetool):
        raise InputError(
            "--camera applies to a recording's view (a setup's view frames its bodies)"
        )
    if setup:
        if snapshot is not None:
            # data just past the snapshot time, so the network thread ends soon after it
            at = 3.0 if opts.at_s is None else float(opts.at_s)
            # and does not start over (the clock stays past --at: the page shows that time)
            opts = dataclasses.replace(
                opts, duration_s=min(opts.duration_s, at + 2.0), repeat=False
            )
        run = start_setup(target, opts)
        try:
            if snapshot is not None:
                at = 3.0 if opts.at_s is None else float(opts.at_s)
                run.wait_network_time(at, timeout_s=at * 3 + 300)  # a first run compiles kernels
                run.view.paused = True  # hold this frame while the browser loads
                return take(run.view.url, snapshot, "live", *size, hide_panel=opts.no_panel)
            return _block(run.view.url, run)
        finally:
            run.close()
    from ..io import read_stream
    from .recording import RecordingTrack, RecordingView
    from .server import ViewServer
    from .tabs import PerTab

    stream, report = read_stream(target, format=opts.format, clean=opts.clean)
    if opts.clean:
        print(str(report), file=sys.stderr)
    if opts.posetool:
        return _posetool(stream, opts, snapshot, size)
    track = RecordingTrack.from_stream(stream)
    at = 0.0 if opts.at_s is None else float(opts.at_s)
    if not 0.0 <= at <= track.duration:
        raise InputError(f"--at {at} s is outside the recording (0 to {track.duration:.3f} s)")

    def make(server=None) -> RecordingView:
        """The view the options ask for, on its own server or on one page (``server``)."""
        view = RecordingView(track, opts.host, opts.port, server=server)
        try:
            view.set_sigma(opts.sigma)
            view.set_offset(opts.offset_s)
            if opts.magnify is not None:
                view.magnify.value = float(opts.magnify)
            view.show(at)
            if opts.camera is not None:  # the user's camera, kept: the body is not followed
                view.place_camera(*opts.camera)
        except BaseException:
            view.close()
            raise
        return view

    if snapshot is not None:  # one page: the snapshot's
        view = make()
        try:
            text = f"t = {view.t_s:.3f} s"
            return take(view.url, snapshot, text, *size, hide_panel=opts.no_panel)
        finally:
            view.close()
    # every tab its own time, error display and camera
    title = f"trackflow: {stream.source} -> {stream.target}"
    tabs = PerTab(ViewServer(opts.host, opts.port, title=title), make)
    try:
        return _block(tabs.url, tabs)
    finally:
        tabs.close()


def _posetool(stream, opts: ViewOptions, snapshot, size) -> Path | None:
    from .browser import snapshot as take
    from .posetool import PoseTool, PoseToolPage
    from .server import ViewServer
    from .tabs import PerTab

    tool = PoseTool(stream, tune_fraction=opts.tune_fraction)

    def make(view) -> PoseToolPage:
        page = PoseToolPage(tool, view)
        if opts.offset_s > 0:
            page.horizon.value = opts.offset_s * 1e3
        return page

    server = ViewServer(opts.host, opts.port, title=tool.title)
    if snapshot is None:  # every tab its own controls and computation
        tabs = PerTab(server, make, note="each tab has its own settings")
        try:
            return _block(tabs.url, tabs)
        finally:
            tabs.close()
    page = make(server)
    try:
        rev = page.wait_tuned(timeout_s=600.0)
        return take(page.url, snapshot, f"revision {rev} ", *size, hide_panel=opts.no_panel)
    finally:
        page.close()
        server.close()


def _block(url: str, what) -> None:
    print(f"trackflow view: {url} (Ctrl-C to stop)", flush=True)
    try:
        while True:
            time.sleep(0.5)
            err = getattr(what, "error", None)
            if err is not None:
                raise ServiceError(f"the network stopped: {err}")
    except KeyboardInterrupt:
        return None
