"""tf2 transforms in ROS bags: ``tf2_msgs/msg/TFMessage`` on ``/tf`` and ``/tf_static``.

A ``TFMessage`` holds many ``geometry_msgs/TransformStamped``; each one with
``header.frame_id = P`` and ``child_frame_id = C`` is the pose ``T_P_C`` (it maps coordinates of
C into P, ``docs/conventions.md``). Together they form tf2's tree: every frame has at most one
parent. Reading a frame pair ``(source, target)`` gives ``T_source_target`` the way tf2's
``lookupTransform(source, target, t)`` would:

1. Walk up the tree from both frames to their nearest common ancestor ``A``; then
   ``T_source_target = T_A_source^-1 @ T_A_target``, each side the product of its
   ``parent <- child`` links from ``A`` down.
2. A link published on a static topic (``/tf_static``, or any TFMessage topic whose last name is
   ``tf_static``) holds at every time; the newest message for it wins, as in tf2.
3. A dynamic link (``/tf``) is interpolated between the two stamps around the asked time:
   linearly in position, by SLERP in rotation (``trackflow.math``). It is never extrapolated.
4. Poses are emitted at every stamp of the *driving* link: the dynamic link of the chain with
   the most stamps (ties: the one nearer the target frame). A stamp where another dynamic link
   of the chain has no data on both sides (before its first or after its last stamp) is
   dropped and counted in the read report (tf2 would raise an extrapolation error there).
   Stamps are not limited by a gap: two neighbouring stamps 5 s apart still interpolate.
5. A chain of static links only gives one pose, stamped with the newest of its messages.

Frame names are compared without a leading ``/`` (ROS 1 tf wrote ``/world``). A repeated stamp
of one link keeps its first transform, like tf2 (``TF_REPEATED_DATA``). A pair the tree cannot
give raises :class:`FrameLookupError` naming both frames and every frame of the bag.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import FormatError, InputError
from ..math import UNIT_TOLERANCE, Pose
from ._report import ReadReport
from ._roscommon import stamp_ns
from ._stream import unit_quaternions

__all__ = ["TF_MSGTYPE", "FrameLookupError", "is_static_topic", "read_tf", "tf_message"]

#: Full type name of tf2's message.
TF_MSGTYPE = "tf2_msgs/msg/TFMessage"


class FrameLookupError(FormatError):
    """A frame pair the transforms of a bag cannot give: not named, unknown or not connected.

    Attributes
    ----------
    source, target : str or None
        The frames asked for.
    frames : tuple of str
        Every frame the bag's transforms name, sorted.
    """

    def __init__(self, message: str, file, source, target, frames):
        self.source, self.target = source, target
        self.frames = tuple(frames)
        super().__init__(message, file)


def is_static_topic(topic: str) -> bool:
    """True for ``/tf_static`` and namespaced ones (``/robot1/tf_static``)."""
    return topic.rstrip("/").rsplit("/", 1)[-1] == "tf_static"


def _name(frame: str) -> str:
    return frame[1:] if frame.startswith("/") else frame


@dataclass
class _Link:
    """The transforms ``T_parent_child`` of one child frame, in time order once finished."""

    parent: str
    child: str
    static: bool
    t_ns: list = field(default_factory=list)
    p: list = field(default_factory=list)
    q: list = field(default_factory=list)
    where: list = field(default_factory=list)  # message index on its topic
    topic: str = ""

    def __str__(self) -> str:
        return f"{self.parent} -> {self.child}" + (" (static)" if self.static else "")


class _Tree:
    """Every link of a bag's transforms, keyed by child frame."""

    def __init__(self):
        self.links: dict[str, _Link] = {}
        self.conflicts: dict[str, set[str]] = {}
        self.frames: set[str] = set()

    def add(self, parent, child, static, t, p, q, where, topic) -> None:
        self.frames.update((parent, child))
        link = self.links.get(child)
        if link is None:
            link = self.links[child] = _Link(parent, child, static, topic=topic)
        elif link.parent != parent or link.static != static:
            self.conflicts.setdefault(child, {str(link)}).add(
                f"{parent} -> {child}" + (" (static)" if static else "")
            )
            return
        if static:  # the newest static transform replaces the older ones, as in tf2
            link.t_ns[:], link.p[:], link.q[:], link.where[:] = [t], [p], [q], [where]
            return
        link.t_ns.append(t)
        link.p.append(p)
        link.q.append(q)
        link.where.append(where)

    def describe(self) -> str:
        edges = ", ".join(str(self.links[c]) for c in sorted(self.links))
        return f"frames {', '.join(sorted(self.frames)) or 'none'} (links: {edges or 'none'})"


def _collect(reader, conns, stamp: str) -> _Tree:
    """Read every transform of the TFMessage connections ``conns`` into a tree."""
    tree = _Tree()
    counts: dict[str, int] = {}
    for conn, t_recv, raw in reader.messages(connections=conns):
        msg = reader.deserialize(raw, conn.msgtype)
        k = counts.get(conn.topic, 0)
        counts[conn.topic] = k + 1
        static = is_static_topic(conn.topic)
        for ts in msg.transforms:
            tr = ts.transform
            p, q = tr.translation, tr.rotation
            tree.add(
                _name(ts.header.frame_id),
                _name(ts.child_frame_id),
                static,
                stamp_ns(ts.header.stamp) if stamp == "header" else int(t_recv),
                (p.x, p.y, p.z),
                (q.x, q.y, q.z, q.w),
                k,
                conn.topic,
            )
    return tree


