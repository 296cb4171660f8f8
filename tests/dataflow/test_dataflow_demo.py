"""``trackflow demo --json``: the stable interface and the thesis's claims against truth."""

from __future__ import annotations

import json
import logging
import math

from trackflow.cli.main import main


def test_demo_json(tmp_path, capsys):
    logging.getLogger("trackflow.filters").setLevel(logging.ERROR)
    png = tmp_path / "demo.png"
    assert main(["demo", "--json", "--backend", "numba", "--out", str(png)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {"naive", "aligned", "predicted", "static_edge_error", "plot"}
    for key in ("naive", "aligned", "predicted"):
        assert set(out[key]) == {"pos_rms_mm", "ori_rms_deg"}
        assert all(math.isfinite(v) and v > 0 for v in out[key].values())
    assert set(out["static_edge_error"]) == {"pos_mm", "ori_deg"}
    assert out["plot"] == str(png) and png.stat().st_size > 10_000
    # Time alignment removes most of the naive chain's simultaneity error (9.2.2).
    assert out["aligned"]["pos_rms_mm"] < 0.5 * out["naive"]["pos_rms_mm"]
    assert out["aligned"]["ori_rms_deg"] < out["naive"]["ori_rms_deg"]
    # The static edge estimated from ~14 s of data is far better than a single camera frame
    # (2 mm, 1 deg noise).
    assert out["static_edge_error"]["pos_mm"] < 2.0
    assert out["static_edge_error"]["ori_deg"] < 0.3
