"""Clock offset (and drift) between two pose streams of rigidly joined bodies.

Frame-independent: the coarse estimate cross-correlates the angular speeds of the two streams
(or their linear speeds when neither rotates enough) with
:func:`trackflow.timesync.correlation_offset`; the refinement fits the offset jointly with
the rotation ``R_a_b`` between the two body frames, using body angular velocities
``w_a(t) = R_a_b w_b(t - offset)``, and reports a standard error. Works on streams of different
rates and with gaps (samples inside gaps are left out).

Convention (:mod:`trackflow.timesync`, ``offset = host - remote`` with ``a`` the host): a sample
of stream ``b`` stamped ``s`` (b's clock) happened at ``s + offset_s`` on stream ``a``'s clock;
with drift, at ``s + offset_s + drift * (s - reference)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..io import PoseStream
from ..math import quat_exp, quat_from_matrix, quat_multiply, quat_to_matrix, skew, umeyama
from ..timesync import CorrelationOffset, correlation_offset
from ._lsq import robust_solve
from ._noise_sandwich import Stream, fit_noise, sandwich_covariance
from ._sampling import (
    Trajectory,
    body_rate_jacobians,
    body_rates,
    common_epoch_ns,
    speeds,
    trajectory,
)

__all__ = ["StreamClockOffset", "coarse_offset", "estimate_clock_offset"]

#: Angular-speed spread [rad/s] below which a stream counts as not rotating.
MIN_ANGULAR_STD = np.radians(2.0)
#: Linear-speed spread [m/s] below which a stream counts as not moving.
MIN_LINEAR_STD = 0.005
#: Half window [s] of the central differences that give the body rates of the refinement. The
#: offset that pose fusion needs is the delay of the poses; a tracker whose delay depends on
#: frequency (the Quest 2 reports predicted poses) shows a different delay in its fast
#: transients, which short differences emphasise. See docs/calibration.md.
RATE_HALF_WINDOW_S = 0.2


@dataclass(frozen=True)
class StreamClockOffset:
    """Result of :func:`estimate_clock_offset`.

    Attributes
    ----------
    offset_s, sigma_s : float
        Offset of b's clock to a's clock [s] (``t_a = t_b + offset_s``) and its standard error.
    drift, drift_sigma : float or None
        Relative clock rate difference [s/s] and its standard error when drift was estimated.
    reference_time_ns : int
        b's stamp at which the drift term is zero (middle of the overlap).
    coarse_offset_s : float
        The speed profiles' offset (:func:`~trackflow.timesync.correlation_offset`), before
        the refinement with the body rotation.
    peak_correlation : float
        Normalised correlation at the peak (1 = identical speed profiles).
    signal : str
        ``"angular"`` or ``"linear"`` speed used for the coarse search.
    quaternion_a_b : ndarray, shape (4,)
        Rotation from b's body frame into a's body frame found by the refinement (hand-eye
        rotation, ``(x, y, z, w)``); identity when the refinement used speeds only.
    lags_s, correlation : ndarray
        The correlation curve of the coarse search, for plots.
    residual_rad_s : float
        RMS of the refinement's angular-velocity residual.
    """

    offset_s: float
    sigma_s: float
    drift: float | None
    drift_sigma: float | None
    reference_time_ns: int
    coarse_offset_s: float
    peak_correlation: float
    signal: str
    quaternion_a_b: np.ndarray
    lags_s: np.ndarray
    correlation: np.ndarray
    residual_rad_s: float

    def as_dict(self) -> dict:
        return {
            "offset_s": self.offset_s,
            "offset_sigma_s": self.sigma_s,
            "drift": self.drift,
            "drift_sigma": self.drift_sigma,
            "reference_time_ns": self.reference_time_ns,
            "coarse_offset_s": self.coarse_offset_s,
            "peak_correlation": self.peak_correlation,
            "signal": self.signal,
            "quaternion_a_b": [float(v) for v in self.quaternion_a_b],
            "residual_rad_s": self.residual_rad_s,
        }


def _grid(a: Trajectory, b: Trajectory, step: float, max_offset_s: float) -> np.ndarray:
    lo, hi = max(a.t[0], b.t[0] - max_offset_s), min(a.t[-1], b.t[-1] + max_offset_s)
    if hi - lo < 4 * max(a.period_s, b.period_s):
        raise InputError(
            f"streams {a.name} and {b.name} do not overlap in time "
            f"(a: {a.t[0]:.3f}..{a.t[-1]:.3f} s, b: {b.t[0]:.3f}..{b.t[-1]:.3f} s "
            f"from the common epoch, searching offsets up to {max_offset_s} s)"
        )
    return np.arange(lo, hi, step)


def coarse_offset(
    a: Trajectory, b: Trajectory, max_offset_s: float = 1.0, signal: str = "auto"
) -> tuple[CorrelationOffset, str]:
    """Offset of the speed profiles (:func:`trackflow.timesync.correlation_offset`, ``a`` the
    host, ``b`` the remote) and the signal used (``"angular"`` or ``"linear"``).

    Raises ``ValueError`` when neither stream moves, or the profiles do not correlate.
    """
    slow = max(a.period_s, b.period_s)
    step = slow / 2
    hw = slow
    grid = _grid(a, b, step, max_offset_s)
    wa, va, oka = speeds(a, grid, hw)
    stats = {}
    for nm, tr in (("a", a), ("b", b)):
        w, v, ok = speeds(tr, tr.t[(tr.t > tr.t[0] + hw) & (tr.t < tr.t[-1] - hw)], hw)
        stats[nm] = (np.std(w[ok]) if ok.any() else 0.0, np.std(v[ok]) if ok.any() else 0.0)
    rotates = all(s[0] >= MIN_ANGULAR_STD for s in stats.values())
    moves = all(s[1] >= MIN_LINEAR_STD for s in stats.values())
    if signal == "auto":
        signal = "angular" if rotates else "linear"
    if signal not in ("angular", "linear"):
        raise InputError(f"signal must be 'auto', 'angular' or 'linear', got {signal!r}")
    if (signal == "angular" and not rotates) or (signal == "linear" and not moves):
        raise InputError(
            "no motion to find a clock offset from: angular-speed spread "
            f"{np.degrees(stats['a'][0]):.2f} / {np.degrees(stats['b'][0]):.2f} deg/s and "
            f"linear-speed spread {stats['a'][1] * 1e3:.1f} / {stats['b'][1] * 1e3:.1f} mm/s "
            f"(a / b); need {np.degrees(MIN_ANGULAR_STD):.0f} deg/s or "
            f"{MIN_LINEAR_STD * 1e3:.0f} mm/s in both streams"
        )
    sa = wa if signal == "angular" else va
    gb = np.arange(b.t[0], b.t[-1], step)
    wb, vb, okb = speeds(b, gb, hw)
    sb = wb if signal == "angular" else vb
    try:
        r = correlation_offset(
            grid, np.where(oka, sa, np.nan), gb, np.where(okb, sb, np.nan),
            max_offset_s=max_offset_s, step_s=step, correlation_time_s=2 * hw,
        )  # fmt: skip
    except ValueError as e:
        raise InputError(f"the {signal} speeds of {a.name} and {b.name}: {e}") from e
    return r, signal


def _rate_covariance(fun, sol, ta, tb, grid, hw, t_ref, drift) -> np.ndarray:
    """Sandwich covariance of the rate fit ``w_a(t) = R w_b(s)`` over the streams' samples."""
    x = sol.x
    d = x[5] if drift else 0.0
    s = (grid - x[4] + d * t_ref) / (1.0 + d)
    G_a, i_a = body_rate_jacobians(ta, grid, hw)
    G_own, i_own = body_rate_jacobians(tb, tb.t, hw)  # b's rates at its samples, interpolated
    m = np.clip(np.searchsorted(tb.t, s, side="right") - 1, 0, len(tb.t) - 2)
    u = np.clip((s - tb.t[m]) / (tb.t[m + 1] - tb.t[m]), 0.0, 1.0)[:, None, None, None]
    G_b = np.concatenate([(1 - u) * G_own[m], u * G_own[m + 1]], axis=1)
    G_b = -np.einsum("ij,kqjc->kqic", quat_to_matrix(x[:4]), G_b)
    i_b = np.concatenate([i_own[m], i_own[m + 1]], axis=1)
    r, J = fun(x)
    k = sol.inliers & np.all(np.isfinite(r), axis=1)
    slow = max(ta.period_s, tb.period_s)
    streams = [
        Stream(G_a[k], i_a[k], ta.t / slow),
        Stream(G_b[k], i_b[k], tb.t / slow),
    ]
    rows = ((0, 1, 2),)
    # cross products up to a few windows apart tell whether the errors are correlated in time
    lags = (0, 1, 2, 4, 8, 16, 32, 64, 128)
    noise = fit_noise(r[k], streams, rows, rows, lags)
    return sandwich_covariance(J[k], sol.sigma**-2, streams, noise)


