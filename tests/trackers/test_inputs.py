"""Live inputs without sockets: handshake order, body selection, rejections with reasons,
exposure-time mapping from the protocol's stamps, covariance and axis conversions."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow.dataflow import parse_input
from trackflow.math import quat_conjugate, quat_exp, quat_log, quat_multiply, quat_to_matrix
from trackflow.trackers import dtrack, natnet, vrpn
from trackflow.trackers.axes import Y_UP_TO_Z_UP, BoundaryConversion
from trackflow.trackers.inputs import make_input, make_inputs

COV = np.diag([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4])
FREQ = 10_000_000
V = (4, 1)


def _natnet(body="head", **extra):
    return make_input("s", parse_input({"natnet": {"body": body}, **extra}), COV)


def _frame(n, tx_ticks, lat_ticks, valid=True, err=0.0002, pos=(1.0, 2.0, 3.0), q=(0, 0, 0, 1)):
    rb = natnet.NatNetRigidBody(3, pos, q, err, valid)
    return natnet.encode_frame(
        natnet.NatNetFrame(n, (rb,), 0.0, tx_ticks - lat_ticks, tx_ticks, tx_ticks), V
    )


def _handshake(inp):
    info = natnet.ServerInfo(clock_frequency=FREQ)
    assert inp.handle(natnet.encode_server_info(info), 0) == []
    defs = natnet.ModelDefinitions((natnet.RigidBodyDescription("head", 3),))
    assert inp.handle(natnet.encode_model_definitions(defs, V), 0) == []


def test_natnet_needs_the_handshake_and_the_names():
    inp = _natnet()
    assert inp.handle(_frame(1, 10 * FREQ, 50_000), 5) == []
    assert inp.status.rejections == {"no handshake yet": 1}
    inp.handle(natnet.encode_server_info(natnet.ServerInfo(clock_frequency=FREQ)), 0)
    inp.handle(_frame(2, 10 * FREQ, 50_000), 5)
    assert inp.status.rejections["unknown body name"] == 1
    _handshake(inp)
    (pair,) = inp.handle(_frame(3, 10 * FREQ + FREQ // 100, 50_000), 10_010_000_000 + 200_000)
    assert pair[1].position.tolist() == [1.0, 2.0, 3.0]


def test_natnet_exposure_from_ticks_and_counted_rejections():
    inp = _natnet()
    _handshake(inp)
    offset = 7_000_000_000  # host = tracker + 7 s; transit 100 us
    got = []
    for k in range(1, 40):
        tx = 100 * FREQ + k * FREQ // 120
        tx_ns = tx * 1_000_000_000 // FREQ
        got += inp.handle(_frame(k if k != 20 else 25, tx, 45_000), tx_ns + offset + 100_000)
    # exposure = transmit - 4.5 ms, on the host clock (+ the 100 us transit)
    s = got[0][1]
    tx0 = (100 * FREQ + FREQ // 120) * 1_000_000_000 // FREQ
    assert s.t_ns == tx0 + offset + 100_000 - 4_500_000
    st = inp.status
    # frames 1..19, 25 (5 missing), then 21..25 again (5 reordered or duplicate)
    assert st.dropouts == 5 and st.rejections["reordered or duplicate frame"] == 5
    # arrivals on the same clock as before (a stamp off the fit would be refused first)
    arrival = 40 * 10**9 // 120 + 100 * 10**9 + offset + 100_000
    inp.handle(_frame(50, 100 * FREQ + 40 * FREQ // 120, 10, valid=False), arrival)
    inp.handle(b"\x07\x00\xff\xff", arrival)
    inp.handle(_frame(51, 100 * FREQ + 41 * FREQ // 120, -5), arrival + 8_333_333)
    assert st.rejections["not tracked"] == 1 and st.rejections["truncated"] == 1
    assert st.rejections["bad stamps"] == 1


def test_natnet_mean_error_scales_the_covariance():
    inp = _natnet()
    _handshake(inp)
    (a,) = inp.handle(_frame(1, 10 * FREQ, 10, err=0.0005), 1)
    (b,) = inp.handle(_frame(2, 10 * FREQ + 100, 10, err=0.0001), 2)
    # below the nominal 1 mm the setup's covariance stands; above it scales with error^2
    np.testing.assert_allclose(a[1].covariance, COV)
    np.testing.assert_allclose(b[1].covariance, COV)
    (c,) = inp.handle(_frame(3, 10 * FREQ + 200, 10, err=0.003), 3)
    np.testing.assert_allclose(c[1].covariance, COV * 9.0)


def test_y_up_conversion_of_pose_and_covariance():
    inp = _natnet(up="y")
    _handshake(inp)
    q = quat_exp(np.array([0.0, 0.3, 0.0]))  # yaw about Y (up) in the Y-up frame
    (p,) = inp.handle(_frame(1, 10 * FREQ, 10, pos=(1.0, 2.0, 3.0), q=tuple(q)), 1)
    s = p[1]
    np.testing.assert_allclose(s.position, [1.0, -3.0, 2.0])  # (x, y, z) -> (x, -z, y)
    # the same yaw is now about Z (up)
    np.testing.assert_allclose(quat_log(s.quaternion), [0, 0, 0.3], atol=1e-6)
    M = Y_UP_TO_Z_UP
    np.testing.assert_allclose(quat_to_matrix(s.quaternion), M @ quat_to_matrix(q) @ M.T, atol=1e-6)


def test_y_up_covariance_against_monte_carlo():
    rng = np.random.default_rng(3)
    conv = BoundaryConversion(1.0, "y")
    t, q = np.array([0.2, 1.5, -0.4]), quat_exp(np.array([0.3, -0.2, 0.5]))
    A = rng.normal(size=(6, 6)) * 1e-2
    C = A @ A.T
    e = rng.multivariate_normal(np.zeros(6), C, 100_000)
    t2, q2 = conv.pose(t, q)
    tt, qt = conv.pose(t + e[:, :3], quat_multiply(q, quat_exp(e[:, 3:])))
    E = np.hstack([tt - t2, quat_log(quat_multiply(quat_conjugate(q2), qt))])
    C_mc = np.cov(E.T)
    assert np.abs(C_mc - conv.covariance(C)).max() < 0.03 * np.abs(C).max()


def _dtrack(**opts):
    return make_input("s", parse_input({"dtrack": {"body": 2, **opts}}), COV)


def _dt_packet(fr, ts2=None, ts=None, quality=1.0, cov=None):
    R = quat_to_matrix(quat_exp(np.array([0.0, 0.0, 0.5])))
    b = dtrack.DTrackBody(2, quality, (100.0, 200.0, 300.0), tuple(R.ravel()))
    covs = () if cov is None else (cov,)
    return dtrack.encode_dtrack(dtrack.DTrackFrame(fr, ts, ts2, None, (b,), covs), None, None)


def test_dtrack_ts2_latency_gives_the_exposure():
    inp = _dtrack()
    (p,) = inp.handle(_dt_packet(1, (1000, 250_000, 4_000)), 1000_254_000_000 + 80_000 + 5)
    s = p[1]
    # send = 1000.254 s tracker; mapped = arrival; exposure = mapped - 4 ms
    assert s.t_ns == 1000_254_000_000 + 80_000 + 5 - 4_000_000
    np.testing.assert_allclose(s.position, [0.1, 0.2, 0.3])
    np.testing.assert_allclose(s.covariance, COV)
    inp.handle(_dt_packet(2, (1000, 260_000, 4_000), quality=-1.0), 1000_264_000_000 + 80_005)
    inp.handle(b"fr 3\r\n6d 1 [2 1.0][1 2 3]\r\n", 0)
    inp.handle(_dt_packet(4), 0)
    assert inp.status.rejections == {"not tracked": 1, "bad line": 1, "no timestamp": 1}


def test_a_copy_with_a_changed_frame_number_touches_nothing():
    """A datagram duplicated on the way with its frame number changed (``fr 100002`` ->
    ``fr 100010``, one flipped bit): its stamp is not after the last one, so it is refused
    before the frame counter, and the real frames after it are taken, not called old."""
    inp = _dtrack()
    out = [inp.handle(_dt_packet(100_000 + k, (1000 + k, 0, 100)), 10**12 + k * 10**9)
           for k in range(3)]  # fmt: skip
    out.append(inp.handle(_dt_packet(100_010, (1002, 0, 100)), 10**12 + 2 * 10**9 + 5))
    out += [inp.handle(_dt_packet(100_000 + k, (1000 + k, 0, 100)), 10**12 + k * 10**9)
            for k in range(3, 6)]  # fmt: skip
    st = inp.status
    assert [len(o) for o in out] == [1, 1, 1, 0, 1, 1, 1]
    assert st.rejections == {"stamp not after the last": 1} and st.dropouts == 0


def test_dtrack_status_names_the_ids_sent_and_hints_at_counting_from_0():
    """A sensor told ``body: 1`` on an output that sends bodies 0 and 2: its status says so
    and hints at the 0-based ids; the hint goes when body 1 appears."""
    inp = make_input("s", parse_input({"dtrack": {"body": 1}}), COV)
    R = tuple(np.eye(3).ravel())

    def packet(fr, ids):
        bodies = tuple(dtrack.DTrackBody(i, 1.0, (1.0, 2.0, 3.0), R) for i in ids)
        frame = dtrack.DTrackFrame(fr, None, (1000 + fr, 0, 100), None, bodies, ())
        return dtrack.encode_dtrack(frame, None, None)

    assert inp.handle(packet(1, (0, 2)), 10**12 + 10**9) == []
    st = inp.status
    assert st.notes["seen"] == "6d ids seen: 0, 2"
    assert "body 1 not in the output; DTrack ids count from 0" in st.notes["hint"]
    assert "[6d ids seen: 0, 2; body 1 not in the output" in st.line(10**12, 0.5)
    assert st.summary(10**12)["notes"] == st.notes
    (pair,) = inp.handle(packet(2, (0, 1, 2)), 10**12 + 2 * 10**9)
    assert st.notes == {"seen": "6d ids seen: 0, 1, 2"}


def test_dtrack_a_line_kind_that_appears_later_is_noted():
    """Bodies first, then a Flystick line too: the ids of the new kind join the notes (a
    kind not seen before must not break the packet)."""
    inp = make_input("s", parse_input({"dtrack": {"body": 0}}), COV)
    R = tuple(np.eye(3).ravel())
    body = dtrack.DTrackBody(0, 1.0, (1.0, 2.0, 3.0), R)
    fly = dtrack.DTrackFlystick(0, 1.0, (1.0, 2.0, 3.0), R, (False,) * 8, (0.0, 0.0))
    first = dtrack.DTrackFrame(1, None, (1001, 0, 100), None, (body,), ())
    later = dtrack.DTrackFrame(2, None, (1002, 0, 100), None, (body,), (), flysticks=(fly,))
    assert len(inp.handle(dtrack.encode_dtrack(first, None, None), 10**12 + 10**9)) == 1
    assert len(inp.handle(dtrack.encode_dtrack(later, None, None), 10**12 + 2 * 10**9)) == 1
    assert inp.seen == {"body": {0}, "flystick": {0}}


def test_dtrack_ts_over_midnight_and_6dcov():
    inp = _dtrack(latency_ms=2.0)
    cov = dtrack.DTrackCovariance(
        2, (0.0, 0.0, 0.0), tuple(np.diag([1.0] * 3 + [1e-6] * 3).ravel())
    )
    ts = [86399.99, 0.0, 0.01]
    out = [
        inp.handle(_dt_packet(k + 1, ts=t, cov=cov), 10**12 + k * 10**7)[0][1]
        for k, t in enumerate(ts)
    ]
    d = np.diff([s.t_ns for s in out])
    np.testing.assert_allclose(d, [1e7, 1e7], atol=2)  # no day jump
    np.testing.assert_allclose(np.diag(out[0].covariance)[:3], [1e-6] * 3)  # mm^2 -> m^2


def test_vrpn_host_clock_and_reconnect_on_garbage():
    spec = parse_input({"vrpn": {"device": "Tracker0@127.0.0.1:1", "sensor": 1, "clock": "host"}})
    inp = make_input("s", spec, COV)
    stream = (
        vrpn.make_cookie()
        + vrpn.encode_description(-1, 0, "Tracker0")
        + vrpn.encode_description(-2, 0, vrpn.POS_QUAT)
        + vrpn.encode_message(12, 500_000, 0, 0, vrpn.encode_pos_quat(1, (1, 2, 3), (0, 0, 0, 1)))
        + vrpn.encode_message(12, 600_000, 0, 0, vrpn.encode_pos_quat(0, (1, 2, 3), (0, 0, 0, 1)))
    )
    (p,) = inp.handle(stream, 99)
    assert p[1].t_ns == 12_500_000_000 and not inp.broken
    inp.handle(b"\xff" * 24, 100)
    assert inp.broken and inp.status.rejections == {"bad length": 1}


def test_sensors_on_one_connection_share_it():
    a = parse_input({"natnet": {"body": "head"}})
    b = parse_input({"natnet": {"body": "hand"}})
    c = parse_input({"natnet": {"body": "hand", "server": "127.0.0.2"}})
    inputs = make_inputs({"h": (a, COV), "k": (b, COV), "x": (c, COV)})
    assert [len(i.bodies) for i in inputs] == [2, 1]


@pytest.mark.parametrize(
    "doc, match",
    [
        ({"natnet": {}}, "missing key 'body'"),
        ({"natnet": {"body": "x"}, "dtrack": {"body": 1}}, "exactly one"),
        ({"dtrack": {"body": "x"}}, "input.dtrack.body"),
        ({"dtrack": {"body": 1, "port": 70000}}, "not a port"),
        ({"dtrack": {"body": 1, "colour": 1}}, "unknown keys"),
        ({"vrpn": {"device": "Tracker0"}}, "Name@host"),
        ({"vrpn": {"device": "T@h", "clock": "gps"}}, "clock"),
        ({"natnet": {"body": "x"}, "up": "x"}, "input.up"),
        ({"natnet": {"body": "x"}, "unit": "inch"}, "input.unit"),
        ({"natnet": {"body": "x", "server": "a b"}}, "not a host"),
        ({"natnet": {"body": True}}, "input.natnet.body"),
    ],
)
def test_bad_input_specs_name_the_key(doc, match):
    with pytest.raises(ValueError, match=match):
        parse_input(doc)


def test_setup_input_key(tmp_path):
    from trackflow.dataflow import load_setup

    text = """frames: [W, B]
