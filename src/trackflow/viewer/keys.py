"""Keyboard shortcuts of a view's page, as presses of the panel's own buttons.

viser has no keyboard events for the Python side, so a view lists its shortcuts with
:func:`add_shortcuts`: a line of the panel that names them and installs, once per page, a
key listener that clicks the panel's button with the mapped text (the buttons stay the one
place where an action is handled: a key and a click do the same). Keys typed into the
panel's inputs and sliders stay theirs. The listener runs in the capture phase and keeps
the keys it uses from the 3D view (whose arrow keys would turn the camera).
"""

from __future__ import annotations

import html
import json

__all__ = ["add_shortcuts", "shortcuts_html"]

#: what the listener ignores: keys typed into inputs or moving a focused slider
_FORM = "input,textarea,select,[contenteditable],[role=slider]"

_SCRIPT = (
    "if(!window.__tfKeys){window.__tfKeys={};window.addEventListener('keydown',function(e){"
    "if(e.ctrlKey||e.metaKey||e.altKey)return;"
    "var t=e.target;if(t&&t.closest&&t.closest('" + _FORM + "'))return;"
    "var label=window.__tfKeys[e.key];if(!label)return;"
    "var b=Array.prototype.find.call(document.querySelectorAll('button'),"
    "function(x){return x.innerText.trim()===label;});"
    "if(!b)return;e.preventDefault();e.stopPropagation();b.click();},true);}"
    "Object.assign(window.__tfKeys,{keys});"
)


def shortcuts_html(keys: dict[str, tuple[str, str]]) -> str:
    """The panel's HTML for ``keys``: ``{key: (button text, what it does)}`` with ``key`` a
    ``KeyboardEvent.key`` value (``" "``, ``"ArrowLeft"``, ``"["``). An image that does not
    load runs the listener's script (HTML set into a page runs no ``<script>``)."""
    script = _SCRIPT.replace("{keys}", json.dumps({k: v[0] for k, v in keys.items()}))
    names = {" ": "space", "ArrowLeft": "\u2190", "ArrowRight": "\u2192"}
    text = ", ".join(f"<b>{html.escape(names.get(k, k))}</b> {html.escape(v[1])}"
                     for k, v in keys.items())  # fmt: skip
    return (f'<img src="data:," alt="" style="display:none" onerror="{html.escape(script)}">'
            f'<div style="font-size:11px">keys: {text}</div>')  # fmt: skip


def add_shortcuts(gui, keys: dict[str, tuple[str, str]]):
    """Add the shortcuts line of ``keys`` (:func:`shortcuts_html`) to ``gui`` (a viser GUI
    API, inside the folder it belongs to); returns the HTML handle."""
    return gui.add_html(shortcuts_html(keys))
