"""Failover between a query's paths (rule 8 of the planner, dataflow/_failover.py): the plan,
the move to a fallback when the preferred sensor stops or is refused, the hold before the
return, and that the answers after a move are honest (NEES against the truth)."""

from __future__ import annotations

import numpy as np
import pytest
from _scenario import MOTION, tracker_truth

from trackflow.dataflow import PathSwitch, RecordingPlayer, plan_query
from trackflow.graph import Query, SpatialRelationshipGraph
from trackflow.math import quat_exp, quat_multiply

RATE_Q = 50  # answers per second
GOOD_HZ, BACKUP_HZ = 60, 30
SIGMA = {"good": (2e-4, 5e-4), "backup": (1e-3, 2e-3)}  # position [m], rotation [rad]
OUTAGE = (1.5e9, 2.7e9)  # the good tracker sends nothing then [ns]
STALE_NS, HOLD_NS = 100_000_000, 400_000_000


def _graph() -> SpatialRelationshipGraph:
    g = SpatialRelationshipGraph()
    for name, rate in (("good", GOOD_HZ), ("backup", BACKUP_HZ)):
        sp, so = SIGMA[name]
        g.add_measured(
            name, "W", "B", latency_s=0.01, rate_hz=rate, motion=MOTION,
            covariance=np.diag([sp**2] * 3 + [so**2] * 3),
        )  # fmt: skip
    return g


def _player(
    name: str, rate: float, rng, gap=None, end_s: float = 4.0, latency_ns: int = 10_000_000
) -> RecordingPlayer:
    t_ns = np.arange(0, int(end_s * 1e9), int(1e9 / rate), dtype=np.int64)
    if gap is not None:
        t_ns = t_ns[(t_ns < gap[0]) | (t_ns >= gap[1])]
    truth = tracker_truth(t_ns * 1e-9)
    sp, so = SIGMA[name]
    pos = truth.position + rng.normal(0, sp, (len(t_ns), 3))
    quat = quat_multiply(truth.quaternion, quat_exp(rng.normal(0, so, (len(t_ns), 3))))
    cov = np.diag([sp**2] * 3 + [so**2] * 3)
    return RecordingPlayer(name, t_ns, pos, quat, cov, latency_ns=latency_ns)


def _run(query: Query, players: dict, stale_ns: int = STALE_NS):
    plan = plan_query(_graph(), query)
    plan.node("switch").params["stale_ns"].update({e: stale_ns for e in players})
    got, events = [], []
    net, _ = plan.build(players, callback=got.append, on_switch=events.append)
    net.run()
    return plan, net, got, events


def test_the_plan_has_a_fallback_path_meeting_in_a_switch():
    q = Query("W", "B", mode="push", rate_hz=RATE_Q, name="q")
    plan = plan_query(_graph(), q)
    assert [str(p) for p in plan.paths] == [str(plan.paths[0])] and plan.paths[0].sensors == {
        "good"
    }
    assert [p.sensors for p in plan.fallbacks] == [{"backup"}]
    assert "fallback 1" in plan.explain()
    switch = plan.node("switch")
    assert switch.params["sensors"] == [[("good", "kf_good")], [("backup", "kf_backup")]]
    # no failover when the query says so, or when it fuses the paths
    for other in (Query("W", "B", failover=False), Query("W", "B", fuse=True)):
        p = plan_query(_graph(), other)
        assert p.fallbacks == [] and p.count("switch") == 0


