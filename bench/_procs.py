"""The processes a benchmark starts: how it ends them, and what it reads of them (resident
memory and CPU time from /proc)."""

from __future__ import annotations

import os
import signal
import subprocess
from pathlib import Path


def stop(popen: subprocess.Popen, timeout_s: float = 10.0) -> None:
    """End ``popen`` as a user would: SIGTERM (after SIGCONT, should a benchmark have frozen
    it), then SIGKILL if it has not ended within ``timeout_s``; waits for it either way."""
    if popen.poll() is not None:
        return
    popen.send_signal(signal.SIGCONT)
    popen.terminate()
    try:
        popen.wait(timeout_s)
    except subprocess.TimeoutExpired:
        popen.kill()
        popen.wait(timeout_s)


def rss_and_cpu(pid: int) -> tuple[float, float] | None:
    """RSS [MB] and CPU time so far (user + system, every thread) [s] of process ``pid``, from
    /proc; None once it is gone."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
        stat = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    rss = next(int(ln.split()[1]) for ln in status.splitlines() if ln.startswith("VmRSS"))
    return rss / 1024, (int(stat[11]) + int(stat[12])) / os.sysconf("SC_CLK_TCK")
