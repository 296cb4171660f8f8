"""The realm page's panel (``viewer.realm_page.realm_panel``) of a realm snapshot, without a
browser or Zenoh: agents alive and gone, the sensors each advertises, the union graph with
the queries' current paths, and the events newest first with their times."""

from __future__ import annotations

import re

from trackflow.viewer.graph_panel import COLOURS
from trackflow.viewer.realm_page import realm_panel

T0 = 1_795_000_000_000_000_000


def _snapshot() -> dict:
    edges = [
        {"name": "s1", "source": "W", "target": "X", "kind": "measured", "agent": "a",
         "live": False},
        {"name": "s2", "source": "W", "target": "Y", "kind": "measured", "agent": "b",
         "live": True},
        {"name": "yx", "source": "Y", "target": "X", "kind": "static", "agent": "b",
         "live": True},
    ]  # fmt: skip
    query = {"state": "running", "paths": ["W->X[s1]", "W->Y[s2] Y->X[yx]"], "path": 1,
             "published": 812}  # fmt: skip
    return {
        "realm": "lab",
        "agents": {
            "a": {"alive": False, "security": "loopback"},
            "b": {"alive": True, "security": "tls+acl"},
            "c": {"alive": True, "security": "tls+acl", "queries": {"q": query}},
        },
        "frames": ["W", "X", "Y"],
        "edges": edges,
        "answers": {},
        "events": [
            {"t_ns": T0, "text": "agent a left"},
            {"t_ns": T0 + 120_000_000, "text": "c: query q re-planned (sensor s1 left): running"},
        ],
        "rejections": {},
    }


def test_the_panel_shows_agents_graph_paths_and_events():
    html = realm_panel(_snapshot())
    text = re.sub(r"<[^>]+>", " ", html)
    assert "realm lab : 2 agent(s) alive" in re.sub(r"\s+", " ", text)
    # agent a is gone (red), its sensor down; b advertises its sensor live
    assert f'<b>a</b> <span style="color:{COLOURS["stale"]}">gone</span>' in html
    assert "advertises s1 (down)" in html and "advertises s2</div>" in html
    assert "query q: running, path W-&gt;Y[s2] Y-&gt;X[yx], published 812" in html
    # the graph: s1 drawn stale, s2 live; the current path's edges marked in the table
    assert re.search(r"<td>&#9654; s2</td><td[^>]*>live</td>", html), html
    assert re.search(r"<td>&#9654; yx</td><td[^>]*>static</td>", html), html
    assert re.search(r"<td>s1</td><td[^>]*>stale</td>", html), html
    # events newest first, each with its time of day
    events = re.findall(r"(\d\d:\d\d:\d\d\.\d{3}) ([^<]+)</div>", html)
    assert [e[1] for e in events] == ["c: query q re-planned (sensor s1 left): running",
                                      "agent a left"]  # fmt: skip
    assert events[0][0][-3:] == "120" and events[1][0][-3:] == "000"


def test_the_command_line_refuses_a_realm_with_files_and_files_with_realm_options(capsys):
    from trackflow.cli.main import main

    assert main(["view"]) != 0
    assert "give a recording, a setup or agent files, or --realm NAME" in capsys.readouterr().err
    assert main(["view", "--realm", "lab", "examples/demo_setup.yaml"]) != 0
    assert "--realm views a running realm: give no file" in capsys.readouterr().err
    assert main(["view", "x.tum", "--connect", "tcp/127.0.0.1:7447"]) != 0
    assert "--connect and --zenoh-config go with --realm" in capsys.readouterr().err
