"""Progress on standard error for long commands.

* :class:`Progress`: a one-line bar (or a plain percentage when stderr is not a terminal) for
  loops whose length is known (reading, converting, plotting, inferring).
* :class:`FinishingStream`: wraps the stream given to the evaluation's tuning bar, whose total
  is an upper bound (the search usually stops early): when the bar is closed it is redrawn full,
  so a finished run ends at 100 % rather than where the estimate left it.
"""

from __future__ import annotations

import re
import sys
import time

__all__ = ["FinishingStream", "Progress"]

_BAR = re.compile(r"\[([#.]+)\]")


class FinishingStream:
    """A text stream proxy that completes a ``[###...]`` bar when its line is ended."""

    def __init__(self, stream):
        self._stream = stream
        self._line = ""

    def write(self, text: str) -> int:
        if text == "\n" and self._line:
            full = _BAR.sub(lambda m: "[" + "#" * len(m.group(1)) + "]", self._line, count=1)
            self._stream.write("\r" + full.replace("evals,", "evals (done),", 1) + "\n")
            self._line = ""
            return len(text)
        if "\r" in text:
            self._line = text.rsplit("\r", 1)[1]
        else:
            self._line += text
        return self._stream.write(text)

    def flush(self) -> None:
        self._stream.flush()


class Progress:
    """``label [####......] 42 %`` on ``stream`` (stderr), at most five updates a second."""

    def __init__(self, label: str, total: int, stream=None, enabled: bool = True):
        self.label, self.total = label, max(int(total), 1)
        self.stream = sys.stderr if stream is None else stream
        self.enabled = enabled
        self._last = 0.0
        self.done = 0

    def update(self, done: int) -> None:
        self.done = min(int(done), self.total)
        now = time.monotonic()
        if not self.enabled or (now - self._last < 0.2 and self.done < self.total):
            return
        self._last = now
        pct = 100 * self.done // self.total
        n = 30 * self.done // self.total
        self.stream.write(f"\r{self.label} [{'#' * n}{'.' * (30 - n)}] {pct:3d} %")
        self.stream.flush()

    def close(self) -> None:
        if self.enabled:
            self._last = 0.0
            self.update(self.total)
            self.stream.write("\n")
            self.stream.flush()
