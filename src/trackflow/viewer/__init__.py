"""Runtime error visualization in the browser (thesis 8.2), built on viser.

* :func:`attach_view` - a live view of any running :class:`trackflow.dataflow.Network`: frames
  as axes, every sensor's filtered pose and every query's answer with its position error
  ellipsoid and orientation error (axis ellipsoids), trails, the prediction ghost, the SRG
  panel with edge states and time plots. Drawn by a separate view process from a shared
  memory board the network's taps write.
* :class:`RecordingView` - a recording on a timeline (each browser tab its own:
  :class:`PerTab`); :class:`PoseToolPage` - the PoseTool's filter tuning in the browser (on a
  :class:`PoseTool`, the recording and its tuning).
* :func:`snapshot` / :class:`Browser` - headless Chromium renders for reports and tests.

``trackflow view`` and ``trackflow run --view`` are the command line (``docs/viewer.md``).
Needs the ``viewer`` extra (``pip install 'trackflow[viewer]'``: viser, playwright) and a
system Chromium for snapshots. Names are imported on first use, so the view process loads only
what it draws with.
"""

from .._lazy import lazy_names

#: public name -> the module holding it
_WHERE = {
    "SetupRun": "app", "ViewOptions": "app", "is_setup": "app", "serve": "app",
    "start_setup": "app",
    "Board": "board",
    "Browser": "browser", "find_chromium": "browser", "snapshot": "browser",
    "EdgeMonitor": "edges", "ViewLayout": "edges",
    "Ellipsoid": "glyphs", "orientation_glyphs": "glyphs", "position_glyph": "glyphs",
    "stable_axes": "glyphs",
    "COLOURS": "graph_panel", "EdgeStatus": "graph_panel", "classify": "graph_panel",
    "render_panel": "graph_panel",
    "LiveView": "live", "SensorInfo": "live", "attach_view": "live",
    "Tap": "monitor",
    "RecordingTrack": "recording", "RecordingView": "recording", "auto_magnify": "recording",
    "auto_ghost_magnify": "recording",
    "Camera": "camera", "default_anchor": "edges", "LabelLayer": "labels",
    "PoseDrawing": "scene", "Style": "scene",
    "ClientView": "server", "ViewServer": "server",
    "PerTab": "tabs",
    "PoseTool": "posetool", "PoseToolPage": "posetool",
    "edge_motion": "simulate", "setup_sources": "simulate",
}  # fmt: skip

__all__ = sorted(_WHERE)


__getattr__, __dir__ = lazy_names(__name__, _WHERE)
