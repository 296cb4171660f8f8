"""What the running system measured, as the live panel shows it below the SRG: each sensor's
measured attributes beside its declared ones (thesis 6.4; the figures of
:class:`trackflow.dataflow.MeasuredAttributes`), the online delay correction applied to its
tracker, and each query's current path with its latest switches (failover).

The main process gathers them (:func:`gather`, a few times a minute is enough: each sensor's
figures are computed from its ring when asked) and sends them to the view process, which
renders them (:func:`render_attributes`). A figure far from its declaration (more than 1.5
times off, as the measured attributes judge it) is drawn in :data:`FAR_COLOUR` (not a colour
of the edge states) with the reason as its tooltip.
"""

from __future__ import annotations

import html
import math

__all__ = ["FAR_COLOUR", "gather", "render_attributes"]

#: the colour of a measured figure far from its declaration
FAR_COLOUR = "#c26a00"

_ROWS = (  # (key, heading, unit, digits)
    ("rate_hz", "rate", "Hz", 1),
    ("latency_ms", "latency", "ms", 1),
    ("noise_mm", "noise", "mm", 2),
    ("noise_deg", "noise", "deg", 3),
)


def gather(
    filters: dict, switches: dict, corrections: dict | None = None, online: dict | None = None
) -> dict:
    """The panel's data, plain (it crosses a pipe).

    Parameters
    ----------
    filters : dict
        Sensor name -> ``(filter, edge)``: a :class:`~trackflow.dataflow.KalmanFilter`
        (its ``measured``) and the :class:`~trackflow.graph.Edge` it declares.
    switches : dict
        Query name -> its :class:`~trackflow.dataflow.PathSwitch` (queries with fallback
        paths).
    corrections : dict, optional
        Sensor name -> the online delay correction applied to its tracker [ms].
    online : dict, optional
        Sensor name -> the newest online estimate of a pair of it (``a``, ``b``,
        ``offset_ms``, ``sigma_ms``; ``OnlineOffsets.latest`` of a live run).
    """
    attrs = {}
    for name, (kf, edge) in filters.items():
        s = kf.measured.summary(edge)
        s["correction_ms"] = (corrections or {}).get(name)
        s["online"] = (online or {}).get(name)
        attrs[name] = s
    paths = {q: sw.summary(last=3) for q, sw in switches.items()}
    return {"attributes": attrs, "switches": paths}


def _cell(measured, declared, digits: int, far: str | None) -> str:
    if measured is None:
        text = "-"
    else:
        text = f"{measured:.{digits}f}"
    decl = "-" if declared is None or not math.isfinite(declared) else f"{declared:.{digits}f}"
    style = f' style="color:{FAR_COLOUR}"' if far else ""
    title = f' title="{html.escape(far)}"' if far else ""
    return f"<td{style}{title}>{text} / {decl}</td>"


def _online(correction_ms, estimate) -> str:
    """The online delay column: the correction applied, and the pair's newest estimate (on
    the corrected times: the residual)."""
    parts = [] if correction_ms is None else [f"{correction_ms:+.1f} ms"]
    if estimate:
        parts.append(
            f"{html.escape(estimate['a'])} - {html.escape(estimate['b'])}: "
            f"{estimate['offset_ms']:+.2f} &plusmn; {estimate['sigma_ms']:.2f} ms"
        )
    return "; ".join(parts) or "-"


def render_attributes(data: dict | None) -> str:
    """HTML of :func:`gather`'s data ("" when there is none yet)."""
    if not data:
        return ""
    out = []
    attrs = data.get("attributes") or {}
    if attrs:
        head = "".join(f"<th>{h} [{u}]</th>" for _, h, u, _ in _ROWS)
        out.append(
            '<div style="font-size:11px;margin-top:6px"><b>measured / declared</b></div>'
            '<table style="font-size:11px;border-collapse:collapse;width:100%">'
            f"<tr><th align=left>sensor</th>{head}<th>NIS</th><th>online delay</th></tr>"
        )
        for name, s in attrs.items():
            m, d, far = s["measured"], s["declared"], s.get("far", {})
            cells = "".join(
                _cell(m.get(k), d.get(k), digits, far.get(k)) for k, _, _, digits in _ROWS
            )
            nis = m.get("nis_mean")
            out.append(
                f"<tr><td>{html.escape(name)}</td>{cells}"
                + _cell(nis, 6.0, 1, far.get("nis_mean"))
                + f"<td>{_online(s.get('correction_ms'), s.get('online'))}</td></tr>"
            )
        out.append("</table>")
    for q, sw in (data.get("switches") or {}).items():
        lines = [
            f"{e['from']} &rarr; {e['to']}: {html.escape(str(e['reason']))}"
            for e in sw.get("switches", [])
        ]
        by_path = ", ".join(str(n) for n in sw.get("answers_by_path", []))
        out.append(
            f'<div style="font-size:11px;margin-top:4px"><b>query {html.escape(q)}</b>: '
            f"path {sw.get('path')} (answers by path {by_path}; "
            f"{sw.get('switch_count', 0)} switches)"
            + "".join(f"<br>&nbsp;&nbsp;{line}" for line in lines)
            + "</div>"
        )
    return "".join(out)
