"""``trackflow demo``: the thesis's demo setup driven by a real recorded motion."""

from __future__ import annotations

import argparse
from pathlib import Path

#: ``DemoConfig.seed`` (mirrored: parsing arguments does not import the library).
DEFAULT_SEED = 7


def register(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "demo",
        help="run the thesis demo (tracker + camera + projector) and report errors vs truth",
        description="Simulate an ART-like tracker and an ARToolKit-like camera from a real "
        "head-motion recording, estimate the target-to-camera edge from data, and compare the "
        "naive, time-aligned and predicted projector->marker chains against the truth.",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--out", type=Path, default=Path("out/demo.png"), help="PNG plot path")
    p.add_argument("--seed", type=int, default=DEFAULT_SEED, help="noise seed")
    p.add_argument(
        "--backend",
        choices=("numpy", "numba"),
        default="numpy",
        help="kernel backend (default numpy: no compile step, so a fresh clone runs in "
        "seconds; numba is faster once its cache is warm; results agree to rounding)",
    )
    p.add_argument(
        "--realm",
        type=Path,
        default=None,
        metavar="DIR",
        help="write the demo split over three agents (examples/distributed: agent files and "
        "recordings) into DIR and print the commands that start them; runs nothing",
    )
    p.add_argument(
        "--seconds", type=float, default=600.0, help="--realm: length of the recordings [s]"
    )
    p.add_argument("--force", action="store_true", help="--realm: replace existing files")
    p.set_defaults(func=run)
    return p


def _write_realm(args) -> int:
    from ..demo.realm import write_demo_realm

    files = write_demo_realm(args.realm, args.seconds, args.seed, overwrite=args.force)
    d = args.realm
    print(f"wrote {', '.join(sorted(files))} to {d}/; start the three agents (bash):")
    print("  start=$(( $(date +%s%N) + 5000000000 ))  # recording time 0 on the agents' clock")
    print(f"  trackflow agent {d}/tracker.yaml --start-ns $start &")
    print(f"  trackflow agent {d}/camera.yaml --start-ns $start &")
    print(f"  trackflow agent {d}/app.yaml --duration 20 --status status.json")
    print("  kill %1 %2  # the tracker and camera agents run until stopped")
    return 0


def run(args) -> int:
    if args.realm is not None:
        return _write_realm(args)
    from ..demo import DemoConfig, demo_json, run_demo
    from ..math import use_backend

    with use_backend(args.backend):
        result = run_demo(args.out, DemoConfig(seed=args.seed))
    if args.json:
        print(demo_json(result))
        return 0
    print("projector -> marker at 60 Hz, errors against the known truth (after 1 s warm-up):")
    for label, text in (
        ("naive", "naive chain (latest values, no time alignment)"),
        ("aligned", "time-aligned chain (filters interpolate to t - 100 ms)"),
        ("predicted", "predicted output (filters predict to the present)"),
    ):
        r = result[label]
        print(f"  {text:55s} {r['pos_rms_mm']:7.2f} mm RMS  {r['ori_rms_deg']:6.3f} deg RMS")
    e = result["static_edge_error"]
    print(
        f"static target->camera edge estimated from data (7.4.1): error {e['pos_mm']:.2f} mm, "
        f"{e['ori_deg']:.3f} deg"
    )
    print(
        f"  the camera made {result['details']['camera_wrong_detections']} wrong detections "
        "(the filters should reject them: 'filter rejected update')"
    )
    print("  rejections (the kf_* filters serve both aligned and predicted, so appear twice):")
    for label, rej in result["details"]["rejections"].items():
        counts = {f"{c}: {r}": n for c, rs in rej.items() for r, n in rs.items()}
        if counts:
            print(f"    {label}: " + ", ".join(f"{k} x{n}" for k, n in counts.items()))
    print(f"plot written to {result['plot']}")
    return 0
