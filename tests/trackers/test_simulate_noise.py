"""``trackflow simulate``'s degradations, decoded from the packets it builds: seeded position
and orientation noise of the asked sigma on top of the recording (whose truth stays
noise-free), and latency and noise that change mid-run (``--change``)."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow.errors import InputError
from trackflow.io import read_stream
from trackflow.math import quat_angle, quat_from_matrix
from trackflow.trackers import dtrack
from trackflow.trackers.simulate import SimConfig, Simulator


def _sent(sim: Simulator) -> tuple[np.ndarray, np.ndarray]:
    """Positions [m] and orientations decoded from every frame's DTrack packet."""
    pos, quat = [], []
    for i in range(len(sim.rel_s)):
        body = dtrack.decode_dtrack(sim._packet(i, 10**18, 10**18 + 5_000_000)).bodies[0]
        pos.append(np.array(body.position_mm) * 1e-3)
        quat.append(quat_from_matrix(np.array(body.rotation).reshape(3, 3)))
    return np.array(pos), np.array(quat)


def test_noise_of_the_asked_sigma_changes_mid_run(room1):
    stream, _ = read_stream(room1)
    cfg = SimConfig("dtrack", port=9, duration_s=20, noise_mm=0.5, noise_deg=0.1,
                    changes=((10.0, {"noise_mm": 2.0, "latency_ms": 30.0}),))  # fmt: skip
    sim = Simulator(stream, cfg)
    try:
        pos, quat = _sent(sim)
    finally:
        sim.close()
    later = sim.rel_s >= 10.0
    err = pos - sim.position
    ang = np.degrees(quat_angle(quat, sim.quaternion))
    for mask, sigma_mm in ((~later, 0.5), (later, 2.0)):
        per_axis = np.std(err[mask], axis=0) * 1e3
        assert np.allclose(per_axis, sigma_mm, rtol=0.1), per_axis  # ~1200 frames per axis
    # the angle of a 3-D Gaussian rotation of 0.1 deg per axis: RMS sqrt(3) * 0.1 deg
    assert np.sqrt(np.mean(ang**2)) == pytest.approx(np.sqrt(3) * 0.1, rel=0.1)
    assert np.all(sim.latency_ns[~later] == 5_000_000) and np.all(sim.latency_ns[later] == 30e6)
    # the same seed, the same noise
    again = Simulator(stream, cfg)
    try:
        assert np.array_equal(_sent(again)[0], pos)
    finally:
        again.close()


@pytest.mark.parametrize(("kw", "message"), [
    ({"noise_mm": -1.0}, "noise_mm >= 0"),
    ({"changes": ((1.0, {"jitter_ms": 1.0}),)}, "a change at 1.0 s needs"),
    ({"changes": ((-1.0, {"noise_mm": 1.0}),)}, "a change at -1.0 s needs"),
])  # fmt: skip
def test_bad_degradations_are_refused(room1, kw, message):
    stream, _ = read_stream(room1)
    with pytest.raises(InputError, match=message):
        Simulator(stream, SimConfig("dtrack", port=9, duration_s=1, **kw))


def test_plays_go_back_and_forth_on_one_time_line():
    """``plays=3``: forwards, backwards, forwards, on one increasing time and frame line, so
    the motion is continuous at every turn."""
    from trackflow.io import PoseStream

    t = np.arange(5, dtype=np.int64) * 10_000_000
    pos = np.stack([np.arange(5.0), np.zeros(5), np.zeros(5)], axis=1)
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (5, 1))
    sim = Simulator(PoseStream("w", "b", t, pos, quat), SimConfig("dtrack", plays=3))
    assert np.all(np.diff(sim.rel_s) > 0) and np.all(np.diff(sim.frames) == 1)
    assert sim.position[:, 0].tolist() == [0, 1, 2, 3, 4, 4, 3, 2, 1, 0, 0, 1, 2, 3, 4]
    np.testing.assert_allclose(sim.rel_s[5] - sim.rel_s[4], 0.01)
    with pytest.raises(ValueError, match="plays"):
        Simulator(PoseStream("w", "b", t, pos, quat), SimConfig("dtrack", plays=0))
