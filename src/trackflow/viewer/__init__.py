"""Runtime error visualization in the browser (thesis 8.2), built on viser.

* :func:`attach_view` - a live view of any running :class:`trackflow.dataflow.Network`: frames
  as axes, every sensor's filtered pose and every query's answer with its position error
  ellipsoid and orientation error (axis ellipsoids), trails, the prediction ghost, the SRG
  panel with edge states and time plots. Decimated in its own thread.
* :class:`RecordingView` - a recording on a timeline; :class:`PoseToolPage` - the PoseTool's
  filter tuning in the browser.
* :func:`snapshot` / :class:`Browser` - headless Chromium renders for reports and tests.

``trackflow view`` is the command line (``docs/viewer.md``). Needs the ``viewer`` extra
(``pip install 'trackflow[viewer]'``: viser, playwright) and a system Chromium for snapshots.
"""

from .app import SetupRun, ViewOptions, is_setup, serve, start_setup
from .browser import Browser, find_chromium, snapshot
from .glyphs import Ellipsoid, orientation_glyphs, position_glyph, stable_axes
from .graph_panel import COLOURS, EdgeStatus, classify, render_panel
from .live import LiveView, attach_view
from .monitor import Tap
from .recording import RecordingTrack, RecordingView, auto_magnify
from .scene import PoseDrawing, Style
from .server import ViewServer
from .simulate import edge_motion, setup_sources

__all__ = [
    "COLOURS",
    "Browser",
    "EdgeStatus",
    "Ellipsoid",
    "LiveView",
    "PoseDrawing",
    "RecordingTrack",
    "RecordingView",
    "SetupRun",
    "Style",
    "Tap",
    "ViewOptions",
    "ViewServer",
    "attach_view",
    "auto_magnify",
    "classify",
    "edge_motion",
    "find_chromium",
    "is_setup",
    "orientation_glyphs",
    "position_glyph",
    "render_panel",
    "serve",
    "setup_sources",
    "snapshot",
    "stable_axes",
    "start_setup",
]
