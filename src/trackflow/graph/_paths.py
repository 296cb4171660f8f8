"""Paths through the spatial relationship graph, including inverse traversal of edges."""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import PlanError
from ..math import UncertainPose
from ._srg import Edge, MotionSpec, SpatialRelationshipGraph

__all__ = ["Path", "PathStep", "find_paths", "infer_motion"]


@dataclass(frozen=True)
class PathStep:
    """One edge of a path; ``inverted`` means it is walked target -> source (``T^-1``)."""

    edge: Edge
    inverted: bool = False

    @property
    def start(self) -> str:
        return self.edge.target if self.inverted else self.edge.source

    @property
    def end(self) -> str:
        return self.edge.source if self.inverted else self.edge.target

    def __str__(self) -> str:
        arrow = "<-" if self.inverted else "->"
        return f"{self.edge.source}{arrow}{self.edge.target}[{self.edge.name}]"


@dataclass(frozen=True)
class Path:
    """A simple path ``source -> ... -> target``: ``T_source_target`` is the product of the
    steps' values (inverted where ``step.inverted``) from left to right."""

    steps: tuple[PathStep, ...]

    @property
    def source(self) -> str:
        return self.steps[0].start

    @property
    def target(self) -> str:
        return self.steps[-1].end

    @property
    def frames(self) -> tuple[str, ...]:
        return (self.source,) + tuple(s.end for s in self.steps)

    @property
    def sensors(self) -> frozenset[str]:
        """Names of the measured edges (sensors) the path uses."""
        return frozenset(s.edge.name for s in self.steps if s.edge.kind == "measured")

    @property
    def motion(self) -> MotionSpec:
        """The motion model inferred for the whole relationship, see :func:`infer_motion`."""
        return infer_motion(self)

    def value(self) -> UncertainPose:
        """Chain the edges' static/nominal values with first-order covariance propagation."""
        out = None
        for s in self.steps:
            v = s.edge.value()
            if s.inverted:
                v = v.inverse()
            out = v if out is None else out.compose(v)
        return out

    def __len__(self) -> int:
        return len(self.steps)

    def __str__(self) -> str:
        return " . ".join(str(s) for s in self.steps)


def infer_motion(path: Path) -> MotionSpec:
    """Motion model of the relationship a path computes.

    All edges static -> static (two static edges chain to a static relationship). Otherwise
    the most demanding model along the path: the largest numbers of derivatives and the sum of
    the scalar process noises (a relationship moves as much as its moving parts together).
    """
    dynamic = [s.edge.motion for s in path.steps if not s.edge.motion.static]
    if not dynamic:
        return MotionSpec.make_static()
    if len(dynamic) == 1:
        return dynamic[0]
    noises = [m.noise for m in dynamic]
    if all(isinstance(n, (int, float)) for n in noises):
        noise = float(sum(noises))
    else:
        noise = dynamic[0].noise
    return MotionSpec(
        static=False,
        n_dp=max(m.n_dp for m in dynamic),
        n_do=max(m.n_do for m in dynamic),
        noise=noise,
    )


def find_paths(
    graph: SpatialRelationshipGraph, source: str, target: str, max_length: int = 8
) -> list[Path]:
    """All simple paths from ``source`` to ``target`` (no frame visited twice).

    Edges may be walked backwards (an inversion). Cycles in the graph are harmless: a path
    never revisits a frame, so the search always terminates.

    Raises
    ------
    ValueError
        For unknown frames, ``source == target`` or when no path exists.
    """
    graph.check_frame(source)
    graph.check_frame(target)
    if source == target:
        raise PlanError(f"query from frame {source!r} to itself: the relationship is identity")
    found: list[Path] = []

    def walk(frame: str, visited: set[str], steps: list[PathStep]) -> None:
        if frame == target:
            found.append(Path(tuple(steps)))
            return
        if len(steps) >= max_length:
            return
        for edge, inverted in graph.incident(frame):
            step = PathStep(edge, inverted)
            if step.end in visited:
                continue
            visited.add(step.end)
            steps.append(step)
            walk(step.end, visited, steps)
            steps.pop()
            visited.discard(step.end)

    walk(source, {source}, [])
    if not found:
        raise PlanError(f"no path from frame {source!r} to frame {target!r} in the graph")
    return found
