"""The optical tracker end to end on rendered frames of real recordings: consistency (NEES),
identities of similar bodies, recovery after a full occlusion, the dataflow sensor, bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.stats import chi2

from trackflow.math import quat_conjugate, quat_log, quat_multiply
from trackflow.optical.pipeline import OpticalTracker, TrackerConfig
from trackflow.optical.render import RenderSettings
from trackflow.optical.source import OpticalBodySensor, load_optical_setup

from ._scene import renderer

ROOT = Path(__file__).resolve().parents[2]


def _error(est, truth):
    dq = quat_multiply(quat_conjugate(est.quaternion), truth.quaternion)
    return np.concatenate([truth.position - est.position, quat_log(dq)])


def _track(r, n, sigma, t0=5.0, rate=120.0):
    trk = OpticalTracker(r.rig, r.models, TrackerConfig(sigma_px=sigma))
    out = []
    for i in range(n):
        t = t0 + i / rate
        fr = r.render(t)
        out.append((fr, trk.process(t, fr.images)))
    return trk, out


@pytest.mark.slow
def test_tracks_three_bodies_consistently_without_swaps(shared_data):
    cal, _ = _track(renderer(shared_data, seed=5), 30, 0.12)
    sigma = cal.pixel_sigma_estimate("poses")
    assert 0.08 < sigma < 0.14  # 0.1 px jitter plus the centroid's own error
    assert abs(cal.pixel_sigma_estimate("points") / sigma - 1) < 0.1
    trk, frames = _track(renderer(shared_data, seed=1), 90, sigma)
    nees, measured = [], 0
    for fr, res in frames:
        for name, b in res.bodies.items():
            if b.pose is None:
                continue
            measured += 1
            e = _error(b.pose, fr.poses[name])
            assert np.linalg.norm(e[:3]) < 0.005, f"{name} at t={fr.t}: wrong body or place"
            nees.append(e @ np.linalg.solve(b.pose.covariance, e))
    assert measured > 0.9 * 3 * len(frames)
    n = len(nees)
    lo, hi = chi2.ppf([0.001, 0.999], 6 * n) / n
    assert lo < np.mean(nees) < hi
    assert trk.stats["tracked"] > 0.9 * measured  # the prediction guides almost every frame


@pytest.mark.slow
def test_recovers_after_a_full_occlusion(shared_data):
    hidden = [("A", 5.1, 5.3)]
    s = RenderSettings(hidden=hidden, visibility_deg=100.0)
    trk, frames = _track(renderer(shared_data, s, seed=2), 48, 0.105)
    modes = {(round(fr.t, 4)): res.bodies["A"].mode for fr, res in frames}
    during = [m for t, m in modes.items() if 5.1 < t < 5.3]
    after = [(t, m) for t, m in modes.items() if t > 5.3]
    assert during and all(m == "lost" for m in during)
    # found by the first searches after the occlusion (one every search_interval_s = 20 ms)
    t_found = next(t for t, m in after if m == "found")
    assert t_found - 5.3 <= trk.config.search_interval_s + 2 / 120.0
    assert after[-1][1] == "tracked"
    for fr, res in frames:
        b = res.bodies["A"]
        if b.pose is not None:
            assert np.linalg.norm(b.pose.position - fr.poses["A"].position) < 0.005


def _example(shared_data, tmp_path, seconds=0.25) -> Path:
    """examples/optical.yaml with absolute paths and a short duration."""
    doc = yaml.safe_load((ROOT / "examples" / "optical.yaml").read_text())
    for tc in doc["render"]["trajectories"].values():
        tc["recording"] = str(shared_data / Path(tc["recording"]).relative_to("../../shared/data"))
    doc["render"]["duration_s"] = seconds
    doc["setup"] = str(ROOT / "examples" / "optical_setup.yaml")
    doc["calibration"] = str(ROOT / "examples" / "optical_cameras.yml")
    p = tmp_path / "optical.yaml"
    p.write_text(yaml.safe_dump(doc))
    return p


def test_optical_sensor_in_a_dataflow_network(shared_data, tmp_path):
    opt = load_optical_setup(_example(shared_data, tmp_path))
    sources = opt.sources()
    assert all(isinstance(s, OpticalBodySensor) for s in sources.values())
    net, sink = opt.setup.plan().build(sources)
    net.run()
    st = net.stats()
    frames = len(opt.run.t_ns)
    for edge in opt.bodies:
        assert st[edge]["events_in"] == frames
        assert st[edge]["events_out"] + sum(st[edge]["rejections"].values()) == frames
        assert st[edge]["events_out"] > 0.5 * frames
    assert len(sink.events) > 0
    cov = sink.events[-1].pose.covariance
    assert np.all(np.isfinite(cov)) and np.linalg.eigvalsh(cov)[0] > 0


def test_bad_input(shared_data, tmp_path):
    r = renderer(shared_data)
    trk = OpticalTracker(r.rig, r.models)
    with pytest.raises(ValueError, match="need 4 images"):
        trk.process(0.0, [np.zeros((10, 10), np.uint8)])
    with pytest.raises(ValueError, match="blobs of 4 cameras"):
        trk.process_blobs(0.0, [])
    with pytest.raises(ValueError, match="sigma_px"):
        TrackerConfig(sigma_px=0.0)
    with pytest.raises(ValueError, match="unique names"):
        OpticalTracker(r.rig, r.models + r.models[:1])
    with pytest.raises(ValueError, match="level"):
        trk.pixel_sigma_estimate("frames")
    assert np.isnan(trk.pixel_sigma_estimate())  # nothing measured yet
    res = trk.process_blobs(0.0, [np.zeros((0, 2))] * 4)  # nothing seen: all lost, no crash
    assert all(b.mode == "lost" and b.pose is None for b in res.bodies.values())
    with pytest.raises(ValueError, match="not after the previous frame"):
        trk.process_blobs(0.0, [np.zeros((0, 2))] * 4)
    res = trk.process_blobs(0.01, [np.full((3, 2), np.nan)] + [np.zeros((0, 2))] * 3)
    assert trk.stats["rejected_blobs"] == 3 and res.n_blobs == 0
    base = yaml.safe_load((ROOT / "examples" / "optical.yaml").read_text())
    base["setup"] = str(ROOT / "examples" / "optical_setup.yaml")
    base["calibration"] = str(ROOT / "examples" / "optical_cameras.yml")
    cases = [
        ({"colour": 1}, "unknown keys"),
        ({"bodies": {"tracker_wand": "nope"}}, "unknown model 'nope'"),
        ({"bodies": {"no_sensor": "wand"}}, "not a sensor"),
        ({"render": {"rate_hz": 10}}, "needs trajectories"),
        ({"tracker": {"speed": 3}}, "tracker: unknown keys"),
    ]
    for change, match in cases:
        p = tmp_path / "bad.yaml"
        p.write_text(yaml.safe_dump(base | change))
        with pytest.raises(ValueError, match=match) as e:
            load_optical_setup(p)
        assert str(p) in str(e.value)


def test_command_line_answers_the_query_and_records(shared_data, tmp_path, capsys):
    from trackflow.cli.main import main
    from trackflow.io import read_stream

    out = tmp_path / "wand_in_tool.tfrec"
    assert main(["optical", str(_example(shared_data, tmp_path, 0.2)), "--out", str(out)]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["query"] == "wand_in_tool" and d["frames"] == 25 and d["results"] > 0
    assert set(d["sensors"]) == {"tracker_wand", "tracker_tool"}
    stream, _ = read_stream(out)
    assert len(stream.t_ns) == d["results"] and stream.covariance is not None


def test_merged_blobs_are_not_used_while_tracking(shared_data):
    """A blob far larger than its body's other blobs in that image (two merged markers) is
    not assigned: the marker whose blobs are declared merged in every camera drops out."""
    import copy

    from trackflow.optical.blobs import detect_blobs

    r = renderer(shared_data, seed=3)
    trk = OpticalTracker(r.rig, r.models, TrackerConfig(sigma_px=0.105))
    for i in range(6):
        fr = r.render(5.0 + i / 120)
        trk.process(fr.t, fr.images)
    fr = r.render(5.0 + 6 / 120)
    bl = [detect_blobs(im, 20, 6) for im in fr.images]
    # the A marker seen by most cameras, and its blob in each of them
    seen = {}
    for c, b in enumerate(bl):
        lab, uvt = fr.blob_label[c], fr.blob_uv[c]
        for k in np.flatnonzero((lab >= 0) & (lab < 1000)):
            d = np.linalg.norm(b.uv - uvt[k], axis=1)
            if d.min() < 0.3:
                seen.setdefault(lab[k], []).append((c, int(d.argmin())))
    marker = max(seen, key=lambda m: len(seen[m]))
    assert len(seen[marker]) >= 2
    areas = [b.area.astype(float) for b in bl]
    merged = [a.copy() for a in areas]
    for c, k in seen[marker]:
        merged[c][k] *= 10
    normal = copy.deepcopy(trk).process_blobs(fr.t, [b.uv for b in bl], areas)
    flagged = trk.process_blobs(fr.t, [b.uv for b in bl], merged)
    assert normal.bodies["A"].mode == flagged.bodies["A"].mode == "tracked"
    assert flagged.bodies["A"].n_markers == normal.bodies["A"].n_markers - 1
    with pytest.raises(ValueError, match="one value per blob"):
        trk.process_blobs(fr.t + 0.01, [b.uv for b in bl], areas[:2])
