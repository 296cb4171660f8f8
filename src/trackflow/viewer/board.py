"""The shared-memory board between a running network and its view process.

The dataflow process writes, the view process reads; neither waits for the other. The board is
one :class:`multiprocessing.shared_memory.SharedMemory` block of 8-byte words, a header and one
slot per drawn body (a sensor behind its filter, a query's answer, a query's prediction):

* per event (written by a :class:`~trackflow.viewer.monitor.Tap` in the dataflow thread, a few
  scalar stores): the event count, the network clock at its arrival, and one entry of a ring of
  ``(event time [ns], latency [ns], NIS)`` for the time plots;
* at most at the view rate: the newest pose ``(position (3,) [m], quaternion (4,) (x, y, z, w),
  covariance (6, 6))`` and its time, behind a sequence lock (odd while being written; a reader
  copies and retries when the sequence moved), so a torn pose is never drawn.

Single 8-byte aligned stores and loads are atomic on the platforms CPython runs the view on
(x86-64, AArch64); the sequence lock orders the multi-word pose record (x86-64 keeps stores in
program order; on weaker memory models a torn read is still caught by the re-check of the
sequence in the common case and would show one odd frame at worst).
"""

from __future__ import annotations

from dataclasses import dataclass
from multiprocessing import resource_tracker, shared_memory

import numpy as np

from ..errors import InputError

__all__ = ["POSE_WORDS", "RING", "Board", "BoardPose"]

MAGIC = 0x7466_7669_6577  # "tfview"
#: Ring entries per slot (about 2 s of a 240 Hz sensor).
RING = 512
#: Words of one pose record: position 3, quaternion 4, covariance 36.
POSE_WORDS = 43

_HEADER = 16
# header words
H_MAGIC, H_SLOTS, H_RING, H_FRAMES, H_CLIENTS, H_NOW, H_WALL = range(7)
# slot words
S_SEQ, S_COUNT, S_ARRIVAL, S_POSE_T, S_POSES = range(5)
_POSE = 8  # first word of the pose record
_RING_T = 64  # ring of event times (int64), then latencies (int64), then NIS (float64)
_SLOT = _RING_T + 3 * RING


def _attach_untracked(name: str) -> shared_memory.SharedMemory:
    """Open an existing block without registering it with this process's resource tracker:
    the creator owns (and unlinks) it; a tracker of the reading process would remove it when
    that process ends (Python < 3.13 registers every opened block; 3.13 has ``track=False``)."""
    try:
        return shared_memory.SharedMemory(name=name, track=False)  # Python >= 3.13
    except TypeError:
        pass
    register = resource_tracker.register
    resource_tracker.register = lambda *args, **kwargs: None
    try:
        return shared_memory.SharedMemory(name=name)
    finally:
        resource_tracker.register = register


@dataclass
class BoardPose:
    """One pose read from the board (copies, safe to keep)."""

    t_ns: int
    position: np.ndarray
    quaternion: np.ndarray
    covariance: np.ndarray