def test_an_outage_moves_the_answers_to_the_fallback_and_back_after_the_hold():
    rng = np.random.default_rng(7)
    players = {
        "good": _player("good", GOOD_HZ, rng, gap=OUTAGE),
        "backup": _player("backup", BACKUP_HZ, rng),
    }
    q = Query("W", "B", mode="push", rate_hz=RATE_Q, name="q", hold_s=HOLD_NS * 1e-9)
    _, net, got, events = _run(q, players)
    assert [(e.from_path, e.to_path) for e in events] == [(0, 1), (1, 0)], events
    away, back = events
    # down once the newest measurement's exposure is older than stale
    newest = int(players["good"].t_ns[players["good"].t_ns < OUTAGE[0]][-1])
    tick = 10**9 // RATE_Q
    assert newest + STALE_NS < away.t_ns <= newest + STALE_NS + tick
    assert away.reason.startswith("sensor good: no data for")
    # back once the good sensor has been live for the hold time (from the arrival of its
    # first measurement, 10 ms after the exposure), not before
    first_back = int(players["good"].t_ns[players["good"].t_ns >= OUTAGE[1]][0]) + 10_000_000
    assert first_back + HOLD_NS <= back.t_ns <= first_back + HOLD_NS + tick
    assert back.reason.startswith("path 0 live for")
    # every answer says which path made it: the fallback's between the two moves
    t = np.array([m.t_ns for m in got])
    path = np.array([m.path for m in got])
    assert np.all(path[(t > away.t_ns) & (t < back.t_ns)] == 1)
    assert np.all(path[(t < away.t_ns) | (t >= back.t_ns)] == 0)
    switch = next(c for c in net.components.values() if isinstance(c, PathSwitch))
    assert switch.answers_by_path == [int((path == 0).sum()), int((path == 1).sum())]
    # the fallback's answers are honest: position NEES against the truth (3 dof)
    on_backup = [m for m in got if m.path == 1]
    truth = tracker_truth(np.array([m.t_ns for m in on_backup]) * 1e-9)
    nees = []
    for m, p in zip(on_backup, truth.position):
        e = m.pose.position - p
        nees.append(e @ np.linalg.solve(m.pose.covariance[:3, :3], e))
    assert len(nees) > 40
    assert np.mean(nees) < 3 * 1.5 and np.mean(np.array(nees) < 11.34) > 0.95, np.mean(nees)


def test_a_flickering_sensor_does_not_make_the_answers_flap():
    rng = np.random.default_rng(3)
    good = _player("good", GOOD_HZ, rng, end_s=6.0)
    keep = np.ones(len(good.t_ns), bool)
    for k in range(4):  # four outages of 0.3 s, 0.2 s apart
        a = 1.0e9 + k * 0.5e9
        keep &= (good.t_ns < a) | (good.t_ns >= a + 0.3e9)
    flicker = RecordingPlayer(
        "good", good.t_ns[keep], good.position[keep], good.quaternion[keep], good.covariance[0],
        latency_ns=10_000_000,
    )  # fmt: skip
    players = {"good": flicker, "backup": _player("backup", BACKUP_HZ, rng, end_s=6.0)}
    q = Query("W", "B", mode="push", rate_hz=RATE_Q, name="q", hold_s=HOLD_NS * 1e-9)
    _, _, _, events = _run(q, players)
    # away at the first outage, back only once the flicker has stopped for the hold time
    assert [(e.from_path, e.to_path) for e in events] == [(0, 1), (1, 0)], events
    assert events[1].t_ns >= 1.0e9 + 3 * 0.5e9 + 0.3e9 + HOLD_NS


def test_a_sensor_whose_measurements_are_refused_is_down():
    rng = np.random.default_rng(5)
    good = _player("good", GOOD_HZ, rng)
    bad = (good.t_ns >= 1.5e9) & (good.t_ns < 2.0e9)
    position = good.position.copy()
    position[bad] += 0.5  # half a metre off: the filter's gate refuses them
    players = {
        "good": RecordingPlayer("good", good.t_ns, position, good.quaternion,
                                good.covariance[0], latency_ns=10_000_000),
        "backup": _player("backup", BACKUP_HZ, rng),
    }  # fmt: skip
    q = Query("W", "B", mode="push", rate_hz=RATE_Q, name="q", refused_down=3)
    _, _, _, events = _run(q, players, stale_ns=10**9)
    assert events and events[0].to_path == 1, events
    assert events[0].reason == "sensor good: 3 measurements refused in a row"
    assert 1.5e9 < events[0].t_ns < 1.5e9 + 4 * 1e9 / GOOD_HZ + 10**9 / RATE_Q + 10_000_000


