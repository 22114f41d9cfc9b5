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

.PHONY: setup demo test test-fast bench lint clean-demo

$(STAMP): pyproject.toml
	@echo "== setting up $(VENV) (torch CPU wheel, then the workbench)"
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q torch==2.13.0
	$(BIN)/python -m pip install -q -e '.[dev]'
	touch $(STAMP)

setup: $(STAMP)

demo: setup
	@echo "== dvc repro (virtual lab -> ingest -> ... ; progress per stage)"
	$(BIN)/dvc repro
	@echo "== done: results under datasets/ (see README 'What the demo leaves')"

test: setup
	$(BIN)/python -m pytest -q -ra

test-fast: setup
	$(BIN)/python -m pytest -q -m "not slow"

bench: setup
	for b in benchmarks/bench_*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

lint: setup
	$(BIN)/ruff check workbench tests benchmarks
