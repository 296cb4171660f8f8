"""The one compiled pass over a NatNet datagram (``kernels.natnet_frame``, used by
``NatNetInput``) against ``decode_message`` + ``decode_frame``: whenever the pass answers, the
decoder decodes the same frame number, clock ticks and rigid-body table; it leaves to the
decoder exactly what the decoder refuses (and a few layouts it does not take). Frames of
every version with every section filled (marker sets, unlabeled markers, skeletons, assets,
labeled markers, force plates, devices), then truncated, bit-flipped, with counts and sizes
overwritten, in both backends. And the input with the pass gives the samples, rejections and
statuses of the input without it, to the bit."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from trackflow.dataflow import parse_input
from trackflow.math import frozen, kernels_for, numba_available, use_backend
from trackflow.trackers import PacketError, kernels, natnet
from trackflow.trackers.inputs import SampleBlock, make_inputs

BACKENDS = ["numpy"] + (["numba"] if numba_available() else [])
FREQ = 10_000_000
COV = np.diag([1e-6] * 3 + [1e-5] * 3)
NONE = frozen(np.empty(0, np.int64), np.int64)
NO_BOUNDS = frozen(np.empty((3, 0)))


def _section(v, count: int, body: bytes) -> bytes:
    return struct.pack("<i", count) + (struct.pack("<I", len(body)) if v >= (4, 1) else b"") + body


def _rb3(bid, p, q, err=2e-4, params=1) -> bytes:
    return struct.pack("<i3f4ffh", bid, *p, *q, err, params)


def build(v, d) -> bytes:
    """A FRAMEOFDATA datagram for version ``v`` (3.0+) from the layout in natnet's module
    docstring, every section filled from the drawn description ``d``."""
    out = [struct.pack("<i", d["frame"])]
    ms = b"".join(
        name + b"\0" + struct.pack(f"<i{3 * n}f", n, *([0.5] * 3 * n)) for name, n in d["msets"]
    )
    out.append(_section(v, len(d["msets"]), ms))
    out.append(_section(v, d["unlabeled"], b"\1" * 12 * d["unlabeled"]))
    rb = b"".join(_rb3(*b) for b in d["bodies"])
    out.append(_section(v, len(d["bodies"]), rb))
    sk = b"".join(
        struct.pack("<ii", 40 + k, n) + _rb3(k, (0, 0, 0), (0, 0, 0, 1)) * n
        for k, n in enumerate(d["skeletons"])
    )
    out.append(_section(v, len(d["skeletons"]), sk))
    if v >= (4, 1):
        out.append(_section(v, d["assets"], b"\2" * 12 * d["assets"]))
    out.append(_section(v, d["labeled"], b"\3" * 26 * d["labeled"]))
    for key in ("plates", "devices"):
        body = b"".join(
            struct.pack("<ii", k, len(chans))
            + b"".join(struct.pack(f"<i{n}f", n, *([1.0] * n)) for n in chans)
            for k, chans in enumerate(d[key])
        )
        out.append(_section(v, len(d[key]), body))
    mid, tx = d["ticks"]
    out.append(struct.pack("<IId", 1, 2, 3.25) + struct.pack("<QQQ", mid, mid + 5, tx))
    if v >= (4, 1):
        out.append(struct.pack("<II", 7, 8))
    out.append(struct.pack("<h", 3))
    if d["eod"]:
        out.append(struct.pack("<i", 0))
    return natnet.encode_message(natnet.FRAMEOFDATA, b"".join(out))


def _legacy(v, d) -> bytes:
    """Before 3.0 (which the pass leaves to the decoder): the encoder's frame."""
    bodies = tuple(natnet.NatNetRigidBody(b[0], b[1], b[2], b[3], True) for b in d["bodies"])
    return natnet.encode_frame(natnet.NatNetFrame(d["frame"], bodies), v)


