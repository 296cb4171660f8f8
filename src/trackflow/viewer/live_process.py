"""The view process of a live network: the viser page, drawn from the shared board.

:func:`main` runs in its own process (started by :func:`trackflow.viewer.attach_view`, at a
lower scheduling priority): it attaches the :class:`~trackflow.viewer.board.Board`, serves the
page, and draws at the view rate (30-60 Hz; 2 Hz while no browser is connected) from the poses
and rings the taps wrote. Nothing here holds the dataflow process's interpreter lock: the
dataflow and the view share only memory and a pipe. Messages on the pipe:

* to the view: ``("stats", rejections, offsets_ms)`` (a few times a second, when they
  changed), ``("attributes", dict)`` (measured attributes and the queries' paths, every 2 s
  when they changed: :mod:`trackflow.viewer.attributes_panel`), ``("set", {name: value})``
  (the Python API's controls), ``("report",)`` (what the page shows,
  :meth:`LiveScene.report`), ``("stop",)``;
* from the view: ``("ready", url)`` or ``("failed", message)`` once, ``("offset", seconds)``
  when the prediction slider moves (the dataflow process moves its prediction samplers),
  ``("report", dict)`` in answer to a report request.

The page itself is :class:`trackflow.viewer.live_scene.LiveScene`.
"""

from __future__ import annotations

import logging
import os
import signal
import sys
import threading

from ..errors import InputError
from .board import Board
from .live_scene import IDLE_RATE_HZ, LiveScene

__all__ = ["IDLE_RATE_HZ", "PRIORITIES", "LiveScene", "lower_priority", "main"]

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
        scene = LiveScene(
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
            if msg[0] == "stats":
                scene.rejections, scene.offsets_ms = msg[1], msg[2]
            elif msg[0] == "attributes":
                scene.attributes = msg[1]
            elif msg[0] == "set":
                scene.apply(**msg[1])
            elif msg[0] == "report":
                send(("report", scene.report()))
        stop.set()

    receiver = threading.Thread(target=receive, daemon=True, name="trackflow-view-pipe")
    receiver.start()
    send(("ready", scene.url))
    try:
        scene.loop(stop)
    finally:
        scene.close()
        board.close()


if __name__ == "__main__":
    from multiprocessing.connection import Connection

    main(Connection(int(sys.argv[1])))
