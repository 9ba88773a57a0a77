# Every target sets up its own virtual environment from nothing (see `venv`).
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip
# The CPU build of torch lies on this machine's disk; pinning it keeps pip from pulling a CUDA build.
TORCH_PIN ?= torch==2.13.0
STAMP := $(VENV)/.installed

.PHONY: venv numba-cache demo test test-slow test-all bench lint docs clean

venv: $(STAMP)

$(STAMP): pyproject.toml Makefile
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PIP) install --quiet --upgrade pip
	$(PIP) install --quiet "$(TORCH_PIN)"
	$(PIP) install --quiet -e ".[dev,bench,ray,sumo,docs,deploy]"
	touch $(STAMP)

# numba keeps its machine code beside each source file and checks only that file: a kernel that
# inlines a function from another file keeps the old one after that file changes. Any change to
# src/ therefore drops the whole cache (a stamp holds the sources' digest).
NUMBA_STAMP := .numba-sources

numba-cache:
	@digest=$$(find src -name '*.py' | LC_ALL=C sort | xargs cat | sha256sum | cut -c1-16); \
	if [ "$$(cat $(NUMBA_STAMP) 2>/dev/null)" != "$$digest" ]; then \
		find src -path '*__pycache__*' \( -name '*.nbi' -o -name '*.nbc' \) -delete; \
		echo $$digest > $(NUMBA_STAMP); \
	fi

demo: venv numba-cache
	$(VENV)/bin/safeswitch demo

# Tests run on both cores (pytest-xdist). `make test` is the fast tier (within 5 minutes on two
# cores); `make test-slow` runs the long ones (training, campaigns, the report, large safety
# sweeps); CI runs both.
PYTEST := $(PY) -m pytest -q -n 2

test: venv numba-cache
	$(PYTEST) -m "not slow"

test-slow: venv numba-cache
	$(PYTEST) -m slow

test-all: venv numba-cache
	$(PYTEST)

bench: venv numba-cache
	$(PY) benchmarks/bench_sim.py
	$(PY) benchmarks/bench_env.py

lint: venv
	$(VENV)/bin/ruff check src tests benchmarks experiments docs/hooks.py
	$(VENV)/bin/ruff format --check src tests benchmarks experiments docs/hooks.py
	$(VENV)/bin/mypy

# The documentation site in site/; any warning (a broken link, a docstring it cannot read) fails.
docs: venv
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict --quiet

clean:
	rm -rf $(VENV) out site .pytest_cache .mypy_cache .ruff_cache $(NUMBA_STAMP)
	find src tests benchmarks -name __pycache__ -type d -prune -exec rm -rf {} +
