"""The documented commands that serve a page until Ctrl-C (``SERVED`` in tests/_doc_table.py),
run as written the way a user runs them: each prints its page's address, serves viser's page
there, and ends on Ctrl-C (SIGINT to its whole process group, as a terminal sends it) within
a minute, with the exit code of an interrupt and without a traceback from any of its
processes."""

from __future__ import annotations

import pytest

from _doc_commands import documented_commands, make_workspace, serve_command
from _doc_table import SERVED

_BY_KEY = {c.key: c for c in documented_commands()}


@pytest.mark.slow
@pytest.mark.parametrize("key", sorted(SERVED))
def test_a_documented_page_serves_and_ends_on_ctrl_c(key, tmp_path, shared_data):
    repo = make_workspace(tmp_path, shared_data)
    if SERVED[key].prepare is not None:
        SERVED[key].prepare(repo)
    r = serve_command(_BY_KEY[key], repo)
    assert r.url, r.describe()
    assert "<html" in r.page.lower() and "viser" in r.page.lower(), r.describe()
    assert "Traceback" not in r.output, r.describe()
    assert r.returncode in (0, 130), r.describe()  # 130: "trackflow: interrupted"
