"""The thesis demo split over three agents (``examples/distributed``), ready to run.

:func:`write_demo_realm` writes, into one directory, the three agent files of the example
realm (``tracker.yaml``, ``camera.yaml``, ``app.yaml``) and the recordings their sensors play
(``art.tfrec``, ``artoolkit.tfrec``): a smooth head motion seen by the demo's two sensors with
their declared rates, latencies and noise, and the camera's 30 ms stamp offset, consistent
with the statics of ``examples/demo_setup.yaml``. ``trackflow demo --realm DIR`` calls it and
prints the commands that start the agents (``docs/distributed.md``).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np

__all__ = ["AGENT_FILES", "demo_realm_recordings", "write_demo_realm"]

#: the example realm's agent files, in the order they are started
AGENT_FILES = ("tracker.yaml", "camera.yaml", "app.yaml")


def _examples():
    return resources.files("trackflow") / "examples"


def demo_realm_recordings(
    out: Path, seconds: float, seed: int = 7, *, overwrite: bool = False
) -> dict[str, Path]:
    """Write ``art.tfrec`` and ``artoolkit.tfrec`` into ``out``: ``seconds`` of the demo's two
    sensors (stamps from 0 s) seen from a smooth head motion; returns ``{sensor: path}``.

    The head ``T_A_T(t)`` moves sinusoidally (positions in metres, rotation vectors in
    radians); the marker lies still at a pose fixed half-way through, so the true projector to
    marker relationship is constant. Each sensor adds its declared noise, latency and stamp
    offset (:class:`~trackflow.dataflow.SimulatedSensor`, seeded by ``seed``).
    """
    from ..dataflow import SimulatedSensor, load_setup
    from ..io import PoseStream, write_stream
    from ..math import Pose, quat_exp

    with resources.as_file(_examples() / "demo_setup.yaml") as setup_file:
        g = load_setup(setup_file).graph
    T_T_C = g.edge("target_camera").pose

    def head(t):
        t = np.asarray(t, float)
        p = np.stack(
            [0.2 * np.sin(0.7 * t), 1.5 + 0.1 * np.cos(0.5 * t), 0.3 * np.sin(0.4 * t)], -1
        )
        r = np.stack([0.2 * np.sin(0.6 * t), 0.3 * np.sin(0.3 * t), 0.1 * np.cos(0.8 * t)], -1)
        return Pose(p, quat_exp(r))

    T_A_M = (
        head(np.array([seconds / 2]))[0] @ T_T_C @ Pose([0.02, 0.01, 0.6], quat_exp([0, 3.0, 0.2]))
    )

    def camera(t):
        return (head(t) @ T_T_C).inverse() @ T_A_M

    rng = np.random.default_rng(seed)
    out = Path(out)
    paths = {}
    for name, truth in (("art", head), ("artoolkit", camera)):
        e = g.edge(name)
        s = SimulatedSensor(
            name,
            truth,
            rate_hz=e.rate_hz,
            latency_s=e.latency_s,
            sigma_pos=float(np.sqrt(e.covariance[0, 0])),
            sigma_ori=np.sqrt(np.diag(e.covariance)[3:]),
            rng=rng,
            start_s=0.0,
            end_s=seconds,
            stamp_offset_s=e.stamp_offset_s,
        )
        paths[name] = out / f"{name}.tfrec"
        stream = PoseStream(
            e.source, e.target, s.t_ns, s.position, s.quaternion, covariance=np.array(s.covariance)
        )
        write_stream(paths[name], stream, overwrite=overwrite)
    return paths


def write_demo_realm(
    out, seconds: float = 600.0, seed: int = 7, *, overwrite: bool = False
) -> dict[str, Path]:
    """Write the example realm's agent files and their recordings into the directory ``out``
    (made if missing).

    Raises
    ------
    FileExistsError
        One of the files is there already and ``overwrite`` is false (nothing is written).

    Returns
    -------
    dict
        ``{file name: path}`` of the three agent files and the two recordings.
    """
    out = Path(out)
    names = (*AGENT_FILES, "art.tfrec", "artoolkit.tfrec")
    there = [n for n in names if (out / n).exists()]
    if there and not overwrite:
        raise FileExistsError(f"{out / there[0]} exists (--force replaces the demo realm's files)")
    out.mkdir(parents=True, exist_ok=True)
    files = {}
    for name in AGENT_FILES:
        files[name] = out / name
        files[name].write_text((_examples() / "distributed" / name).read_text())
    for path in demo_realm_recordings(out, seconds, seed, overwrite=overwrite).values():
        files[path.name] = path
    return files
