"""``trackflow view --realm`` on the three-agent demo, timed (issue 29's realm bar; part of
``bench/viewer.py --json`` as ``"realm_view"``).

The demo realm's three agents (``trackflow demo --realm``: tracker, camera, app; their Zenoh
endpoints moved to free loopback ports) run as processes. Then ``trackflow view --realm demo``
is started as a process and headless Chromium opens its page:

* ``agents_shown_s``: from starting the view's process (Chromium already running, as a user's
  browser is) to its page listing all three agents alive and both sensors (``art``,
  ``artoolkit``) advertised; ``url_s`` of it until the process printed its URL (Python,
  viser and Zenoh started), ``shown_after_open_s`` from opening the page (loading viser's
  client and its first frames in software WebGL is most of it);
* ``replan_shown_s``: from a kill -9 of the camera agent to the page listing the app's
  re-plan; ``replan_event_s`` of it until the app re-planned (the time the page shows).

Wall-clock figures of a machine that may be shared: the text says the load.
"""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
# the app's re-plan after the camera agent left (its sensor or static edge)
_REPLANNED = (
    "() => /app: query sheep re-planned \\([^)]*of agent camera left/.test(document.body.innerText)"
)


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _cli(*args, log=None) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    out = subprocess.PIPE if log is None else log
    return subprocess.Popen(
        [sys.executable, "-m", "trackflow.cli.main", *map(str, args)],
        stdout=out, stderr=subprocess.PIPE if log is None else subprocess.STDOUT, text=True,
        env=env,
    )  # fmt: skip


def _moved_ports(realm_dir: Path) -> dict[str, str]:
    """The demo's agent files with free ports; ``{agent file stem: its endpoint}``."""
    ports = {name: f"tcp/127.0.0.1:{_port()}" for name in ("tracker", "camera", "app")}
    old = {"tcp/127.0.0.1:7451": "tracker", "tcp/127.0.0.1:7452": "camera",
           "tcp/127.0.0.1:7453": "app"}  # fmt: skip
    for name in ports:
        path = realm_dir / f"{name}.yaml"
        text = path.read_text()
        for endpoint, owner in old.items():
            text = text.replace(endpoint, ports[owner])
        yaml.safe_load(text)  # still a valid file
        path.write_text(text)
    return ports


def _wait(cond, timeout_s: float, what: str):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        got = cond()
        if got:
            return got
        time.sleep(0.05)
    raise TimeoutError(what)


def measure_realm_view(timeout_s: float = 120.0) -> dict:
    """``{"agents_shown_s", "replan_shown_s"}`` (module docstring)."""
    from trackflow.demo.realm import write_demo_realm
    from trackflow.viewer import Browser

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        realm_dir = tmp / "demo_realm"
        write_demo_realm(realm_dir, 120.0, 7)
        ports = _moved_ports(realm_dir)
        start = time.time_ns() + 5_000_000_000
        logs, agents = {}, {}
        for name in ("tracker", "camera", "app"):
            logs[name] = open(tmp / f"{name}.log", "w")
            extra = ("--duration", 120) if name == "app" else ("--start-ns", start)
            agents[name] = _cli("agent", realm_dir / f"{name}.yaml", *extra, log=logs[name])
        view = None
        try:
            for name in agents:
                _wait(lambda n=name: '"ready"' in (tmp / f"{n}.log").read_text(), timeout_s,
                      f"agent {name} not ready")  # fmt: skip
            with Browser(1100, 700, timeout_s=timeout_s) as b:  # a browser already running
                t0 = time.monotonic()
                view = _cli("view", "--realm", "demo", "--port", 0,
                            *(a for p in ports.values() for a in ("--connect", p)))  # fmt: skip
                url = None
                while url is None:  # bounded: the process prints its URL or ends
                    line = view.stderr.readline()
                    if not line:
                        raise RuntimeError("the view ended without serving its page")
                    if line.startswith("view: "):
                        url = line.strip().split(" ", 1)[1]
                t_url = time.monotonic() - t0
                t_open = time.monotonic()
                page = b.open(url)
                for text in ("realm demo: 3 agent(s) alive", "advertises art", "advertises "
                             "artoolkit"):  # fmt: skip
                    b.wait_text(page, text)
                shown = time.monotonic() - t0
                after_open = time.monotonic() - t_open
                agents["camera"].send_signal(signal.SIGKILL)
                t1, killed_ns = time.monotonic(), time.time_ns()
                page.wait_for_function(_REPLANNED)
                replan = time.monotonic() - t1
                # when the app re-planned, as the page says (its time of day, ms)
                m = re.search(r"(\d\d):(\d\d):(\d\d)\.(\d{3}) app: query sheep re-planned "
                              r"\([^)]*of agent camera left", page.inner_text("body"))  # fmt: skip
                h, mi, sec, ms = (int(x) for x in m.groups())
                lt = time.localtime(killed_ns / 1e9)
                day0 = killed_ns / 1e9 - (lt.tm_hour * 3600 + lt.tm_min * 60 + lt.tm_sec)
                event_s = day0 + h * 3600 + mi * 60 + sec + ms / 1e3 - killed_ns / 1e9
        finally:
            if view is not None:
                view.terminate()
                view.communicate(timeout=30)
            for p in agents.values():
                if p.poll() is None:
                    p.terminate()
                p.wait(timeout=30)
            for f in logs.values():
                f.close()
    return {"agents_shown_s": round(shown, 2), "url_s": round(t_url, 2),
            "shown_after_open_s": round(after_open, 2),
            "replan_shown_s": round(replan, 2), "replan_event_s": round(event_s, 3)}  # fmt: skip


if __name__ == "__main__":
    print(measure_realm_view())
