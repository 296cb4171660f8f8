"""Rehearsal: twins of an input's packet path that leave the live path untouched.

The live answers, filter states and counts with a rehearsal of each previous frame between
the packets are the same to the bit as without; the twins take the frames themselves; a
sensor the twins cannot copy is refused by name; a failing rehearsal is turned off and
reported, and the live input goes on."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow.dataflow import KalmanFilter, parse_input
from trackflow.graph import MotionSpec
from trackflow.math import quat_exp
from trackflow.trackers import natnet
from trackflow.trackers.inputs import SampleBlock, make_inputs
from trackflow.trackers.rehearsal import Rehearsal
from trackflow.trackers.runtime import LiveSource, LiveSources

BODIES, FREQ = 4, 10_000_000
MOTION = MotionSpec(static=False, n_dp=1, n_do=1, noise=(0.0, 30.0, 0.0, 100.0))


def _frames(n: int) -> list[tuple[bytes, int]]:
    """NatNet 4.1 frames of moving bodies at 240 Hz, received 3 ms after transmit."""
    out = []
    t0 = 1_700_000_000_000_000_000
    for i in range(n):
        t = t0 + i * 1_000_000_000 // 240
        bodies = tuple(
            natnet.NatNetRigidBody(
                k,
                (0.1 * k + 0.01 * np.sin(0.05 * i), 0.2, 0.5 + 0.001 * i),
                tuple(quat_exp(np.array([0.1, 0.2 + 0.002 * i, 0.03 * k]))),
                2e-4,
                True,
            )
            for k in range(1, BODIES + 1)
        )
        tick = t * FREQ // 1_000_000_000
        frame = natnet.NatNetFrame(i + 1, bodies, t * 1e-9, tick, tick, tick + 20_000)
        out.append((natnet.encode_frame(frame, (4, 1)), t + 3_000_000))
    return out


def _network(rehearse_us: float = 0.0):
    specs = {
        f"b{k}": (
            parse_input({"natnet": {"command_port": 1, "body": k, "rehearse_us": rehearse_us}}),
            np.eye(6) * 1e-6,
        )
        for k in range(1, BODIES + 1)
    }
    (inp,) = make_inputs(specs)
    inp.handle(
        natnet.encode_server_info(
            natnet.ServerInfo(natnet_version=(4, 1, 0, 0), clock_frequency=FREQ)
        ),
        0,
    )
    sources = {name: LiveSource(name) for name in specs}
    for name, src in sources.items():
        src.consumers.append((KalmanFilter(f"kf_{name}", MOTION), 0))
    return inp, sources


def _run(frames, rehearse: bool):
    """The live answers of every frame (arrays), with or without rehearsals between."""
    inp, sources = _network(400 if rehearse else 0)
    names = [b.name for b in inp.bodies]
    delivery = LiveSources(sources)
    rehearsal = Rehearsal(inp, sources, answer=True) if rehearse else None
    answers = []
    for k, (data, arrival) in enumerate(frames):
        if rehearsal is not None and k:
            rehearsal(*frames[k - 1])  # the last frame, before this one
        block = inp.handle(data, arrival)
        assert type(block) is SampleBlock
        got = []
        delivery.deliver_block(
            [names[i] for i in block.index], block, arrival, answer=(arrival, got.append)
        )
        (a,) = got
        answers.append(np.concatenate([a.position, a.quaternion, a.covariance.reshape(-1, 36)], 1))
    return inp, sources, rehearsal, np.stack(answers)


def test_the_live_path_is_the_same_to_the_bit_with_rehearsals():
    frames = _frames(120)
    inp0, src0, _, plain = _run(frames, rehearse=False)
    inp1, src1, rehearsal, rehearsed = _run(frames, rehearse=True)
    assert np.array_equal(plain, rehearsed)  # every answer, to the bit
    for name in src0:
        f0, f1 = src0[name].consumers[0][0], src1[name].consumers[0][0]
        assert np.array_equal(f0.filter._x, f1.filter._x)
        assert np.array_equal(f0.filter._p, f1.filter._p)
        assert f0.stats.events_in == f1.stats.events_in == len(frames)
        assert src1[name].stats.events_out == len(frames)
        assert f1.last_t == f0.last_t
    for b0, b1 in zip(inp0.bodies, inp1.bodies):  # the live input's counts: its own
        assert b0.status.summary(0, 1.0) == b1.status.summary(0, 1.0)
    # the twins took the frames themselves: their own filters and counts
    assert rehearsal.runs == len(frames) - 1
    for name, src in rehearsal.sources.sources.items():
        kf = src.consumers[0][0]
        assert kf is not src1[name].consumers[0][0]
        assert kf.stats.events_in == len(frames) - 1
    assert rehearsal.twin.packets == len(frames) - 1
    assert rehearsal.twin.server is inp1.server  # the handshake mirrored
    rehearsal(*frames[-2])  # the same frame again: skipped
    assert rehearsal.runs == len(frames) - 1
    twin = rehearsal.sources.sources["b1"].consumers[0][0]
    rehearsal(*frames[-1], lambda: True)  # a datagram waits: decoded, not delivered
    assert rehearsal.runs == len(frames) - 1 and rehearsal.cut == 1
    assert twin.stats.events_in == len(frames) - 1
    assert rehearsal.twin.packets == len(frames)


def test_a_sensor_the_twins_cannot_copy_is_named():
    inp, sources = _network()
    sources["b2"].consumers.append((KalmanFilter("extra", MOTION), 0))  # two consumers
    with pytest.raises(ValueError, match=r"sensor 'b2': a rehearsal needs a source"):
        Rehearsal(inp, sources)
    sources["b2"].consumers.pop()
    del sources["b3"]  # no source
    with pytest.raises(ValueError, match=r"sensor 'b3': a rehearsal needs a source"):
        Rehearsal(inp, sources)


def test_a_failing_rehearsal_is_turned_off_and_reported():
    inp, sources = _network(400)
    calls = []

    def broken(data, arrival, waiting):
        calls.append(arrival)
        raise RuntimeError("twin exploded")

    inp.rehearsal = broken
    wait = inp._due_wait()
    assert wait.rehearse is not None and wait.rehearse_s == pytest.approx(4e-4)
    inp._rehearse(lambda: False)  # no frame yet: nothing to rehearse
    assert calls == []
    data, arrival = _frames(1)[0]
    inp._frame_arrived(wait, data, arrival)
    inp._rehearse(lambda: False)
    assert calls == [arrival]
    assert wait.rehearse is None  # off for the rest of the run
    for b in inp.bodies:
        assert b.status.connection == {"rehearsal off: RuntimeError: twin exploded": 1}


def test_trackflow_run_gives_an_input_with_rehearse_us_its_rehearsal_or_says_why_not():
    from trackflow.trackers.runtime import _rehearse

    inp, sources = _network(400)
    _rehearse(inp, sources)
    assert isinstance(inp.rehearsal, Rehearsal) and inp.rehearsal.input is inp
    off, _ = _network(0)
    _rehearse(off, sources)
    assert off.rehearsal is None  # not asked for
    other, sources = _network(400)
    sources["b1"].consumers.clear()
    _rehearse(other, sources)
    assert other.rehearsal is None
    assert other.bodies[0].status.connection == {
        "rehearsal off: sensor 'b1': a rehearsal needs a source feeding one Kalman filter": 1
    }


def _dtrack_frames(n: int) -> list[tuple[bytes, int]]:
    """DTrack frames (``fr``, ``ts2``, ``6d``) of two moving bodies at 240 Hz [mm]."""
    from trackflow.math import quat_to_matrix
    from trackflow.trackers import dtrack

    out = []
    for i in range(n):
        t_us = 1_700_000_000_000_000 + i * 1_000_000 // 240
        bodies = tuple(
            dtrack.DTrackBody(
                k,
                1.0,
                (100.0 * k + 10 * np.sin(0.05 * i), 200.0, 500.0 + i),
                tuple(quat_to_matrix(quat_exp(np.array([0.1, 0.002 * i, 0.03 * k]))).ravel()),
            )
            for k in (1, 2)
        )
        ts2 = (t_us // 1_000_000, t_us % 1_000_000, 4_000)
        frame = dtrack.DTrackFrame(i + 1, None, ts2, 2, bodies)
        out.append((dtrack.encode_dtrack(frame), t_us * 1000 + 5_000_000))
    return out


def test_a_dtrack_path_of_sample_pairs_is_rehearsed_and_untouched():
    from trackflow.trackers.runtime import _dispatched

    frames = _dtrack_frames(60)
    specs = {
        f"d{k}": (
            parse_input({"dtrack": {"port": 1, "body": k, "rehearse_us": 400}}),
            np.eye(6) * 1e-6,
        )
        for k in (1, 2)
    }
    runs = []
    for with_rehearsal in (False, True):
        (inp,) = make_inputs(specs)
        sources = {name: LiveSource(name) for name in specs}
        for name, src in sources.items():
            src.consumers.append((KalmanFilter(f"kf_{name}", MOTION), 0))
        delivery = LiveSources(sources)
        rehearsal = Rehearsal(inp, sources, answer=True) if with_rehearsal else None
        for k, (data, arrival) in enumerate(frames):
            if rehearsal is not None and k:
                rehearsal(*frames[k - 1])
            pairs = inp.handle(data, arrival)
            assert len(pairs) == 2 and type(pairs) is not SampleBlock
            names = [inp.bodies[i].name for i, _ in pairs]
            delivery.deliver(_dispatched(names, pairs, arrival))
        filters = [sources[n].consumers[0][0] for n in specs]
        runs.append(([f.filter._x.copy() for f in filters], [f.stats.events_in for f in filters]))
        if rehearsal is not None:
            assert rehearsal.runs == len(frames) - 1
            twin = rehearsal.sources.sources["d1"].consumers[0][0]
            assert twin.stats.events_in == len(frames) - 1
    (x0, n0), (x1, n1) = runs
    assert n0 == n1 == [len(frames)] * 2
    assert all(np.array_equal(a, b) for a, b in zip(x0, x1))


def test_bodies_named_in_the_model_definitions_are_rehearsed_with_the_live_names():
    """A body given by name needs MODELDEF: the twin input takes the live input's model
    definitions (and server info) before each run, so it finds the body as the live one."""
    specs = {
        "head": (parse_input({"natnet": {"command_port": 1, "body": "rig"}}), np.eye(6) * 1e-6)
    }
    (inp,) = make_inputs(specs)
    inp.handle(
        natnet.encode_server_info(
            natnet.ServerInfo(natnet_version=(4, 1, 0, 0), clock_frequency=FREQ)
        ),
        0,
    )
    defs = natnet.ModelDefinitions((natnet.RigidBodyDescription("rig", 2),))
    inp.handle(natnet.encode_model_definitions(defs, (4, 1)), 0)
    sources = {"head": LiveSource("head")}
    sources["head"].consumers.append((KalmanFilter("kf_head", MOTION), 0))
    rehearsal = Rehearsal(inp, sources)
    for data, arrival in _frames(5):  # bodies 1..4: "rig" is body 2
        rehearsal(data, arrival)
    assert rehearsal.runs == 5 and rehearsal.twin.models is inp.models
    twin = rehearsal.sources.sources["head"].consumers[0][0]
    assert twin.stats.events_in == 5 and twin.stats.rejected == 0