def _up(tree: _Tree, frame: str, path) -> list[_Link]:
    """The links from ``frame`` up to the root of its tree (child first)."""
    out, seen = [], {frame}
    while frame in tree.links:
        link = tree.links[frame]
        out.append(link)
        frame = link.parent
        if frame in seen:
            raise FormatError(f"the transforms form a loop through {frame!r}", path)
        seen.add(frame)
    return out


def _chain(tree: _Tree, source: str, target: str, path) -> tuple[list[_Link], list[_Link]]:
    """The links from the common ancestor down to ``source`` and to ``target`` (child first)."""
    for frame in (source, target):
        if frame not in tree.frames:
            raise FrameLookupError(
                f"frame {frame!r} (of the pair {source!r} -> {target!r}) is not in the bag's "
                f"transforms; it has {tree.describe()}",
                path,
                source,
                target,
                sorted(tree.frames),
            )
    up_s, up_t = _up(tree, source, path), _up(tree, target, path)
    above_t = [target] + [link.parent for link in up_t]
    above_s = [source] + [link.parent for link in up_s]
    common = next((f for f in above_s if f in set(above_t)), None)
    if common is None:
        raise FrameLookupError(
            f"frames {source!r} and {target!r} are not connected by the bag's transforms "
            f"(roots {above_s[-1]!r} and {above_t[-1]!r}); it has {tree.describe()}",
            path,
            source,
            target,
            sorted(tree.frames),
        )
    links_s, links_t = up_s[: above_s.index(common)], up_t[: above_t.index(common)]
    for link in links_s + links_t:
        if link.child in tree.conflicts:
            raise FormatError(
                f"frame {link.child!r} on the way {source!r} -> {target!r} has several "
                f"parents or is both static and dynamic: {sorted(tree.conflicts[link.child])} "
                "(tf2 needs a tree)",
                path,
            )
    return links_s, links_t


def _finish_link(link: _Link, path, clean: bool, report: ReadReport, driving: bool) -> None:
    """Arrays in time order: non-finite transforms refused (dropped with ``clean``), repeated
    stamps dropped (tf2 keeps the first), quaternions checked for unit length."""
    t = np.array(link.t_ns, dtype=np.int64)
    p = np.array(link.p, dtype=float).reshape(-1, 3)
    q = np.array(link.q, dtype=float).reshape(-1, 4)
    where = np.array(link.where, dtype=np.int64)
    bad = ~(np.isfinite(p).all(axis=1) & np.isfinite(q).all(axis=1))
    if np.any(bad):
        k = int(np.flatnonzero(bad)[0])
        if not clean:
            raise FormatError(
                f"{link.topic} message {int(where[k])}: transform {link.parent} -> "
                f"{link.child} is not finite",
                path,
            )
        if driving:
            report.drop("non-finite transform", where[bad])
        else:
            report.notes.append(f"{int(bad.sum())} non-finite transform(s) of {link} dropped")
    order = np.argsort(t[~bad], kind="stable")
    t, p, q, where = t[~bad][order], p[~bad][order], q[~bad][order], where[~bad][order]
    repeated = np.zeros(len(t), dtype=bool)
    repeated[1:] = t[1:] == t[:-1]
    if np.any(repeated):
        if driving:
            report.drop("repeated stamp (tf2 keeps the first)", where[repeated])
        else:
            report.notes.append(f"{int(repeated.sum())} repeated stamp(s) of {link} ignored")
        t, p, q, where = t[~repeated], p[~repeated], q[~repeated], where[~repeated]
    norm = np.linalg.norm(q, axis=1)
    off = np.abs(norm - 1.0) > UNIT_TOLERANCE
    if np.any(off):
        k = int(np.flatnonzero(off)[0])
        if not clean or np.any(norm[off] == 0.0):
            raise FormatError(
                f"{link.topic} message {int(where[k])}: transform {link.parent} -> "
                f"{link.child} has a quaternion of length {norm[k]:.9g} (pass clean=True to "
                "normalise it)",
                path,
            )
        q[off] /= norm[off, None]
        report.notes.append(f"{int(off.sum())} quaternion(s) of {link} normalised")
    link.t_ns, link.p, link.q, link.where = t, p, unit_quaternions(q) if len(q) else q, where


