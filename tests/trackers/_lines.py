"""A child process's output lines, read in a thread, and a bounded wait for one of them (the
live tests that run `trackflow run` / `simulate` as real processes)."""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable


def read_lines(stream) -> queue.Queue:
    """The lines of ``stream`` (a text pipe), put on a queue by a daemon thread."""
    lines: queue.Queue = queue.Queue()

    def read() -> None:
        for line in stream:
            lines.put(line)

    threading.Thread(target=read, daemon=True).start()
    return lines


def wait_line(lines: queue.Queue, accept: str | Callable[[str], bool], timeout_s: float) -> str:
    """The first line that starts with ``accept`` (or that ``accept(line)`` takes), stripped,
    within ``timeout_s``; else an AssertionError naming the last lines seen."""
    take = (lambda line: line.startswith(accept)) if isinstance(accept, str) else accept
    end, seen = time.monotonic() + timeout_s, []
    while time.monotonic() < end:
        try:
            line = lines.get(timeout=max(end - time.monotonic(), 0.01))
        except queue.Empty:
            break
        if take(line):
            return line.strip()
        seen.append(line)
    raise AssertionError(f"no such line ({accept!r}) within {timeout_s} s: {seen[-5:]}")


def stop_when_stale(run, lines: queue.Queue, sensors: int, timeout_s: float = 60.0) -> str:
    """Wait for a status line with ``sensors`` STALE sensors (every sent packet has been
    received), then end ``trackflow run`` with SIGTERM; its stdout (the summary)."""
    import signal

    wait_line(lines, lambda line: line.count("STALE") == sensors, timeout_s)
    run.send_signal(signal.SIGTERM)
    out, _ = run.communicate(timeout=60)
    return out