_names = st.one_of(
    st.binary(max_size=6).map(lambda b: bytes(c % 127 + 1 for c in b)),  # ASCII, no NUL
    st.sampled_from([b"K\xc3\xb6rper", b"\xff\xfe", b"x" * 256, b"y" * 257]),
)
_f = st.floats(-10, 10, width=32)
frames = st.fixed_dictionaries({
    "frame": st.integers(-(2**31), 2**31 - 1),
    "msets": st.lists(st.tuples(_names, st.integers(0, 3)), max_size=3),
    "unlabeled": st.integers(0, 2),
    "bodies": st.lists(
        st.tuples(st.integers(-3, 30), st.tuples(_f, _f, _f), st.tuples(_f, _f, _f, _f),
                  st.floats(0, 0.0078125, width=32), st.integers(-3, 3)),  # fmt: skip
        max_size=5,
    ),
    "skeletons": st.lists(st.integers(0, 2), max_size=2),
    "assets": st.integers(0, 2),
    "labeled": st.integers(0, 3),
    "plates": st.lists(st.lists(st.integers(0, 3), max_size=2), max_size=2),
    "devices": st.lists(st.lists(st.integers(0, 3), max_size=2), max_size=2),
    "ticks": st.tuples(st.integers(0, 2**64 - 6), st.integers(0, 2**64 - 1)),
    "eod": st.booleans(),
})  # fmt: skip


def _decode(data: bytes, v):
    try:
        msg, payload = natnet.decode_message(data)
        if msg != natnet.FRAMEOFDATA:
            return None
        return natnet.decode_frame(payload, v, table=True)
    except PacketError:
        return None


def _pass(data: bytes, v, backend: str):
    out = np.zeros(5, np.uint64)
    with use_backend(backend):
        code = kernels_for(kernels).natnet_frame(
            np.frombuffer(data, np.uint8), 256 * v[0] + v[1], NONE, NONE, NO_BOUNDS, 0,
            np.empty((0, 3)), np.empty((0, 4)), out,
        )  # fmt: skip
    return code, out.tolist()


def _check(data: bytes, v, backend: str) -> int:
    """The pass agrees with the decoder on ``data``; returns the pass's answer."""
    code, (number, mid, tx, table, n) = _pass(data, v, backend)
    f = _decode(data, v)
    if code == kernels.FRAME_SLOW:
        return code
    assert code == kernels.FRAME_DECODED and f is not None
    assert number - (number >> 31 << 32) == f.frame
    assert (mid, tx) == (f.mid_exposure, f.transmit)
    assert n == len(f.body_table)
    assert data[table : table + 38 * n] == f.body_table.tobytes()
    return code


def _mutate(data: bytes, how: str, at: int, value: int) -> bytes:
    b = bytearray(data)
    at = at % max(len(b), 1)
    if how == "cut":
        b = b[:at]
    elif how == "cut_and_fix":  # a shorter payload whose header says so
        b = b[: max(at, 4)]
        b[2:4] = struct.pack("<H", len(b) - 4)
    elif how == "flip":
        b[at] ^= 1 << (value % 8)
    elif how == "word":  # a count or size overwritten
        b[at : at + 4] = struct.pack("<i", value)[: len(b) - at]
    elif how == "append":
        b += bytes([value % 256]) * (at % 9)
    return bytes(b)


