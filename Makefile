# Every target that needs the package depends on the virtual environment, so a
# fresh clone needs nothing but `make demo` or `make test`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: venv test test-min lint demo demo-live bench clean browser tls-tools doc-shots

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev,distributed,viewer]'
	# compile the numba kernels once, at install, so no command's first run waits for it
	$(VENV)/bin/trackflow compile
	touch $(STAMP)

venv: $(STAMP)

lint: $(STAMP)
	$(VENV)/bin/ruff check src tests bench experiments
	$(VENV)/bin/ruff format --check src tests bench experiments

# Headless Chromium for the viewer's browser tests and `trackflow view --snapshot`: Debian's
# package (Playwright drives it; it downloads no browser).
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
browser:
	@command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1 || \
		{ $(SUDO) apt-get update -qq && $(SUDO) apt-get install -y -qq chromium; }

# The pictures of docs/viewer.md, taken by the viewer's pixel tests on what they assert
# (tests/viewer/_shots.py); the live run's picture by its experiment.
doc-shots: $(STAMP) browser
	TRACKFLOW_DOC_SHOTS=1 $(PY) -m pytest -q -p no:xdist tests/viewer/test_scene_recording.py \
		tests/viewer/test_scene_live.py tests/viewer/test_live_run.py
	$(PY) experiments/viewer_live_run.py

# openssl makes the certificates of the Zenoh TLS test (tests/distributed/test_tls_processes.py).
tls-tools:
	@command -v openssl >/dev/null 2>&1 || \
		{ $(SUDO) apt-get update -qq && $(SUDO) apt-get install -y -qq openssl; }

test: lint browser tls-tools
	$(PY) -m pytest -q -n 2 --dist loadfile

# The suite on the declared minimum versions (constraints/min.txt), in a venv of its own.
# Its numba is another version: its kernels are cached apart (numba keeps one cache index per
# source file, so two versions sharing one cache directory recompile each other's kernels) and
# compiled once at install, as for the main venv.
MIN := .venv-min
MIN_ENV := NUMBA_CACHE_DIR=$(CURDIR)/$(MIN)/numba-cache
$(MIN)/.installed: pyproject.toml constraints/min.txt
	$(PYTHON) -m venv $(MIN)
	$(MIN)/bin/python -m pip install --quiet --upgrade pip
	$(MIN)/bin/python -m pip install --quiet -c constraints/min.txt -e '.[all]' \
		'pytest>=8' 'pytest-xdist>=3.5' 'hypothesis>=6.100'
	$(MIN_ENV) $(MIN)/bin/trackflow compile
	touch $(MIN)/.installed

test-min: $(MIN)/.installed
	$(MIN_ENV) $(MIN)/bin/python -m pytest -q -n 2 --dist loadfile

demo: $(STAMP)
	$(VENV)/bin/trackflow demo
	$(MAKE) demo-live

# Simulated NatNet + DTrack trackers replaying ../shared/data recordings over 127.0.0.1,
# `trackflow run` on examples/live_demo.yaml, answers against the truth, replay bit for bit.
LIVE_SECONDS ?= 60
demo-live: $(STAMP)
	$(PY) -m trackflow.trackers.demo --seconds $(LIVE_SECONDS)

# Benchmarks compare against peers that are never runtime dependencies.
$(VENV)/.bench: $(STAMP)
	$(PY) -m pip install --quiet -e '.[dev,distributed,viewer,bench]'
	touch $(VENV)/.bench

bench: $(VENV)/.bench
	$(PY) bench/run_all.py

clean:
	rm -rf $(VENV) $(MIN) .pytest_cache .ruff_cache
