# Every target that needs the package depends on the virtual environment, so a
# fresh clone needs nothing but `make demo` or `make test`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: venv test lint demo demo-live bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

venv: $(STAMP)

lint: $(STAMP)
	$(VENV)/bin/ruff check src tests bench experiments
	$(VENV)/bin/ruff format --check src tests bench experiments

test: lint
	$(PY) -m pytest -q -n 2 --dist loadfile

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
	$(PY) -m pip install --quiet -e '.[dev,bench]'
	touch $(VENV)/.bench

bench: $(VENV)/.bench
	$(PY) bench/run_all.py

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache
