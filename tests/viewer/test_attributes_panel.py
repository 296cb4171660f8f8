"""The live panel's measured attributes and paths (``viewer.attributes_panel``), without a
browser: what the main process gathers from the filters and switches, and the HTML the view
process renders of it."""

from __future__ import annotations

import re
from types import SimpleNamespace

import numpy as np

from trackflow.dataflow import MeasuredAttributes, SwitchEvent
from trackflow.graph import SpatialRelationshipGraph
from trackflow.math import quat_exp
from trackflow.viewer.attributes_panel import FAR_COLOUR, gather, render_attributes


def _sensor(rate_hz: float, noise_mm: float, seed: int) -> MeasuredAttributes:
    """The measured attributes of a still body seen at ``rate_hz`` with white noise
    (``noise_mm`` per axis, orientation as declared below)."""
    rng = np.random.default_rng(seed)
    m = MeasuredAttributes()
    step = int(round(1e9 / rate_hz))
    for k in range(400):
        t = 1_000_000_000 + k * step
        p = rng.normal(0.0, noise_mm * 1e-3, 3)
        q = quat_exp(rng.normal(0.0, np.sqrt(1e-5), 3))  # the declared orientation noise
        m.update(t, t + 5_000_000, 6.0, p, q)
    return m


class _Switch:
    """A query's path switch as the panel reads it (its ``summary``)."""

    def __init__(self, events):
        self.events = events

    def summary(self, last: int = 20) -> dict:
        return {"path": self.events[-1].to_path, "answers_by_path": [120, 45],
                "switch_count": len(self.events),
                "switches": [e.as_dict() for e in self.events[-last:]]}  # fmt: skip


def test_the_panel_shows_measured_beside_declared_and_marks_what_is_far():
    g = SpatialRelationshipGraph()
    cov = np.diag([1e-6] * 3 + [1e-5] * 3)
    g.add_measured("art", "room", "head", rate_hz=60.0, latency_s=0.005, covariance=cov)
    g.add_measured("opti", "room", "head", rate_hz=240.0, latency_s=0.005, covariance=cov)
    filters = {
        "art": (SimpleNamespace(measured=_sensor(60.0, 1.0, 1)), g.edge("art")),
        # declared 240 Hz, runs at 120: far
        "opti": (SimpleNamespace(measured=_sensor(120.0, 1.0, 2)), g.edge("opti")),
    }
    events = [SwitchEvent(5_000_000_000, 0, 1, "sensor art: no data for 103 ms")]
    estimate = {"a": "art", "b": "opti", "offset_ms": 0.05, "sigma_ms": 0.01}
    data = gather(filters, {"head_q": _Switch(events)}, {"opti": 15.0}, {"opti": estimate})
    art, opti = data["attributes"]["art"], data["attributes"]["opti"]
    assert abs(art["measured"]["rate_hz"] - 60.0) < 0.1 and art["far"] == {}
    assert abs(art["measured"]["latency_ms"] - 5.0) < 1e-6
    assert 0.8 < art["measured"]["noise_mm"] < 1.2, art
    assert "rate_hz" in opti["far"] and opti["correction_ms"] == 15.0
    html = render_attributes(data)
    rows = dict(re.findall(r"<tr><td>(\w+)</td>(.*?)</tr>", html))
    assert set(rows) == {"art", "opti"}
    assert "<td>60.0 / 60.0</td>" in rows["art"] and FAR_COLOUR not in rows["art"]
    far_cell = re.search(rf'<td style="color:{FAR_COLOUR}" title="([^"]*)">120.0 / 240.0</td>',
                         rows["opti"])  # fmt: skip
    assert far_cell is not None and "declared" in far_cell.group(1), rows["opti"]
    assert "<td>+15.0 ms; art - opti: +0.05 &plusmn; 0.01 ms</td>" in rows["opti"]
    assert rows["art"].endswith("<td>-</td>")
    assert "query head_q</b>: path 1" in html and "0 &rarr; 1: sensor art: no data" in html


def test_nothing_gathered_yet_renders_nothing():
    assert render_attributes(None) == "" and render_attributes({}) == ""
    assert render_attributes(gather({}, {})) == ""
