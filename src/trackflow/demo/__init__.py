"""The thesis's demo setup (section 2.3, figure 7.2) driven by a real recorded motion.

Frames: projector ``P``, outside-in tracker ``A`` (ART-like), tracked target ``T`` rigidly
mounted on a hand-held camera ``C``, and a marker ``M`` lying still on the table. Edges:

* ``P -> A`` static (the projector is calibrated to the tracker),
* ``A -> T`` measured by the tracker: 60 Hz, low noise, 20 ms latency,
* ``T -> C`` static, estimated from data first (section 7.4.1),
* ``C -> M`` measured by the ARToolKit-like camera: 30 Hz, noisy orientation, 50 ms latency,
  occasional wrong detections, and host-side timestamps 30 ms late (the constant time offset
  of section 9.2.2, known from calibration),
* ``A -> M`` static, the surveyed marker location used only to estimate ``T -> C``.

The target moves like the shipped head-motion excerpt. Because the marker does not move, the
true ``T_P_M`` is constant, so every wobble of the computed relationship is error - exactly the
experiment of section 9.2.2. Three dataflows answer the query ``P -> M`` at 60 Hz:

* naive: the newest measurement of each sensor chained as it is (no time alignment);
* aligned: Kalman filters interpolate both sensors to one common time 100 ms in the past;
* predicted: the same filters predict both sensors to the present (the real-time output).
"""

from .report import demo_json, plot_errors
from .run import pose_errors, run_demo
from .simulation import (
    DemoConfig,
    demo_frames,
    demo_graph,
    demo_sensors,
    demo_truth,
    load_demo_motion,
)

__all__ = [
    "DemoConfig",
    "demo_frames",
    "demo_graph",
    "demo_json",
    "demo_sensors",
    "demo_truth",
    "load_demo_motion",
    "plot_errors",
    "pose_errors",
    "run_demo",
]
