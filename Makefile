# Every target sets up its own virtual environment from nothing (see `venv`).
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip
# The CPU build of torch lies on this machine's disk; pinning it keeps pip from pulling a CUDA build.
TORCH_PIN ?= torch==2.13.0
STAMP := $(VENV)/.installed

.PHONY: venv demo test test-slow test-all bench lint docs clean

venv: $(STAMP)

$(STAMP): pyproject.toml Makefile
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PIP) install --quiet --upgrade pip
	$(PIP) install --quiet "$(TORCH_PIN)"
	$(PIP) install --quiet -e ".[dev,bench,ray,sumo,docs]"
	touch $(STAMP)

demo: venv
	$(VENV)/bin/safeswitch demo

# Tests run on both cores (pytest-xdist). `make test` is the fast tier (within 5 minutes on two
# cores); `make test-slow` runs the long ones (training, campaigns, the report, large safety
# sweeps); CI runs both.
PYTEST := $(PY) -m pytest -q -n 2

test: venv
	$(PYTEST) -m "not slow"

test-slow: venv
	$(PYTEST) -m slow

test-all: venv
	$(PYTEST)

bench: venv
	$(PY) benchmarks/bench_sim.py
	$(PY) benchmarks/bench_env.py

lint: venv
	$(VENV)/bin/ruff check src tests benchmarks docs/hooks.py
	$(VENV)/bin/ruff format --check src tests benchmarks docs/hooks.py
	$(VENV)/bin/mypy

# The documentation site in site/; any warning (a broken link, a docstring it cannot read) fails.
docs: venv
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict --quiet

clean:
	rm -rf $(VENV) out site .pytest_cache .mypy_cache .ruff_cache
	find src tests benchmarks -name __pycache__ -type d -prune -exec rm -rf {} +
