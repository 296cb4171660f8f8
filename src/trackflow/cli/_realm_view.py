"""``trackflow view --realm NAME``: a running realm in the browser, read-only (a realm watcher
drawn on a realm page; ``docs/viewer.md``)."""

from __future__ import annotations

import sys
import threading

#: how often the page is redrawn from the watcher [s]
_DRAW_PERIOD_S = 0.2


def view_realm(args) -> int:
    from ..distributed.realm_status import observer_config
    from ..distributed.realm_watch import RealmWatch
    from ..optional import require
    from ..viewer.browser import snapshot
    from ..viewer.realm_page import RealmPage

    zenoh = require("zenoh", extra="distributed", feature="trackflow view --realm")
    conf = observer_config(zenoh, args.connect, args.zenoh_config)  # (a bad one: no page)
    port = 0 if args.snapshot is not None else args.port
    page = RealmPage(args.host, port, args.realm, magnify=args.magnify or 100.0)
    # the page is served before the realm is joined: a browser loads viser's client (seconds
    # in software WebGL) while Zenoh connects and the watcher asks the agents
    print(f"view: {page.url}", file=sys.stderr, flush=True)
    stop = threading.Event()
    try:
        page.view.set_status(f"joining realm {args.realm} ...")
        with zenoh.open(conf) as session:
            watch = RealmWatch(session, args.realm).start()

            def draw() -> None:
                while not stop.is_set():
                    page.show(watch.snapshot())
                    stop.wait(_DRAW_PERIOD_S)

            drawer = threading.Thread(target=draw, name="realm-page", daemon=True)
            drawer.start()
            try:
                if args.snapshot is not None:
                    stop.wait(3.0 if args.at is None else float(args.at))  # the realm appears
                    out = snapshot(page.url, args.snapshot, f"realm {args.realm}",
                                   args.width, args.height, hide_panel=args.no_panel)  # fmt: skip
                    print(f"snapshot written to {out}")
                else:
                    stop.wait()  # until Ctrl-C
            except KeyboardInterrupt:
                pass
            finally:
                stop.set()
                drawer.join(timeout=5.0)
                watch.close()
    finally:
        page.close()
    return 0
