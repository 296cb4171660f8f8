"""The commands of the docs/*.md pages that tests/test_readme.py does not run (README_PAGES),
run as written: a file of its own so that `make test`'s two workers (--dist loadfile) share
the pages."""

from __future__ import annotations

import pytest

from _doc_commands import make_workspace
from _doc_table import README_PAGES, pages, run_page


@pytest.mark.slow
@pytest.mark.parametrize("doc", [p for p in pages() if p not in README_PAGES])
def test_documented_commands_run_as_written(doc, tmp_path, shared_data):
    """Every RUN command of the page runs as written (``run_page``) in a workspace laid out like
    a checkout beside the shared data."""
    run_page(doc, make_workspace(tmp_path, shared_data))
