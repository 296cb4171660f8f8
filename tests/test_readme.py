"""The README's API example runs and shows what it claims."""

from __future__ import annotations

import re

import numpy as np

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
