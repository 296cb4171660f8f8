"""Command-line wall times as a new user meets them: first run, warm run, --help, infer.

Each figure is the wall time of a fresh ``trackflow`` process (``python -m trackflow.cli.main``)
on a real recording:

* ``first_run_s``: ``evaluate``, ``filter`` and ``plot``, each the first run of that command on
  a fresh installation: a fresh temporary ``NUMBA_CACHE_DIR`` / ``XDG_CACHE_HOME`` filled by
  the install step ``trackflow compile`` (what ``make`` runs after ``pip install``) and by
  nothing else;
* ``warm_run_s``: the same command again with that cache;
* ``install_compile_s``: the install step itself (``trackflow compile`` into the empty cache);
* ``cold_first_run_s``: ``evaluate`` with an empty cache and no install step (a ``pip install``
  that skipped ``trackflow compile``): it compiles what it runs, and says so on stderr;
* ``help_s``: ``trackflow --help`` (best of five);
* ``infer_euroc_s``: ``infer`` chaining the EuRoC V1_01 ground truth (28.7k samples) with
  itself (warm cache).

Bars (issue 12): first minus warm <= 10 s per command, help < 0.3 s, infer on EuRoC < 3 s.
The machine is shared: run it when it is quiet, and read the figures as upper bounds.

    python bench/cli.py [--json] [--recording PATH] [--data ../shared/data]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT / ".." / "shared" / "data"
FALLBACK_RECORDING = ROOT / "tests" / "cli" / "data" / "fr1_xyz_groundtruth_10s.txt"


def run(args: list[str], env: dict, cwd: Path) -> float:
    """Wall time [s] of one ``trackflow`` process; raises if it fails."""
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "trackflow.cli.main", *args], cwd=cwd, env=env,
                       capture_output=True, timeout=3600)  # fmt: skip
    dt = time.perf_counter() - t0
    if r.returncode != 0:
        raise RuntimeError(f"trackflow {' '.join(args)} failed: {r.stderr.decode()[-2000:]}")
    return dt


def commands(rec: Path, out: Path) -> dict[str, list[str]]:
    return {
        "evaluate": ["evaluate", str(rec), "--quiet"],
        "filter": ["filter", str(rec), str(out / "filtered.tfrec"), "--force", "--quiet"],
        "plot": ["plot", str(rec), "--out", str(out), "--force", "--quiet"],
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", action="store_true", help="print the issue's JSON keys only")
    ap.add_argument("--recording", type=Path, default=None, help="recording for the commands")
    ap.add_argument("--data", type=Path, default=SHARED, help="the shared recordings folder")
    args = ap.parse_args()
    args.data = args.data.resolve()  # the commands run in a temporary directory
    default = args.data / "tum_rgbd" / "freiburg1_xyz-groundtruth.txt"
    rec = args.recording or (default if default.exists() else FALLBACK_RECORDING)
    euroc = args.data / "euroc" / "V1_01_easy_groundtruth_200hz.txt"
    base = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    base.pop("NUMBA_CACHE_DIR", None)
    first, warm = {}, {}
    with tempfile.TemporaryDirectory(prefix="trackflow-bench-") as d:
        d = Path(d)
        cache = d / "cache-installed"
        cache.mkdir()
        env = dict(base, NUMBA_CACHE_DIR=str(cache / "numba"), XDG_CACHE_HOME=str(cache))
        install_s = run(["compile", "--quiet"], env, d)
        for name, argv in commands(rec, d).items():
            first[name] = run(argv, env, d)
            warm[name] = run(argv, env, d)
        cold = d / "cache-cold"
        cold.mkdir()
        cold_env = dict(base, NUMBA_CACHE_DIR=str(cold / "numba"), XDG_CACHE_HOME=str(cold))
        cold_first = run(commands(rec, d)["evaluate"], cold_env, d)
        env = dict(base, NUMBA_CACHE_DIR=str(d / "cache-infer" / "numba"))
        help_s = min(run(["--help"], base, d) for _ in range(5))
        infer_s = None
        if euroc.exists():
            argv = ["infer", str(euroc), str(euroc), str(d / "inferred.tfrec"), "--target", "mid",
                    "--source2", "mid", "--force", "--quiet"]  # fmt: skip
            run(argv, env, d)  # compile once
            infer_s = run(argv, env, d)
    result = {
        "first_run_s": first,
        "warm_run_s": warm,
        "help_s": help_s,
        "infer_euroc_s": infer_s,
        "install_compile_s": install_s,
        "cold_first_run_s": {"evaluate": cold_first},
    }
    if args.json:
        print(json.dumps(result))
        return 0
    print(f"recording: {rec}")
    for name in first:
        extra = first[name] - warm[name]
        print(f"{name:<9} first {first[name]:7.2f} s  warm {warm[name]:7.2f} s  "
              f"first - warm {extra:6.2f} s (bar <= 10)")  # fmt: skip
    print(f"install step (trackflow compile): {install_s:.1f} s; evaluate with no install step: "
          f"{cold_first:.1f} s")  # fmt: skip
    print(f"--help    {help_s:.3f} s (bar < 0.3)")
    print(f"infer on EuRoC: {'n/a' if infer_s is None else f'{infer_s:.2f} s'} (bar < 3)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
