"""What a benchmark reads of the processes it started: resident memory and CPU time from /proc."""

from __future__ import annotations

import os
from pathlib import Path


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
