"""A realm seen from outside: every agent's status, gathered read-only over Zenoh.

:func:`realm_status` asks the realm's liveliness for its agents (``agent/<name>`` tokens)
and each agent's ``status/<name>`` queryable, and returns them by name;
:func:`status_text` makes a terminal page of it: per agent how its links are protected, its
sensors (live inputs with rate, latency and rejections; measured against declared figures),
each query's state, current path and latest switches or re-plans, and its rejections. It is
what ``trackflow status --realm NAME [--watch]`` prints; a secure realm is joined with an
observer's configuration from ``trackflow realm init --observer``.
"""

from __future__ import annotations

import json

from .discovery import realm_key

__all__ = ["agent_statuses", "observer_config", "realm_status", "status_text"]


def observer_config(zenoh, connect: list[str], zenoh_config=None):
    """The Zenoh configuration of a read-only observer of a realm: ``zenoh_config`` (a
    complete file, such as a secure realm's observer configuration from ``trackflow realm
    init``) or a peer that listens nowhere and connects to the agents' ``connect``
    endpoints, without multicast scouting.

    Raises
    ------
    InputError
        Neither given.
    """
    import json

    from ..errors import InputError

    if zenoh_config is not None:
        return zenoh.Config.from_file(str(zenoh_config))
    if not connect:
        raise InputError("give --connect ENDPOINT (an agent's) or --zenoh-config FILE")
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("transport/shared_memory/enabled", "false")  # (zenohconf.NO_SHARED_MEMORY)
    return conf


def realm_status(session, realm: str, timeout_s: float = 2.0) -> dict[str, dict]:
    """``{agent: status}`` of every agent alive in ``realm`` (``{"error": why}`` for one
    whose status did not come)."""
    names = []
    for reply in session.liveliness().get(realm_key(realm, "agent", "*"), timeout=timeout_s):
        if reply.ok is not None:
            names.append(str(reply.ok.key_expr).rsplit("/", 1)[-1])
    return agent_statuses(session, realm, sorted(set(names)), timeout_s)


def agent_statuses(session, realm: str, names, timeout_s: float = 2.0) -> dict[str, dict]:
    """``{agent: status}`` of the agents ``names``, asked all at once (the slowest reply sets
    the time taken, not their sum); ``{"error": why}`` for one whose status did not come."""
    asked = {n: session.get(realm_key(realm, "status", n), timeout=timeout_s) for n in names}
    out: dict[str, dict] = {}
    for name, replies in asked.items():
        out[name] = {"error": "no status reply"}
        for reply in replies:
            if reply.ok is not None:
                try:
                    out[name] = json.loads(reply.ok.payload.to_bytes())
                except ValueError as exc:
                    out[name] = {"error": f"status not JSON: {exc}"}
                break
    return out


def _attributes(name: str, a: dict) -> str:
    m, d = a.get("measured", {}), a.get("declared", {})

    def fig(key: str, unit: str) -> str:
        got, want = m.get(key), d.get(key)
        return f"{key.split('_')[0]} {got if got is not None else '-'}/{want}{unit}"

    far = f"; far: {', '.join(a['far'])}" if a.get("far") else ""
    return (f"    {name}: {fig('rate_hz', ' Hz')}, {fig('latency_ms', ' ms')}, "
            f"{fig('noise_mm', ' mm')} (measured/declared){far}")  # fmt: skip


def _query(name: str, q: dict) -> list[str]:
    path = q.get("paths", ["-"])[q.get("path", 0)] if q.get("paths") else "-"
    lines = [f"    {name}: {q.get('state')}, path {path}, published {q.get('published', 0)}"
             + (f" ({q['reason']})" if q.get("reason") else "")]  # fmt: skip
    for sw in q.get("switches", [])[-3:]:
        lines.append(f"      switch {sw.get('from')} -> {sw.get('to')}: {sw.get('reason')}")
    for ev in q.get("events", [])[-3:]:  # re-plans: why, and how long planning took
        lines.append(f"      re-planned ({ev.get('reason')}): {ev.get('state')}, paths "
                     f"{ev.get('paths')}, {ev.get('replan_ms', 0):.1f} ms")  # fmt: skip
    return lines


def status_text(realm: str, statuses: dict[str, dict]) -> str:
    """A terminal page of :func:`realm_status` (module docstring)."""
    lines = [f"realm {realm}: {len(statuses)} agent(s)"]
    for name, st in statuses.items():
        if "error" in st and "agent" not in st:
            lines.append(f"  {name}: {st['error']}")
            continue
        lines.append(f"  {name} (links: {st.get('security', '?')})")
        own = [e for e, a in sorted(st.get("live_edges", {}).items()) if a == name]
        for sensor, s in st.get("inputs", {}).items():
            rej = ", ".join(f"{k} {v}" for k, v in s.get("rejections", {}).items()) or "0"
            lines.append(f"    {sensor} ({s.get('protocol')}): {s.get('rate_hz', 0):.1f} Hz, "
                         f"rejected {rej}{', STALE' if s.get('stale') else ''}")  # fmt: skip
        for sensor, a in st.get("attributes", {}).items():
            lines.append(_attributes(sensor, a))
        if own:
            lines.append(f"    advertises: {', '.join(own)}")
        for q, qs in st.get("queries", {}).items():
            lines += _query(q, qs)
        if st.get("rejections"):
            lines.append(f"    rejections: {st['rejections']}")
        if st.get("error"):
            lines.append(f"    error: {st['error']}")
    return "\n".join(lines)
