"""The documented commands that serve until Ctrl-C (``SERVED`` in tests/_doc_table.py), run as
written the way a user runs them: each prints its page's address and serves viser's page
there (or prints the line that says it runs), and ends on Ctrl-C (SIGINT to its whole process
group, as a terminal sends it) within a minute, with the exit code of an interrupt and without
a traceback from any of its processes."""

from __future__ import annotations

import contextlib

import pytest

from _doc_commands import documented_commands, make_workspace, serve_command
from _doc_table import SERVED

_BY_KEY = {c.key: c for c in documented_commands()}


@pytest.mark.slow
@pytest.mark.parametrize("key", sorted(SERVED))
def test_a_documented_server_serves_and_ends_on_ctrl_c(key, tmp_path, shared_data):
    how, cmd = SERVED[key], _BY_KEY[key]
    repo = make_workspace(tmp_path, shared_data)
    if how.prepare is not None:
        how.prepare(repo)
    with how.around(cmd, repo) if how.around is not None else contextlib.nullcontext():
        r = serve_command(cmd, repo, ready=how.ready)
    assert r.ready, r.describe()
    if how.ready is None:  # a page
        assert r.url and "<html" in r.page.lower() and "viser" in r.page.lower(), r.describe()
    assert "Traceback" not in r.output, r.describe()
    assert r.returncode in (0, 130), r.describe()  # 130: "trackflow: interrupted"
