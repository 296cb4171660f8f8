"""The views without a browser: loopback binding, what the server serves, the live view's
edge states and decimation, the PoseTool page's recomputation, and the command line."""

from __future__ import annotations

import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("viser", reason="the viewer extra (viser) is not installed")

from trackflow.cli.main import main
from trackflow.dataflow import Network, RecordingPlayer, parse_setup
from trackflow.evaluation import evaluate_predictors
from trackflow.io import PoseStream, write_stream
from trackflow.math import quat_exp
from trackflow.viewer import ViewServer, attach_view, setup_sources
from trackflow.viewer.posetool import PoseTool, PoseToolPage, manual_predictor


def _get(url: str) -> tuple[int, bytes]:
    try:
        with urllib.request.urlopen(url, timeout=10) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, b""


def test_binds_loopback_and_serves_only_its_page():
    view = ViewServer(port=0)
    try:
        assert view.server.get_host() == "127.0.0.1"
        status, body = _get(view.url)
        assert status == 200 and b"<html" in body.lower()
        for path in ("../pyproject.toml", "%2e%2e/%2e%2e/etc/passwd", "does-not-exist.js"):
            code, body = _get(view.url + path)
            assert code == 404 or b"root:" not in body and b"[project]" not in body
        # a client's share request never opens a tunnel
        assert view.server.request_share_url() is None
    finally:
        view.close()


class _Camera:
    """What viser keeps of a page's camera, after the page reported it (a stand-in: the
    race below cannot be timed with a real page)."""

    def __init__(self):
        self.update_timestamp = 1.0  # reported
        self.wxyz, self.position, self.look_at = (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 5.0), (0, 0, 0)
        self.fov, self.image_width, self.image_height = 1.0, 640, 480
        self.callbacks = []

    def on_update(self, cb):
        self.callbacks.append(cb)


class _Page:
    client_id = 7

    def __init__(self):
        self.camera = _Camera()


def test_a_page_that_reported_before_it_was_watched_goes_home():
    """viser runs the connect callbacks on its thread pool after the page's first camera
    report has passed the camera callbacks: a page watched after its report is moved to the
    home camera at once, not at a next report that a still camera never sends (a burner
    run: no ball on the page for 90 s)."""
    view = ViewServer(port=0)
    try:
        view.place_camera((4.0, -1.0, 2.0), (2.5, 2.0, 0.4))
        page = _Page()
        view.watch_page(page)
        assert np.allclose(page.camera.position, (4.0, -1.0, 2.0))
        assert np.allclose(page.camera.look_at, (2.5, 2.0, 0.4))
        assert view.has_browser_camera and len(page.camera.callbacks) == 1
        page.camera.position = (9.0, 9.0, 9.0)  # the user moves it: a report keeps it there
        page.camera.callbacks[0](page.camera)
        assert np.allclose(page.camera.position, (9.0, 9.0, 9.0))
    finally:
        view.close()


SETUP = {
    "frames": ["A", "T"],
    "sensors": [{"name": "art", "source": "A", "target": "T", "rate_hz": 100, "latency_ms": 10,
                 "sigma_pos_mm": 1.0, "sigma_ori_deg": 0.5}],
    "queries": [{"name": "q", "source": "A", "target": "T", "mode": "push", "rate_hz": 50},
                {"name": "lost", "source": "T", "target": "A", "exclude": ["art"]}],
}  # fmt: skip


