"""The picture of ``trackflow run --view`` in ``docs/viewer.md``: the live demo, in the browser.

Starts ``trackflow run examples/live_demo.yaml --view`` (the head tracked over NatNet, the tool
over DTrack, the tool in the head's frame at 60 Hz) on free loopback ports, two
``trackflow simulate`` senders replaying the real recordings of the live demo
(``ar_table/table_01`` as the head, the EuRoC V1_01 ground truth as the tool, with clock
offsets), and renders the page through headless Chromium once both sensors are live.

Usage: ``python experiments/viewer_live_run.py [--out docs/viewer/live_run.png] [--data DIR]``.
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import yaml

from trackflow.viewer import Browser

# tick the view's "pause" checkbox (the row whose label reads "pause")
_PAUSE_JS = """() => {
  for (const el of document.querySelectorAll('label, div, span, p')) {
    if (el.childElementCount === 0 && el.textContent.trim() === 'pause') {
      for (let row = el, i = 0; i < 6 && row !== null; i++, row = row.parentElement) {
        const box = row.querySelector('input[type=checkbox]');
        if (box !== null) { if (!box.checked) box.click(); return true; }
      }
    }
  }
  return false;
}"""

ROOT = Path(__file__).resolve().parents[1]


def _port(kind=socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _cmd(*args) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    return subprocess.Popen(
        [sys.executable, "-m", "trackflow.cli.main", *map(str, args)],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip


def _data_dir() -> Path:
    """``$TRACKFLOW_DATA``, else ``../shared/data`` next to the repository, else
    ``/work/shared/data`` (as the tests look for it)."""
    env = os.environ.get("TRACKFLOW_DATA")
    if env:
        return Path(env)
    for candidate in (ROOT.parent / "shared" / "data", Path("/work/shared/data")):
        if (candidate / "README.md").is_file():
            return candidate
    return ROOT.parent / "shared" / "data"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "viewer" / "live_run.png")
    ap.add_argument("--data", type=Path, default=_data_dir())
    args = ap.parse_args(argv)
    if not (args.data / "euroc").is_dir():
        print(f"the recordings are missing under {args.data}", file=sys.stderr)
        return 1
    doc = yaml.safe_load((ROOT / "examples" / "live_demo.yaml").read_text())
    nn, dt = _port(), _port()
    doc["sensors"][0]["input"]["natnet"]["command_port"] = nn
    doc["sensors"][1]["input"]["dtrack"]["port"] = dt
    procs = []
    with tempfile.TemporaryDirectory() as tmp:
        setup = Path(tmp) / "live_demo.yaml"
        setup.write_text(yaml.safe_dump(doc, sort_keys=False))
        run = _cmd("run", setup, "--view", "--view-port", 0, "--duration", 300)
        procs.append(run)
        try:
            url = None
            end = time.monotonic() + 120
            while url is None and time.monotonic() < end:
                line = run.stderr.readline()
                if line.startswith("view: "):
                    url = line.split(" ", 1)[1].strip()
            if url is None:
                raise RuntimeError("trackflow run --view did not start its view")
            status: list[str] = []
            threading.Thread(target=lambda: status.extend(run.stderr), daemon=True).start()
            procs += [
                _cmd("simulate", "natnet", args.data / "ar_table" / "table_01.txt", "--port", nn,
                     "--body", "head", "--latency-ms", 4, "--clock-offset-s", 1234.5,
                     "--duration", 200, "--wait", 60),
                _cmd("simulate", "dtrack", args.data / "euroc" / "V1_01_easy_groundtruth_200hz.txt",
                     "--port", dt, "--latency-ms", 6, "--clock-offset-s", -86000.25,
                     "--start", 10, "--duration", 200),
            ]  # fmt: skip
            time.sleep(12)  # both sensors live; the view framed the scene
            print(status[-1].strip() if status else "(no status line)")
            # the page shows the DTrack tracker's measured clock offset once it is live; then
            # the view is paused from the page (software WebGL draws the bodies' updates later
            # than the camera's: held still, the page catches up) and the picture taken
            with Browser(1280, 800, timeout_s=120) as browser:
                page = browser.open(url, "86000250.0 ms")
                page.wait_for_timeout(3000)
                page.evaluate(_PAUSE_JS)
                browser.capture(page, args.out, stable_s=20.0)
            print(f"snapshot written to {args.out}")
        finally:
            for p in procs[::-1]:
                p.terminate()
                try:
                    p.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    p.kill()
    return 0


if __name__ == "__main__":
    sys.exit(main())
