"""The spatial relationship graph (SRG): frames, measured and static edges, their attributes.

An edge ``a -> b`` stands for the relationship ``T_a_b`` (it maps frame b into frame a, see
``docs/conventions.md``). A *measured* edge is a sensor stream; a *static* edge is a calibration
with its covariance. Every edge carries the quality attributes of the thesis's section 2.1.2:
latency, update rate, confidence, pose accuracy (a 6x6 covariance over ``(dt, dtheta)``) and
cost, plus a motion model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError, PlanError
from ..math import Pose, UncertainPose, check_covariance

__all__ = ["Edge", "MotionSpec", "SpatialRelationshipGraph"]


@dataclass(frozen=True)
class MotionSpec:
    """How a relationship may move (thesis 2.1.2, "Motion models").

    Parameters
    ----------
    static : bool
        The relationship never changes: every measurement stays valid forever.
    n_dp, n_do : int
        Number of time derivatives of position / orientation kept in a filter state
        (0 = constant pose, 1 = constant velocity, 2 = constant acceleration).
    noise : float or tuple of float
        Process noise handed to :class:`trackflow.filters.MotionModel` unchanged (how far the
        motion may diverge from the polynomial model).
    """

    static: bool = False
    n_dp: int = 1
    n_do: int = 1
    noise: float | tuple[float, ...] = 1.0

    def __post_init__(self):
        for name in ("n_dp", "n_do"):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or not 0 <= v <= 3:
                raise InputError(f"motion model {name} must be an integer in 0..3, got {v!r}")

    @classmethod
    def make_static(cls) -> MotionSpec:
        """The motion model of a rigid, never-changing relationship."""
        return cls(static=True, n_dp=0, n_do=0, noise=0.0)


@dataclass(frozen=True, eq=False)
class Edge:
    """One directed relationship ``T_source_target`` of the SRG.

    Parameters
    ----------
    source, target : str
        Frame names; the edge's value maps ``target`` coordinates into ``source``.
    name : str
        Unique edge name; for measured edges it identifies the sensor (paths that share no
        sensor name are independent).
    kind : {"measured", "static"}
    latency_s : float
        Time from the measurement to its availability [s] (measured edges).
    rate_hz : float
        Update rate [1/s]; ``inf`` for static edges.
    confidence : float
        Probability in [0, 1] that a detection is correct.
    covariance : ndarray (6, 6)
        Typical measurement covariance over ``(dt [m, frame source], dtheta [rad, right])``:
        ``t_true = t + dt``, ``R_true = R Exp(dtheta)``.
    cost : float
        Monetary (or any additive) cost of using the edge.
    motion : MotionSpec
        Motion model of the relationship (static edges always ``MotionSpec.make_static()``).
    pose : Pose or None
        The value of a static edge; for a measured edge an optional nominal pose used by
        covariance-based evaluation functions (identity when omitted).
    stamp_offset_s : float
        Known constant error of the sensor's timestamps: ``stamp = true time + offset`` [s]
        (thesis 9.2.2, "Constant Time Offset"). Time-aligning filters subtract it.
    """

    source: str
    target: str
    name: str
    kind: str = "measured"
    latency_s: float = 0.0
    rate_hz: float = math.inf
    confidence: float = 1.0
    covariance: np.ndarray = field(default_factory=lambda: np.zeros((6, 6)))
    cost: float = 0.0
    motion: MotionSpec = field(default_factory=MotionSpec)
    pose: Pose | None = None
    stamp_offset_s: float = 0.0

    def __post_init__(self):
        if self.kind not in ("measured", "static"):
            raise InputError(f"edge {self.name!r}: kind must be 'measured' or 'static'")
        if self.source == self.target:
            raise InputError(f"edge {self.name!r} connects frame {self.source!r} to itself")
        object.__setattr__(
            self, "covariance", check_covariance(self.covariance, f"edge {self.name!r} covariance")
        )
        if self.covariance.shape != (6, 6):
            raise InputError(f"edge {self.name!r}: covariance must be 6x6")
        for attr in ("latency_s", "cost"):
            v = float(getattr(self, attr))
            if not math.isfinite(v) or v < 0:
                raise InputError(f"edge {self.name!r}: {attr} must be finite and >= 0, got {v}")
        if not self.rate_hz > 0:
            raise InputError(f"edge {self.name!r}: rate_hz must be > 0, got {self.rate_hz}")
        if not 0.0 <= self.confidence <= 1.0:
            raise InputError(f"edge {self.name!r}: confidence must be in [0, 1]")
        if self.kind == "static":
            if self.pose is None:
                raise InputError(f"static edge {self.name!r} needs a pose")
            object.__setattr__(self, "motion", MotionSpec.make_static())
            object.__setattr__(self, "rate_hz", math.inf)
        if self.pose is not None and self.pose.shape != ():
            raise InputError(f"edge {self.name!r}: pose must be a single pose")

    @property
    def is_static(self) -> bool:
        """True for static edges and for measured edges of a static relationship."""
        return self.motion.static

    def value(self) -> UncertainPose:
        """The static value (or nominal pose, identity if unset) with the edge covariance."""
        pose = self.pose if self.pose is not None else Pose.identity()
        return UncertainPose(pose, self.covariance)

    def __repr__(self) -> str:
        return f"Edge({self.name!r}: {self.source} -> {self.target}, {self.kind})"


class SpatialRelationshipGraph:
    """Frames (nodes) and directed relationship edges, several edges per frame pair allowed.

    Examples
    --------
    >>> from trackflow import Pose
    >>> g = SpatialRelationshipGraph()
    >>> g.add_static("calib", "P", "A", Pose.identity())
    Edge('calib': P -> A, static)
    >>> g.frames
    ('A', 'P')
    """

    def __init__(self):
        self._frames: set[str] = set()
        self._edges: dict[str, Edge] = {}
        self._incident: dict[str, list[tuple[Edge, bool]]] = {}

    # -- construction ---------------------------------------------------------------------------
    def add_frame(self, name: str) -> None:
        """Declare a frame; edges add their frames implicitly."""
        if not isinstance(name, str) or not name:
            raise InputError(f"frame names must be non-empty strings, got {name!r}")
        self._frames.add(name)

    def add_edge(self, edge: Edge) -> Edge:
        """Add an edge; names must be unique."""
        if edge.name in self._edges:
            raise InputError(f"duplicate edge name {edge.name!r}")
        self.add_frame(edge.source)
        self.add_frame(edge.target)
        self._edges[edge.name] = edge
        self._incident.setdefault(edge.source, []).append((edge, False))
        self._incident.setdefault(edge.target, []).append((edge, True))
        return edge

    def add_measured(self, name: str, source: str, target: str, **attributes) -> Edge:
        """Add a sensor edge ``T_source_target``; ``attributes`` as in :class:`Edge`."""
        return self.add_edge(Edge(source, target, name, kind="measured", **attributes))

    def add_static(
        self, name: str, source: str, target: str, pose: Pose, covariance=None, **attributes
    ) -> Edge:
        """Add a calibrated static edge ``T_source_target`` with its 6x6 covariance."""
        cov = np.zeros((6, 6)) if covariance is None else covariance
        return self.add_edge(
            Edge(source, target, name, kind="static", pose=pose, covariance=cov, **attributes)
        )

    # -- access ---------------------------------------------------------------------------------
    @property
    def frames(self) -> tuple[str, ...]:
        """All frame names, sorted."""
        return tuple(sorted(self._frames))

    @property
    def edges(self) -> tuple[Edge, ...]:
        """All edges in insertion order."""
        return tuple(self._edges.values())

    def edge(self, name: str) -> Edge:
        """The edge called ``name``."""
        try:
            return self._edges[name]
        except KeyError:
            raise PlanError(f"unknown edge {name!r}") from None

    def check_frame(self, name: str) -> None:
        """Raise ``ValueError`` naming the known frames if ``name`` is not one of them."""
        if name not in self._frames:
            raise PlanError(f"unknown frame {name!r} (known: {', '.join(self.frames)})")

    def incident(self, frame: str) -> list[tuple[Edge, bool]]:
        """Edges leaving ``frame`` as ``(edge, inverted)``: forward edges ``frame -> x`` and
        edges ``x -> frame`` traversed backwards (``inverted=True``), in insertion order.

        An index kept by :meth:`add_edge`: O(degree), not O(edges)."""
        return list(self._incident.get(frame, ()))