def test_live_view_taps_states_and_no_path(tmp_path):
    setup = parse_setup(SETUP)
    sources = setup_sources(setup, 2.0, seed=3)
    net = Network()
    plan = setup.plan("q")
    plan.build(sources, network=net, prefix="q:")
    with pytest.raises(ValueError):
        setup.plan("lost")
    live = attach_view(
        net, setup, {"q": (plan, "q:")}, port=0, rate_hz=10, errors={"lost": "no path"}
    )
    try:
        net.run(until_ns=int(1.5e9))
        tap = net["view:art"]
        # every accepted measurement reached the tap, behind the sensor's filter
        kf = net["kf_art"].stats
        # samples at 0, 10, ..., 1490 ms arrived (10 ms latency) by 1.5 s
        assert kf.events_in == 150
        assert tap.count == kf.events_in - kf.rejected
        assert tap.latest.t_ns == 1_490_000_000
        lat_ms = np.array([r[1] for r in tap.recent]) * 1e-6
        np.testing.assert_allclose(lat_ms, 10.0)  # the configured sensor latency
        assert np.isfinite([r[2] for r in tap.recent][5:]).all()  # NIS of every update
        states = {s.name: s for s in live.edge_statuses()}
        assert states["art"].state == "live" and states["art"].on_path
        assert states["lost"].state == "no path"
        # a push query is drawn from its own answers (50 Hz), with no extra pulls ...
        own = net["q:sampler"].stats
        assert net["view:q:now:tap"].count == own.events_in - own.rejected > 70
        # ... and the prediction ghost is pulled only while an offset is set
        ahead = live.layout.queries[0].ahead_slot
        assert live.board.read_pose(ahead) is None
        # the view process draws from the board while the network stands still
        assert live.wait_frames(1, timeout_s=60), "the view process drew no frame"
        pose = live.board.read_pose(tap.slot)  # the filter's posterior, decimated to 10 Hz
        assert pose is not None and 1_390_000_000 <= pose.t_ns <= 1_490_000_000
        # two seconds of data end; the clock runs on (the query's sampler) -> stale
        states = {s.name: s.state for s in live.edge_statuses(now_ns=int(2.6e9))}
        assert states["art"] == "stale"
        # with an offset, the query's tap pulls the answer that far ahead (view-rate decimated)
        live.set_offset(0.05)
        net.run(until_ns=int(1.0e9))
        got = live.board.read_pose(ahead)
        now = live.board.read_pose(live.layout.queries[0].now_slot)
        assert got is not None and got.t_ns == now.t_ns + 50_000_000
        assert 0.9e9 <= now.t_ns <= 1.0e9
    finally:
        live.close()


def test_attach_view_to_a_bare_network():
    t = np.arange(0, 1.0, 0.01)
    n = len(t)
    stamps = np.round(t * 1e9).astype(np.int64)
    quats = np.tile([0, 0, 0, 1.0], (n, 1))
    p = RecordingPlayer("cam", stamps, np.zeros((n, 3)), quats, np.eye(6) * 1e-6)
    net = Network()
    net.add(p)
    live = attach_view(net, port=0, rate_hz=10)
    try:
        net.run()
        assert net["view:cam"].count == n
        assert [s.name for s in live.edge_statuses()] == ["cam"]
    finally:
        live.close()


def _stream(duration=8.0, rate=100.0, seed=0) -> PoseStream:
    t = np.arange(0, duration, 1 / rate)
    rng = np.random.default_rng(seed)
    pos = np.stack([0.3 * np.sin(1.3 * t), 0.2 * np.cos(0.7 * t), 0.1 * np.sin(2.1 * t)], 1)
    pos += rng.normal(0, 5e-4, pos.shape)
    q = quat_exp(np.stack([0.3 * np.sin(t), 0.2 * np.sin(0.5 * t), 0 * t], 1))
    return PoseStream("world", "head", np.round(t * 1e9).astype(np.int64), pos, q)


def test_manual_predictor_layout():
    from trackflow.evaluation import default_predictor

    s = _stream()
    t = (s.t_ns - s.t_ns[0]) * 1e-9
    base = default_predictor(t, s.position, s.quaternion)
    m = manual_predictor(base, 3, 2, 1.0, -1.0).model
    assert (m.n_dp, m.n_do) == (3, 2)
    np.testing.assert_allclose(
        m.noise, [base.pos_sigma, 0, 0, 10.0, base.ori_sigma, 0, 0.1], rtol=1e-12
    )


@pytest.mark.slow
def test_posetool_recomputes_when_a_slider_moves():
    tool = PoseTool(_stream(), tune_fraction=0.5)
    server = ViewServer(port=0)
    page = PoseToolPage(tool, server)
    try:
        page.wait_tuned(timeout_s=600)
        before = page.last_rows
        assert set(before) == {"Kalman (hand)", "Kalman (tuned)", "linear", "none"}
        page.log_pos.value = -2.0
        page.wait_settled(timeout_s=120)
        after = page.last_rows
        assert after["Kalman (hand)"] != before["Kalman (hand)"]
        # the page shows exactly what the library computes for the slider setting
        pred = manual_predictor(tool.base, 2, 1, -2.0, float(page.log_ori.value))
        rep = evaluate_predictors(tool.recording, pred, (0.1,), scored_from=tool.split)
        assert after["Kalman (hand)"] == rep.stats["kalman"][100]
        # baselines and the tuning's choice do not depend on the hand setting
        assert after["linear"] == before["linear"]
        assert after["Kalman (tuned)"] == before["Kalman (tuned)"]
    finally:
        page.close()
        server.close()


