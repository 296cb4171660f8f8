"""The view process of a live network: the viser page, drawn from the shared board.

:func:`main` runs in its own process (started by :func:`trackflow.viewer.attach_view`, at a
lower scheduling priority): it attaches the :class:`~trackflow.viewer.board.Board`, serves the
page, and draws at the view rate (30-60 Hz; 2 Hz while no browser is connected) from the poses
and rings the taps wrote. Nothing here holds the dataflow process's interpreter lock: the
dataflow and the view share only memory and a pipe. Messages on the pipe:

* to the view: ``("stats", rejections, offsets_ms)`` (a few times a second, when they
  changed), ``("attributes", dict)`` (measured attributes and the queries' paths, every 2 s
  when they changed: :mod:`trackflow.viewer.attributes_panel`), ``("set", {name: value})``
  (the Python API's controls: every open tab, and the default of tabs opened later),
  ``("report",)`` (what the oldest open tab shows, :meth:`LiveTabs.report`), ``("stop",)``;
* from the view: ``("ready", url)`` or ``("failed", message)`` once, ``("offset", seconds)``
  when a tab's prediction slider moves (the dataflow process moves its prediction samplers:
  one offset for every tab), ``("report", dict)`` in answer to a report request.

Each browser tab gets its own page (:class:`trackflow.viewer.live_scene.LiveScene`), drawn by
:class:`trackflow.viewer.live_loop.LiveTabs` from the state every tab shares
(:mod:`trackflow.viewer.live_state`).
"""

from __future__ import annotations

import logging
import os
import signal
import sys
import threading

from ..errors import InputError
from .board import Board
from .live_loop import IDLE_RATE_HZ, LiveTabs

__all__ = ["IDLE_RATE_HZ", "PRIORITIES", "LiveTabs", "lower_priority", "main"]

#: View process priorities: ``low`` is niceness +10, ``idle`` runs only on CPU time no other
#: process wants (Linux ``SCHED_IDLE``; elsewhere the lowest niceness), ``normal`` as is.
PRIORITIES = ("idle", "low", "normal")


def lower_priority(priority: str) -> str:
    """Lower this process's CPU priority (before it starts threads, which inherit it);
    returns what was applied (``SCHED_IDLE``, ``nice +N`` or ``normal``)."""
    if priority not in PRIORITIES:
        raise InputError(f"view priority must be one of {PRIORITIES}, got {priority!r}")
    if priority == "normal":
        return "normal"
    if priority == "idle" and hasattr(os, "SCHED_IDLE"):
        try:
            os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
            return "SCHED_IDLE"
        except OSError:
            pass  # not permitted here: fall back to the lowest niceness
    step = 19 if priority == "idle" else 10
    os.nice(step)
    return f"nice +{step}"


def main(conn) -> None:
    """The view process: receive ``(layout, board name, options)``, serve and draw until
    ``("stop",)`` arrives or the connection closes.

    ``options``: ``host``, ``port``, ``rate_hz``, ``style`` (:class:`Style`), ``priority``
    (:func:`lower_priority`)."""
    # the dataflow process owns the stop: a terminal's Ctrl-C reaches the whole process group,
    # and the view must not die of it mid-frame (a traceback) before the pipe tells it to stop
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    send_lock = threading.Lock()

    def send(msg) -> None:
        with send_lock:
            try:
                conn.send(msg)
            except (BrokenPipeError, OSError):
                pass  # the dataflow process is gone; the receiver stops us

    board = None
    try:
        layout, board_name, options = conn.recv()
        lower_priority(options.get("priority", "low"))
        # a browser that opens a speculative connection and drops it is not an error here
        logging.getLogger("websockets.server").setLevel(logging.CRITICAL)
        board = Board.attach(board_name)
        view = LiveTabs(
            layout, board, options["host"], options["port"], options["rate_hz"],
            options["style"], send, options.get("anchor"),
        )  # fmt: skip
    except (EOFError, OSError):
        if board is not None:
            board.close()
        return  # the dataflow process went away before we started
    except Exception as exc:  # reported to the dataflow process, which raises it
        if board is not None:
            board.close()  # its views released, so the interpreter's exit is quiet
        send(("failed", f"{type(exc).__name__}: {exc}"))
        return
    stop = threading.Event()

    def receive() -> None:
        while not stop.is_set():
            try:
                msg = conn.recv()
            except (EOFError, OSError):
                break
            if msg[0] == "stop":
                break
            try:
                handle(msg)
            except (KeyError, TypeError, ValueError, IndexError) as exc:  # a bad message
                print(f"trackflow view: message {msg[0]!r} refused: {type(exc).__name__}: "
                      f"{exc}", file=sys.stderr, flush=True)  # fmt: skip
        stop.set()

    def handle(msg) -> None:
        if msg[0] == "stats":
            view.state.rejections, view.state.offsets_ms = msg[1], msg[2]
        elif msg[0] == "attributes":
            view.state.attributes = msg[1]
        elif msg[0] == "set":
            view.apply(**msg[1])
        elif msg[0] == "report":
            send(("report", view.report()))
        else:
            raise KeyError(f"no view message {msg[0]!r}")

    receiver = threading.Thread(target=receive, daemon=True, name="trackflow-view-pipe")
    receiver.start()
    send(("ready", view.url))
    try:
        view.loop(stop)
    finally:
        view.close()
        board.close()


if __name__ == "__main__":
    from multiprocessing.connection import Connection

    main(Connection(int(sys.argv[1])))
