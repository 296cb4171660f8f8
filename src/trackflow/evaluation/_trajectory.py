"""The PoseTool's input: a recording checked once, at the boundary, into one typed value."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..io import PoseStream
from ..math import UncertainPose, check_trajectory
from ._targets import default_gap, interpolate_poses, scored_mask

__all__ = ["Trajectory"]


@dataclass(frozen=True)
class Trajectory:
    """A checked recording ``T_a_b``: what every PoseTool step (tuning, prediction, scoring)
    takes, so the times are validated, the gap threshold chosen and the scoring masks and
    targets computed once per recording instead of once per step.

    Build it with :meth:`check` (or :meth:`from_stream`); the constructor trusts its input.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Strictly increasing, finite times [s].
    position : ndarray, shape (N, 3)
        Finite positions of ``T_a_b`` [m].
    quaternion : ndarray, shape (N, 4)
        Finite orientations of ``T_a_b`` ``(x, y, z, w)``.
    gap_s : float
        Sample intervals longer than this [s] are gaps: filters restart after them and targets
        across them are not scored (``inf``: none).
    """

    t: np.ndarray
    position: np.ndarray
    quaternion: np.ndarray
    gap_s: float
    _memo: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @classmethod
    def check(cls, t, position, quaternion, gap_s: float | None = None) -> Trajectory:
        """Validate arrays into a :class:`Trajectory` (the one boundary check).

        Parameters
        ----------
        t, position, quaternion : array_like, shapes (N,), (N, 3), (N, 4)
            Times [s], positions [m], quaternions ``(x, y, z, w)``; N >= 4.
        gap_s : float, optional
            Default :func:`default_gap` (three median sample intervals).

        Raises
        ------
        ValueError
            Wrong shapes, fewer than 4 samples, non-finite values, times not strictly
            increasing (naming the sample), or a gap threshold that is not > 0.
        """
        t, p, q = check_trajectory(t, position, quaternion, min_samples=4, what="the recording")
        gap = default_gap(t) if gap_s is None else float(gap_s)
        if not gap > 0:
            raise InputError(f"gap_s must be > 0, got {gap_s!r}")
        return cls(t, p, q, gap)

    @classmethod
    def from_stream(cls, stream: PoseStream, gap_s: float | None = None) -> Trajectory:
        """:meth:`check` of a stream, times relative to its first sample [s]."""
        t = (stream.t_ns - stream.t_ns[0]).astype(np.float64) * 1e-9
        return cls.check(t, stream.position, stream.quaternion, gap_s)

    def select(self, rows) -> Trajectory:
        """The samples ``rows`` (bool mask or slice), same gap threshold (no re-check: a
        subsequence of a checked recording is one)."""
        return Trajectory(self.t[rows], self.position[rows], self.quaternion[rows], self.gap_s)

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def _cached(self, key, make):
        if key not in self._memo:
            self._memo[key] = make()
        return self._memo[key]

    @property
    def step(self) -> float:
        """Median sample interval [s]."""
        return self._cached("step", lambda: float(np.median(np.diff(self.t))))

    @property
    def max_gap(self) -> float | None:
        """The filters' restart threshold: :attr:`gap_s`, or ``None`` (never) for ``inf``."""
        return self.gap_s if np.isfinite(self.gap_s) else None

    @property
    def n_gaps(self) -> int:
        """Number of sample intervals longer than :attr:`gap_s`."""
        return int(np.count_nonzero(np.diff(self.t) > self.gap_s))

    def scored(self, horizon: float) -> np.ndarray:
        """Samples with a trustworthy target ``horizon`` [s] ahead (:func:`scored_mask`), (N,)."""
        return self._cached(("scored", float(horizon)),
                            lambda: scored_mask(self.t, horizon, self.gap_s))  # fmt: skip

    def target(self, horizon: float) -> tuple[np.ndarray, np.ndarray]:
        """The recording interpolated ``horizon`` [s] after every sample
        (:func:`interpolate_poses`): positions (N, 3), quaternions (N, 4)."""
        return self._cached(
            ("target", float(horizon)),
            lambda: interpolate_poses(self.t, self.position, self.quaternion, self.t + horizon),
        )

    def measurements(self, covariance: np.ndarray) -> UncertainPose:
        """The samples as filter input, each with the 6x6 ``covariance`` over ``(dt, dtheta)``
        (frame a [m], body frame [rad]); (N,) poses."""
        c = np.asarray(covariance, dtype=float)
        return self._cached(("measurements", c.tobytes()), lambda: UncertainPose._trusted(
            self.position, self.quaternion,
            np.ascontiguousarray(np.broadcast_to(c, (len(self), 6, 6))),
        ))  # fmt: skip