sensors:
  - name: head
    source: W
    target: B
    input: {natnet: {server: 127.0.0.1, body: head}, up: y}
queries:
  - {name: q, source: W, target: B, mode: push, rate_hz: 60}
"""
    p = tmp_path / "s.yaml"
    p.write_text(text)
    s = load_setup(p)
    assert s.inputs["head"].protocol == "natnet" and s.inputs["head"].up == "y"
    p.write_text(text.replace("body: head", "bodyy: head"))
    with pytest.raises(ValueError, match=r"s.yaml:\d+: sensors\[0\]: input.natnet: unknown keys"):
        load_setup(p)


@pytest.mark.parametrize("before", [500_000, 4_590])
def test_a_restarted_tracker_is_an_event_not_a_loss(before):
    """The counter jumps back and the next frame follows the jump: a restart, confirmed by
    that next frame (the jump's own frame is refused, as one bogus counter would be). Also a
    tracker restarted after fewer frames than a jump ahead needs (4,590 at 100 Hz: 46 s; it
    was refused as "reordered" until its counter passed the old one)."""
    inp = _dtrack()
    for k, fr in enumerate([before, before + 1, 3, 4, 5]):
        inp.handle(_dt_packet(fr, (1000 + k, 0, 100)), 10**12 + k * 10**9)
    st = inp.status
    assert st.dropouts == 0 and st.connection == {"frame counter restarted": 1}
    assert st.measurements == 4 and st.rejections == {"frame counter jump not confirmed": 1}


@pytest.mark.parametrize("bogus", [999_999_999, 0])
def test_a_bogus_frame_counter_touches_neither_counter_nor_clock(bogus):
    """``fr 999999999`` (or 0) between real frames, with and without a timestamp: refused
    and counted; no restart, no dropout, and the clock fit keeps every real sample."""
    inp = _dtrack()
    frames = [_dt_packet(100_000 + k, (1000 + k, 0, 100)) for k in range(6)]
    frames.insert(2, _dt_packet(bogus, (1000, 0, 100)))  # a stamp that goes back 2 s
    frames.insert(5, f"fr {bogus}\r\n".encode())  # no timestamp at all
    out = [inp.handle(f, 10**12 + k * 10**9) for k, f in enumerate(frames)]
    st = inp.status
    assert [len(o) for o in out] == [1, 1, 0, 1, 1, 0, 1, 1]
    assert st.connection == {} and st.dropouts == 0 and st.measurements == 6
    assert st.rejections == {"frame counter jump not confirmed": 1, "no timestamp": 1}
    assert inp.clock.count == 6 and inp.clock.steps == 0