@pytest.mark.parametrize(("spec", "message"), [
    ({"failover": "yes"}, "failover: expected true, false or a mapping"),
    ({"failover": {"hold": 1}}, "failover: unknown keys ['hold']"),
    ({"failover": {"refused_down": 1.5}}, "failover.refused_down: expected an integer"),
    ({"failover": {"refused_down": 0}}, "refused_down must be an integer >= 1"),
    ({"failover": {"hold_ms": -1}}, "hold_s must be finite and >= 0"),
])  # fmt: skip
def test_bad_failover_keys_name_the_query(spec, message):
    from trackflow.dataflow import parse_setup

    doc = {
        "frames": ["W", "B"],
        "sensors": [{"name": "s", "source": "W", "target": "B", "rate_hz": 10}],
        "queries": [{"name": "q", "source": "W", "target": "B", **spec}],
    }
    with pytest.raises(ValueError, match="queries\\[0\\]") as err:
        parse_setup(doc, "lab.yaml")
    assert message in str(err.value)


def test_a_sensor_that_never_delivers_is_down_after_its_stale_time():
    rng = np.random.default_rng(11)
    backup = _player("backup", BACKUP_HZ, rng)
    silent = RecordingPlayer(
        "good", np.array([10**10]), np.zeros((1, 3)), np.array([[0.0, 0, 0, 1]]), np.eye(6) * 1e-6
    )  # one sample long after the run: the good tracker never sends during it
    q = Query("W", "B", mode="push", rate_hz=RATE_Q, name="q")
    _, _, got, events = _run(q, {"good": silent, "backup": backup})
    assert events[0].to_path == 1, events
    assert events[0].reason.startswith("sensor good: no data since the start")
    # down once stale has passed since the switch's first pull (the first tick, within a
    # period of the first arrival at 10 ms); the first answer comes with the move
    tick = 10**9 // RATE_Q
    assert STALE_NS < events[0].t_ns <= STALE_NS + 10_000_000 + 2 * tick
    assert got[0].t_ns == events[0].t_ns and got[0].path == 1
    # the late sample: the backup has long ended, so the good path is the live one again
    assert [(e.from_path, e.to_path) for e in events[1:]] == [(1, 0)], events
    assert events[1].reason.startswith("sensor backup: no data for")


class _LatePlayer(RecordingPlayer):
    """A player whose samples arrive at given times (a backlog delivered late)."""

    def __init__(self, name, t_ns, position, quaternion, covariance, arrival_ns):
        self._arrival = np.asarray(arrival_ns, dtype=np.int64)
        super().__init__(name, t_ns, position, quaternion, covariance, 0)

    def arrivals(self) -> np.ndarray:
        return self._arrival


def test_a_late_backlog_of_old_measurements_does_not_make_a_sensor_live():
    rng = np.random.default_rng(9)
    good = _player("good", GOOD_HZ, rng)
    kept = good.t_ns < 2.0e9  # it stops at 2.0 s ...
    arrival = good.t_ns[kept] + 10_000_000
    arrival[good.t_ns[kept] >= 1.5e9] = 2.7e9  # ... its last 0.5 s held and flushed at 2.7 s
    late = _LatePlayer(
        "good", good.t_ns[kept], good.position[kept], good.quaternion[kept],
        good.covariance[0], arrival,
    )  # fmt: skip
    players = {"good": late, "backup": _player("backup", BACKUP_HZ, rng)}
    q = Query("W", "B", mode="push", rate_hz=RATE_Q, name="q", hold_s=0.0)
    _, _, got, events = _run(q, players)
    # down 100 ms after the newest exposure it had (before 1.5 s), and never back: the backlog that
    # came at 2.7 s was 0.7 s old and older
    assert [(e.from_path, e.to_path) for e in events] == [(0, 1)], events
    newest = int(good.t_ns[good.t_ns < 1.5e9][-1])
    assert newest + STALE_NS < events[0].t_ns <= newest + STALE_NS + 10**9 // RATE_Q
    assert all(m.path == 1 for m in got if m.t_ns > events[0].t_ns)


