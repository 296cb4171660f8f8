"""The README's API example runs and shows what it claims; every command of README.md and
docs/*.md runs as written and shows what the docs say it shows.

Which lines are commands is one rule (tests/_doc_commands.py). Every documented command is in
exactly one of five tables (tests/_doc_table.py): RUN (run as written, then checked), SERVED
(pages served until Ctrl-C: started as written, the page fetched, then interrupted;
tests/test_doc_serving.py), SCRIPTS (commands that work only together, run as one script;
tests/test_doc_scripts.py), SYNOPSES (usage lines: their options must be in --help), EXEMPT
(with the reason and the covering test). A command in none of them fails
test_every_documented_command_is_run_or_exempted, so a new command in the docs cannot go
untested by accident; an entry no doc has any more fails it too. The pages of README_PAGES run
here, the others in tests/test_doc_pages.py.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from _doc_commands import (
    DocCommand,
    assert_as_documented,
    documented_commands,
    half_ulp,
    make_workspace,
    quoted_output_mismatch,
    run_command,
)
from _doc_table import (
    EXEMPT,
    README_PAGES,
    RUN,
    SCRIPTS,
    SERVED,
    SYNOPSES,
    pages,
    ratio_matches,
    run_page,
)
from conftest import REPO_ROOT


def test_readme_example_runs_and_propagates_lever_arm_error():
    text = (REPO_ROOT / "README.md").read_text()
    code = re.search(r"```python\n(.*?)```", text, re.S).group(1)
    namespace: dict = {"print": lambda *a, **k: None}
    exec(compile(code, "README.md", "exec"), namespace)
    c = namespace["T_world_target"].covariance
    # A 1 m lever arm under 1 degree of rotation error adds ~17.5 mm across the arm.
    assert np.sqrt(c[1, 1]) > 10 * np.sqrt(namespace["C"][1, 1])
    x, c_x = namespace["x_world"], namespace["C_x"]
    assert x.shape == (3,) and c_x.shape == (3, 3)


#: every documented command is in exactly one of these
TABLES = (
    ("RUN", RUN),
    ("SERVED", SERVED),
    ("SCRIPTS", {key for script in SCRIPTS.values() for key in script.keys}),
    ("SYNOPSES", SYNOPSES),
    ("EXEMPT", EXEMPT),
)


# -- the tests -----------------------------------------------------------------------------------


def test_every_documented_command_is_run_or_exempted():
    commands = documented_commands()
    keys = {c.key for c in commands}
    for c in commands:
        tables = [name for name, t in TABLES if c.key in t]
        assert len(tables) == 1, f"{c.where}: {c.key!r} is in {tables or 'no table'}"
        if c.key in RUN:
            assert c.expected or RUN[c.key].check, f"{c.where}: run, but nothing checks it"
    for _, table in TABLES:
        stale = set(table) - keys
        assert not stale, f"no doc has these commands any more: {sorted(stale)}"


def test_the_rule_finds_commands_and_their_quoted_output():
    """The extraction rule on the docs' own shapes: a console-style block with prompts and
    output, a wrapped command, an output line that is not a command."""
    by_key = {c.key: c for c in documented_commands()}
    gripper = by_key["trackflow info robot_bag --source world --target gripper"]
    assert gripper.doc == "docs/formats.md"
    assert gripper.expected.startswith("trackflow: error: robot_bag: frame 'gripper'")
    assert not any(k.startswith("trackflow:") for k in by_key)
    wrapped = [c for c in by_key.values() if "\\\n" in c.text]
    assert wrapped and all(" \\ " not in c.key for c in wrapped)


def test_quoted_output_comparison_uses_the_docs_rounding():
    quoted = "scale 1.008\n...\nrmse 0.013470 n 785"
    assert quoted_output_mismatch(quoted, "x scale 1.0084\nfoo\nrmse 0.0134704 n 785") is None
    assert quoted_output_mismatch(quoted, "scale 1.0086\nrmse 0.013470 n 785") is not None
    assert quoted_output_mismatch(quoted, "scale 1.008\nrmse 0.013470 n 786") is not None
    assert quoted_output_mismatch("a b\nc", "a\nb c") is None  # wrapping does not matter
    assert half_ulp("0.25") == 0.005 and half_ulp("12") == 0.5
    assert_as_documented(["264.6", "0.046"], [264.64, 0.0455], "within the rounding")
    with pytest.raises(AssertionError, match="doc says 264.6, got 264.66"):
        assert_as_documented(["264.6"], [264.66], "offset")
    assert ratio_matches("0.654", "2.03", "0.322") and not ratio_matches("0.654", "2.03", "0.33")


@pytest.mark.slow
@pytest.mark.parametrize("doc", [p for p in pages() if p in README_PAGES])
def test_documented_commands_run_as_written(doc, tmp_path, shared_data):
    """Every RUN command of the page runs as written (``run_page``) in a workspace laid out like
    a checkout beside the shared data."""
    run_page(doc, make_workspace(tmp_path, shared_data))


@pytest.mark.parametrize("synopsis", sorted(SYNOPSES))
def test_documented_synopses_name_only_real_options(synopsis, tmp_path):
    """Every --option and {choice} of a usage line is in the command's --help."""
    tokens = synopsis.split()
    assert tokens[0] == "trackflow"
    cmd = DocCommand("synopsis", 0, f"trackflow {tokens[1]} --help")
    r = run_command(cmd, make_workspace(tmp_path))
    assert r.returncode == 0, r.describe()
    named = re.findall(r"(--[a-z][a-z0-9-]*)", synopsis.split(" # ")[0])
    for choices in re.findall(r"\{([a-z0-9,]+)\}", synopsis):
        named += choices.split(",")
    assert named
    for word in named:
        assert re.search(rf"(?<![\w-]){re.escape(word)}(?![\w-])", r.stdout), (word, synopsis)
