"""The demo's outputs: the stable JSON of ``trackflow demo --json`` and the error plot."""

from __future__ import annotations

import json
from pathlib import Path

from ..optional import pyplot

__all__ = ["demo_json", "plot_errors"]


def demo_json(result: dict) -> str:
    """The stable one-line JSON of ``trackflow demo --json`` (without ``details``)."""
    keys = ("naive", "aligned", "predicted", "static_edge_error", "plot")
    return json.dumps({k: result[k] for k in keys})


def plot_errors(series: dict, path: Path, result: dict) -> None:
    """PNG of the position [mm] and orientation [deg] errors of every variant over time
    (``series[label] = (t [s], position error, orientation error)``), RMS in the legend."""
    plt = pyplot("the demo's plot")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    for label, (t, dp, dq) in series.items():
        r = result[label]
        axes[0].plot(t, dp, lw=0.8, label=f"{label} (RMS {r['pos_rms_mm']:.1f} mm)")
        axes[1].plot(t, dq, lw=0.8, label=f"{label} (RMS {r['ori_rms_deg']:.2f} deg)")
    axes[0].set_ylabel("position error [mm]")
    axes[1].set_ylabel("orientation error [deg]")
    axes[1].set_xlabel("time [s]")
    axes[0].set_title("projector -> marker (marker at rest: truth is constant)")
    for ax in axes:
        ax.legend(loc="upper right", fontsize=8)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
