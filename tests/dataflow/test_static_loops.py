"""Statics that contradict each other are refused, naming the file, the line and both."""

from __future__ import annotations

import pytest

from trackflow.dataflow import load_setup
from trackflow.errors import ConfigError

HEAD = """frames: [room, cam, proj, table]
statics:
"""


def _setup(tmp_path, statics: str):
    p = tmp_path / "s.yaml"
    p.write_text(HEAD + statics)
    return p


def test_the_same_static_twice_with_other_poses_is_refused(tmp_path):
    p = _setup(tmp_path, """\
  - {name: cam_a, source: room, target: cam, position: [1.0, 0, 0]}
  - {name: cam_b, source: room, target: cam, position: [1.0, 0, 2.0]}
""")  # fmt: skip
    want = r"s\.yaml:4: statics\[1\]: static 'cam_b' \(room -> cam\) contradicts 'cam_a' by 2000.0"
    with pytest.raises(ConfigError, match=want):
        load_setup(p)


def test_a_loop_at_identity_against_a_2_m_edge_is_refused(tmp_path):
    p = _setup(tmp_path, """\
  - {name: room_cam, source: room, target: cam}
  - {name: cam_proj, source: cam, target: proj}
  - {name: proj_room, source: proj, target: room, position: [0, 2.0, 0]}
""")  # fmt: skip
    with pytest.raises(ConfigError, match=r"s\.yaml:5: .*'proj_room' \(proj -> room\) "
                       r"contradicts 'cam_proj', 'room_cam' by 2000.0 mm"):  # fmt: skip
        load_setup(p)


def test_loops_that_agree_within_their_covariance_are_kept(tmp_path):
    # a loop closing 0.3 mm and 0.05 deg off (printed digits): within 1 mm and 0.1 deg
    load_setup(_setup(tmp_path, """\
  - {name: room_cam, source: room, target: cam, position: [1.0, 0.5, 0]}
  - {name: cam_proj, source: cam, target: proj, position: [0, 1.0, 0]}
  - {name: room_proj, source: room, target: proj, position: [1.0003, 1.5, 0],
     quaternion: [0.0004363, 0, 0, 0.9999999]}
"""))  # fmt: skip
    # 5 cm apart, but each calibration only good to 2 cm (sigma): five sigma holds it
    load_setup(_setup(tmp_path, """\
  - {name: room_table, source: room, target: table, position: [2.0, 0, 0], sigma_pos_mm: 20}
  - {name: table_room, source: table, target: room, position: [-2.05, 0, 0], sigma_pos_mm: 20}
"""))  # fmt: skip


def test_a_thousand_statics_in_loops_are_checked_and_the_one_that_disagrees_is_named():
    """Frames placed in a room, joined by a random spanning tree and 80 more statics (each
    loop agrees), added in random order: none is refused; a static moved 10 cm is refused
    naming only the statics of its loop. (Joining trees copied every name into every frame
    before: a 1,000-frame setup ran out of memory.)"""
    import numpy as np

    from trackflow.dataflow import StaticLoops
    from trackflow.math import Pose, quat_exp

    rng = np.random.default_rng(5)
    n = 1000
    world = [Pose(rng.uniform(-5, 5, 3), quat_exp(rng.normal(size=3))) for _ in range(n)]
    order = rng.permutation(n)
    pairs = [(int(order[rng.integers(0, i)]), int(order[i])) for i in range(1, n)]
    pairs += [tuple(int(x) for x in rng.choice(n, 2, replace=False)) for _ in range(80)]
    cov = np.eye(6) * 1e-8
    loops = StaticLoops()
    for k in rng.permutation(len(pairs)):
        a, b = pairs[k]
        why = loops.add(f"s{k}", f"F{a}", f"F{b}", world[a].inverse() @ world[b], cov)
        assert why is None, why
    a, b = pairs[0]  # along the tree: the loop it closes is the tree path from a to b
    true = world[a].inverse() @ world[b]
    why = loops.add(
        "moved", f"F{a}", f"F{b}", Pose(true.position + [0.1, 0, 0], true.quaternion), cov
    )
    assert why is not None and "by 100.0 mm" in why, why
    named = why.split("contradicts ")[1].split(" by ")[0]
    assert 1 <= named.count("'") // 2 < 40, named  # the loop's statics, not the realm's