def _at(link: _Link, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``T_parent_child`` at times ``t`` (inside the link's data): (N, 3), (N, 4).

    Exact at the link's own stamps; between two stamps linear in position, SLERP in rotation.
    """
    n = len(t)
    if link.static:
        return np.broadcast_to(link.p[0], (n, 3)), np.broadcast_to(link.q[0], (n, 4))
    s = link.t_ns
    i = np.clip(np.searchsorted(s, t, side="right") - 1, 0, len(s) - 1)
    p, q = link.p[i].copy(), link.q[i].copy()
    between = s[i] != t
    if np.any(between):
        i0 = i[between]
        i1 = np.minimum(i0 + 1, len(s) - 1)
        frac = (t[between] - s[i0]) / (s[i1] - s[i0]).astype(float)
        pose = Pose(link.p[i0], link.q[i0]).interpolate(Pose(link.p[i1], link.q[i1]), frac)
        p[between], q[between] = pose.position, pose.quaternion
    return p, q


def _product(links: list[_Link], t: np.ndarray) -> Pose | tuple | None:
    """``T_A_x`` for the links from the ancestor ``A`` down to ``x`` (given child first).

    One link gives its arrays ``(p, q)`` untouched (a one-link chain reads back bit for bit);
    several give a ``Pose``; none gives ``None``.
    """
    if len(links) == 1:
        return _at(links[0], t)
    out = None
    for link in reversed(links):
        pose = Pose(*_at(link, t))
        out = pose if out is None else out @ pose
    return out


def _pose(x) -> Pose:
    return x if isinstance(x, Pose) else Pose(*x)


def read_tf(reader, conns, path, *, source, target, stamp: str, clean: bool, report: ReadReport):
    """Chain the transforms of ``conns`` (TFMessage connections) for ``T_source_target``.

    Parameters
    ----------
    reader : rosbags AnyReader
        Open bag.
    conns : list of Connection
        One dynamic topic's connections and those of the static topics.
    source, target : str
        The frame pair (see the module docstring for the rule).
    stamp : {"header", "receive"}
    report : ReadReport
        Receives ``rows_read`` (transforms of the driving link), drops and notes.

    Returns
    -------
    where : ndarray of int, shape (N,)
        Message index (on the dynamic topic) of each pose's driving transform.
    t_ns : ndarray of int64, shape (N,)
    position : ndarray, shape (N, 3)
        ``t_source_target`` [m].
    quaternion : ndarray, shape (N, 4)
        ``R_source_target`` ``(x, y, z, w)``.
    """
    tree = _collect(reader, conns, stamp)
    frames = sorted(tree.frames)
    if not source or not target:
        raise FrameLookupError(
            "a TFMessage topic holds many frames: pass the pair as source= and target= "
            f"(the pose T_source_target); the bag has {tree.describe()}",
            path,
            source,
            target,
            frames,
        )
    source, target = _name(source), _name(target)
    if source == target:
        raise InputError(f"source and target are the same frame {source!r}")
    links_s, links_t = _chain(tree, source, target, path)
    chain = links_t + links_s  # nearer the target first: ties of the driving link go there
    dynamic = [link for link in chain if not link.static]
    driving = max(dynamic, key=lambda link: len(link.t_ns), default=None)
    n_driving = 0 if driving is None else len(driving.t_ns)
    for link in chain:
        _finish_link(link, path, clean, report, link is driving)
    if driving is None:
        how = "all static: one pose"
    else:
        how = f"poses at the stamps of {driving}" + (
            ", the other links interpolated" if len(chain) > 1 else ""
        )
    links = ", ".join(str(x) for x in chain)
    report.notes.append(f"{source} -> {target} from TFMessage links {links}; {how}")
    if driving is None:
        newest = max(chain, key=lambda link: int(link.t_ns[0]))
        t = newest.t_ns[:1].copy()
        where = np.zeros(1, dtype=np.int64)
        report.rows_read = 1
    else:
        report.rows_read = n_driving
        t, where = driving.t_ns, driving.where
        keep = np.ones(len(t), dtype=bool)
        for link in dynamic:
            if link is driving:
                continue
            inside = np.zeros(len(t), dtype=bool)
            if len(link.t_ns):
                inside = (t >= link.t_ns[0]) & (t <= link.t_ns[-1])
            report.drop(f"no {link} transform around it", where[keep & ~inside])
            keep &= inside
        t, where = t[keep], where[keep]
    t_s, t_t = _product(links_s, t), _product(links_t, t)
    if t_s is None:
        out = t_t if isinstance(t_t, tuple) else (t_t.position, t_t.quaternion)
    else:
        pose = _pose(t_s).inverse() if t_t is None else _pose(t_s).inverse() @ _pose(t_t)
        out = (pose.position, pose.quaternion)
    return where, t, np.array(out[0], dtype=float), np.array(out[1], dtype=float)


def tf_message(store, hdr, child: str, position, quaternion):
    """A ``TFMessage`` with one ``TransformStamped`` (``hdr.frame_id`` -> ``child``)."""
    T = store.types
    Vec3, Quat = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    x, y, z = (float(v) for v in position)
    qx, qy, qz, qw = (float(v) for v in quaternion)
    tr = T["geometry_msgs/msg/Transform"](
        translation=Vec3(x=x, y=y, z=z), rotation=Quat(x=qx, y=qy, z=qz, w=qw)
    )
    ts = T["geometry_msgs/msg/TransformStamped"](header=hdr, child_frame_id=child, transform=tr)
    return T[TF_MSGTYPE](transforms=[ts])
