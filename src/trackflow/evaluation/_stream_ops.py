"""Trajectory processing before a comparison or a plot (what evo_traj offers): merge several
recordings into one, apply a fixed transform on either side, downsample, motion filter,
associate in time, and a full validity check with the trajectory's figures.

Each function takes and returns :class:`trackflow.io.PoseStream` (``T_source_target``,
positions [m], quaternions ``(x, y, z, w)``, times in integer nanoseconds) and keeps the
samples' covariances, confidences and flags where the samples are kept.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import ConfigError, InputError
from ..io import PoseStream
from ..math import Pose
from ._compare import associate
from ._ops import _per_interval
from ._pairs import downsample_ids, motion_filter_ids

__all__ = [
    "check_stream",
    "downsample_stream",
    "load_transform",
    "merge_streams",
    "motion_filter_stream",
    "sync_streams",
    "transform_stream",
]


def merge_streams(streams) -> PoseStream:
    """Several recordings of one relationship as one, ordered by time.

    Parameters
    ----------
    streams : sequence of PoseStream
        Same ``source`` and ``target`` frames; no two samples at the same time.

    Returns
    -------
    PoseStream
        Every sample, sorted by time, with covariances when every input has them.

    Raises
    ------
    InputError
        No streams, different frames, some with covariances and some without, or two samples
        at the same time.
    """
    streams = list(streams)
    if not streams:
        raise InputError("nothing to merge")
    frames = {(s.source, s.target) for s in streams}
    if len(frames) > 1:
        raise InputError(f"cannot merge recordings of different relationships: {sorted(frames)}")
    has_cov = [s.covariance is not None for s in streams]
    if any(has_cov) and not all(has_cov):
        raise InputError(
            "cannot merge recordings with and without covariances (drop them first, e.g. "
            "'trackflow convert' to TUM)"
        )
    t = np.concatenate([s.t_ns for s in streams])
    order = np.argsort(t, kind="stable")
    t = t[order]
    same = np.flatnonzero(np.diff(t) == 0)
    if len(same):
        raise InputError(
            f"the merged recordings have {len(same)} sample(s) at the same time, the first at "
            f"{t[same[0]] * 1e-9:.9f} s"
        )

    def cat(name):
        return np.concatenate([np.asarray(getattr(s, name)) for s in streams])[order]

    src, tgt = frames.pop()
    return PoseStream(
        src, tgt, t, cat("position"), cat("quaternion"),
        covariance=cat("covariance") if all(has_cov) else None,
        confidence=cat("confidence"), flags=cat("flags"),
    )  # fmt: skip


def load_transform(path) -> Pose:
    """A rigid transform from a JSON file, for :func:`transform_stream`.

    The file (or, with ``FILE#KEY``, its entry ``KEY``; ``#X.pose`` descends) holds either

    * a 4x4 homogeneous matrix, row by row: ``[[r00, r01, r02, tx], ..., [0, 0, 0, 1]]``, bare
      or as ``{"matrix": [[...], ...]}`` (rotation orthonormal to 1e-6, translation [m]); or
    * a pose ``{"position": [x, y, z], "quaternion": [qx, qy, qz, qw]}`` [m], the form of
      ``X`` and ``Z`` in ``trackflow calibrate hand-eye --json`` (``calib.json#X``).

    Raises
    ------
    ConfigError
        Unreadable JSON, no such key, or neither form (naming the file and key).
    """
    text = str(path)
    file, _, key = text.partition("#")
    try:
        data = json.loads(Path(file).read_text())
    except json.JSONDecodeError as exc:
        raise ConfigError(f"not JSON: {exc.msg}", file=file, line=exc.lineno) from None
    for part in key.split(".") if key else ():
        if not isinstance(data, dict) or part not in data:
            raise ConfigError(f"no entry {part!r}", file=file, key=key)
        data = data[part]
    if isinstance(data, dict) and "matrix" in data:
        data = data["matrix"]
    try:
        if isinstance(data, dict) and "position" in data and "quaternion" in data:
            return Pose(data["position"], data["quaternion"], normalize=True)
        m = np.asarray(data, dtype=float)
        if m.shape != (4, 4):
            raise InputError(
                "expected a 4x4 matrix, {'matrix': 4x4} or {'position', 'quaternion'}, got "
                + (f"an array of shape {m.shape}" if m.ndim else type(data).__name__)
            )
        return Pose.from_matrix(m)
    except (InputError, ValueError, TypeError) as exc:
        raise ConfigError(str(exc), file=file, key=key or None) from None


def transform_stream(stream: PoseStream, left: Pose | None = None, right: Pose | None = None):
    """``L @ T_i @ R`` for every sample ``T_i`` of ``stream``: ``left`` re-expresses the poses
    in another world (``T_w'_w``), ``right`` moves the tracked point (``T_body_body'``, e.g. a
    hand-eye ``X``). Both are exact; covariances are propagated (first order, exact here).
    The frame names are kept."""
    if left is None and right is None:
        return stream
    poses = stream.uncertain_poses if stream.covariance is not None else stream.poses
    if left is not None:
        poses = left @ poses
    if right is not None:
        poses = poses @ right
    return PoseStream.from_poses(stream.source, stream.target, stream.t_ns, poses,
                                 stream.confidence, stream.flags)  # fmt: skip


def downsample_stream(stream: PoseStream, max_poses: int) -> PoseStream:
    """At most ``max_poses`` samples, evenly spaced in index from the first to the last
    (:func:`trackflow.evaluation._pairs.downsample_ids`)."""
    return stream[downsample_ids(len(stream), max_poses)]


def motion_filter_stream(stream: PoseStream, min_dist_m: float, min_angle_deg: float):
    """The samples that moved: the first, then each sample whose path since the last kept
    one reaches ``min_dist_m`` [m] or whose rotation from it reaches ``min_angle_deg`` [deg]
    (:func:`trackflow.evaluation._pairs.motion_filter_ids`)."""
    return stream[motion_filter_ids(stream.position, stream.quaternion, min_dist_m, min_angle_deg)]


def sync_streams(ref: PoseStream, est: PoseStream, t_max_diff: float = 0.01, t_offset=0.0):
    """The samples of two recordings that :func:`associate` pairs, each on its own clock.

    Every sample of the recording with fewer samples is paired with the nearest sample of the
    other (after adding ``t_offset`` to ``est``'s times) within ``t_max_diff`` [s]; a sample
    of the denser one nearest to two samples of the sparser one is kept once, so the two
    streams can differ in length (evo repeats it: a stream's times are strictly increasing).

    Returns
    -------
    (PoseStream, PoseStream)
        The associated samples of ``ref`` and of ``est``.

    Raises
    ------
    InputError
        No sample associated.
    """
    ir, ie = associate(ref.t_ns * 1e-9, est.t_ns * 1e-9, t_max_diff, t_offset)
    if not len(ir):
        raise InputError(
            f"no samples within {t_max_diff:g} s of each other (time offset {t_offset:g} s)"
        )
    return ref[np.unique(ir)], est[np.unique(ie)]


def check_stream(stream: PoseStream, report=None) -> dict:
    """Every validity check of a recording, and its figures (``--full-check``).

    Parameters
    ----------
    stream : PoseStream
    report : trackflow.io.ReadReport, optional
        The reader's account: rows dropped (and why), quaternions normalised, truncation, and
        its notes (quaternions off unit length within the rounding of the file's printed
        digits are normalised and noted, not counted as invalid).

    Returns
    -------
    dict
        ``"valid"`` (bool: nothing dropped, repaired or out of tolerance), ``"checks"``
        (name -> ``"ok"`` or what is wrong) and the figures: ``samples``, ``t_start_s``,
        ``t_end_s``, ``duration_s``, ``path_length_m``, ``position_start_m``,
        ``position_end_m``, ``speed_m_s`` (``max``, ``min``, ``mean``) and ``dt_s`` (``max``,
        ``min``, ``mean``) between consecutive samples.
    """
    n = len(stream)
    t = stream.t_ns
    p = np.asarray(stream.position)
    q = np.asarray(stream.quaternion)
    checks = {}
    norm_dev = float(np.max(np.abs(np.linalg.norm(q, axis=1) - 1.0))) if n else 0.0
    checks["quaternions"] = (
        "ok" if norm_dev <= 1e-6 else "invalid"
    ) + f" (largest | |q| - 1 |: {norm_dev:.1e})"
    checks["timestamps"] = (
        "ok (strictly increasing)" if n < 2 or np.all(np.diff(t) > 0) else "not increasing"
    )
    checks["positions"] = "ok (finite)" if np.all(np.isfinite(p)) else "not finite"
    flips = int(np.count_nonzero(np.einsum("ij,ij->i", q[:-1], q[1:]) < 0)) if n > 1 else 0
    checks["quaternion signs"] = (
        "ok" if not flips else f"{flips} sign flip(s) (q and -q are the same rotation)"
    )
    valid = norm_dev <= 1e-6
    if report is not None:
        for reason, rows in report.dropped.items():
            checks[f"dropped: {reason}"] = f"{len(rows)} {report.unit}(s), first {rows[0]}"
        if report.normalized:
            checks["normalised quaternions"] = (
                f"{len(report.normalized)} {report.unit}(s), first {report.normalized[0]}"
            )
        valid &= not (report.dropped or report.normalized or report.truncated)
        checks["rows"] = f"{report.rows_kept} of {report.rows_read} kept"
        for k, note in enumerate(report.notes):
            checks[f"reader note {k + 1}"] = note
    out = {"valid": bool(valid), "checks": checks, "samples": n}
    if n < 2:
        return out
    dt = _per_interval(n, lambda i, j: np.diff(t[i : j + 1]) * 1e-9)
    step = _per_interval(n, lambda i, j: np.linalg.norm(p[i:j] - p[i + 1 : j + 1], axis=1))
    speed = step / dt
    out.update(
        t_start_s=float(t[0] * 1e-9),
        t_end_s=float(t[-1] * 1e-9),
        duration_s=float((t[-1] - t[0]) * 1e-9),
        path_length_m=float(np.sum(step)),
        position_start_m=p[0].tolist(),
        position_end_m=p[-1].tolist(),
        speed_m_s={"max": float(speed.max()), "min": float(speed.min()),
                   "mean": float(speed.mean())},
        dt_s={"max": float(dt.max()), "min": float(dt.min()), "mean": float(dt.mean())},
    )  # fmt: skip
    return out
