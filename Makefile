# Two commands for a fresh machine:
#   make demo   create the environment, install, run the whole demo pipeline (dvc repro)
#   make test   create the environment if needed, run the tests
SHELL := /bin/bash
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
export PATH := $(abspath $(BIN)):$(PATH)
export MPLBACKEND := Agg
# one BLAS thread: on 2 shared cores multi-threaded OpenBLAS made small products 1000x slower
export OPENBLAS_NUM_THREADS := 1
# compiled bytecode is cached (__pycache__/, git-ignored) even where the shell sets PYTHONDONTWRITEBYTECODE: without
# the cache every test worker re-rewrote all test files' asserts and every workbench process recompiled the package
unexport PYTHONDONTWRITEBYTECODE

.PHONY: setup system-deps demo test test-fast bench paper lint clean-demo

$(STAMP): pyproject.toml
	@echo "== setting up $(VENV) (torch CPU wheel, then the workbench)"
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q torch==2.13.0
	$(BIN)/python -m pip install -q -e '.[full,dev]'
	touch $(STAMP)

setup: $(STAMP)

# Debian packages some integration tests need (real PostgreSQL, real headless Chromium).
SYSTEM_PKGS := postgresql chromium chromium-driver
system-deps:
	@missing=""; for p in $(SYSTEM_PKGS); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    echo "== installing$$missing (Debian packages for the integration tests)"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing >/dev/null; \
	  else echo "== missing system packages:$$missing (sudo apt-get install$$missing); their tests will fail"; fi; \
	fi

demo: setup
	@echo "== dvc repro (virtual lab -> ingest -> ... ; progress per stage)"
	$(BIN)/dvc repro
	@echo "== done: results under datasets/ (see README 'What the demo leaves')"

# Two pytest-xdist workers, one test file each at a time (--dist loadfile: a module's fixtures stay in one
# process), files in collection order (--no-loadscope-reorder: tests/conftest.py puts the longest files first,
# so the 15-minute walk-through starts at once instead of last). TEST_WORKERS=0 runs everything in this process.
# The 30 slowest tests are listed at the end (where CI time goes; docs/testing.md).
TEST_WORKERS ?= 2
test: setup system-deps
	$(BIN)/python -m pytest -q -ra --durations=30 -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder

# under 2 minutes on an idle 2-core machine (docs/testing.md); the slowest tests are listed at the end.
# The -p no: flags skip pytest plugins that third-party packages install and no test uses (about 1 s of
# start-up CPU: hydra-core's plugin imports hydra). Two pytest-xdist workers, one test file each at a time
# (a module's fixtures stay in one process); FAST_WORKERS=0 runs everything in this process.
FAST_PLUGINS_OFF := -p no:hydra_pytest -p no:anyio -p no:platformdirs
FAST_WORKERS ?= 2
test-fast: setup
	$(BIN)/python -m pytest -q -m "not slow" $(FAST_PLUGINS_OFF) -n $(FAST_WORKERS) --dist loadfile --durations=10

# the paper's study end to end in a scratch copy of this commit, timed per stage (docs/pipeline.md)
paper: setup
	$(BIN)/python benchmarks/paper_scale.py

bench: setup
	for b in benchmarks/bench_*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

lint: setup
	$(BIN)/ruff check workbench tests benchmarks