class Board:
    """A view board of ``n_slots`` slots; :meth:`create` in the dataflow process,
    :meth:`attach` (by :attr:`name`) in the view process.

    Attributes
    ----------
    q, d : memoryview
        The block as int64 and as float64 words (fast scalar stores, same word index).
    words : ndarray (n,) int64 and ``fwords`` (n,) float64
        The same block as arrays (bulk copies).
    """

    def __init__(self, shm: shared_memory.SharedMemory, owner: bool):
        self.shm, self.owner = shm, owner
        self.q = shm.buf.cast("q")
        self.d = shm.buf.cast("d")
        n = len(self.q)
        self.words = np.frombuffer(shm.buf, dtype=np.int64, count=n)
        self.fwords = np.frombuffer(shm.buf, dtype=np.float64, count=n)
        self.n_slots = int(self.q[H_SLOTS])

    @property
    def name(self) -> str:
        return self.shm.name

    @classmethod
    def create(cls, n_slots: int) -> Board:
        size = 8 * (_HEADER + max(int(n_slots), 1) * _SLOT)
        shm = shared_memory.SharedMemory(create=True, size=size)
        shm.buf[:size] = bytes(size)
        q = shm.buf.cast("q")
        q[H_SLOTS], q[H_RING], q[H_MAGIC] = int(n_slots), RING, MAGIC
        q.release()
        return cls(shm, owner=True)

    @classmethod
    def attach(cls, name: str) -> Board:
        """Open the board ``name`` made by :meth:`create` (raises ValueError if it is not one)."""
        shm = _attach_untracked(name)
        board = cls(shm, owner=False)
        if board.q[H_MAGIC] != MAGIC or board.q[H_RING] != RING:
            board.close()
            raise InputError(f"shared memory {name!r} is not a trackflow view board")
        return board

    # -- layout ---------------------------------------------------------------------------------
    @staticmethod
    def base(slot: int) -> int:
        """First word of ``slot``."""
        return _HEADER + int(slot) * _SLOT

    # -- header ---------------------------------------------------------------------------------
    def set_clock(self, now_ns: int, dispatch_wall_ns: int) -> None:
        """The network clock and the wall time (``perf_counter_ns``) of its last dispatch."""
        self.q[H_NOW], self.q[H_WALL] = int(now_ns), int(dispatch_wall_ns)

    def clock(self) -> tuple[int, int]:
        return int(self.q[H_NOW]), int(self.q[H_WALL])

    @property
    def frames_sent(self) -> int:
        """View frames the view process has pushed to its page (written by it)."""
        return int(self.q[H_FRAMES])

    @frames_sent.setter
    def frames_sent(self, n: int) -> None:
        self.q[H_FRAMES] = int(n)

    @property
    def clients(self) -> int:
        """Browsers connected to the view's page (written by the view process)."""
        return int(self.q[H_CLIENTS])

    @clients.setter
    def clients(self, n: int) -> None:
        self.q[H_CLIENTS] = int(n)

    # -- slots: writer side ---------------------------------------------------------------------
    def clear(self, slot: int) -> None:
        """Forget a slot's events and pose (a network reset)."""
        b = self.base(slot)
        self.words[b : b + _SLOT] = 0

    def write_event(self, slot: int, t_ns: int, latency_ns: int, nis: float, now_ns: int) -> None:
        """Count one event and append it to the slot's ring (the per-event path)."""
        q, b = self.q, self.base(slot)
        n = q[b + S_COUNT]
        k = n % RING
        q[b + _RING_T + k] = t_ns
        q[b + _RING_T + RING + k] = latency_ns
        self.d[b + _RING_T + 2 * RING + k] = nis
        q[b + S_ARRIVAL] = now_ns
        q[b + S_COUNT] = n + 1

    def write_pose(self, slot: int, t_ns: int, position, quaternion, covariance) -> None:
        """Replace the slot's pose under its sequence lock."""
        q, b, f = self.q, self.base(slot), self.fwords
        q[b + S_SEQ] += 1  # odd: being written
        p = b + _POSE
        f[p : p + 3] = position
        f[p + 3 : p + 7] = quaternion
        f[p + 7 : p + POSE_WORDS] = np.asarray(covariance).reshape(36)
        q[b + S_POSE_T] = t_ns
        q[b + S_POSES] += 1
        q[b + S_SEQ] += 1  # even: consistent

    # -- slots: reader side ---------------------------------------------------------------------
    def count(self, slot: int) -> int:
        return int(self.q[self.base(slot) + S_COUNT])

    def arrival_ns(self, slot: int) -> int:
        return int(self.q[self.base(slot) + S_ARRIVAL])

    def last_event_ns(self, slot: int) -> int | None:
        """Time of the slot's newest event [ns] (None before the first)."""
        q, b = self.q, self.base(slot)
        n = int(q[b + S_COUNT])
        return int(q[b + _RING_T + (n - 1) % RING]) if n else None

    def read_pose(self, slot: int, tries: int = 100) -> BoardPose | None:
        """The slot's newest pose, or None if none was written yet (or it kept changing)."""
        q, b = self.q, self.base(slot)
        p = b + _POSE
        for _ in range(tries):
            s1 = q[b + S_SEQ]
            if s1 & 1:
                continue
            if q[b + S_POSES] == 0:
                return None
            rec = self.fwords[p : p + POSE_WORDS].copy()
            t = int(q[b + S_POSE_T])
            if q[b + S_SEQ] == s1:
                return BoardPose(t, rec[:3], rec[3:7], rec[7:].reshape(6, 6))
        return None

    def read_ring(self, slot: int, last: int = RING) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The newest ``last`` ring entries, oldest first: event times [ns] (int64), latencies
        [ns] (int64) and NIS (float64)."""
        b = self.base(slot)
        n = int(self.q[b + S_COUNT])
        m = min(n, RING, int(last))
        idx = (np.arange(n - m, n) % RING) + b + _RING_T
        return (
            self.words[idx].copy(),
            self.words[idx + RING].copy(),
            self.fwords[idx + 2 * RING].copy(),
        )

    def close(self) -> None:
        """Release the mapping (and, for the creator, remove the block)."""
        del self.words, self.fwords
        self.q.release()
        self.d.release()
        try:
            self.shm.close()
        except BufferError:  # a reader still holds a view: the mapping goes with it
            pass
        if self.owner:
            try:
                self.shm.unlink()
            except FileNotFoundError:
                pass
