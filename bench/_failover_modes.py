"""What bench/adaptive.py and bench/adaptive_agents.py share: the three failure modes run in
turn, their figures pooled into the keys the adaptive-tracking issue names, and the table."""

from __future__ import annotations

import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

MODES = ("outage", "kill", "freeze")


def run_modes(measure: Callable[[str, Path], dict], label: str = "") -> dict:
    """``measure(mode, folder)`` for every mode, each in a fresh temporary folder."""
    modes = {}
    for mode in MODES:
        with tempfile.TemporaryDirectory() as d:
            print(f"{mode}{label} ...", file=sys.stderr, flush=True)
            modes[mode] = measure(mode, Path(d))
    return modes


def summary(modes: dict, bound_ms: float) -> dict:
    """``failover_gap_ms`` per mode, ``post_switch_nees`` (mean and p99, pooled over the
    modes), ``switch_back_s`` (the largest) and the gap bound; the modes' own figures (their
    NEES samples taken out) under ``modes``."""
    nees = np.concatenate([m.pop("nees") for m in modes.values()])
    return {
        "failover_gap_ms": {m: round(v["failover_gap_ms"], 1) for m, v in modes.items()},
        "post_switch_nees": round(float(nees.mean()), 3),
        "post_switch_nees_p99": round(float(np.percentile(nees, 99)), 3),
        "switch_back_s": round(max(v["switch_back_s"] for v in modes.values()), 3),
        "bound_ms": bound_ms,
        "modes": modes,
    }


def print_table(out: dict) -> None:
    print(f"{'mode':8} {'gap ms':>8} {'back s':>7}  reason")
    for m, v in out["modes"].items():
        print(f"{m:8} {v['failover_gap_ms']:8.1f} {v['switch_back_s']:7.3f}  {v['reason']}")
    print(f"NEES on the fallback: mean {out['post_switch_nees']}, "
          f"p99 {out['post_switch_nees_p99']} (3 dof: 99 % bound 11.34)")  # fmt: skip
