"""Online offsets applied (the setup's ``online_offsets: {apply: true}``), without sockets: a
connection's requested shift moves its exposure times from its next packet on, and the
estimator corrects the connection paired with the reference by the relative delay it finds,
then sees only the residual."""

from __future__ import annotations

import json

import numpy as np
import pytest

from trackflow.dataflow import OnlineOffsetSpec, parse_setup
from trackflow.math import quat_exp, quat_to_matrix
from trackflow.trackers import dtrack, natnet
from trackflow.trackers.inputs import make_inputs
from trackflow.trackers.online_offsets import OnlineOffsets, offsets_log_path
from trackflow.yamlfile import parse_yaml

SETUP = """frames: [W, B]
sensors:
  - {name: art, source: W, target: B, rate_hz: 120, sigma_pos_mm: 0.5, sigma_ori_deg: 0.2,
     input: {dtrack: {port: 5001, body: 0}}}
  - {name: opti, source: W, target: B, rate_hz: 120, sigma_pos_mm: 0.5, sigma_ori_deg: 0.2,
     input: {natnet: {command_port: 5002, body: rig}}}
queries:
  - {name: q, source: W, target: B, mode: push, rate_hz: 50}
online_offsets: {apply: true, reference: art, every_s: 2, min_span_s: 3}
"""
FREQ = 10_000_000  # NatNet ticks per second


def _setup():
    return parse_setup(parse_yaml(SETUP, "setup.yaml"), "setup.yaml")


def _inputs(setup):
    cov = {e: setup.graph.edge(e).covariance for e in setup.inputs}
    return {b.name: inp for inp in make_inputs({e: (setup.inputs[e], cov[e]) for e in cov})
            for b in inp.bodies}  # fmt: skip


def _dtrack_packet(fr: int, tx_s: float) -> bytes:
    """A DTrack frame sent at ``tx_s`` [s] on the tracker's clock, 2 ms after exposure."""
    sec = int(tx_s)
    usec = int(round((tx_s - sec) * 1e6))
    R = quat_to_matrix(quat_exp(np.array([0.0, 0.0, 0.3])))
    body = dtrack.DTrackBody(0, 1.0, (100.0, 200.0, 300.0), tuple(R.ravel()))
    frame = dtrack.DTrackFrame(fr, None, (sec, usec, 2_000), None, (body,), ())
    return dtrack.encode_dtrack(frame, None, None)


def test_a_requested_shift_moves_the_exposure_times_from_the_next_packet_on():
    inp = _inputs(_setup())["art"]
    arrival = 1000_000_000_000
    ((_, first),) = inp.handle(_dtrack_packet(1, 1000.0), arrival)
    seen = []
    inp.request_shift(15_000_000, seen.append)
    assert inp.shift_ns == 0 and seen == []  # nothing moves before the next packet
    ((_, second),) = inp.handle(_dtrack_packet(2, 1000.01), arrival + 10_000_000)
    assert seen == [arrival + 10_000_000] and inp.shift_ns == 15_000_000
    # the same mapping, 10 ms later, moved by the 15 ms asked
    assert second.t_ns - first.t_ns == 10_000_000 + 15_000_000
    ((_, third),) = inp.handle(_dtrack_packet(3, 1000.02), arrival + 20_000_000)
    assert third.t_ns - second.t_ns == 10_000_000 and seen == [arrival + 10_000_000]