def test_cli_errors_are_clear(tmp_path, capsys):
    assert main(["view", str(tmp_path / "missing.tum"), "--snapshot", str(tmp_path / "x.png")]) == 1
    assert "missing.tum" in capsys.readouterr().err
    rec = tmp_path / "rec.tum"
    write_stream(rec, _stream(duration=2.0))
    code = main(["view", str(rec), "--snapshot", str(tmp_path / "x.png"), "--at", "5"])
    assert code == 1
    assert "outside the recording" in capsys.readouterr().err
    bad = tmp_path / "bad.yaml"
    bad.write_text("sensors:\n  - {name: a, source: A}\n")
    assert main(["view", str(bad), "--snapshot", str(tmp_path / "y.png")]) == 1
    assert "bad.yaml" in capsys.readouterr().err
    # a camera is a position and an aim, for a recording's view; no panel is for a snapshot
    assert main(["view", str(rec), "--camera", "0,1,2"]) == 1
    assert "--camera and --look-at go together" in capsys.readouterr().err
    assert main(["view", str(rec), "--no-panel"]) == 1
    assert "--no-panel applies to --snapshot" in capsys.readouterr().err
    setup = Path(__file__).resolve().parents[2] / "examples" / "demo_setup.yaml"
    snap = ["--snapshot", str(tmp_path / "z.png"), "--camera", "0,1,2", "--look-at", "0,0,0"]
    assert main(["view", str(setup), *snap]) == 1
    assert "--camera applies to a recording's view" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["view", str(rec), "--camera", "0,1", "--look-at", "0,0,0"])
    assert "expected X,Y,Z, got '0,1'" in capsys.readouterr().err


def test_a_setup_runs_live_on_the_wall_clock(tmp_path):
    import yaml

    from trackflow.viewer import ViewOptions, start_setup

    path = tmp_path / "setup.yaml"
    path.write_text(yaml.safe_dump(SETUP))
    run = start_setup(path, ViewOptions(port=0, duration_s=2.0, rate_hz=20))
    try:
        run.wait_network_time(1.0, timeout_s=120)
        states = {s.name: s.state for s in run.view.edge_statuses()}
        assert states == {"art": "live", "lost": "no path"}
        assert run.network["view:art"].count > 50
    finally:
        run.close()
    assert run.error is None


def test_the_view_runs_in_its_own_lower_priority_process():
    import os

    net = Network()
    t = np.arange(0, 0.1, 0.01)
    stamps = np.round(t * 1e9).astype(np.int64)
    quats = np.tile([0, 0, 0, 1.0], (len(t), 1))
    net.add(RecordingPlayer("cam", stamps, np.zeros((len(t), 3)), quats, np.eye(6) * 1e-6))
    with pytest.raises(ValueError, match="priority"):
        attach_view(net, port=0, priority="high")
    live = attach_view(net, port=0, rate_hz=10)  # priority "low": niceness +10
    try:
        assert live.pid != os.getpid()
        mine = os.getpriority(os.PRIO_PROCESS, 0)
        assert os.getpriority(os.PRIO_PROCESS, live.pid) == min(mine + 10, 19)
    finally:
        live.close()
    assert live.process.returncode is not None  # closed means ended
    with pytest.raises(ValueError, match="duplicate"):  # one view per network
        attach_view(net, port=0)


def test_the_idle_priority_puts_the_view_process_in_the_idle_class():
    """``priority="idle"`` as the view process applies it (:func:`lower_priority`, first
    thing it does). Watched from outside: on a machine whose cores are busy, an idle-class
    process gets no CPU at all, so it could not report back (nor serve a view)."""
    import os
    import subprocess
    import sys

    code = (
        "from trackflow.viewer.live_process import lower_priority; import time; "
        "print(lower_priority('idle'), flush=True); time.sleep(120)"
    )
    src = str(Path(__file__).resolve().parents[2] / "src")
    env = {**os.environ, "PYTHONPATH": src}
    child = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env=env
    )
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and os.sched_getscheduler(child.pid) != os.SCHED_IDLE:
            time.sleep(0.05)
        assert os.sched_getscheduler(child.pid) == os.SCHED_IDLE
        assert os.sched_getscheduler(0) != os.SCHED_IDLE  # the caller keeps its class
    finally:
        child.kill()
        child.communicate()


