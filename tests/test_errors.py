"""trackflow.errors (typed errors that are also the builtin they stand for) and
trackflow.optional (the one seam of optional dependencies, naming the pip extra)."""

from __future__ import annotations

import importlib.util
import sys
import types
from pathlib import Path

import numpy as np
import pytest

from trackflow import errors
from trackflow.errors import (
    ConfigError,
    ExtrapolationError,
    FormatError,
    MissingExtraError,
    TrackflowError,
)
from trackflow.optional import available, require

SRC = Path(__file__).resolve().parents[1] / "src" / "trackflow"


@pytest.mark.parametrize(
    ("name", "builtin"),
    [
        ("InputError", ValueError),
        ("ConfigError", ValueError),
        ("FormatError", ValueError),
        ("PlanError", ValueError),
        ("ExtrapolationError", ValueError),
        ("NumericalError", ValueError),
        ("StateError", RuntimeError),
        ("ServiceError", RuntimeError),
        ("MissingExtraError", ImportError),
    ],
)
def test_each_error_is_a_trackflow_error_and_its_builtin(name, builtin):
    cls = getattr(errors, name)
    assert issubclass(cls, TrackflowError) and issubclass(cls, builtin)
    assert not issubclass(KeyError, TrackflowError)  # a bug is not a user's mistake


def test_config_and_format_errors_say_where():
    e = ConfigError("must be > 0", "lab.yaml", 7, "rate_hz")
    assert str(e) == "lab.yaml:7: rate_hz: must be > 0"
    assert (e.file, e.line, e.key, e.reason) == ("lab.yaml", 7, "rate_hz", "must be > 0")
    assert str(ConfigError("plain")) == "plain"
    assert str(FormatError("truncated", sensor="art", packet=12)) == (
        "sensor art, packet 12: truncated"
    )
    assert str(FormatError("short row", "a.txt", 3)) == "a.txt:3: short row"


def test_extrapolation_error_reads_like_tf2():
    future = ExtrapolationError("T_world_head", 12.29, 10.0, 12.25)
    assert "40 ms into the future" in str(future) and "newest data 12.250000 s" in str(future)
    past = ExtrapolationError("the estimate", 1.0, 1.5, None, "older than the stored history")
    assert "500 ms into the past" in str(past) and str(past).endswith(
        "older than the stored history"
    )
    unix = 1_700_000_000.0  # 2023-11-14 22:13:20 UTC
    assert "newest data 22:13:20.000" in str(ExtrapolationError("T", unix + 0.04, unix, unix))
    assert "no data yet" in str(ExtrapolationError("T", 3.0))


def _block(monkeypatch, module: str) -> None:
    """Make ``import module`` fail as if the package were not installed."""
    for name in list(sys.modules):
        if name == module or name.startswith(module + "."):
            monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, module, None)


def test_require_names_the_extra(monkeypatch):
    _block(monkeypatch, "json")
    with pytest.raises(MissingExtraError, match=r"pip install 'trackflow\[fast\]'") as e:
        require("json.decoder", extra="fast", feature="a test")
    assert e.value.module == "json" and e.value.extra == "fast"
    assert isinstance(e.value, ImportError) and "a test needs" in str(e.value)
    assert not available("json")


