"""The ``online_offsets:`` block of a setup: estimate the relative delay of every two trackers
that see one body while the run goes on (thesis 10.3.6-10.3.7), and, only when the setup
opts in with ``apply: true``, correct the trackers' exposure times by it.

.. code-block:: yaml

    online_offsets:
      apply: true          # default false: estimated and shown, never applied
      reference: optitrack # the sensor whose tracker keeps its times (default: the first
                           # sensor of the setup that has a partner)
      window_s: 30         # the last seconds of both streams an estimate uses
      every_s: 5           # how often one is made (off the dispatch thread)
      max_offset_s: 1.0    # the largest relative delay searched
      max_sigma_ms: 1.0    # an estimate is applied only with at most this standard error
      min_span_s: 3.0      # ... and over at least this much common data
      min_step_ms: 0.5     # ... and when it moves the correction by more than this

Only ``trackflow run`` honours the block (:mod:`trackflow.trackers.online_offsets`); the
other ways of running a setup refuse it with the file, the line and the key
(:meth:`trackflow.dataflow.Setup.refuse_online_offsets`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["OnlineOffsetSpec"]


@dataclass(frozen=True)
class OnlineOffsetSpec:
    """What the ``online_offsets:`` block asks (module docstring); units in the names."""

    apply: bool = False
    reference: str | None = None
    window_s: float = 30.0
    every_s: float = 5.0
    max_offset_s: float = 1.0
    max_sigma_ms: float = 1.0
    min_span_s: float = 3.0
    min_step_ms: float = 0.5

    @classmethod
    def from_mapping(cls, d) -> OnlineOffsetSpec:
        """The block as parsed YAML (a mapping; ``None`` or ``{}``: the defaults).

        Raises
        ------
        ValueError
            An unknown key, a value of the wrong type or out of range, naming the key.
        """
        if d is None:
            return cls()
        if not isinstance(d, dict):
            raise ValueError(f"online_offsets must be a mapping, got {d!r}")
        fields = cls.__dataclass_fields__
        unknown = sorted(set(map(str, d)) - set(fields))
        if unknown:
            raise ValueError(f"online_offsets: unknown keys {unknown} (allowed: {sorted(fields)})")
        kw: dict = {}
        if "apply" in d:
            if not isinstance(d["apply"], bool):
                raise ValueError(f"online_offsets.apply must be true or false, got {d['apply']!r}")
            kw["apply"] = d["apply"]
        if d.get("reference") is not None:
            kw["reference"] = str(d["reference"])
        for key in fields:
            if key in ("apply", "reference") or key not in d:
                continue
            v = d[key]
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ValueError(f"online_offsets.{key} must be a number, got {v!r}")
            least = 0.0 if key == "min_step_ms" else math.ulp(0.0)
            if not (math.isfinite(v) and v >= least):
                raise ValueError(f"online_offsets.{key} must be finite and > 0, got {v!r}")
            kw[key] = float(v)
        return cls(**kw)
