"""Keyboard shortcuts and click-to-seek on a view's page, as uses of the panel's own
controls.

viser passes neither key presses nor clicks on its plots to Python, so a view adds a line
to its panel with :func:`add_shortcuts`: it names the keys and installs, once per page, a
small script that

* on a key, clicks the panel's button with the mapped text (the buttons stay the one place
  where an action is handled: a key and a click do the same). Keys typed into the panel's
  fields or moving a focused slider stay theirs; the keys used are kept from the 3D view
  (whose arrow keys would turn the camera);
* on a click in a time plot, reads the time under the pointer from the plot's legend (uPlot
  shows the cursor's x there) and types it into the panel's text field named ``seek``
  (the view's "go to" field, which moves the view there);
* with ``now``, draws the view's current time as a vertical line in every time plot, five
  times a second: the time is the value of the panel's time slider, placed on the plots'
  fixed time span (the view gives its plots that span,
  :func:`~trackflow.viewer.server.span_axis`).

The script runs from an image that does not load: HTML set into a page runs no
``<script>``.
"""

from __future__ import annotations

import html
import json

from .server import span_axis

__all__ = ["add_shortcuts", "shortcuts_html"]

#: what the key listener ignores: keys typed into fields or moving a focused slider
_FORM = "input,textarea,select,[contenteditable],[role=slider]"

_SCRIPT = (
    "if(!window.__tf){window.__tf={keys:{},seek:null};"
    "var byText=function(sel,text){return Array.prototype.find.call("
    "document.querySelectorAll(sel),function(x){return x.textContent.trim()===text;});};"
    "window.addEventListener('keydown',function(e){"
    "if(e.ctrlKey||e.metaKey||e.altKey)return;"
    "var t=e.target;if(t&&t.closest&&t.closest('" + _FORM + "'))return;"
    "var label=window.__tf.keys[e.key];if(!label)return;"
    "var b=byText('button',label);if(!b)return;"
    "e.preventDefault();e.stopPropagation();b.click();},true);"
    "document.addEventListener('click',function(e){"
    "var over=e.target&&e.target.closest&&e.target.closest('.u-over');"
    "if(!over||!window.__tf.seek)return;"
    "var plot=over.closest('.uplot');"
    "var v=plot&&plot.querySelector('.u-legend .u-series .u-value');"
    "var t=v?parseFloat(v.textContent):NaN;if(!isFinite(t))return;"
    "var lab=byText('label',window.__tf.seek);"
    "var row=lab&&lab.closest('.mantine-Flex-root');"
    "var input=row&&row.querySelector('input');if(!input)return;"
    "var set=Object.getOwnPropertyDescriptor(HTMLInputElement.prototype,'value').set;"
    "set.call(input,String(t));input.dispatchEvent(new Event('input',{bubbles:true}));"
    "},true);"
    "setInterval(function(){var now=window.__tf.now;if(!now)return;"
    "var lab=byText('label',now.slider);var row=lab&&lab.closest('.mantine-Flex-root');"
    "var th=row&&row.querySelector('[role=slider]');"
    "var v=th?parseFloat(th.getAttribute('aria-valuenow')):NaN;if(!isFinite(v))return;"
    "var f=Math.min(Math.max((v-now.span[0])/(now.span[1]-now.span[0]),0),1);"
    "document.querySelectorAll('.u-over').forEach(function(o){"
    "var l=o.querySelector('.tf-now');if(!l){l=document.createElement('div');"
    "l.className='tf-now';l.style.cssText='position:absolute;top:0;bottom:0;width:0;"
    "border-left:1px solid #e33;pointer-events:none';o.appendChild(l);}"
    "l.style.left=(100*f)+'%';});},200);}"
    "Object.assign(window.__tf.keys,{keys});window.__tf.seek={seek};"
    "window.__tf.now={now};"
)


def shortcuts_html(
    keys: dict[str, tuple[str, str]], seek: str | None = None, now: tuple | None = None
) -> str:
    """The panel's HTML: ``keys`` maps a ``KeyboardEvent.key`` value (``" "``,
    ``"ArrowLeft"``, ``"["``) to ``(the text of the button it presses, what it does)``;
    ``seek`` is the label of the text field a click in a time plot types its time into
    (``None``: clicks do nothing); ``now = (slider label, t0_s, t1_s)`` draws the slider's
    time as a line in the time plots, which span ``[t0_s, t1_s]`` (``None``: no line)."""
    script = _SCRIPT.replace("{keys}", json.dumps({k: v[0] for k, v in keys.items()}))
    script = script.replace("{seek}", json.dumps(seek))
    if now is not None:
        label, t0, t1 = now
        now = {"slider": label, "span": span_axis(t0, t1)["x"]["range"]}
    script = script.replace("{now}", json.dumps(now))
    names = {" ": "space", "ArrowLeft": "\u2190", "ArrowRight": "\u2192"}
    text = ", ".join(f"<b>{html.escape(names.get(k, k))}</b> {html.escape(v[1])}"
                     for k, v in keys.items())  # fmt: skip
    if seek is not None:
        text += "; <b>click</b> a time plot to go to its time"
    return (f'<img src="data:," alt="" style="display:none" onerror="{html.escape(script)}">'
            f'<div style="font-size:11px">keys: {text}</div>')  # fmt: skip


def add_shortcuts(
    gui, keys: dict[str, tuple[str, str]], seek: str | None = None, now: tuple | None = None
):
    """Add the shortcuts line (:func:`shortcuts_html`) to ``gui`` (a viser GUI API, inside
    the folder it belongs to); returns the HTML handle."""
    return gui.add_html(shortcuts_html(keys, seek, now))
