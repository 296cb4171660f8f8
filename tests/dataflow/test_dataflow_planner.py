"""Planner construction rules (thesis 7.4), explain output, dot export and the plan CLI."""

from __future__ import annotations

import numpy as np
import pytest

from trackflow import Pose
from trackflow.cli.main import main
from trackflow.dataflow import load_setup, parse_setup, plan_query
from trackflow.graph import Query, SpatialRelationshipGraph

COV = np.diag([1e-6] * 3 + [1e-4] * 3)


def demo_graph() -> SpatialRelationshipGraph:
    g = SpatialRelationshipGraph()
    g.add_static("projector", "P", "A", Pose([0, 2, 0], [0, 0, 0, 1]), COV)
    g.add_measured("art", "A", "T", latency_s=0.02, rate_hz=60, covariance=COV)
    g.add_static("mount", "T", "C", Pose([0.1, 0, 0], [0, 0, 0, 1]), COV)
    g.add_measured("cam", "C", "M", latency_s=0.05, rate_hz=30, covariance=COV)
    return g


def kinds(plan):
    return [n.kind for n in plan.nodes]


def test_forward_chain_gets_a_filter_per_sensor_and_one_inference():
    plan = plan_query(demo_graph(), Query("P", "M", mode="push", rate_hz=60))
    assert plan.count("kalman") == 2
    assert plan.count("inversion") == 0
    assert plan.count("inference") == 1
    assert plan.count("sampler") == 1
    inference = next(n for n in plan.nodes if n.kind == "inference")
    assert [i for i, _ in inference.inputs] == [
        "static_projector",
        "kf_art",
        "static_mount",
        "kf_cam",
    ]
    for name in ("art", "cam"):
        assert plan.node(f"kf_{name}").inputs == [(f"src_{name}", "push")]
    assert plan.node("sampler").inputs == [("inference_path", "pull")]


def test_all_edges_backwards_means_one_inversion_at_the_end():
    plan = plan_query(demo_graph(), Query("M", "P"))
    assert plan.count("inversion") == 1
    inv = next(n for n in plan.nodes if n.kind == "inversion")
    assert plan.node(inv.inputs[0][0]).kind == "inference"
    assert plan.node("app").inputs == [(inv.id, "pull")]


def test_single_backwards_sensor_edge_is_inverted_behind_its_filter():
    g = demo_graph()
    g.add_static("marker", "A", "M", Pose([0, 0, 1], [0, 0, 0, 1]), COV)
    plan = plan_query(g, Query("T", "C", static=True, exclude=("mount",)))
    invs = [n for n in plan.nodes if n.kind == "inversion"]
    assert sorted(n.inputs[0][0] for n in invs) == ["kf_art", "kf_cam"]
    # Static relationship measured through moving edges: a static estimator at the end (7.4.1),
    # fed by the path inference that the slower sensor (cam, 30 Hz) triggers.
    est = plan.node("static_estimator")
    assert est.params["motion"].static
    inference = plan.node(est.inputs[0][0])
    assert ("kf_cam", "push") in inference.inputs
    assert plan.relationship_static


def test_static_edges_fold_at_planning_time():
    g = demo_graph()
    g.add_static("table", "M", "S", Pose([0, 0, 0.5], [0, 0, 0, 1]), COV)
    plan = plan_query(g, Query("S", "A"))  # all backwards: table, cam, mount, art
    assert plan.count("kalman") == 2 and plan.count("inversion") == 1
    plan2 = plan_query(g, Query("P", "A"))
    assert kinds(plan2) == ["static", "pull sink"]
    assert plan2.relationship_static
    g.add_static("p2", "A", "Q", Pose([1, 0, 0], [0, 0, 0, 1]), COV)
    plan3 = plan_query(g, Query("P", "Q"))
    assert kinds(plan3) == ["static", "pull sink"]
    value = plan3.nodes[0].params["value"]
    assert np.allclose(value.position, [1, 2, 0])
    # T_P_Q = T_P_A @ T_A_Q: rotation error of T_P_A on the 1 m lever arm moves y and z.
    assert value.covariance[0, 0] == pytest.approx(2e-6)
    assert value.covariance[1, 1] == pytest.approx(2e-6 + 1e-4)


