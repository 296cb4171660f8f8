"""Reusing a hand-eye calibration in another session: X kept, the world and the clock refitted
(``refit_calibration``; the command line's ``--use --refit world`` is in test_fragments.py, the
alignment's lever arm in test_align_noise_pivot.py, the motion-pair residual in
test_hand_eye.py)."""

from __future__ import annotations

import numpy as np
import pytest
from _synth import X_TRUE, Z_TRUE, two_trackers
from scipy import stats

from trackflow.calibration import (
    REFIT_CHOICES,
    align_trajectories,
    evaluate_hand_eye,
    refit_calibration,
    solve_hand_eye,
)
from trackflow.math import (
    Pose,
    UncertainPose,
    quat_conjugate,
    quat_exp,
    quat_log,
    quat_multiply,
)

#: Another session's world: the headset re-created its origin 0.3 m and 40 deg away.
Z_OTHER = (Z_TRUE[0] + np.array([0.2, -0.15, 0.15]), quat_multiply(Z_TRUE[1], quat_exp(
    np.radians([10.0, -25.0, 30.0]))))  # fmt: skip


def _err(est, true):
    """Error in the conventions: t_true = t + dt, R_true = R Exp(dtheta)."""
    dt = true[0] - est.position
    return np.concatenate([dt, quat_log(quat_multiply(quat_conjugate(est.quaternion), true[1]))])


def _X(position, quaternion, cov=None):
    return UncertainPose(Pose(position, quaternion), np.zeros((6, 6)) if cov is None else cov)


def test_refit_world_recovers_the_new_sessions_world_and_offset():
    a1, b1 = two_trackers(1, duration=20.0, offset=0.25)
    a2, b2 = two_trackers(2, duration=20.0, offset=0.17, Z=Z_OTHER)
    stored = solve_hand_eye(a1, b1)
    # the stored world does not fit the new session; X still does
    ev = evaluate_hand_eye(a2, b2, stored.X.pose, stored.Z.pose, stored.offset_s)
    assert ev["residual_pos_mm"] > 50.0
    r = refit_calibration(a2, b2, stored.X)
    assert r.form == "refit-world"
    np.testing.assert_array_equal(r.X.position, stored.X.position)
    np.testing.assert_array_equal(r.X.covariance, stored.X.covariance)
    # Z within its covariance (which carries X's), the offset to a tenth of the slower period
    e = _err(r.Z, Z_OTHER)
    assert e @ np.linalg.solve(r.Z.covariance, e) < stats.chi2.ppf(0.999, 6), e
    assert abs(r.offset_s - 0.17) < 0.1 / 30.0
    assert abs(r.offset_s - 0.17) < 4 * r.offset_sigma_s + 1e-4
    # the same measures as the new session's own calibration, within 1.3 times
    own = solve_hand_eye(a2, b2)
    for key in ("residual_pos_mm", "residual_ori_deg", "pair_residual_pos_mm",
                "pair_residual_ori_deg"):  # fmt: skip
        assert getattr(r, key) <= 1.3 * getattr(own, key), (key, getattr(r, key), getattr(own, key))
    assert r.n_pairs > 100
    # joint covariance over (X, Z, offset): symmetric, positive definite, X block as stored
    assert r.covariance.shape == (13, 13)
    np.testing.assert_allclose(r.covariance, r.covariance.T, rtol=0, atol=1e-15)
    assert np.linalg.eigvalsh(r.covariance).min() > 0
    np.testing.assert_array_equal(r.covariance[:6, :6], stored.X.covariance)
    np.testing.assert_allclose(r.covariance[6:12, 6:12], r.Z.covariance)


@pytest.mark.slow
def test_refit_world_covariance_carries_the_stored_X_uncertainty():
    """X off by draws of its own covariance (0.3 mm, 0.3 deg; the streams' noise is 0.5 mm):
    the NEES of (Z, offset) is in the band (5.7 of 7) only because X's translation covariance
    is propagated (without it: 78). Larger X errors make it conservative (1 mm: 3.5, 3 mm:
    3.0): the part of X's error that Z cannot absorb also inflates the alignment's own
    residual-based covariance."""
    runs = 10
    C_X = np.diag([0.3e-3**2] * 3 + [np.radians(0.3) ** 2] * 3)
    L = np.linalg.cholesky(C_X)
    rng = np.random.default_rng(7)
    nees, nees_without = [], []
    for seed in range(runs):
        a, b = two_trackers(20 + seed, duration=20.0, offset=0.2, Z=Z_OTHER)
        d = L @ rng.normal(size=6)
        # X_true = X_stored (+) d: the stored X has error d in the conventions
        Xp = X_TRUE[0] - d[:3]
        Xq = quat_multiply(X_TRUE[1], quat_exp(-d[3:]))
        r = refit_calibration(a, b, _X(Xp, Xq, C_X))  # the offset refitted too
        e = np.r_[_err(r.Z, Z_OTHER), 0.2 - r.offset_s]
        nees.append(e @ np.linalg.solve(r.covariance[6:, 6:], e))
        bare = align_trajectories(a, b, lever_arm=Xp)
        nees_without.append(e @ np.linalg.solve(bare.covariance, e))
    lo, hi = stats.chi2.ppf([0.025, 0.975], 7 * runs) / runs
    assert lo <= np.mean(nees) <= hi, (np.mean(nees), lo, hi)
    assert np.mean(nees_without) > 3 * hi, np.mean(nees_without)


def test_other_refit_values_are_refused_with_the_allowed_ones():
    a, b = two_trackers(3, duration=10.0)
    X = _X(*X_TRUE)
    assert REFIT_CHOICES == ("world",)
    for bad in ("X", "offset", "all", ""):
        with pytest.raises(ValueError, match=r"cannot refit .*allowed: 'world'"):
            refit_calibration(a, b, X, refit=bad)
    with pytest.raises(ValueError, match="needs offset_s"):
        refit_calibration(a, b, X, estimate_offset=False)
