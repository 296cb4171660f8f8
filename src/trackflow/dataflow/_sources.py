"""Source components: recording player, simulated sensor and static pose."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np

from ..errors import InputError
from ..math import Pose, UncertainPose, quat_exp, quat_multiply
from ..scheduler import TimedSource
from ._component import Component
from ._events import Measurement

__all__ = ["BACKLOG_NS", "RecordingPlayer", "PlayerSource", "SimulatedSensor", "StaticPose",
           "NO_ORIGIN"]  # fmt: skip

#: ``origin_ns`` of data that never came from a sensor (static calibrations).
NO_ORIGIN = -(2**62)
#: a live measurement (a tracker's sample, another agent's filter state) older than this when
#: it arrives is dropped and counted, not replayed: the backlog a stalled sender flushes when
#: it continues is of no use to any answer and would only hold the fresh data back [ns]
BACKLOG_NS = 500_000_000


class RecordingPlayer(Component):
    """Plays recorded measurements of one edge into the network (push output).

    Each sample is delivered at its arrival time ``t_ns + latency_ns`` on the network clock.
    Samples are checked one by one as they are played: a non-finite or non-unit pose or
    covariance, and a timestamp not after the previous accepted one ("timestamp backwards"),
    are counted rejections and never reach the network.

    Parameters
    ----------
    name : str
    t_ns : array_like of int (N,)
        Sensor timestamps [ns] (as the sensor stamped them, offset included).
    position : array_like (N, 3)
        ``t_a_b`` [m].
    quaternion : array_like (N, 4)
        ``R_a_b`` as ``(x, y, z, w)``.
    covariance : array_like (N, 6, 6) or (6, 6)
        Measurement covariance over ``(dt, dtheta)``, ``t_true = t + dt``,
        ``R_true = R Exp(dtheta)``.
    latency_ns : int
        Delay from sensor timestamp to availability in the network [ns].
    """

    push_out = True
    kind = "player"

    def __init__(self, name, t_ns, position, quaternion, covariance, latency_ns: int = 0):
        super().__init__(name)
        self.t_ns = np.asarray(t_ns)
        if self.t_ns.ndim != 1 or not np.issubdtype(self.t_ns.dtype, np.integer):
            raise InputError(f"player {name!r}: t_ns must be a 1-D integer array [ns]")
        n = len(self.t_ns)
        self.position = np.asarray(position, dtype=float).reshape(n, 3)
        self.quaternion = np.asarray(quaternion, dtype=float).reshape(n, 4)
        cov = np.asarray(covariance, dtype=float)
        self.covariance = np.broadcast_to(cov, (n, 6, 6)) if cov.shape == (6, 6) else cov
        if self.covariance.shape != (n, 6, 6):
            raise InputError(f"player {name!r}: covariance must be (6, 6) or ({n}, 6, 6)")
        self.latency_ns = int(latency_ns)
        if self.latency_ns < 0:
            raise InputError(f"player {name!r}: latency must be >= 0")
        self._prepare()
        self.reset()

    def _prepare(self) -> None:
        """Check every sample once, vectorised, and keep what :meth:`deliver` needs: the
        reason a sample is rejected (or ``None``), and arrays of the valid values
        (quaternions normalised, covariances exactly symmetric), so that delivering a sample
        builds its pose without re-validating it."""
        p, q, c = self.position, self.quaternion, self.covariance
        n = len(p)
        one = c.shape == (n, 6, 6) and n > 0 and c.strides[0] == 0  # one broadcast matrix
        cs = c[:1] if one else c
        finite_c = np.isfinite(cs).all(axis=(1, 2))
        ok_c = np.zeros(len(cs), dtype=bool)
        sym = np.zeros_like(cs)
        if finite_c.any():
            # the tolerances of trackflow.math.check_covariance, on the whole batch at once
            cf = cs[finite_c]
            ct = np.swapaxes(cf, 1, 2)
            scale = np.maximum(np.abs(cf).max(axis=(1, 2)), 1e-300)
            symmetric = np.abs(cf - ct).max(axis=(1, 2)) <= 1e-9 * scale
            cf = 0.5 * (cf + ct)
            eig = np.linalg.eigvalsh(cf)
            psd = eig[:, 0] >= -1e-12 * np.maximum(eig[:, -1], 1e-300)
            ok_c[finite_c] = symmetric & psd
            sym[finite_c] = cf
        if one:
            ok_c = np.broadcast_to(ok_c, (n,))
        finite = (
            np.isfinite(p).all(axis=1)
            & np.isfinite(q).all(axis=1)
            & np.isfinite(c).all(axis=(1, 2))
        )
        with np.errstate(invalid="ignore", divide="ignore"):
            qq = np.einsum("ij,ij->i", q, q)
            unit = np.abs(qq - 1.0) <= 1e-5
            # unit to rounding: used as is (normalising again would change the last bit, and a
            # recorded-then-replayed stream must give the same poses)
            exact = np.abs(qq - 1.0) <= 1e-12
            qn = np.where(exact[:, None], q, q / np.sqrt(qq)[:, None])
        reason = np.full(n, None, dtype=object)
        reason[~ok_c] = "invalid covariance"
        reason[~unit] = "non-unit quaternion"
        reason[~finite] = "non-finite pose"
        self._reason = reason.tolist()
        # C-contiguous writable float64 rows, the one layout the compiled kernels expect; the
        # poses share them (nothing downstream writes into a pose's arrays)
        self._p = np.array(p, dtype=float, order="C")
        self._q = np.ascontiguousarray(qn, dtype=float)
        self._c = np.ascontiguousarray(sym, dtype=float)
        self._c_one = self._c[0] if one else None

    @classmethod
    def from_stream(cls, name: str, stream, latency_ns: int = 0, covariance=None):
        """Play a :class:`trackflow.io.PoseStream`; ``covariance`` (6x6) replaces a missing
        one."""
        cov = stream.covariance
        if cov is None:
            if covariance is None:
                raise InputError(f"player {name!r}: the stream has no covariance; pass one")
            cov = covariance
        return cls(name, stream.t_ns, stream.position, stream.quaternion, cov, latency_ns)

    def arrivals(self) -> np.ndarray:
        """Arrival time [ns] of every sample: ``t_ns + latency_ns``, but never before the
        previous sample's arrival - a recording is played in file order, so a timestamp that
        goes backwards arrives (and is rejected) where it stands."""
        return np.maximum.accumulate(self.t_ns + self.latency_ns) if len(self.t_ns) else self.t_ns

    def events(self) -> Iterator[tuple[int, int]]:
        """``(arrival_ns, index)`` of every sample in file order."""
        for i, a in enumerate(self.arrivals()):
            yield int(a), i

    def reset(self) -> None:
        super().reset()
        self._last_t: int | None = None

    def deliver(self, index: int) -> None:
        """Push sample ``index`` (or count why not: checks made once in the constructor)."""
        self.stats.events_in += 1
        why = self._reason[index]
        if why is not None:
            self.stats.reject(why)
            return
        t = int(self.t_ns[index])
        if self._last_t is not None and t <= self._last_t:
            self.stats.reject("timestamp backwards")
            return
        self._last_t = t
        c = self._c_one if self._c_one is not None else self._c[index]
        pose = UncertainPose._trusted(self._p[index], self._q[index], c)
        self.emit(Measurement(t, pose, t))


class SimulatedSensor(RecordingPlayer):
    """A sensor simulated from a ground-truth motion, played like a recording.

    Samples are taken every ``1 / rate_hz`` seconds from ``start_s`` to ``end_s``; each is the
    truth at its time with Gaussian noise ``dt ~ N(0, sigma_p^2 I)``,
    ``dtheta ~ N(0, diag(sigma_o^2))`` applied as ``t + dt``, ``R Exp(dtheta)`` (the library's
    error convention, so the reported covariance ``diag(sigma_p^2, sigma_o^2)`` is exact).
    With probability ``outlier_rate`` a sample is a wrong detection: a pose off by
    ``outlier_pos_m`` and ``outlier_ori_rad`` in random directions, reported with the usual
    covariance. The timestamp written is ``true time + stamp_offset_s``; the sample becomes
    available at ``true time + latency_s``.

    Parameters
    ----------
    truth : callable
        ``truth(t_s: ndarray (N,)) -> Pose`` of batch shape (N,), the true ``T_a_b``.
    rng : numpy.random.Generator
        Source of all noise (no global RNG).
    sigma_ori : float or array_like (3,)
        Per-axis rotation noise [rad] (in frame b).
    """

    kind = "sensor"

    def __init__(
        self,
        name: str,
        truth: Callable[[np.ndarray], Pose],
        *,
        rate_hz: float,
        latency_s: float,
        sigma_pos: float,
        sigma_ori,
        rng: np.random.Generator,
        start_s: float,
        end_s: float,
        stamp_offset_s: float = 0.0,
        outlier_rate: float = 0.0,
        outlier_pos_m: float = 0.1,
        outlier_ori_rad: float = 0.3,
    ):
        if not rate_hz > 0 or not end_s > start_s:
            raise InputError(f"sensor {name!r}: need rate_hz > 0 and end_s > start_s")
        if not isinstance(rng, np.random.Generator):
            raise InputError(f"sensor {name!r}: rng must be a numpy Generator")
        n = int(np.floor((end_s - start_s) * rate_hz)) + 1
        t_true = start_s + np.arange(n) / rate_hz
        true = truth(t_true)
        so = np.broadcast_to(np.asarray(sigma_ori, dtype=float), (3,))
        dp = rng.normal(0.0, sigma_pos, (n, 3))
        dth = rng.normal(0.0, 1.0, (n, 3)) * so
        pos = true.position + dp
        quat = quat_multiply(true.quaternion, quat_exp(dth))
        self.outliers = rng.random(n) < outlier_rate
        k = int(self.outliers.sum())
        if k:
            dirs = rng.normal(size=(k, 3))
            dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
            axes = rng.normal(size=(k, 3))
            axes /= np.linalg.norm(axes, axis=1, keepdims=True)
            pos[self.outliers] = true.position[self.outliers] + outlier_pos_m * dirs
            quat[self.outliers] = quat_multiply(
                true.quaternion[self.outliers], quat_exp(outlier_ori_rad * axes)
            )
        cov = np.diag(np.concatenate([np.full(3, sigma_pos**2), so**2]))
        stamps = np.round((t_true + stamp_offset_s) * 1e9).astype(np.int64)
        latency_ns = int(round((latency_s - stamp_offset_s) * 1e9))
        if latency_ns < 0:
            raise InputError(f"sensor {name!r}: the stamp offset exceeds the latency")
        super().__init__(name, stamps, pos, quat, cov, latency_ns)
        self.t_true_s = t_true


class StaticPose(Component):
    """A calibrated static relationship: ``pull(t)`` returns it for any ``t``."""

    pull_out = True
    kind = "static"

    def __init__(self, name: str, value: UncertainPose):
        super().__init__(name)
        if not isinstance(value, UncertainPose) or value.shape != ():
            raise InputError(f"static {name!r}: value must be one UncertainPose")
        self.value = value

    def pull(self, t_ns: int) -> Measurement:
        self.stats.events_out += 1
        return Measurement(int(t_ns), self.value, NO_ORIGIN)


class PlayerSource(TimedSource):
    """A :class:`RecordingPlayer` as a scheduler's event source: each sample at its arrival
    time, up to ``end_ns``.

    Samples arriving before ``skip_before_ns`` (a process started late into its recording)
    are skipped and counted in :attr:`skipped`; :attr:`played` is the number of samples
    played or skipped so far.
    """

    def __init__(self, player: RecordingPlayer, end_ns: int | None = None, skip_before_ns=None):
        self.player = player
        self.name = player.name
        self.end_ns = end_ns
        self.arrivals = player.arrivals()
        self.played = 0
        self.skipped = 0
        if skip_before_ns is not None:
            self.skipped = self.played = int(np.searchsorted(self.arrivals, skip_before_ns))

    def next_ns(self) -> int | None:
        k = self.played
        if k >= len(self.arrivals):
            return None
        t = int(self.arrivals[k])
        return None if self.end_ns is not None and t > self.end_ns else t

    def fire(self, t_ns: int) -> None:
        k = self.played
        self.played = k + 1
        self.player.deliver(k)
