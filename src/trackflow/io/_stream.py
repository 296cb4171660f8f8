"""``PoseStream``: an immutable batch of time-stamped pose samples of one relationship.

A stream holds the fields of the thesis's ``PoseData`` (Pustka, table 7.1) for ``N`` samples of
one spatial relationship ``T_source_target`` (see ``docs/conventions.md``): integer-nanosecond
timestamps, position, orientation, optional 6x6 covariance, confidence and validity flags.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..errors import InputError
from ..math import Pose, UncertainPose, check_covariance, check_quaternion

__all__ = [
    "FLAG_CONFIDENCE",
    "FLAG_COVARIANCE",
    "FLAG_ORIENTATION",
    "FLAG_POSITION",
    "PoseStream",
]

#: Validity bit: ``position`` holds a measured value.
FLAG_POSITION = np.uint32(1)
#: Validity bit: ``quaternion`` holds a measured value.
FLAG_ORIENTATION = np.uint32(2)
#: Validity bit: ``covariance`` holds a meaningful value for this sample.
FLAG_COVARIANCE = np.uint32(4)
#: Validity bit: ``confidence`` was set by the sensor (otherwise it is the default 1.0).
FLAG_CONFIDENCE = np.uint32(8)


def present_fields(covariance: bool, confidence: bool) -> int:
    """Flags of a sample with position and orientation, and covariance / confidence if given."""
    f = FLAG_POSITION | FLAG_ORIENTATION
    if covariance:
        f |= FLAG_COVARIANCE
    if confidence:
        f |= FLAG_CONFIDENCE
    return f


def _readonly(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


def unit_quaternions(q: np.ndarray) -> np.ndarray:
    """``check_quaternion`` that keeps the given bits where ``|q|`` is 1 to 1e-12.

    Rescaling an already-unit quaternion changes its last bits; keeping them makes copies and
    file round trips exactly equal.
    """
    unit = check_quaternion(q)
    close = np.abs(np.sum(q * q, axis=-1) - 1.0) <= 2e-12
    return np.where(close[..., None], q, unit)


def check_frame_name(name, what: str) -> str:
    if not isinstance(name, str) or not name:
        raise InputError(f"{what} frame must be a non-empty string, got {name!r}")
    if "\n" in name or "\0" in name:
        raise InputError(f"{what} frame may not contain newline or NUL characters: {name!r}")
    return name


class PoseStream:
    """Time-stamped samples of the relationship ``T_source_target``, immutable.

    Parameters
    ----------
    source, target : str
        Frame names; each sample is ``T_source_target`` (maps target coordinates into source,
        ``x_source = R x_target + t``).
    t_ns : array_like of int, shape (N,)
        Timestamps in integer nanoseconds, strictly increasing. The epoch is whatever the
        recording used (Unix time for real clocks, an arbitrary origin otherwise).
    position : array_like, shape (N, 3)
        ``t_source_target`` in metres, finite.
    quaternion : array_like, shape (N, 4)
        ``R_source_target`` as unit quaternions ``(x, y, z, w)``. Deviations from unit length
        above ``1e-6`` raise ``ValueError``; the stored sign is kept as given.
    covariance : array_like, shape (N, 6, 6), optional
        Covariance of ``(dt, dtheta)`` with ``t_true = t + dt`` (dt in frame source, metres) and
        ``R_true = R Exp(dtheta)`` (dtheta in frame target, radians). Symmetric and positive
        semi-definite. ``None`` when the recording carries no uncertainty.
    confidence : array_like, shape (N,), optional
        Probability in [0, 1] that the measurement exists (thesis table 7.1). Default 1.
    flags : array_like of uint32, shape (N,), optional
        Validity bits ``FLAG_POSITION | FLAG_ORIENTATION | FLAG_COVARIANCE | FLAG_CONFIDENCE``.
        Default: position and orientation valid, plus covariance when one is given. A field
        whose bit is clear still holds a finite placeholder (zeros, identity quaternion).

    Notes
    -----
    All arrays are stored read-only; use :meth:`with_` to derive a modified copy. Indexing with
    a slice, boolean mask or integer array returns a stream (an integer gives a length-1
    stream). Streams compare equal (``==``) when frames and every array are exactly equal.
    """

    __slots__ = ("_source", "_target", "_t", "_p", "_q", "_c", "_conf", "_flags")

    def __init__(
        self,
        source: str,
        target: str,
        t_ns,
        position,
        quaternion,
        covariance=None,
        confidence=None,
        flags=None,
    ):
        t = np.asarray(t_ns)
        if t.ndim != 1:
            raise InputError(f"t_ns must have shape (N,), got {t.shape}")
        if t.size and not np.issubdtype(t.dtype, np.integer):
            raise InputError(
                f"t_ns must be integer nanoseconds, got dtype {t.dtype} "
                "(use PoseStream.from_seconds for float seconds)"
            )
        t = t.astype(np.int64)
        n = t.shape[0]
        p = np.asarray(position, dtype=float)
        if p.shape != (n, 3):
            raise InputError(f"position must have shape ({n}, 3), got {p.shape}")
        if not np.all(np.isfinite(p)):
            bad = int(np.argwhere(~np.isfinite(p).all(axis=1))[0, 0])
            raise InputError(f"position contains NaN or inf at index {bad}")
        q = np.asarray(quaternion, dtype=float)
        if q.shape != (n, 4):
            raise InputError(f"quaternion must have shape ({n}, 4), got {q.shape}")
        if n:
            q = unit_quaternions(q)
        if n > 1:
            d = np.diff(t)
            if np.any(d <= 0):
                i = int(np.argmax(d <= 0)) + 1
                raise InputError(
                    f"t_ns must be strictly increasing: index {i} has {t[i]} after {t[i - 1]}"
                )
        c = None
        if covariance is not None:
            c = np.asarray(covariance, dtype=float)
            if c.shape != (n, 6, 6):
                raise InputError(f"covariance must have shape ({n}, 6, 6), got {c.shape}")
            if n:
                c = check_covariance(c)
        if confidence is None:
            conf = np.ones(n)
        else:
            conf = np.asarray(confidence, dtype=float)
            if conf.shape != (n,):
                raise InputError(f"confidence must have shape ({n},), got {conf.shape}")
            bad = ~((conf >= 0.0) & (conf <= 1.0))
            if np.any(bad):
                i = int(np.argmax(bad))
                raise InputError(f"confidence must lie in [0, 1]: index {i} has {conf[i]}")
        if flags is None:
            fl = np.full(n, present_fields(c is not None, confidence is not None), dtype=np.uint32)
        else:
            fl = np.asarray(flags)
            if fl.shape != (n,):
                raise InputError(f"flags must have shape ({n},), got {fl.shape}")
            if fl.size and not np.issubdtype(fl.dtype, np.integer):
                raise InputError(f"flags must be unsigned integers, got dtype {fl.dtype}")
            if fl.size and (fl.min() < 0 or fl.max() > 0xFFFFFFFF):
                raise InputError("flags must fit in uint32")
            fl = fl.astype(np.uint32)
        source = check_frame_name(source, "source")
        target = check_frame_name(target, "target")
        self._init(source, target, t, p, q, c, conf, fl)

    def _init(self, source, target, t, p, q, c, conf, fl) -> None:
        self._source = source
        self._target = target
        self._t = _readonly(np.ascontiguousarray(t, dtype=np.int64))
        self._p = _readonly(np.ascontiguousarray(p, dtype=float))
        self._q = _readonly(np.ascontiguousarray(q, dtype=float))
        self._c = None if c is None else _readonly(np.ascontiguousarray(c, dtype=float))
        self._conf = _readonly(np.ascontiguousarray(conf, dtype=float))
        self._flags = _readonly(np.ascontiguousarray(fl, dtype=np.uint32))

    @classmethod
    def _trusted(cls, source, target, t, p, q, c, conf, fl) -> PoseStream:
        """Build from arrays already validated by a reader (internal fast path)."""
        obj = cls.__new__(cls)
        obj._init(source, target, t, p, q, c, conf, fl)
        return obj

    # -- construction -------------------------------------------------------------------------
    @classmethod
    def from_seconds(cls, source: str, target: str, times_s, position, quaternion, **fields):
        """Build from float seconds; ``t_ns = round(times_s * 1e9)``.

        Float64 seconds since 1970 resolve only about 0.2 microseconds, so prefer integer
        nanoseconds when the source has them. ``fields`` are the remaining constructor
        arguments (``covariance``, ``confidence``, ``flags``).
        """
        ts = np.asarray(times_s, dtype=float)
        if not np.all(np.isfinite(ts)):
            raise InputError("times_s contains NaN or inf")
        return cls(
            source, target, np.round(ts * 1e9).astype(np.int64), position, quaternion, **fields
        )

    @classmethod
    def from_poses(cls, source: str, target: str, t_ns, poses, confidence=None, flags=None):
        """Build from a batch ``Pose`` (no covariance) or ``UncertainPose`` of shape (N,)."""
        if isinstance(poses, UncertainPose):
            cov = poses.covariance
        elif isinstance(poses, Pose):
            cov = None
        else:
            raise InputError(f"poses must be a Pose or UncertainPose, got {type(poses).__name__}")
        return cls(source, target, t_ns, poses.position, poses.quaternion, cov, confidence, flags)

    @classmethod
    def concatenate(cls, streams: Sequence[PoseStream]) -> PoseStream:
        """Join streams of the same relationship in time order (timestamps must keep increasing).

        All streams need the same ``source``/``target`` and either all or none a covariance.
        """
        streams = list(streams)
        if not streams:
            raise InputError("concatenate needs at least one stream")
        first = streams[0]
        for i, s in enumerate(streams):
            if not isinstance(s, PoseStream):
                raise InputError(f"item {i} is not a PoseStream but {type(s).__name__}")
            if (s.source, s.target) != (first.source, first.target):
                raise InputError(
                    f"cannot concatenate T_{s.source}_{s.target} (item {i}) "
                    f"with T_{first.source}_{first.target}"
                )
            if (s.covariance is None) != (first.covariance is None):
                raise InputError(f"item {i}: either all streams or none must carry a covariance")
        t = np.concatenate([s.t_ns for s in streams])
        if t.size > 1 and np.any(np.diff(t) <= 0):
            raise InputError(
                "concatenated timestamps are not strictly increasing (streams overlap)"
            )
        cov = None if first.covariance is None else np.concatenate([s.covariance for s in streams])
        return cls._trusted(
            first.source,
            first.target,
            t,
            np.concatenate([s.position for s in streams]),
            np.concatenate([s.quaternion for s in streams]),
            cov,
            np.concatenate([s.confidence for s in streams]),
            np.concatenate([s.flags for s in streams]),
        )

    def with_(self, **changes) -> PoseStream:
        """A validated copy with some fields replaced, e.g. ``s.with_(covariance=None)``.

        Accepted names: ``source, target, t_ns, position, quaternion, covariance, confidence,
        flags``. Replacing ``covariance`` keeps the flags unless ``flags`` is also given, except
        that ``covariance=None`` clears ``FLAG_COVARIANCE``.
        """
        names = ("source", "target", "t_ns", "position", "quaternion", "covariance")
        names += ("confidence", "flags")
        unknown = set(changes) - set(names)
        if unknown:
            raise InputError(f"unknown PoseStream field(s): {', '.join(sorted(unknown))}")
        fields = {k: getattr(self, k) for k in names}
        fields.update(changes)
        if "covariance" in changes and changes["covariance"] is None and "flags" not in changes:
            fields["flags"] = self.flags & ~FLAG_COVARIANCE
        return PoseStream(**fields)

    # -- attributes ---------------------------------------------------------------------------
    @property
    def source(self) -> str:
        """Name of frame ``source`` (the reference frame of the poses)."""
        return self._source

    @property
    def target(self) -> str:
        """Name of frame ``target`` (the tracked frame)."""
        return self._target

    @property
    def t_ns(self) -> np.ndarray:
        """Timestamps, int64 nanoseconds, shape (N,), strictly increasing."""
        return self._t

    @property
    def position(self) -> np.ndarray:
        """``t_source_target``, metres, shape (N, 3)."""
        return self._p

    @property
    def quaternion(self) -> np.ndarray:
        """``R_source_target`` as unit ``(x, y, z, w)``, shape (N, 4), signs as recorded."""
        return self._q

    @property
    def covariance(self) -> np.ndarray | None:
        """6x6 covariance of ``(dt, dtheta)`` per sample, shape (N, 6, 6), or ``None``."""
        return self._c

    @property
    def confidence(self) -> np.ndarray:
        """Existence probability per sample, shape (N,)."""
        return self._conf

    @property
    def flags(self) -> np.ndarray:
        """Validity bits per sample, uint32, shape (N,)."""
        return self._flags

    @property
    def times_s(self) -> np.ndarray:
        """Timestamps as float64 seconds on the same (absolute) epoch as ``t_ns``.

        Absolute Unix seconds resolve about 0.2 microseconds in float64; use :attr:`elapsed_s`
        for differences and plots, ``t_ns`` for exact arithmetic.
        """
        return self._t * 1e-9

    @property
    def elapsed_s(self) -> np.ndarray:
        """Seconds since the first sample (float64, exact to the nanosecond for hours)."""
        if not len(self):
            return np.zeros(0)
        return (self._t - self._t[0]) * 1e-9

    @property
    def duration_s(self) -> float:
        """Time from the first to the last sample in seconds (0 for fewer than two)."""
        return float((self._t[-1] - self._t[0]) * 1e-9) if len(self) > 1 else 0.0

    @property
    def poses(self) -> Pose:
        """The samples as a batch ``Pose`` of shape (N,)."""
        return Pose._trusted(self._p, self._q)

    @property
    def uncertain_poses(self) -> UncertainPose:
        """The samples with their covariance as a batch ``UncertainPose`` of shape (N,).

        Raises ``ValueError`` when the stream has no covariance.
        """
        if self._c is None:
            raise InputError(
                f"stream T_{self._source}_{self._target} has no covariance; "
                "use .poses or .with_(covariance=...)"
            )
        return UncertainPose._trusted(self._p, self._q, self._c)

    # -- container protocol -------------------------------------------------------------------
    def __len__(self) -> int:
        return int(self._t.shape[0])

    def __getitem__(self, index) -> PoseStream:
        if isinstance(index, (int, np.integer)):
            n = len(self)
            if not -n <= index < n:
                raise IndexError(f"index {index} out of range for stream of length {n}")
            index = slice(int(index) % n, int(index) % n + 1)
        elif not isinstance(index, slice):
            index = np.asarray(index)
            if index.dtype == bool:
                if index.shape != (len(self),):
                    raise IndexError(f"boolean mask must have shape ({len(self)},)")
            elif np.issubdtype(index.dtype, np.integer) and index.ndim == 1:
                if index.size > 1 and np.any(np.diff(index) <= 0):
                    raise IndexError("integer index arrays must be strictly increasing")
            else:
                raise IndexError(f"cannot index a PoseStream with {index!r}")
        elif index.step is not None and index.step <= 0:
            raise IndexError("slice step must be positive (streams stay in time order)")
        return PoseStream._trusted(
            self._source,
            self._target,
            self._t[index],
            self._p[index],
            self._q[index],
            None if self._c is None else self._c[index],
            self._conf[index],
            self._flags[index],
        )

    def time_slice(self, start_ns: int | None = None, stop_ns: int | None = None) -> PoseStream:
        """Samples with ``start_ns <= t_ns < stop_ns`` (either bound may be ``None``)."""
        i0 = 0 if start_ns is None else int(np.searchsorted(self._t, start_ns, "left"))
        i1 = len(self) if stop_ns is None else int(np.searchsorted(self._t, stop_ns, "left"))
        return self[i0:i1]

    def __eq__(self, other) -> bool:
        if not isinstance(other, PoseStream):
            return NotImplemented
        if (self._c is None) != (other._c is None):
            return False
        return (
            self._source == other._source
            and self._target == other._target
            and np.array_equal(self._t, other._t)
            and np.array_equal(self._p, other._p)
            and np.array_equal(self._q, other._q)
            and (self._c is None or np.array_equal(self._c, other._c))
            and np.array_equal(self._conf, other._conf)
            and np.array_equal(self._flags, other._flags)
        )

    __hash__ = None  # mutable-looking arrays inside: not hashable

    def __repr__(self) -> str:
        cov = "with covariance" if self._c is not None else "no covariance"
        if len(self):
            span = f", {self.duration_s:.3f} s from t_ns={int(self._t[0])}"
        else:
            span = ""
        return f"PoseStream(T_{self._source}_{self._target}, {len(self)} samples{span}, {cov})"