# -- requirements (a query's require:) ---------------------------------------------------------
def test_the_planner_keeps_to_paths_that_meet_the_requirements():
    from trackflow.errors import PlanError
    from trackflow.graph import Requirements

    # the backup's 1 mm per axis is 1.7 mm radial RMS: only the good path meets 0.5 mm
    q = Query("W", "B", name="q", require=Requirements(max_sigma_pos_m=0.5e-3))
    plan = plan_query(_graph(), q)
    assert plan.paths[0].sensors == {"good"} and plan.fallbacks == []
    assert plan.count("switch") == 1  # it checks the answers all the same
    # 40 Hz: the backup's 30 Hz does not make it a fallback either
    plan = plan_query(_graph(), Query("W", "B", name="q", require=Requirements(min_rate_hz=40)))
    assert plan.paths[0].sensors == {"good"} and plan.fallbacks == []
    # nothing meets 100 Hz: the error names the requirement and the best path's figure
    with pytest.raises(PlanError) as err:
        plan_query(_graph(), Query("W", "B", name="q", require=Requirements(min_rate_hz=100)))
    assert "no path meets require.min_rate_hz 100 (path W->B[good]: 60 Hz)" in str(err.value)
    with pytest.raises(PlanError, match="require.max_latency_ms 5 .*10 ms"):
        plan_query(_graph(), Query("W", "B", name="q", require=Requirements(max_latency_s=0.005)))


def test_a_path_whose_answers_keep_breaking_a_requirement_is_left_for_one_that_meets_it():
    from trackflow.graph import Requirements

    rng = np.random.default_rng(13)
    players = {
        "good": _player("good", GOOD_HZ, rng, gap=(1.5e9, 4.0e9)),  # it stops at 1.5 s
        "backup": _player("backup", BACKUP_HZ, rng),
    }
    # stale 1 s: liveness alone would keep the good path for a second of extrapolation; its
    # answers' position sigma (under 5 mm while it measures, with this motion model and a
    # 50 Hz sampler) grows past 15 mm well before that; the backup's stays under 12 mm
    need = Requirements(max_sigma_pos_m=15e-3)
    q = Query("W", "B", mode="push", rate_hz=RATE_Q, name="q", require=need)
    _, net, got, events = _run(q, players, stale_ns=10**9)
    assert events and events[0].to_path == 1, events
    assert events[0].reason.startswith("path 0 kept breaking require.max_sigma_pos_mm 15 ("), events
    # the answers that broke it before the move are flagged, five in a row (refused_down;
    # none before, once the starting filter has settled: its first answer is flagged too)
    assert got[0].broken and not any(m.broken for m in got if 0.5e9 < m.t_ns < 1.45e9)
    flagged = [m for m in got if m.broken and 1.45e9 < m.t_ns <= events[0].t_ns]
    assert len(flagged) == 5 and all(m.path == 0 for m in flagged)
    assert flagged[0].broken.startswith("require.max_sigma_pos_mm 15 (answer: ")
    assert events[0].t_ns - 1.5e9 < 1e9  # within a second of the degradation
    switch = next(c for c in net.components.values() if isinstance(c, PathSwitch))
    assert switch.summary()["broken"]["require.max_sigma_pos_mm"] >= 5
    # the fallback meets it: no flags after the move
    assert not any(m.broken for m in got if m.t_ns > events[0].t_ns and m.path == 1)


@pytest.mark.parametrize(("spec", "message"), [
    ({"require": {"max_sigma": 1}}, "require: unknown keys ['max_sigma']"),
    ({"require": {"max_latency_ms": "fast"}}, "require.max_latency_ms: expected a number"),
    ({"require": {"min_rate_hz": 0}}, "min_rate_hz must be finite and > 0"),
    ({"require": [1]}, "require: expected a mapping"),
])  # fmt: skip
def test_bad_requirements_name_the_query(spec, message):
    test_bad_failover_keys_name_the_query(spec, message)


