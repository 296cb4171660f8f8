"""The NatNet input takes a frame's rigid bodies as one record array (``decode_frame(...,
table=True)``) and makes their samples with array arithmetic; the samples, rejections and
statuses are those of the per-body path (one ``NatNetRigidBody`` each) to the last bit, on
frames mixing valid, untracked, missing, non-finite, non-unit and noisy bodies with Y-up and
millimetre inputs."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from trackflow.dataflow import parse_input
from trackflow.trackers import natnet
from trackflow.trackers.inputs import SampleBlock, make_inputs

from .test_natnet_pass import status_of

FREQ = 10_000_000
COV = np.diag([1e-6] * 3 + [1e-5] * 3)


def _input(up_y: int, mm: int):
    specs = {}
    for k in range(1, 7):
        doc = {"natnet": {"command_port": 1, "body": k}}
        if k == up_y:
            doc["up"] = "y"
        if k == mm:
            doc["unit"] = "mm"
        specs[f"b{k}"] = (parse_input(doc), COV)
    (inp,) = make_inputs(specs)
    info = natnet.ServerInfo(natnet_version=(4, 1, 0, 0), clock_frequency=FREQ)
    inp.handle(natnet.encode_server_info(info), 0)
    return inp


def _frame(rng, i, kinds):
    bodies = []
    for k in range(1, 8):
        kind = kinds[k - 1]
        if kind == "missing":
            continue
        p = rng.normal(0, 1, 3)
        q = rng.normal(0, 1, 4)
        q /= np.linalg.norm(q)
        err, valid = 2e-4, True
        if kind == "untracked":
            valid = False
        elif kind == "nan":
            p[1] = np.nan
        elif kind == "long":
            q *= 1.2  # outside the 10 % band
        elif kind == "slightly":
            q *= 1.04  # normalised
        elif kind == "noisy":
            err = 5e-3  # above the nominal sigma: a scaled covariance
        elif kind == "bad_error":
            err = -1.0
        elif kind == "huge":
            p[0] = 3e38
        bodies.append(natnet.NatNetRigidBody(k, tuple(p), tuple(q), err, valid))
    tick = 1_000_000 + i * FREQ // 240
    frame = natnet.NatNetFrame(i + 1, tuple(bodies), i / 240, tick, tick, tick + 20_000)
    return natnet.encode_frame(frame, (4, 1))


KINDS = ("ok", "ok", "ok", "missing", "untracked", "nan", "long", "slightly", "noisy",
         "bad_error", "huge")  # fmt: skip


def _per_body(inp, data, arrival):
    """The per-body path: decode_frame without the table (and without the one pass over the
    datagram, which finds the table by itself)."""
    real = natnet.decode_frame
    natnet.decode_frame = lambda payload, version, table=False: real(payload, version)
    inp._frame_pass = lambda data, arrival_ns: None
    try:
        return inp.handle(data, arrival)
    finally:
        natnet.decode_frame = real
        del inp._frame_pass


def _same(a, b):
    assert [i for i, _ in a] == [i for i, _ in b]
    for (_, x), (_, y) in zip(a, b):
        assert type(x) is type(y) and x.t_ns == y.t_ns and x.arrival_ns == y.arrival_ns
        for u, v in ((x.position, y.position), (x.quaternion, y.quaternion),
                     (x.covariance, y.covariance)):  # fmt: skip
            assert u.dtype == v.dtype == np.float64 and u.tobytes() == v.tobytes()


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.lists(st.sampled_from(KINDS), min_size=7, max_size=7), min_size=1, max_size=8),
    st.integers(0, 6),
    st.integers(0, 6),
    st.integers(0, 2**32 - 1),
)
def test_table_path_equals_per_body_path(frames, up_y, mm, seed):
    rng = np.random.default_rng(seed)
    fast, slow = _input(up_y, mm), _input(up_y, mm)
    for i, kinds in enumerate(frames):
        data = _frame(rng, i, kinds)
        arrival = 1_700_000_000_000_000_000 + i * 4_166_667 + 3_000_000
        _same(fast.handle(data, arrival), _per_body(slow, data, arrival))
    for a, b in zip(fast.bodies, slow.bodies):
        assert status_of(a.status) == status_of(b.status)


@pytest.mark.parametrize("mm", [0, 3])
def test_all_plain_bodies_take_the_one_pass_path(mm):
    """Every body plainly valid (some quaternions normalised, one in millimetres): one
    SampleBlock, equal as a sequence to the per-body path's samples, with the statuses."""
    fast, slow = _input(0, mm), _input(0, mm)
    rng = np.random.default_rng(1)
    for i in range(4):
        kinds = ["ok", "slightly"] * 3 + ["missing"]
        data = _frame(rng, i, kinds)
        out = fast.handle(data, 10**18 + i * 4_166_667)
        assert isinstance(out, SampleBlock) and list(out.index) == list(range(6))
        assert not out.position.flags.writeable and out.covariance.shape == (6, 6, 6)
        want = _per_body(slow, data, 10**18 + i * 4_166_667)
        _same(out, want)
        assert isinstance(out[2:5], SampleBlock)  # a slice is a block too
        _same(out[2:5], want[2:5])
    assert [b.status.measurements for b in fast.bodies] == [4] * 6
    # an untracked body: the per-body path, which counts it
    out = fast.handle(_frame(rng, 9, ["untracked"] + ["ok"] * 6), 10**18 + 9 * 4_166_667)
    assert not isinstance(out, SampleBlock) and [i for i, _ in out] == list(range(1, 6))
    assert fast.bodies[0].status.rejections == {"not tracked": 1}
