"""``trackflow lookup SETUP --from A --to B [--at T]``: one pose from a setup (like tf2_echo)."""

from __future__ import annotations

import json


def register(subparsers):
    p = subparsers.add_parser(
        "lookup",
        help="T_A_B at a time from a YAML setup and its recordings (pose, RPY, sigma, age)",
        description="Plan the pull dataflow of the query A->B in the setup, play the sensors' "
        "recordings up to the time and print the pose with its uncertainty and the age of "
        "the newest measurement used.",
    )
    p.add_argument("setup", help="YAML setup file (sensors need 'recording:' entries)")
    p.add_argument("--from", dest="source", required=True, help="reference frame A")
    p.add_argument("--to", dest="target", required=True, help="frame B")
    p.add_argument(
        "--at", type=float, default=None, help="time [s, the recordings' clock] (default: the "
        "latest common time of the recordings)"
    )  # fmt: skip
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    from ..dataflow import load_setup, lookup

    setup = load_setup(args.setup)
    setup.refuse_online_offsets("trackflow lookup")
    t_ns = None if args.at is None else int(round(args.at * 1e9))
    d = lookup(setup, args.source, args.target, t_ns).as_dict()
    if args.json:
        print(json.dumps(d, indent=2))
        return 0
    age = "static" if d["age_ms"] is None else f"{d['age_ms']:.1f} ms"
    print(f"At time {d['t_s']:.9f} s: T_{d['source']}_{d['target']} via {d['path']}")
    print("- Translation: [{:.6f}, {:.6f}, {:.6f}] m".format(*d["position_m"]))
    print("- Rotation: in Quaternion (xyzw) [{:.6f}, {:.6f}, {:.6f}, {:.6f}]".format(
        *d["quaternion_xyzw"]))  # fmt: skip
    print("            in RPY (degree)      [{:.4f}, {:.4f}, {:.4f}]".format(*d["rpy_deg"]))
    print("- Sigma: position [{:.3f}, {:.3f}, {:.3f}] mm, rotation [{:.4f}, {:.4f}, {:.4f}] deg"
          .format(*d["sigma_position_mm"], *d["sigma_rotation_deg"]))  # fmt: skip
    print(f"- Age of the newest measurement: {age}")
    return 0
