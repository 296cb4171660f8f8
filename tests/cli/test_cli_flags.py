"""The options users reach for: reading flags, --version, defaults, negative values, stdin/out."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from trackflow.cli import _common
from trackflow.cli.main import build_parser, flag_hints, main
from trackflow.io import FORMATS, MESSAGE_TYPES, PoseStream, read_stream, write_stream

DATA = Path(__file__).parent / "data"
GT = DATA / "fr1_xyz_groundtruth_10s.txt"
SRC = Path(__file__).resolve().parents[2] / "src"


def _cli(*args, stdin: bytes | None = None, cwd=None):
    env = dict(os.environ, PYTHONPATH=str(SRC))
    return subprocess.run(
        [sys.executable, "-m", "trackflow.cli.main", *args], input=stdin, capture_output=True,
        cwd=cwd, env=env, timeout=120,
    )  # fmt: skip


def test_mirrored_names_match_the_library():
    from trackflow.cli.cmd_demo import DEFAULT_SEED
    from trackflow.demo import DemoConfig
    from trackflow.evaluation import LEARNED_ORDERS

    assert _common.FORMATS == FORMATS
    assert _common.ROS_MESSAGE_TYPES == tuple(MESSAGE_TYPES)
    assert _common.LEARNED_ORDERS == tuple(LEARNED_ORDERS)
    assert DEFAULT_SEED == DemoConfig.seed


def test_help_does_not_import_the_library():
    code = (
        "import sys\nfrom trackflow.cli.main import build_parser\nbuild_parser()\n"
        "print(sorted(m for m in ('numpy', 'numba', 'scipy', 'matplotlib') if m in sys.modules))"
    )
    env = dict(os.environ, PYTHONPATH=str(SRC))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                       timeout=60)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]"


def test_import_does_not_touch_the_environment():
    code = "import os\nimport trackflow.math\nprint(os.environ.get('NUMBA_CACHE_DIR'))"
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["PYTHONPATH"] = str(SRC)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                       timeout=60)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "None"


def test_version(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    import trackflow

    assert capsys.readouterr().out.strip() == f"trackflow {trackflow.__version__}"


def test_help_shows_defaults():
    text = build_parser()._subparsers._group_actions[0].choices["evaluate"].format_help()
    assert "(default: 10,20,50,100,200)" in " ".join(text.split())
    assert "(default: 0.5)" in text


@pytest.mark.parametrize("value", ["-2e9", "-1.5", "-.5", "-3E+2"])
def test_negative_numbers_as_option_values(value, tmp_path):
    args = build_parser().parse_args(["shift", "a", "b", "--offset", value])
    assert args.offset == float(value)


def test_shift_negative_exponent_end_to_end(tmp_path):
    out = tmp_path / "o.txt"
    assert main(["shift", str(GT), str(out), "--offset", "-1e9", "--quiet"]) == 0
    a, _ = read_stream(GT)
    b, _ = read_stream(out)
    assert np.all(a.t_ns - b.t_ns == 10**18)


def test_flag_hints():
    assert flag_hints("read with clean=True to drop them") == "read with --clean to drop them"
    assert "pass --topic one of" in flag_hints("several pose topics; pass topic= one of: /a")
    assert "pass --format" in flag_hints("cannot tell the format from the name; pass format=")
    assert flag_hints("does not take option(s) ['topic']") == "does not take option(s) [--topic]"


def _two_topic_bag(path: Path) -> PoseStream:
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    T = store.types
    name = "geometry_msgs/msg/PoseStamped"
    with Writer(path) as w:
        conns = [w.add_connection(tp, name, typestore=store) for tp in ("/head", "/hand")]
        for k in range(10):
            for j, c in enumerate(conns):
                t = 1_000_000_000 + k * 10_000_000
                hdr = T["std_msgs/msg/Header"](
                    seq=k, stamp=T["builtin_interfaces/msg/Time"](sec=1, nanosec=t - 10**9),
                    frame_id="world",
                )  # fmt: skip
                pose = T["geometry_msgs/msg/Pose"](
                    position=T["geometry_msgs/msg/Point"](x=float(k), y=float(j), z=0.0),
                    orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                )
                w.write(c, t, store.serialize_ros1(T[name](header=hdr, pose=pose), name))


def test_topic_flag_opens_a_multi_topic_bag(tmp_path, capsys):
    bag = tmp_path / "two.bag"
    _two_topic_bag(bag)
    assert main(["info", str(bag)]) == 1
    err = capsys.readouterr().err
    assert "pass --topic one of" in err and "/hand" in err
    assert main(["convert", str(bag), str(tmp_path / "h.txt"), "--topic", "/hand"]) == 0
    s, _ = read_stream(tmp_path / "h.txt")
    assert len(s) == 10 and np.all(s.position[:, 1] == 1.0) and s.target == "hand"


def test_columns_time_unit_and_frames(tmp_path):
    src = tmp_path / "a.csv"
    rows = "\n".join(f"{k * 10},{k},0,0,0,0,0,1" for k in range(5))
    src.write_text("stamp_ms,px,py,pz,a,b,c,d\n" + rows + "\n")
    cols = "t=stamp_ms,x=px,y=py,z=pz,qx=a,qy=b,qz=c,qw=7"
    out = tmp_path / "o.tfrec"
    argv = ["convert", str(src), str(out), "--columns", cols, "--time-unit", "ms"]
    assert main(argv + ["--source", "room", "--target", "head"]) == 0
    s, _ = read_stream(out)
    assert (s.source, s.target) == ("room", "head")
    assert s.t_ns.tolist() == [k * 10_000_000 for k in range(5)]


@pytest.mark.slow
def test_infer_chains_two_tum_files_with_frame_flags(tmp_path):
    out = tmp_path / "o.txt"
    argv = ["infer", str(GT), str(GT), str(out), "--interpolate", "--target", "cam",
            "--source2", "cam", "--target2", "cam2"]  # fmt: skip
    assert main(argv) == 0
    s, _ = read_stream(out)
    assert (s.source, s.target) == ("world", "cam2") and len(s) > 900


def test_stdin_to_stdout_pipe(tmp_path):
    r = _cli("convert", "-", "-", "--to", "csv", "--quiet", stdin=GT.read_bytes())
    assert r.returncode == 0, r.stderr
    lines = r.stdout.decode().splitlines()
    assert lines[1].startswith("t,x,y,z,qx,qy,qz,qw") and len(lines) == 1002


def test_broken_pipe_is_quiet(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(SRC))
    cmd = f"{sys.executable} -m trackflow.cli.main convert {GT} - --quiet | head -n 2"
    r = subprocess.run(["bash", "-o", "pipefail", "-c", cmd], capture_output=True, env=env,
                       timeout=120)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert r.stderr == b"" and len(r.stdout.splitlines()) == 2


def test_kitti_round_trip(tmp_path):
    s, _ = read_stream(GT)
    s = s.with_(t_ns=np.arange(len(s), dtype=np.int64) * 100_000_000)  # 10 Hz
    write_stream(tmp_path / "a.kitti", s)
    back, report = read_stream(tmp_path / "a.kitti")
    assert np.array_equal(back.t_ns, s.t_ns)
    assert np.allclose(back.position, s.position, atol=0)
    dots = np.abs(np.sum(back.quaternion * s.quaternion, axis=1))
    assert np.all(dots > 1 - 1e-12)
    assert any("no timestamps" in n for n in report.notes)


def test_kitti_reads_a_times_file(tmp_path):
    (tmp_path / "p.txt").write_text("1 0 0 1 0 1 0 2 0 0 1 3\n1 0 0 4 0 1 0 5 0 0 1 6\n")
    (tmp_path / "times.txt").write_text("0.000000e+00\n1.036e-01\n")
    s, _ = read_stream(tmp_path / "p.txt", format="kitti", times=tmp_path / "times.txt")
    assert s.t_ns.tolist() == [0, 103_600_000]
    assert s.position.tolist() == [[1, 2, 3], [4, 5, 6]]


@pytest.mark.slow
def test_model_file_round_trip_learned_family(tmp_path, capsys):
    """``tune --output`` writes any family; ``filter --model`` runs it (the learned one too)."""
    model = tmp_path / "m.json"
    argv = ["tune", str(GT), "--quiet", "--learned-orders", "3", "--pos-derivatives", "2",
            "--ori-derivatives", "1", "--output", str(model)]  # fmt: skip
    assert main(argv) == 0
    printed = json.loads(capsys.readouterr().out)["motion_model"]
    doc = json.loads(model.read_text())
    assert doc["trackflow_model"] == 1
    assert doc["predictor"]["family"] == printed["family"]
    from trackflow.evaluation import load_model, predictor_from_dict, predictor_to_dict
    from trackflow.filters import TwistARModel

    pred = load_model(model)
    assert predictor_to_dict(predictor_from_dict(predictor_to_dict(pred))) == doc["predictor"]
    # a learned model given explicitly, whatever tune chose
    learned = {
        "family": "twist_ar", "dt": 0.01, "coefficients": (0.5 * np.eye(6))[None].tolist(),
        "noise": (1e-6 * np.eye(6)).tolist(), "pos_sigma": 1e-3, "ori_sigma": 1e-2,
    }  # fmt: skip
    assert isinstance(predictor_from_dict(learned).model, TwistARModel)
    model.write_text(json.dumps({"trackflow_model": 1, "predictor": learned}))
    out = tmp_path / "f.tfrec"
    assert main(["filter", str(GT), str(out), "--model", str(model)]) == 0
    assert "twist_ar model" in capsys.readouterr().err
    s, _ = read_stream(out)
    assert len(s) == 1000 and s.covariance is not None


@pytest.mark.slow
def test_evaluate_names_the_winning_model(capsys):
    assert main(["evaluate", str(GT), "--quiet", "--learned-orders", "none"]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert first.startswith("kalman = derivative model (")
