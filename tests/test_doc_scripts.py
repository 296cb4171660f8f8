"""Documented commands that work only together (``SCRIPTS`` in tests/_doc_table.py: a shell
variable, background jobs), run as one bash script, as written and in the doc's order, in a
workspace laid out like a checkout; then each script's check."""

from __future__ import annotations

import pytest

from _doc_commands import DocCommand, documented_commands, make_workspace, run_command
from _doc_table import SCRIPTS

pytestmark = pytest.mark.slow


def _script(name: str) -> DocCommand:
    """The script's commands as the doc writes them, one after the other in one block."""
    cmds = documented_commands()
    keys = SCRIPTS[name].keys
    first = next(i for i, c in enumerate(cmds) if c.key == keys[0])
    block = cmds[first : first + len(keys)]
    assert [c.key for c in block] == list(keys), f"not consecutive in {cmds[first].where}"
    return DocCommand(block[0].doc, block[0].line, "\n".join(c.text for c in block))


def test_the_demo_realm_answers_over_three_agents(tmp_path, shared_data):
    pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed (.[distributed])")
    script = SCRIPTS["the demo realm"]
    repo = make_workspace(tmp_path, shared_data)
    script.prepare(repo)
    r = run_command(_script("the demo realm"), repo, timeout=240)
    assert r.returncode == 0, r.describe()
    script.check(r)


def test_the_demo_realm_is_never_replaced_without_force(tmp_path):
    repo = make_workspace(tmp_path)
    written = DocCommand("test", 0, "trackflow demo --realm demo_realm --seconds 5")
    assert run_command(written, repo).returncode == 0
    again = run_command(written, repo)
    assert again.returncode == 1 and "--force" in again.stderr, again.describe()