def test_independent_paths_meet_in_one_fusion_filter():
    g = demo_graph()
    g.add_measured("cam2", "A", "M", latency_s=0.03, rate_hz=30, covariance=COV)
    plan = plan_query(g, Query("P", "M", mode="push", rate_hz=60, fuse=True))
    assert len(plan.paths) == 2
    fusion = plan.node("fusion")
    assert fusion.kind == "kalman"
    assert len(fusion.inputs) == 2 and all(m == "push" for _, m in fusion.inputs)
    assert plan.count("kalman") == 4  # art, cam, cam2 filters + fusion
    assert plan.node("sampler").inputs == [("fusion", "pull")]


def test_naive_plan_has_no_filters():
    plan = plan_query(demo_graph(), Query("P", "M", mode="push", rate_hz=60), align=False)
    assert plan.count("kalman") == 0
    assert plan.count("latest") == 2


def test_explain_and_dot():
    plan = plan_query(
        demo_graph(), Query("M", "P", mode="push", rate_hz=60, time_offset_s=-0.1, name="q")
    )
    text = plan.explain()
    assert "query q: T_M_P, push delivery at 60 Hz, offset -100 ms" in text
    assert "path 1 (score" in text
    assert "one inversion at the cheapest place (rule 3)" in text
    assert "interpolator" in text  # negative offset -> filters interpolate
    for n in plan.nodes:
        assert f"  {n.id}: " in text
    dot = plan.to_dot()
    assert dot.startswith('digraph "q"') and dot.rstrip().endswith("}")
    assert dot.count("->") == sum(len(n.inputs) for n in plan.nodes)
    assert "style=dashed" in dot


def test_plan_cli(tmp_path, capsys):
    setup = tmp_path / "s.yaml"
    setup.write_text(
        "sensors:\n"
        "  - {name: art, source: A, target: T, rate_hz: 60, latency_ms: 20}\n"
        "statics:\n"
        "  - {name: p, source: P, target: A}\n"
        "queries:\n"
        "  - {name: q, source: P, target: T, mode: push, rate_hz: 30}\n"
    )
    dot = tmp_path / "plan.dot"
    assert main(["plan", str(setup), "--explain", "--dot", str(dot)]) == 0
    out = capsys.readouterr().out
    assert "query q: T_P_T" in out and "kf_art" in out and "because" in out
    assert dot.read_text().startswith("digraph")
    assert main(["plan", str(setup), "--from", "T", "--to", "P"]) == 0
    assert "A<-T[art] . P<-A[p]" in capsys.readouterr().out
    assert main(["plan", str(setup), "--from", "T", "--to", "nowhere"]) == 1
    assert "unknown frame 'nowhere'" in capsys.readouterr().err


def test_yaml_errors_name_file_and_line(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("sensors:\n  - name: a\n    source: A\n    target: B\n    speed: 3\n")
    with pytest.raises(ValueError, match=r"bad\.yaml:2: sensors\[0\]: unknown keys \['speed'\]"):
        load_setup(bad)
    bad.write_text("queries:\n  - {name: q, source: A, target: B}\n")
    with pytest.raises(ValueError, match=r"bad\.yaml:2: queries\[0\]: unknown frame 'A'"):
        load_setup(bad)


def test_yaml_and_python_give_the_same_plan(request):
    root = request.config.rootpath
    setup = load_setup(root / "examples" / "demo_setup.yaml")
    from_yaml = setup.plan("sheep").explain()
    same = parse_setup(
        {
            "sensors": [
                {
                    "name": e.name,
                    "source": e.source,
                    "target": e.target,
                    "rate_hz": e.rate_hz,
                    "latency_ms": e.latency_s * 1e3,
                    "stamp_offset_ms": e.stamp_offset_s * 1e3,
                    "motion": {"n_dp": 1, "n_do": 1, "noise": [1.0, 3.0]},
                }
                for e in setup.graph.edges
                if e.kind == "measured"
            ],
            "statics": [
                {"name": e.name, "source": e.source, "target": e.target}
                for e in setup.graph.edges
                if e.kind == "static"
            ],
            "queries": [
                {"name": "sheep", "source": "P", "target": "M", "mode": "push", "rate_hz": 60}
            ],
        }
    )
    assert same.plan("sheep").explain() == from_yaml
    for name in ("calibration_setup.yaml", "fusion_setup.yaml"):
        assert load_setup(root / "examples" / name).plan().nodes