def estimate_clock_offset(
    a: PoseStream,
    b: PoseStream,
    *,
    max_offset_s: float = 1.0,
    drift: bool = False,
    signal: str = "auto",
    refine: bool = True,
    rate_half_window_s: float = RATE_HALF_WINDOW_S,
) -> StreamClockOffset:
    """Offset (and optionally drift) of ``b``'s clock relative to ``a``'s, with standard error.

    Parameters
    ----------
    a, b : PoseStream
        Two streams of rigidly joined bodies (any world frames, any rates, gaps allowed).
    max_offset_s : float
        Search range of the coarse cross-correlation, seconds.
    drift : bool
        Also estimate a linear clock drift (s/s).
    signal : {"auto", "angular", "linear"}
        Speed profile for the coarse search; auto takes angular speed when both streams rotate.
    refine : bool
        Refine jointly with the body rotation (False: the speed profiles' offset and its
        standard error).
    rate_half_window_s : float
        Half window [s] of the central differences for the refinement's body rates (at least
        the slower stream's sample period): rates averaged over ``2 rate_half_window_s``
        weigh the motion in the band where the poses carry it, so the offset matches the
        pose-based one of :func:`~trackflow.calibration.solve_hand_eye` on trackers whose
        delay depends on frequency.

    Raises
    ------
    ValueError
        No overlap, no motion, no correlation, or a peak at the edge of the search range.
    """
    epoch = common_epoch_ns(a, b)
    ta, tb = trajectory(a, epoch, "a"), trajectory(b, epoch, "b")
    coarse, sig = coarse_offset(ta, tb, max_offset_s, signal)
    off0, peak, lags, corr = coarse.offset_s, coarse.peak, coarse.lags_s, coarse.correlation
    slow = max(ta.period_s, tb.period_s)
    hw = max(slow, float(rate_half_window_s))
    # Refinement on a grid at the slower stream's rate, inside the overlap.
    lo, hi = max(ta.t[0], tb.t[0] + off0) + 3 * slow, min(ta.t[-1], tb.t[-1] + off0) - 3 * slow
    grid = np.arange(lo, hi, slow)
    t_ref = 0.5 * (lo + hi) - off0  # in b's clock
    wa, oka = body_rates(ta, grid, hw)
    if sig == "linear" or not refine:
        return StreamClockOffset(
            off0, coarse.sigma_s, None, None, epoch + int(round(t_ref * 1e9)),
            off0, peak, sig, np.array([0.0, 0.0, 0.0, 1.0]), lags, corr, float("nan"),
        )  # fmt: skip
    wb0, okb0 = body_rates(tb, grid - off0, hw)
    ok0 = oka & okb0
    R0 = umeyama(wa[ok0], wb0[ok0], with_translation=False, allow_collinear=True).rotation
    axes = np.linalg.svd(wb0[ok0] / max(np.abs(wb0[ok0]).max(), 1e-12), compute_uv=False)
    full = axes[1] > 0.05 * axes[0]

    # b's smoothed rates at its own samples, then linear interpolation: a smooth objective in
    # the offset (interpolating noisy orientations first would make it wiggle at the sample
    # scale) and cheap to evaluate.
    wb_s, okb_s = body_rates(tb, tb.t, hw)
    ab_s = np.gradient(wb_s, tb.t, axis=0)

    def rates_b(s):
        wb = np.stack([np.interp(s, tb.t, wb_s[:, k]) for k in range(3)], axis=1)
        ab = np.stack([np.interp(s, tb.t, ab_s[:, k]) for k in range(3)], axis=1)
        ok = np.interp(s, tb.t, okb_s.astype(float), left=0.0, right=0.0) > 0.999
        return wb, ab, ok

    def fun(x):
        R = quat_to_matrix(x[:4])
        off = x[4]
        d = x[5] if drift else 0.0
        s = (grid - off + d * t_ref) / (1.0 + d)
        wb, alpha, okb = rates_b(s)
        if full:
            pred = wb @ R.T
            r = wa - pred
            J_rot = np.einsum("ij,njk->nik", R, skew(wb))
            J_off = (alpha @ R.T)[:, :, None]
        else:
            na, nb = np.linalg.norm(wa, axis=1), np.linalg.norm(wb, axis=1)
            r = (na - nb)[:, None]
            J_rot = np.zeros((len(grid), 1, 3))
            u = wb / np.maximum(nb, 1e-12)[:, None]
            J_off = np.einsum("ni,ni->n", u, alpha)[:, None, None]
        ds_dd = (t_ref - s) / (1.0 + d)
        J = [J_rot, J_off]
        if drift:
            J.append(-J_off * ds_dd[:, None, None])
        r = np.where((oka & okb)[:, None], r, np.nan)
        return r, np.concatenate(J, axis=2)

    def update(x, dx):
        q = quat_multiply(x[:4], quat_exp(dx[:3]))
        return np.concatenate([q / np.linalg.norm(q), x[4:] + dx[3:]])

    x0 = np.concatenate([quat_from_matrix(R0), [off0], [0.0] if drift else []])
    nb = 3 if full else 1
    sol = robust_solve(
        fun, x0, np.full(nb, np.radians(5.0)), update=update, groups=(tuple(range(nb)),)
    )
    # The rates are differences of poses over +-hw: neighbouring residuals share samples, so
    # the covariance is the sandwich over the samples' rotation errors (_noise_sandwich).
    cov = _rate_covariance(fun, sol, ta, tb, grid, hw, t_ref, drift) if full else sol.cov
    return StreamClockOffset(
        offset_s=float(sol.x[4]),
        sigma_s=float(np.sqrt(cov[3, 3])),
        drift=float(sol.x[5]) if drift else None,
        drift_sigma=float(np.sqrt(cov[4, 4])) if drift else None,
        reference_time_ns=epoch + int(round(t_ref * 1e9)),
        coarse_offset_s=off0,
        peak_correlation=peak,
        signal=sig,
        quaternion_a_b=sol.x[:4] if full else np.array([0.0, 0.0, 0.0, 1.0]),
        lags_s=lags,
        correlation=corr,
        residual_rad_s=float(np.sqrt(np.mean(sol.residuals[sol.inliers] ** 2))),
    )