FUZZ = settings(max_examples=250, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@pytest.mark.parametrize("backend", BACKENDS)
@FUZZ
@given(
    st.sampled_from(natnet.SUPPORTED_VERSIONS),
    frames,
    st.sampled_from(["none", "cut", "cut_and_fix", "flip", "word", "append"]),
    st.integers(0, 2**16),
    st.integers(-(2**31), 2**31 - 1),
)
def test_pass_agrees_with_decode_frame(backend, v, d, how, at, value):
    data = build(v, d) if v >= (3, 0) else _legacy(v, d)
    code = _check(data, v, backend)
    plain = all(len(n) <= 256 and all(c < 128 for c in n) for n, _ in d["msets"])
    if v >= (3, 0) and plain:  # every plain frame of 3.0+ takes the pass
        assert code == kernels.FRAME_DECODED
    elif v < (3, 0):
        assert code == kernels.FRAME_SLOW
    _check(_mutate(data, how, at, value), v, backend)


@pytest.mark.parametrize("backend", BACKENDS)
@FUZZ
@given(st.binary(max_size=120), st.sampled_from(natnet.SUPPORTED_VERSIONS))
def test_pass_on_random_bytes(backend, data, v):
    _check(data, v, backend)
    _check(natnet.encode_message(natnet.FRAMEOFDATA, data), v, backend)


# -- the input with and without the pass -----------------------------------------------------------
def _input(v, up_y: int, mm: int, bodies=6):
    specs = {}
    for k in range(1, bodies + 1):
        doc = {"natnet": {"command_port": 1, "body": k}}
        if k == up_y:
            doc["up"] = "y"
        if k == mm:
            doc["unit"] = "mm"
        specs[f"b{k}"] = (parse_input(doc), COV)
    (inp,) = make_inputs(specs)
    info = natnet.ServerInfo(natnet_version=(*v, 0, 0), clock_frequency=FREQ)
    inp.handle(natnet.encode_server_info(info), 0)
    return inp


def without_pass(inp):
    """The input decoding every datagram with decode_frame (the path before the pass)."""
    inp._frame_pass = lambda data, arrival_ns: None
    return inp


def _same(a, b):
    assert type(a) is type(b)
    assert [i for i, _ in a] == [i for i, _ in b]
    for (_, x), (_, y) in zip(a, b):
        assert type(x) is type(y) and x.t_ns == y.t_ns and x.arrival_ns == y.arrival_ns
        for u, w in ((x.position, y.position), (x.quaternion, y.quaternion),
                     (x.covariance, y.covariance)):  # fmt: skip
            assert u.dtype == w.dtype == np.float64 and u.tobytes() == w.tobytes()
    if isinstance(a, SampleBlock):
        for u, w in ((a.position, b.position), (a.quaternion, b.quaternion),
                     (a.covariance, b.covariance)):  # fmt: skip
            assert u.tobytes() == w.tobytes() and not u.flags.writeable


def status_of(s) -> dict:
    """Every figure a reader of a SensorStatus sees."""
    now = 1_700_000_000_000_000_000
    return {
        "summary": s.summary(now),
        "line": s.line(now),
        "latency": list(s.latency_ns),
        "arrivals": list(s.arrivals_ns),
        "fields": (
            s.packets,
            s.measurements,
            s.dropouts,
            s.last_frame,
            s.last_arrival_ns,
            s.connected,
            s.clock,
            s.rejected,
        ),  # fmt: skip
        "rejections": dict(s.rejections),
        "connection": dict(s.connection),
    }


def _stream(rng, n, kinds_of):
    """Frames of 7 bodies (ids 1-7) with some bodies missing, untracked, non-finite, too
    long, noisy; some frames repeated, reordered or with bad stamps."""
    out = []
    number = 100
    for i in range(n):
        kinds = kinds_of(i)
        bodies = []
        for k in range(1, 8):
            kind = kinds[k - 1]
            if kind == "missing":
                continue
            p = rng.normal(0, 1, 3)
            q = rng.normal(0, 1, 4)
            q /= np.linalg.norm(q)
            err, params = 2e-4, 1
            if kind == "untracked":
                params = 0
            elif kind == "nan":
                p[1] = np.nan
            elif kind == "long":
                q *= 1.2
            elif kind == "slightly":
                q *= 1.04
            elif kind == "noisy":
                err = 5e-3
            elif kind == "bad_error":
                err = -1.0
            elif kind == "huge":
                p[0] = 3e38
            bodies.append((k, tuple(p), tuple(q), err, params))
        number += 1 if i % 11 else (-3 if i % 22 else 2)  # duplicates, gaps
        tick = 1_000_000 + i * FREQ // 240
        d = {"frame": number, "msets": [(b"all", 2)], "unlabeled": 0, "bodies": bodies,
             "skeletons": [], "assets": 0, "labeled": 2, "plates": [], "devices": [],
             "ticks": (tick, tick + (20_000 if i % 13 else -5)), "eod": True}  # fmt: skip
        out.append(d)
    return out


KINDS = ("ok", "ok", "ok", "ok", "missing", "untracked", "nan", "long", "slightly", "noisy",
         "bad_error", "huge")  # fmt: skip


@pytest.mark.parametrize("backend", BACKENDS)
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.sampled_from([(3, 0), (3, 1), (4, 0), (4, 1)]),
    st.integers(0, 7),
    st.integers(0, 7),
    st.floats(0.0, 1.0),
    st.integers(0, 2**32 - 1),
)
def test_input_with_the_pass_equals_without(backend, v, up_y, mm, bad_share, seed):
    rng = np.random.default_rng(seed)
    kind_rng = np.random.default_rng(seed + 1)

    def kinds_of(i):
        if kind_rng.random() >= bad_share:
            return ["ok"] * 6 + ["ok" if i % 3 else "missing"]
        return list(kind_rng.choice(KINDS, 7))

    with use_backend(backend):
        fast, slow = _input(v, up_y, mm), without_pass(_input(v, up_y, mm))
        for i, d in enumerate(_stream(rng, 40, kinds_of)):
            data = build(v, d)
            if i % 17 == 5:
                data = data[:-30]  # truncated: a counted rejection
            arrival = 1_700_000_000_000_000_000 + i * 4_166_667 + 3_000_000 + (i % 5) * 1000
            _same(fast.handle(data, arrival), slow.handle(data, arrival))
            if i == 20:  # the model definitions arrive: a new plan
                defs = natnet.ModelDefinitions((natnet.RigidBodyDescription("b", 1),))
                msg = natnet.encode_model_definitions(defs, v)
                assert fast.handle(msg, arrival) == slow.handle(msg, arrival) == []
    for a, b in zip(fast.bodies, slow.bodies):
        assert status_of(a.status) == status_of(b.status)
    assert fast.clock.estimate == slow.clock.estimate and fast.packets == slow.packets


