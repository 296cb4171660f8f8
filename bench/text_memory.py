"""Peak memory and time of ``trackflow info`` and ``trackflow compare`` on large TUM text files
(issues 12 and 30).

Runs ``trackflow info FILE`` in a fresh interpreter twice in one run: with the block reader
(trackflow's) and with the former line-list parser (``tests/io/_reference_reader.py``, every
line of the file held in memory) as the named peer. Each child resets its peak-memory mark
(``/proc/self/clear_refs``) once its modules are imported, so ``info_peak_rss_mb`` is the
process's peak resident memory while reading and summarising, imports included, and
``peak_over_file`` is that peak minus the imports' resident memory, over the file size.
``read_s`` is the time of ``read_stream`` alone (best of ``--repeat``).

Then ``trackflow compare FILE EST --align se3 --t-max-diff 0.005`` (EST a second file of the
same size, another seed) in a fresh interpreter the same way: ``compare_peak_rss_mb``, and
``compare_over_info``, its peak over ``info``'s on FILE (``info`` is the named peer: reading
one file and summarising it; ``compare`` reads two and keeps what its metrics need).

The files are generated (``--lines`` rows of random but valid TUM data, 75 bytes per row, into
a temporary folder) unless ``--file`` names one (then ``compare`` is measured against itself).
Linux only (``/proc``).

Usage: ``python bench/text_memory.py [--json] [--lines N | --file F] [--repeat R]``
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TESTS_IO = ROOT / "tests" / "io"

_CHILD = """
import contextlib, io, json, sys, time
from unittest import mock
args = json.loads(sys.argv[1])
sys.path.insert(0, sys.argv[3])
import trackflow.io, trackflow.evaluation
import trackflow.io._devices, trackflow.io._imu, trackflow.io._kitti, trackflow.io._text
from trackflow.cli.main import main


def status(key):
    with open("/proc/self/status") as f:
        return next(int(ln.split()[1]) for ln in f if ln.startswith(key + ":"))


patches = contextlib.ExitStack()
if sys.argv[2] == "former":
    import _reference_reader
    for m in (trackflow.io._text, trackflow.io._devices, trackflow.io._kitti, trackflow.io._imu):
        patches.enter_context(mock.patch.object(m, "parse_rows", _reference_reader.parse_rows))
with patches:
    rss0 = status("VmRSS")
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")
    with contextlib.redirect_stdout(io.StringIO()):
        code = main(args)
    peak = status("VmHWM")
    best = float("inf")
    for _ in range(int(sys.argv[4])):
        t0 = time.perf_counter()
        trackflow.io.read_stream(args[-1])
        best = min(best, time.perf_counter() - t0)
print(json.dumps({"code": code, "rss0_kb": rss0, "peak_kb": peak, "read_s": best}))
"""


def _measure(args: list, reader: str, repeat: int) -> dict:
    """Peak and imports' resident memory of ``trackflow ARGS`` in a fresh interpreter; the
    best time of ``repeat`` reads of the last argument's file."""
    out = subprocess.run(
        [
            sys.executable,
            "-c",
            _CHILD,
            json.dumps([str(a) for a in args]),
            reader,
            str(TESTS_IO),
            str(repeat),
        ],
        capture_output=True,
        text=True,
        timeout=1800,
    )
    if out.returncode != 0:
        raise SystemExit(f"{reader} child failed:\n{out.stderr}")
    return json.loads(out.stdout)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--lines", type=int, default=1_700_000)
    ap.add_argument("--file", type=Path)
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="trackflow-bench-") as d:
        path, est = args.file, args.file
        if path is None:
            sys.path.insert(0, str(TESTS_IO))
            from _io_helpers import write_big_tum

            path, est = Path(d) / "big.txt", Path(d) / "big_est.txt"
            write_big_tum(path, args.lines)
            write_big_tum(est, args.lines, seed=6)
        size = path.stat().st_size
        info = ["info", "--quiet", path]
        runs = {r: _measure(info, r, args.repeat) for r in ("block", "former")}
        compare = ["compare", path, est, "--align", "se3", "--t-max-diff", "0.005", "--quiet"]
        cmp_run = _measure(compare, "block", 0)
    mb = 1024 / 1e6  # kB -> MB
    result = {
        "file_mb": round(size / 1e6, 1),
        "imports_rss_mb": round(runs["block"]["rss0_kb"] * mb, 1),
        "info_peak_rss_mb": {r: round(v["peak_kb"] * mb, 1) for r, v in runs.items()},
        "peak_over_file": {
            r: round((v["peak_kb"] - v["rss0_kb"]) * 1024 / size, 2) for r, v in runs.items()
        },
        "read_s": {r: round(v["read_s"], 2) for r, v in runs.items()},
        "compare_peak_rss_mb": round(cmp_run["peak_kb"] * mb, 1),
        "compare_over_info": round(cmp_run["peak_kb"] / runs["block"]["peak_kb"], 2),
    }
    if args.json:
        print(json.dumps(result))
    else:
        print(f"{path} ({result['file_mb']} MB); imports {result['imports_rss_mb']} MB")
        for r in runs:
            print(
                f"  {r:>6}: info peak {result['info_peak_rss_mb'][r]:7.1f} MB "
                f"({result['peak_over_file'][r]:.2f} x the file above the imports), "
                f"read {result['read_s'][r]:.2f} s"
            )
        print(f"  compare with a second such file: peak {result['compare_peak_rss_mb']:.1f} MB "
              f"({result['compare_over_info']:.2f} x info's)")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