def test_require_passes_a_broken_install_on(monkeypatch, tmp_path):
    # an installed package whose own import fails is not a missing extra
    (tmp_path / "tf_broken_pkg.py").write_text("import tf_no_such_module_anywhere\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(ModuleNotFoundError) as e:
        require("tf_broken_pkg", extra="fast")
    assert not isinstance(e.value, MissingExtraError)
    assert require("json").dumps([1]) == "[1]"


def test_agent_without_zenoh_names_the_distributed_extra(monkeypatch):
    from trackflow.dataflow import parse_setup
    from trackflow.distributed import AgentConfig, zenoh_config

    _block(monkeypatch, "zenoh")
    with pytest.raises(MissingExtraError, match=r"trackflow\[distributed\]"):
        zenoh_config(AgentConfig("a", parse_setup({})))


def test_viewer_without_viser_or_playwright_names_the_viewer_extra(monkeypatch):
    from trackflow.viewer.browser import Browser
    from trackflow.viewer.server import ViewServer

    _block(monkeypatch, "viser")
    with pytest.raises(MissingExtraError, match=r"trackflow\[viewer\]"):
        ViewServer(port=0)
    _block(monkeypatch, "playwright")
    with pytest.raises(MissingExtraError, match=r"trackflow\[viewer\]"):
        with Browser():
            pass


def test_plots_without_matplotlib_name_the_plot_extra(monkeypatch, tmp_path):
    from trackflow.calibration.report import plot_residuals
    from trackflow.demo.report import plot_errors

    _block(monkeypatch, "matplotlib")
    with pytest.raises(MissingExtraError, match=r"trackflow\[plot\]"):
        plot_residuals(tmp_path / "r.png", np.arange(3.0), np.zeros((3, 6)), np.ones(3, bool), "t")
    with pytest.raises(MissingExtraError, match=r"trackflow\[plot\]"):
        plot_errors({}, tmp_path / "e.png", {})
    assert list(tmp_path.iterdir()) == []


def test_optical_kernels_load_without_numba(monkeypatch):
    """The optical tracker's kernels are a kernel source behind the backend seam: without
    numba the module loads (no numba import of its own) and runs on the NumPy backend."""
    _block(monkeypatch, "numba")
    spec = importlib.util.spec_from_file_location(
        "trackflow.optical._kernels_without_numba", SRC / "optical" / "_kernels.py"
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert "refine_pose" in mod.KERNELS and callable(mod.refine_pose)


def test_compiled_backend_without_numba_names_the_fast_extra(monkeypatch):
    from trackflow.math import _backend

    _block(monkeypatch, "numba")
    source = types.ModuleType("tf_test_kernel_source")  # never compiled before: not cached
    monkeypatch.setitem(sys.modules, source.__name__, source)
    with pytest.raises(MissingExtraError, match=r"trackflow\[fast\]"):
        _backend._compiled(source.__name__)


def test_optical_blobs_and_seeds_run_on_the_numpy_backend():
    from trackflow.math import numba_available, use_backend
    from trackflow.optical import matching
    from trackflow.optical.blobs import detect_blobs

    rng = np.random.default_rng(3)
    img = rng.integers(0, 40, size=(24, 32)).astype(np.uint8)
    img[5:8, 4:7] = 200
    img[15:17, 20:25] = 180
    with use_backend("numpy"):
        plain = detect_blobs(img, threshold=100, background=20)
    assert len(plain) == 2
    np.testing.assert_allclose(np.sort(plain.uv[:, 0]), [5.0, 22.0])
    E = rng.random((5, 5, 4, 4)) < 0.5
    S = rng.random((5, 4))  # distinct supports: no ties in the ordering
    seeds = (np.array([0, 2]), np.array([1, 3]))
    with use_backend("numpy"):
        tp, tm = matching.kernels_for(matching)._seed_triangles(E, S, *seeds, 4)
    if numba_available():
        fast = detect_blobs(img, threshold=100, background=20)
        np.testing.assert_array_equal(fast.uv, plain.uv)
        np.testing.assert_array_equal(fast.area, plain.area)
        tp2, tm2 = matching.kernels_for(matching)._seed_triangles(E, S, *seeds, 4)
        np.testing.assert_array_equal(tp, tp2)
        np.testing.assert_array_equal(tm, tm2)


@pytest.mark.parametrize(
    "err",
    [
        ConfigError("must be > 0", "lab.yaml", 7, "rate_hz"),
        FormatError("truncated", sensor="art", packet=3),
        ExtrapolationError("T_a_b", 2.0, 0.0, 1.0),
        MissingExtraError("zenoh", "distributed", "trackflow agent"),
        errors.PlanError("no path"),
    ],
)
def test_errors_survive_a_process_boundary(err):
    import pickle

    from trackflow.distributed.wire import WireError
    from trackflow.trackers._packet import PacketError

    for e in (err, WireError("bad", "detail"), PacketError("truncated", "at 3")):
        back = pickle.loads(pickle.dumps(e))
        assert type(back) is type(e) and str(back) == str(e) and vars(back) == vars(e)