def test_the_view_process_places_frames_and_bodies_like_pose_algebra():
    from trackflow.math import Pose, UncertainPose
    from trackflow.viewer.board import Board
    from trackflow.viewer.edges import EdgeLayout, QueryLayout, ViewLayout
    from trackflow.viewer.live_state import LiveState

    rng = np.random.default_rng(7)

    def pose():
        return Pose(rng.normal(size=3), quat_exp(rng.normal(size=3)))

    T_A_T, T_T_C, T_M_C = pose(), pose(), pose()  # a sensor, a static, a sensor seen backwards
    static = UncertainPose(T_T_C, np.eye(6) * 1e-6)
    edges = [
        EdgeLayout("art", "A", "T", False, 0),
        EdgeLayout("mount", "T", "C", True, value=static),
        EdgeLayout("cam", "M", "C", False, 1),
    ]
    layout = ViewLayout(["A", "T", "C", "M"], "A", edges, [QueryLayout("q", "A", "M")], 2)
    board = Board.create(2)
    cov = np.diag([1e-4, 4e-4, 9e-4, 1e-3, 2e-3, 3e-3])
    for slot, T in ((0, T_A_T), (1, T_M_C)):
        board.write_pose(slot, 1, T.position, T.quaternion, cov)
    state = LiveState(layout, board, 10.0)
    try:
        poses = state.read_poses()
        places = state.place_frames("A", poses)
        T_A_M = T_A_T @ T_T_C @ T_M_C.inverse()
        for frame, want in (("T", T_A_T), ("C", T_A_T @ T_T_C), ("M", T_A_M)):
            q, p = places[frame]
            np.testing.assert_allclose(p, want.position, atol=1e-12)
            got = Pose(p, q)
            assert abs(abs(np.dot(got.quaternion, want.quaternion)) - 1) < 1e-12
        bodies = state.bodies_in(places, poses)
        cam = bodies[[b.name for b in state.bodies].index("cam")]
        world = T_A_M @ T_M_C  # the camera's pose drawn at its source frame M
        np.testing.assert_allclose(cam.position, world.position, atol=1e-12)
        r = T_A_M.rotation_matrix  # translation error rotates into the world; rotation stays
        np.testing.assert_allclose(cam.covariance[:3, :3], r @ cov[:3, :3] @ r.T, atol=1e-15)
        np.testing.assert_allclose(cam.covariance[3:, 3:], cov[3:, 3:], atol=1e-15)
    finally:
        board.close()


def test_a_realms_agent_files_are_viewed_as_one_setup(tmp_path):
    """`trackflow view tracker.yaml camera.yaml app.yaml`: the union of a realm's agent files,
    as `trackflow plan` plans it; the app's query runs over both other agents' sensors."""
    from trackflow.demo.realm import write_demo_realm
    from trackflow.distributed.realm_setup import realm_setup
    from trackflow.viewer import ViewOptions, start_setup

    files = write_demo_realm(tmp_path, seconds=10.0)
    paths = [files[n] for n in ("tracker.yaml", "camera.yaml", "app.yaml")]
    run = start_setup(realm_setup(paths), ViewOptions(port=0, duration_s=5.0, rate_hz=20))
    try:
        run.wait_network_time(2.0, timeout_s=120)
        states = {s.name: s.state for s in run.view.edge_statuses()}
        assert states["art"] == "live" and states["artoolkit"] == "live", states
        assert run.network["view:art"].count > 0
    finally:
        run.close()
    assert run.error is None


def test_view_refuses_a_recording_among_agent_files(tmp_path, capsys):
    from trackflow.demo.realm import write_demo_realm

    files = write_demo_realm(tmp_path, seconds=2.0)
    assert main(["view", str(files["app.yaml"]), str(files["art.tfrec"])]) == 1
    assert "viewed together only as setups or agent files" in capsys.readouterr().err