# -- measured attributes (dataflow/_attributes.py) ---------------------------------------------
def test_sensor_filters_measure_rate_latency_and_consistency_beside_the_declaration():
    rng = np.random.default_rng(17)
    g = _graph()
    players = {"good": _player("good", GOOD_HZ, rng), "backup": _player("backup", BACKUP_HZ, rng)}
    plan = plan_query(g, Query("W", "B", mode="push", rate_hz=RATE_Q, name="q"))
    net, _ = plan.build(players)
    net.run()
    good = net.components["kf_good"].measured.summary(g.edge("good"))
    # the players deliver at the declared rate, 10 ms after each exposure
    assert good["measured"]["rate_hz"] == pytest.approx(GOOD_HZ, rel=1e-3)
    assert good["measured"]["latency_ms"] == pytest.approx(10.0, abs=1e-6)
    assert good["measured"]["measurements"] == len(players["good"].t_ns)
    assert good["declared"] == {
        "rate_hz": GOOD_HZ,
        "latency_ms": 10.0,
        "noise_mm": 0.2,
        "noise_deg": pytest.approx(np.degrees(5e-4), rel=1e-3),
    }
    # the noise sigma from third differences of the ring (white noise of SIGMA["good"])
    assert good["measured"]["noise_mm"] == pytest.approx(0.2, rel=0.2)
    assert good["measured"]["noise_deg"] == pytest.approx(np.degrees(5e-4), rel=0.2)
    assert good["measured"]["dropout"] == 0
    assert 0 < good["measured"]["nis_mean"] < 6 * 2.25 and "rate_hz" not in good["far"]
    # a sensor declared 3x slower than it is, with ten times the latency: both reported
    slow = SpatialRelationshipGraph()
    sp, so = SIGMA["good"]
    slow.add_measured("good", "W", "B", latency_s=0.1, rate_hz=20, motion=MOTION,
                      covariance=np.diag([sp**2] * 3 + [so**2] * 3))  # fmt: skip
    far = net.components["kf_good"].measured.summary(slow.edge("good"))["far"]
    assert far["rate_hz"] == "60 measured vs 20 declared"
    assert far["latency_ms"] == "10 measured vs 100 declared"


def test_the_query_moves_to_the_path_whose_measured_figures_are_truly_better():
    """Declared: "good" 5 ms late at 60 Hz, "backup" 40 ms late at 30 Hz (eq. 2.5 prefers
    good). Truly: good is 150 ms late, backup 10 ms: once warm, the measured scores reverse
    the order and the answers move to backup, with both scores in the reason; with
    ``rescore=False`` they stay."""
    g = SpatialRelationshipGraph()
    for name, rate, lat in (("good", GOOD_HZ, 0.005), ("backup", BACKUP_HZ, 0.04)):
        sp, so = SIGMA[name]
        g.add_measured(name, "W", "B", latency_s=lat, rate_hz=rate, motion=MOTION,
                       covariance=np.diag([sp**2] * 3 + [so**2] * 3))  # fmt: skip
    for rescore in (True, False):
        rng = np.random.default_rng(5)
        players = {
            "good": _player("good", GOOD_HZ, rng, end_s=12.0, latency_ns=150_000_000),
            "backup": _player("backup", BACKUP_HZ, rng, end_s=12.0, latency_ns=10_000_000),
        }
        q = Query("W", "B", mode="push", rate_hz=RATE_Q, name="q", rescore=rescore)
        plan = plan_query(g, q)
        plan.node("switch").params["stale_ns"].update({e: 500_000_000 for e in players})
        events = []
        net, _ = plan.build(players, on_switch=events.append)
        net.run()
        switch = net.components["switch"]
        if not rescore:
            assert events == [] and switch.order == [0, 1]
            continue
        assert [(e.from_path, e.to_path) for e in events] == [(0, 1)], events
        assert events[0].reason.startswith("path 1 measured better: "), events[0].reason
        good, backup = switch.measured_scores
        assert backup < 0.9 * good
        assert good == pytest.approx(0.150 + 1 / GOOD_HZ, rel=0.02)
        assert backup == pytest.approx(0.010 + 1 / BACKUP_HZ, rel=0.02)
        # not before the backup sensor is warm (256 measurements at 30 Hz: 8.5 s)
        assert events[0].t_ns >= players["backup"].t_ns[255]
        assert switch.summary()["order"] == [1, 0]
