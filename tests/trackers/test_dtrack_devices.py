"""DTrack Flysticks (``6df2``), measurement tools (``6dmt2``), Fingertracking hands (``gl``)
and system status (``st``): golden datagrams, exact round trips, bad lines, fuzzing."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trackflow.trackers import PacketError
from trackflow.trackers.dtrack import (
    DTrackFinger,
    DTrackFlystick,
    DTrackFrame,
    DTrackHand,
    DTrackStatus,
    DTrackTool,
    decode_dtrack,
    encode_dtrack,
)

ROT_Z90 = b"[0.000000 1.000000 0.000000 -1.000000 0.000000 0.000000 0.000000 0.000000 1.000000]"
EYE = b"[1.000000 0.000000 0.000000 0.000000 1.000000 0.000000 0.000000 0.000000 1.000000]"
ZERO9 = b"[" + b" ".join([b"0.000000"] * 9) + b"]"

# Written by hand from the line formats (dtrack.py's docstring): Flystick 0 rotated +90 deg
# about z with buttons 0, 2 and 5 pressed (word 37 = 0b100101) and its joystick at
# (-0.5, 1.0); Flystick 1 not tracked; a tool with its second button pressed and a 3x3 tip
# covariance; a right hand with three fingers; all three status groups for two cameras.
GOLDEN = (
    b"fr 512\r\n"
    b"ts2 1712345678 500000 3900\r\n"
    b"6df2 2 2 [0 1.000 6 2][100.000 200.000 300.000]" + ROT_Z90 + b"[37 -0.50 1.00]"
    b" [1 -1.000 6 2][0.000 0.000 0.000]" + ZERO9 + b"[0 0.00 0.00]\r\n"
    b"6dmt2 1 1 [0 1.000 2 1.500][10.000 20.000 30.000]" + EYE + b"[2]"
    b"[0.010000 0.001000 0.000000 0.020000 0.000000 0.030000]\r\n"
    b"gl 1 [4 0.800 1 3][-50.000 120.000 900.000]" + ROT_Z90 + b""
    b"[40.000 -10.000 5.000]" + EYE + b"[8.000 30.000 10.000 25.000 15.000 20.000]"
    b"[60.000 0.000 2.000]" + EYE + b"[7.500 32.000 12.000 27.000 18.000 22.000]"
    b"[55.000 10.000 0.000]" + EYE + b"[7.000 28.000 9.000 24.000 14.000 19.000]\r\n"
    b"st 3 [0 3][4 2 17] [1 5][0 1 0 2 5] [2 2 3][0 12 10 180][1 9 9 201]\r\n"
)


def test_golden_decodes_every_field():
    f = decode_dtrack(GOLDEN)
    assert f.frame == 512 and f.skipped == ()
    f0, f1 = f.flysticks
    assert f0.id == 0 and f0.quality == 1.0 and f0.position_mm == (100.0, 200.0, 300.0)
    # column-wise on the wire -> rows: R = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    assert f0.rotation == (0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0)
    assert f0.buttons == (True, False, True, False, False, True)
    assert f0.joysticks == (-0.5, 1.0)
    assert f1.quality == -1.0 and f1.buttons == (False,) * 6 and f1.joysticks == (0.0, 0.0)
    (t,) = f.tools
    assert t.tip_radius_mm == 1.5 and t.buttons == (False, True)
    c = np.array(t.position_cov_mm2).reshape(3, 3)
    np.testing.assert_array_equal(c, c.T)
    assert c[0, 0] == 0.01 and c[0, 1] == 0.001 and c[1, 1] == 0.02 and c[2, 2] == 0.03
    (h,) = f.hands
    assert h.id == 4 and h.quality == 0.8 and h.right and len(h.fingers) == 3
    assert h.position_mm == (-50.0, 120.0, 900.0)
    g = h.fingers[1]
    assert g.position_mm == (60.0, 0.0, 2.0) and g.tip_radius_mm == 7.5
    assert g.phalanx_mm == (32.0, 27.0, 22.0) and g.angles_deg == (12.0, 18.0)
    assert f.status == DTrackStatus(4, 2, 17, 0, 1, 0, 2, 5, ((0, 12, 10, 180), (1, 9, 9, 201)))


def test_golden_round_trips_bytes():
    assert encode_dtrack(decode_dtrack(GOLDEN)) == GOLDEN


def test_exact_encoding_round_trips_doubles():
    rng = np.random.default_rng(3)
    for _ in range(10):
        p = tuple(rng.normal(0, 1000, 3))
        r = tuple(rng.normal(0, 1, 9))
        nb = int(rng.integers(0, 70))
        buttons = tuple(bool(b) for b in rng.integers(0, 2, nb))
        cov = rng.normal(size=(3, 3))
        cov = tuple((cov @ cov.T).ravel())
        finger = DTrackFinger(p, r, 7.25, (30.5, 25.0, 20.125), (10.0, 15.5))
        fr = DTrackFrame(
            3,
            None,
            (1, 2, 3),
            flysticks=(DTrackFlystick(0, 1.0, p, r, buttons, tuple(rng.uniform(-1, 1, 2))),),
            tools=(DTrackTool(0, 0.5, p, r, 1.25, buttons, cov),),
            hands=(DTrackHand(2, 1.0, False, p, r, (finger, finger)),),
            status=DTrackStatus(cameras=5, tracked_bodies=1, tracked_markers=3),
        )
        assert decode_dtrack(encode_dtrack(fr, digits=None, rot_digits=None)) == fr


def test_status_groups_are_optional_and_unknown_ones_skipped():
    f = decode_dtrack(b"fr 1\r\nst 2 [1 5][1 2 3 4 5] [7 2][9 9]\r\n")
    assert f.status == DTrackStatus(camera_errors=1, camera_warnings=2, other_errors=3,
                                    other_warnings=4, infos=5)  # fmt: skip
    f = decode_dtrack(b"fr 1\r\nst 1 [9 1 2][0 1 2]\r\n")  # an unknown per-camera group
    assert f.status == DTrackStatus()


@pytest.mark.parametrize(
    "line",
    [
        b"6df2 1 1 [1 1.000 0 0][0 0 0]" + EYE + b"[]",  # ids must be 0 .. n-1 in order
        b"6df2 1 1 [0 1.000 2 0][0 0 0]" + EYE + b"[]",  # 2 buttons need one word
        b"6df2 1 1 [0 1.000 0 0][0 0 0]" + EYE,  # a missing block
        b"6df2 1 [0 1.000 0 0][0 0 0]" + EYE + b"[]",  # one count instead of two
        b"6df2 1 1 [0 1.000 0 0][0 0 0]" + EYE + b"[][]",  # one block too many
        b"6df2 1 1 [0 1.000 999 0][0 0 0]" + EYE + b"[]",  # absurd button count
        b"6dmt2 1 1 [0 1.000 1 1.0][0 0 0]" + EYE + b"[-1][1 0 0 1 0 1]",  # negative word
        b"6dmt2 1 1 [0 1.000 0 1.0][0 0 0]" + EYE + b"[][1 0 0 1 0]",  # 5 covariance values
        b"gl 1 [0 1.000 2 0][0 0 0]" + EYE,  # left/right must be 0 or 1
        b"gl 1 [0 1.000 1 9][0 0 0]" + EYE,  # more than 5 fingers
        b"gl 1 [0 1.000 1 1][0 0 0]" + EYE + b"[0 0 0]" + EYE + b"[1 2 3 4 5]",
        b"st 1 [0 2][1 2]",  # general status needs 3 values
        b"st 1 [2 1 2][0 1 2]",  # camera status needs 3 values after the id
        b"st 1 [0 1 2 3][1 2 3]",  # a group description has 2 or 3 numbers
        b"st 0 1 2",
    ],
)
def test_bad_lines_are_typed(line):
    with pytest.raises(PacketError) as e:
        decode_dtrack(b"fr 1\r\n" + line + b"\r\n")
    assert e.value.reason == "bad line"


@settings(max_examples=300, deadline=None)
@given(st.integers(0, len(GOLDEN)), st.integers(0, 8 * len(GOLDEN) - 1))
def test_truncations_and_bit_flips_only_raise_packet_errors(cut, bit):
    for data in (GOLDEN[:cut], _flip(GOLDEN, bit)):
        try:
            decode_dtrack(data)
        except PacketError:
            pass


def _flip(data: bytes, bit: int) -> bytes:
    b = bytearray(data)
    b[bit // 8] ^= 1 << (bit % 8)
    return bytes(b)


def test_inputs_pick_flysticks_tools_and_hands_and_keep_the_status():
    from trackflow.dataflow import parse_input
    from trackflow.trackers.inputs import make_inputs

    nominal = np.diag([4e-6] * 3 + [1e-4] * 3)
    nominal[0, 3] = nominal[3, 0] = 1e-7  # a cross term the tool's own block replaces
    sensors = {
        name: (parse_input({"dtrack": {"port": 5999, "body": bid, "kind": kind}}), nominal)
        for name, bid, kind in (("fly", 0, "flystick"), ("tool", 0, "tool"),
                                ("hand", 4, "hand"), ("gone", 1, "flystick"),
                                ("absent", 9, "hand"))
    }  # fmt: skip
    (inp,) = make_inputs(sensors)
    arrival = 1712345678_500_000_000 + 3_900_000 + 100_000
    got = {inp.bodies[i].name: s for i, s in inp.handle(GOLDEN, arrival)}
    assert sorted(got) == ["fly", "hand", "tool"]
    np.testing.assert_allclose(got["fly"].position, [0.1, 0.2, 0.3])
    np.testing.assert_allclose(got["fly"].quaternion, [0, 0, np.sqrt(0.5), np.sqrt(0.5)])
    np.testing.assert_allclose(got["hand"].position, [-0.05, 0.12, 0.9])
    c = got["tool"].covariance
    np.testing.assert_allclose(np.diag(c)[:3], [0.01e-6, 0.02e-6, 0.03e-6])  # mm^2 -> m^2
    assert c[0, 1] == 0.001e-6 and c[0, 3] == 0.0 and c[3, 3] == 1e-4
    np.testing.assert_array_equal(got["fly"].covariance, nominal)
    assert inp.bodies[3].status.rejections == {"not tracked": 1}
    assert inp.bodies[4].status.rejections == {"hand not in frame": 1}
    assert inp.tracker_status.cameras == 4 and len(inp.tracker_status.camera_status) == 2
    with pytest.raises(ValueError, match="input.dtrack.kind must be"):
        parse_input({"dtrack": {"body": 0, "kind": "glove"}})