def test_a_natnet_block_is_shifted_too():
    inp = _inputs(_setup())["opti"]
    inp.handle(natnet.encode_server_info(natnet.ServerInfo(clock_frequency=FREQ)), 0)
    defs = natnet.ModelDefinitions((natnet.RigidBodyDescription("rig", 3),))
    inp.handle(natnet.encode_model_definitions(defs, (4, 1)), 0)

    def frame(n: int, tx_ticks: int) -> bytes:
        rb = natnet.NatNetRigidBody(3, (1.0, 2.0, 3.0), (0, 0, 0, 1), 0.0002, True)
        f = natnet.NatNetFrame(n, (rb,), 0.0, tx_ticks - 40_000, tx_ticks, tx_ticks)
        return natnet.encode_frame(f, (4, 1))

    tx, arrival = 100 * FREQ, 100_000_100_000
    ((_, a),) = inp.handle(frame(1, tx), arrival)
    inp.request_shift(-3_000_000)
    ((_, b),) = inp.handle(frame(2, tx + FREQ // 100), arrival + 10_000_000)
    assert b.t_ns - a.t_ns == 10_000_000 - 3_000_000


def _angles(t_s: np.ndarray) -> np.ndarray:
    """A hand-held motion: rotation vectors whose speed varies (the estimator correlates it)."""
    w = 2 * np.pi * t_s
    return np.stack(
        [0.4 * np.sin(0.7 * w), 0.3 * np.sin(1.3 * w + 1.0), 0.8 * np.sin(0.45 * w)], axis=1
    )


def _feed(est, t0_s: float, seconds: float, b_late_ms: float) -> None:
    """Both sensors see one body at 120 Hz; ``b``'s exposure times read ``b_late_ms`` early
    (``t_a = t_b + b_late_ms``)."""
    t = t0_s + np.arange(0.0, seconds, 1 / 120)
    q = quat_exp(_angles(t))
    for tk, qk in zip(t, q):
        est.add_a(int(round(tk * 1e9)), (0.0, 0.0, 0.0), qk)
        est.add_b(int(round(tk * 1e9 - b_late_ms * 1e6)), (0.0, 0.0, 0.0), qk)


def test_the_connection_paired_with_the_reference_is_corrected_then_left_alone(tmp_path):
    setup = _setup()
    inputs = _inputs(setup)
    log = offsets_log_path(tmp_path / "out.tfrec")
    offsets = OnlineOffsets(setup, setup.online_offsets, log)
    offsets.connect(inputs.values())
    (est,) = offsets.estimators
    assert (est.a, est.b, offsets.reference) == ("art", "opti", "art")
    _feed(est, 100.0, 6.0, b_late_ms=15.0)
    (r,) = offsets.step()
    assert abs(r["offset_ms"] - 15.0) < 0.5 and r["applied_ms"] == 0.0, r
    opti = inputs["opti"]
    assert opti.shift_ns == 0  # asked for; applied at opti's next packet
    opti.handle(b"\x07\x00\xff\xff", 200_000_000_000)  # any packet: a counted rejection
    assert abs(opti.shift_ns - 15_000_000) < 500_000 and inputs["art"].shift_ns == 0
    (event,) = offsets.events
    assert event["t_ns"] == 200_000_000_000 and event["sensors"] == ["opti"]
    assert event["reference"] == "art" and event["total_ms"] == event["step_ms"]
    assert json.loads(log.read_text()) == event  # flushed as it happened
    # the pair forgot the old times; on the corrected ones it finds the residual only
    (r,) = offsets.step()
    assert r["why"] == "too few measurements yet", r
    _feed(est, 106.0, 6.0, b_late_ms=15.0 - opti.shift_ns * 1e-6)
    (r,) = offsets.step()
    assert abs(r["offset_ms"]) < 0.5 and abs(r["applied_ms"] - 15.0) < 0.5, r
    opti.handle(b"\x07\x00\xff\xff", 210_000_000_000)
    assert len(offsets.events) == 1  # a residual within its step is not applied
    lines = offsets.new_lines()
    assert any("opti corrected by +15" in line for line in lines), lines
    offsets.close()


def test_an_estimate_only_spec_never_corrects():
    setup = _setup()
    inputs = _inputs(setup)
    offsets = OnlineOffsets(setup, OnlineOffsetSpec(), None)
    offsets.connect(inputs.values())
    (est,) = offsets.estimators
    _feed(est, 100.0, 6.0, b_late_ms=15.0)
    (r,) = offsets.step()
    assert abs(r["offset_ms"] - 15.0) < 0.5
    inputs["opti"].handle(b"\x07\x00\xff\xff", 1)
    assert inputs["opti"].shift_ns == 0 and offsets.events == []


@pytest.mark.parametrize(
    "block, message",
    [
        ("{apply: yes please}", "online_offsets.apply must be true or false"),
        ("{every: 2}", "online_offsets: unknown keys ['every']"),
        ("{window_s: 0}", "online_offsets.window_s must be finite and > 0"),
        ("{max_sigma_ms: .nan}", "online_offsets.max_sigma_ms must be finite and > 0"),
        ("{reference: nobody}", "'nobody' is not a sensor with an 'input:'"),
        ("[1, 2]", "online_offsets must be a mapping"),
    ],
)
def test_a_bad_block_is_refused_with_its_file_and_line(block, message):
    text = SETUP.replace(
        "online_offsets: {apply: true, reference: art, every_s: 2, min_span_s: 3}",
        f"online_offsets: {block}",
    )
    with pytest.raises(ValueError, match="setup.yaml:9") as info:
        parse_setup(parse_yaml(text, "setup.yaml"), "setup.yaml")
    assert message in str(info.value)


def test_other_ways_of_running_a_setup_refuse_the_block():
    with pytest.raises(ValueError, match=r"setup.yaml:9: online_offsets: an agent does not"):
        _setup().refuse_online_offsets("an agent")
    _setup_without = parse_setup(
        parse_yaml(SETUP.rsplit("online_offsets", 1)[0], "s.yaml"), "s.yaml"
    )
    _setup_without.refuse_online_offsets("an agent")  # nothing to refuse
    assert _setup_without.online_offsets is None
