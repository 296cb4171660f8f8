"""DTrack ASCII: golden datagrams, exact round trips, midnight roll-over, 6dcov conversion."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow.math import quat_conjugate, quat_log, quat_multiply, quat_to_matrix
from trackflow.trackers import PacketError
from trackflow.trackers.dtrack import (
    DayUnwrapper,
    DTrackBody,
    DTrackCovariance,
    DTrackFrame,
    decode_dtrack,
    dtrack_covariance,
    dtrack_pose,
    encode_dtrack,
)

# Written by hand from the DTrack2 manual's line formats: body 3 rotated +90 deg about z
# (matrix column-wise on the wire: first column (0, 1, 0)), body 5 not tracked (dummy
# zeros), one 6dcov, one marker, one hybrid body and a line this decoder does not know
# (6dj, the ART-Human model). Flysticks, tools, hands and status: test_dtrack_devices.py.
GOLDEN = (
    b"fr 21753\r\n"
    b"ts 86399.995000\r\n"
    b"ts2 1712345678 250000 4200\r\n"
    b"6dcal 6\r\n"
    b"6d 2 [3 1.000][100.000 -200.500 1500.250 0.0000 0.0000 90.0000]"
    b"[0.000000 1.000000 0.000000 -1.000000 0.000000 0.000000 0.000000 0.000000 1.000000]"
    b" [5 -1.000][0.000 0.000 0.000 0.0000 0.0000 0.0000]"
    b"[0.000000 0.000000 0.000000 0.000000 0.000000 0.000000 0.000000 0.000000 0.000000]\r\n"
    b"6dcov 1 [3 10.000 0.000 -5.000][0.250000000 0.010000000 0.000000000 0.000000000 "
    b"0.000000000 0.000000000 0.360000000 0.000000000 0.000000000 0.000000000 0.000000000 "
    b"0.490000000 0.000000000 0.000000000 0.000000000 0.000001000 0.000000000 0.000000000 "
    b"0.000002000 0.000000000 0.000003000]\r\n"
    b"3d 1 [84 1.000][270.980 -195.843 222.058]\r\n"
    b"6di 1 [0 2 0.125][1.000 2.000 3.000]"
    b"[1.000000 0.000000 0.000000 0.000000 1.000000 0.000000 0.000000 0.000000 1.000000]\r\n"
    b"6dj 1 0\r\n"
)


def test_golden_decodes_every_field():
    f = decode_dtrack(GOLDEN)
    assert f.frame == 21753 and f.ts == 86399.995 and f.ts2 == (1712345678, 250000, 4200)
    assert f.calibrated == 6 and f.skipped == ("6dj",)
    b3 = f.body(3)
    assert b3.position_mm == (100.0, -200.5, 1500.25)
    # column-wise on the wire -> rows: R = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    assert b3.rotation == (0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0)
    p, q = dtrack_pose(b3)
    np.testing.assert_allclose(p, [0.1, -0.2005, 1.50025])
    np.testing.assert_allclose(q, [0, 0, np.sqrt(0.5), np.sqrt(0.5)], atol=1e-12)
    assert f.body(5).quality == -1.0
    c = f.covariance(3)
    assert c.reference_mm == (10.0, 0.0, -5.0)
    m = np.array(c.matrix).reshape(6, 6)
    assert m[0, 1] == m[1, 0] == 0.01 and m[2, 2] == 0.49 and m[5, 5] == 3e-6
    assert f.markers[0].id == 84 and f.markers[0].position_mm == (270.98, -195.843, 222.058)
    assert f.inertial[0].state == 2 and f.inertial[0].error_deg == 0.125


def test_golden_round_trips_bytes():
    f = decode_dtrack(GOLDEN)
    # the encoder writes exactly the golden text (minus the unknown line it never knew)
    assert encode_dtrack(f) == GOLDEN.replace(b"6dj 1 0\r\n", b"")


def test_not_tracked_is_never_a_pose():
    f = decode_dtrack(GOLDEN)
    with pytest.raises(PacketError) as e:
        dtrack_pose(f.body(5))
    assert e.value.reason == "not tracked"
    bad = DTrackBody(7, 1.0, (0, 0, 0), (0.0,) * 9)
    with pytest.raises(PacketError, match="bad rotation"):
        dtrack_pose(bad)


def test_exact_encoding_round_trips_doubles():
    rng = np.random.default_rng(1)
    for _ in range(20):
        p = tuple(rng.normal(0, 1000, 3))
        R = quat_to_matrix(rng.normal(size=4) / 2.0 / np.linalg.norm(rng.normal(size=4) / 2.0))
        fr = DTrackFrame(7, None, (1, 2, 3), None, (DTrackBody(2, 1.0, p, tuple(R.ravel())),))
        g = decode_dtrack(encode_dtrack(fr, digits=None, rot_digits=None))
        assert g.bodies[0].position_mm == p and g.bodies[0].rotation == tuple(R.ravel())


def test_lf_only_and_unknown_lines():
    f = decode_dtrack(b"fr 1\n6dmtr 0 1 2\n6d 0\n")
    assert f.frame == 1 and f.bodies == () and f.skipped == ("6dmtr",)


@pytest.mark.parametrize(
    "packet, reason",
    [
        (b"", "empty"),
        (b"hello world\r\n", "empty"),
        (b"fr x\r\n", "bad line"),
        (b"fr 1\r\n6d 2 [0 1.0][1 2 3 0 0 0][1 0 0 0 1 0 0 0 1]\r\n", "bad line"),
        (b"fr 1\r\n6d 1 [0 1.0][1 2 3 0 0][1 0 0 0 1 0 0 0 1]\r\n", "bad line"),
        (b"fr 1\r\n6d 1 [0 1.0][1 2 nan 0 0 0][1 0 0 0 1 0 0 0 1]\r\n", "bad line"),
        (b"fr 1\r\n6d 1 [0.5 1.0][1 2 3 0 0 0][1 0 0 0 1 0 0 0 1]\r\n", "bad line"),
        (b"ts 90000.0\r\n", "bad line"),
        (b"ts2 1 2000000 3\r\n", "bad line"),
        ("fr 1 \u00e9\r\n".encode(), "not ASCII"),
        (b"fr 1\r\n" + b" " * 70000, "oversized"),
    ],
)
def test_bad_datagrams_are_typed(packet, reason):
    with pytest.raises(PacketError) as e:
        decode_dtrack(packet)
    assert e.value.reason == reason


def test_midnight_roll_over():
    u = DayUnwrapper()
    seq = [86399.98, 86399.99, 0.0, 0.01, 86399.995, 0.02]  # one late packet from before
    out = [u(t) for t in seq]
    np.testing.assert_allclose(out, [86399.98, 86399.99, 86400.0, 86400.01, 86399.995, 86400.02])


def _skew(v):
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def _euler_matrix(eta, theta, phi):
    """DTrack2 manual, appendix B.1: R written out in the angles (independent of the code)."""
    ce, se, ct, st, cp, sp = (np.cos(eta), np.sin(eta), np.cos(theta), np.sin(theta),
                              np.cos(phi), np.sin(phi))  # fmt: skip
    return np.array(
        [
            [cp * ct, -sp * ct, st],
            [sp * ce + cp * st * se, cp * ce - sp * st * se, -ct * se],
            [sp * se - cp * st * ce, cp * se + sp * st * ce, ct * ce],
        ]
    )


def test_6dcov_conversion_against_monte_carlo():
    """Sample DTrack's error model (reference-point location error in room coordinates,
    Euler-angle errors) and measure trackflow's error (origin error, rotation error on the
    right)."""
    from trackflow.math import quat_from_matrix
    from trackflow.trackers.dtrack import dtrack_euler

    rng = np.random.default_rng(5)
    ang = np.array([0.4, -0.7, 2.1])  # eta, theta, phi
    R = _euler_matrix(*ang)
    np.testing.assert_allclose(dtrack_euler(R), ang, atol=1e-12)
    q = quat_from_matrix(R)
    t = np.array([0.3, -0.1, 1.2])
    c_mm = np.array([40.0, -25.0, 60.0])
    A = rng.normal(size=(6, 6))
    C_dt = A @ A.T
    C_dt[:3, :3] *= 0.04  # mm^2 scale
    C_dt[3:, 3:] *= 1e-6  # rad^2 scale
    C_dt[:3, 3:] *= 2e-4
    C_dt[3:, :3] *= 2e-4
    C_dt = 0.5 * (C_dt + C_dt.T)
    cov = DTrackCovariance(0, tuple(c_mm), tuple(C_dt.ravel()))
    C = dtrack_covariance(R, cov)
    n = 100_000
    e = rng.multivariate_normal(np.zeros(6), C_dt, size=n)
    dp, da = e[:, :3] * 1e-3, e[:, 3:]
    R_true = np.array([_euler_matrix(*(ang + d)) for d in da])
    q_true = quat_from_matrix(R_true)
    p_ref = t + R @ (c_mm * 1e-3)
    t_true = p_ref + dp - np.einsum("nij,j->ni", R_true, c_mm * 1e-3)
    dtheta = quat_log(quat_multiply(quat_conjugate(q), q_true))
    E = np.hstack([t_true - t, dtheta])
    C_mc = np.cov(E.T)
    scale = np.sqrt(np.outer(np.diag(C), np.diag(C)))
    assert np.abs(C_mc - C).max() / scale.max() < 0.02
    np.testing.assert_allclose(np.diag(C_mc), np.diag(C), rtol=0.03)
    # the conversion is not the identity: the lever arm couples rotation into translation
    assert np.abs(C[:3, 3:]).max() > 0 and not np.allclose(C[:3, :3], C_dt[:3, :3] * 1e-6)
