"""Optional extras, packaged examples, progress output and the sequence plot's annotations."""

from __future__ import annotations

import io
import sys
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from trackflow.cli._progress import FinishingStream, Progress
from trackflow.cli.main import main
from trackflow.math import use_backend

DATA = Path(__file__).parent / "data"
GT = DATA / "fr1_xyz_groundtruth_10s.txt"
DEMO_SETUP = resources.files("trackflow") / "examples" / "demo_setup.yaml"


def test_examples_are_package_data():
    ex = resources.files("trackflow") / "examples"
    names = {p.name for p in ex.iterdir()}
    assert {"demo_setup.yaml", "fusion_setup.yaml", "calibration_setup.yaml"} <= names


@pytest.mark.parametrize(
    "module,argv,extra",
    [
        ("rosbags", ["convert", str(GT), "{tmp}/o.bag"], "trackflow[ros]"),
        ("matplotlib", ["plot-traj", str(GT), "--out", "{tmp}/t.png"], "trackflow[plot]"),
        # a live setup's view: said before its view process starts (no BufferError from it)
        ("viser", ["view", str(DEMO_SETUP), "--snapshot", "{tmp}/v.png"], "trackflow[viewer]"),
    ],
)
def test_missing_extra_is_named(module, argv, extra, tmp_path, monkeypatch, capsys):
    for name in list(sys.modules):
        if name == module or name.startswith(module + "."):
            monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, module, None)  # makes `import module` fail
    assert main([a.replace("{tmp}", str(tmp_path)) for a in argv]) == 1
    err = capsys.readouterr().err
    assert err.startswith("trackflow: error:") and extra in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_finishing_stream_completes_an_early_stopped_bar():
    out = io.StringIO()
    s = FinishingStream(out)
    s.write("\rtuning x [#####.........................]   10 evals, best cost 0.5")
    s.write("\n")
    last = out.getvalue().split("\r")[-1]
    assert "[" + "#" * 30 + "]" in last and last.endswith("\n") and "(done)" in last


@pytest.mark.slow
def test_evaluate_bar_reaches_100_percent(capsys):
    assert main(["evaluate", str(GT), "--learned-orders", "none", "--horizons", "50"]) == 0
    err = capsys.readouterr().err
    finals = [seg for seg in err.split("\r") if "\n" in seg and "tuning" in seg]
    assert finals and "[" + "#" * 30 + "]" in finals[-1]


def test_progress_bar_percentages():
    out = io.StringIO()
    p = Progress("reading", 200, stream=out)
    p.update(50)
    p.close()
    text = out.getvalue()
    assert " 25 %" in text and text.rstrip().endswith("100 %")


@pytest.mark.slow
def test_sequence_plot_has_title_and_explained_legends(tmp_path, monkeypatch):
    import trackflow.plotting as plotting
    from trackflow.evaluation import Trajectory, default_predictor
    from trackflow.io import read_stream

    seen = {}

    def capture(fig, path, overwrite=False, dpi=110):
        seen["title"] = fig._suptitle.get_text()
        seen["legends"] = [
            [t.get_text() for t in leg.get_texts()]
            for ax in fig.axes
            for leg in [c for c in ax.get_children() if type(c).__name__ == "Legend"]
        ]
        seen["z"] = sorted(
            (ln.get_zorder(), ln.get_linestyle(), ln.get_marker()) for ln in fig.axes[0].lines
        )

    monkeypatch.setattr(plotting, "save_figure", capture)
    s, _ = read_stream(GT)
    t = s.elapsed_s
    pred = default_predictor(t, s.position, s.quaternion)
    recording = Trajectory.check(t, s.position, s.quaternion)
    plotting.plot_sequence(tmp_path / "s.png", recording, pred, 0.1, (2, 4), title="fr1")
    assert seen["title"].startswith("fr1: measured, filtered and predicted")
    labels = sorted(sum(seen["legends"], []))
    assert {"x", "y", "z", "measured", "Kalman filtered"} <= set(labels)
    # measurement markers lie under every line
    marker_z = max(z for z, ls, m in seen["z"] if m == ".")
    assert all(z > marker_z for z, ls, m in seen["z"] if m != "." and ls == "-" and z >= 4)
    with pytest.raises(ValueError, match="holds 0 samples"):
        plotting.plot_sequence(tmp_path / "e.png", recording, pred, 0.1, (1000, 1003))
    assert not (tmp_path / "e.png").exists()
    assert np.isfinite(t).all()


def test_the_numpy_backend_is_announced_once_before_the_work(capsys, monkeypatch):
    monkeypatch.setenv("TRACKFLOW_BACKEND", "numpy")  # the user's choice, as at a start
    with use_backend("numpy"):
        assert main(["compare", str(GT), str(GT), "--align", "se3"]) == 0
    err = capsys.readouterr().err
    assert err.startswith("trackflow: TRACKFLOW_BACKEND=numpy, so the numerical kernels")
    assert err.count("run as plain NumPy") == 1 and "100x slower" in err


def test_a_command_that_chose_numpy_itself_is_not_announced_as_slow(capsys):
    with use_backend("numpy"):  # as `trackflow demo` does by default
        assert main(["compare", str(GT), str(GT), "--align", "se3"]) == 0
    assert "plain NumPy" not in capsys.readouterr().err


def test_the_numpy_reason_names_the_variable_or_the_missing_numba(monkeypatch):
    from trackflow.math import _backend

    monkeypatch.setenv("TRACKFLOW_BACKEND", "numpy")
    assert _backend.numpy_reason() == "TRACKFLOW_BACKEND=numpy"
    monkeypatch.setattr(_backend, "numba_available", lambda: False)
    assert _backend.numpy_reason() == "numba is not installed"


def test_compile_on_the_numpy_backend_says_why_nothing_compiles(capsys):
    with use_backend("numpy"):
        assert main(["compile"]) == 0
    err = capsys.readouterr().err
    assert "nothing to compile: the numpy backend was selected" in err and "plain NumPy" in err


def test_an_agent_without_zenoh_names_the_distributed_extra(tmp_path, monkeypatch, capsys):
    from trackflow.demo.realm import AGENT_FILES, write_demo_realm

    files = write_demo_realm(tmp_path / "realm", seconds=5.0)
    for name in list(sys.modules):
        if name == "zenoh" or name.startswith("zenoh."):
            monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "zenoh", None)  # makes `import zenoh` fail
    assert main(["agent", str(files[AGENT_FILES[0]]), "--duration", "1"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("trackflow: error:") and "Traceback" not in err
    assert "trackflow[distributed]" in err, err


def test_the_all_extra_holds_every_optional_part():
    import tomllib

    meta = tomllib.loads((Path(__file__).parents[2] / "pyproject.toml").read_text())["project"]
    extras = meta["optional-dependencies"]
    parts = set().union(*(set(extras[k]) for k in extras if k not in {"all", "dev", "bench"}))
    assert parts and parts <= set(extras["all"]), parts - set(extras["all"])