def test_plain_frames_make_blocks_through_the_pass():
    """20 plainly valid bodies: the pass makes the block (decode_frame is not called)."""
    inp = _input((4, 1), 0, 0, bodies=20)
    real = natnet.decode_frame
    calls = []
    natnet.decode_frame = lambda *a, **k: calls.append(1) or real(*a, **k)
    try:
        for i in range(3):
            bodies = [(k, (0.1 * k, 1.0, 2.0), (0.0, 0.0, 0.6, 0.8), 1e-4, 1)
                      for k in range(20, 0, -1)]  # fmt: skip
            tick = 10_000 + i * 41_667
            d = {"frame": 5 + i, "msets": [(b"all", 1), (b"rb", 3)], "unlabeled": 1,
                 "bodies": bodies, "skeletons": [1], "assets": 1, "labeled": 4,
                 "plates": [[2, 0]], "devices": [[1]], "ticks": (tick, tick + 20_000),
                 "eod": False}  # fmt: skip
            out = inp.handle(build((4, 1), d), 10**18 + i * 4_166_700)  # as the ticks go
            assert isinstance(out, SampleBlock) and list(out.index) == list(range(20))
            assert out.position[0].tolist() == [np.float32(0.1).item(), 1.0, 2.0]
    finally:
        natnet.decode_frame = real
    assert calls == [] and [b.status.measurements for b in inp.bodies] == [3] * 20


@pytest.mark.skipif(not numba_available(), reason="needs numba (the compiled backend)")
def test_warm_up_compiles_what_a_live_packet_runs():
    """After warm_up_inputs, frames (blocks, per-body fallbacks, new ids) compile nothing."""
    from trackflow.trackers.inputs import warm_up_inputs

    with use_backend("numba"):
        warm_up_inputs()
        k = kernels_for(kernels)
        before = {name: len(getattr(k, name).signatures) for name in kernels.KERNELS}
        inp = _input((4, 1), 0, 0)
        for i, d in enumerate(_stream(np.random.default_rng(3), 30, lambda i: KINDS[:7])):
            inp.handle(build((4, 1), d), 10**18 + i * 4_166_667)
        bodies = [(k, (0.1 * k, 1.0, 2.0), (0.0, 0.0, 0.6, 0.8), 1e-4, 1) for k in range(1, 8)]
        d = {"frame": 10_000, "msets": [], "unlabeled": 0, "bodies": bodies, "skeletons": [],
             "assets": 0, "labeled": 0, "plates": [], "devices": [], "ticks": (10, 20),
             "eod": True}  # fmt: skip
        inp = _input((4, 1), 0, 0)  # a new tracker clock (one input's would refuse the step)
        for i in range(3):  # all plainly valid: blocks
            ticks = (10 + 41_667 * i, 20 + 41_667 * i)  # a frame's stamps go forward
            out = inp.handle(
                build((4, 1), {**d, "frame": 10_000 + i, "ticks": ticks}),
                2 * 10**18 + i * 4_166_700,
            )
            assert isinstance(out, SampleBlock)
        after = {name: len(getattr(k, name).signatures) for name in kernels.KERNELS}
    assert before == after
