"""Compile the numerical kernels ahead of time, as the commands will call them.

numba compiles a kernel the first time it runs with a new combination of argument types and
caches the machine code on disk (``trackflow.math._backend``). :func:`compile_kernels` runs
every library path the command line uses (tuning and scoring, filtering with covariances and
predictions, the learned model, the whole-recording smoother of ``infer``, the live filter of
``run``/``view``/``lookup``/``demo``, uncertain composition, the point-set fit of ``compare``
and the alignments)
on a small synthetic recording, so that a command's first run finds its kernels compiled.
``make`` calls it through ``trackflow compile`` right after installing.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..filters import PoseFilterBank, PoseKalmanFilter, TwistARModel
from ..io import PoseStream
from ..math import Pose, UncertainPose, get_backend, quat_exp, umeyama
from ._model_file import filter_stream
from ._ops import infer_streams
from ._pairs import rpe_pairs
from ._predictor import TwistARPredictor, default_predictor
from ._stream_ops import motion_filter_stream
from ._trajectory import Trajectory
from ._tuning import evaluate_recording

__all__ = ["compile_kernels"]


def _synthetic(seconds: float = 12.0, rate: float = 100.0):
    """A smooth hand-held-like motion with 0.3 mm / 0.05 deg noise (seeded) and a 1 s dropout,
    so that the filters run on several segments as they do on real recordings."""
    rng = np.random.default_rng(0)
    t = np.arange(0.0, seconds, 1.0 / rate)
    t = t[(t < 0.5 * seconds) | (t >= 0.5 * seconds + 1.0)]
    pos = np.stack([0.3 * np.sin(0.9 * t), 0.2 * np.cos(1.3 * t), 0.1 * np.sin(0.4 * t)], 1)
    rot = np.stack([0.4 * np.sin(0.7 * t), 0.3 * np.cos(0.5 * t), 0.2 * t], 1)
    pos = pos + rng.normal(0.0, 3e-4, pos.shape)
    rot = rot + rng.normal(0.0, np.radians(0.05), rot.shape)
    return t, pos, quat_exp(rot)


def compile_kernels(progress: Callable[[str], None] | None = None) -> list[str]:
    """Run every kernel path of the command line once; returns the steps done.

    With the NumPy backend there is nothing to compile and nothing runs.
    """
    if get_backend() != "numba":
        return []
    say = progress or (lambda step: None)
    t, pos, quat = _synthetic()
    t_ns = np.round(t * 1e9).astype(np.int64)
    # through a stream, as the commands read recordings (its arrays are read-only)
    stream = PoseStream.from_poses("world", "body", t_ns, Pose(pos, quat))
    steps = []

    say("tuning and scoring (evaluate, tune, plot)")
    recording = Trajectory.from_stream(stream)
    report = evaluate_recording(recording, ar_orders=(3,))
    # the learned model's filter, whether or not the tuning above chose it
    model = TwistARModel.fit(t, pos, quat, order=3)
    TwistARPredictor(model, 3e-4, 1e-3).predict(recording, np.array([0.05, 0.1]))
    steps.append("evaluate")

    say("filtering with covariances and predictions (filter)")
    for horizon in (0.0, 0.05):
        filter_stream(stream, report.predictor, horizon, calibrate=True)
    steps.append("filter")

    say("whole-recording smoothing (infer)")
    inverse = PoseStream.from_poses("body", "world", t_ns, Pose(pos, quat).inverse())
    infer_streams(stream, inverse)
    steps.append("infer")

    say("live filtering (run, view, lookup, demo)")
    live = default_predictor(t, pos, quat)
    kf = PoseKalmanFilter(live.model, history=1.0)
    meas = live.measurements(pos[:50], quat[:50])
    for k in range(50):
        kf.update_pose(float(t[k]), meas[k])
    kf.predict(float(t[49]) + 0.05), kf.predict(float(t[25]) + 1e-3)
    # the filter bank of a live packet's bodies (trackflow run, bench/trackers.py)
    bank = PoseFilterBank([PoseKalmanFilter(live.model, history=1.0) for _ in range(2)])
    for k in range(3):
        bank.update_poses([0, 1], [float(t[k])] * 2, [meas[k], meas[k]])
    bank.predict_poses([0, 1], [float(t[2]) + 1e-3] * 2)
    z = [np.stack([a, a]) for a in (meas[3].position, meas[3].quaternion, meas[3].covariance)]
    bank.update_block([0, 1], [float(t[3])] * 2, *z, defer=True, predict_at=float(t[3]) + 1e-3)
    bank.settle()  # a packet with its answers (LiveSources.deliver_block)
    steps.append("live")

    say("uncertain composition")
    c = np.diag([1e-6] * 3 + [1e-5] * 3)
    a = UncertainPose(Pose(pos[:5], quat[:5]), np.broadcast_to(c, (5, 6, 6)).copy())
    (a[0] @ a[1]).inverse()
    a @ a
    steps.append("compose")

    say("trajectory alignment (compare, calibrate align)")
    umeyama(pos[:100], pos[1:101], with_scale=True)
    steps.append("align")

    say("RPE pairs by path and angle, motion filter (compare, plot-traj)")
    short = stream[:200]
    for unit, delta in (("m", 0.01), ("d", 1.0)):
        for all_pairs in (False, True):
            rpe_pairs(short.position, short.quaternion, delta, unit, all_pairs=all_pairs)
    motion_filter_stream(short, 0.01, 1.0)
    steps.append("compare")
    return steps
