# The two commands of the README: `make demo` (the main job) and `make test`.
# Each creates .venv and installs the package (torch pinned by constraints.txt) by itself:
# the demo the package with the pushing world's simulator (the push extra), the tests the dev
# extras on top of it. pip compiles the installed modules' bytecode on one core; `--no-compile`
# and compileall on every core make the same .pyc files (BENCHMARKS.md, "Both cores through
# `make demo`").
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DEV_STAMP := $(VENV)/.installed-dev
PIP := $(BIN)/python -m pip install --quiet --no-compile -c constraints.txt
COMPILE := $(BIN)/python -m compileall -qq -j 0 $(VENV)/lib > /dev/null || true
DEMO_DIR ?= results/demo

.PHONY: demo test test-all lint bench clean install

install: $(DEV_STAMP)

$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(PIP) -e '.[push]'
	$(COMPILE)
	touch $(STAMP)

$(DEV_STAMP): $(STAMP)
	$(PIP) -e '.[dev]'
	$(COMPILE)
	touch $(DEV_STAMP)

demo: $(STAMP)
	$(BIN)/latent-sindy reproduce --scale demo --out $(DEMO_DIR)

test: $(DEV_STAMP)
	$(BIN)/ruff check .
	$(BIN)/lint-imports --no-cache
	$(BIN)/python -m pytest -q -m "not slow" -n auto --dist loadscope

test-all: $(DEV_STAMP)
	$(BIN)/python -m pytest -q -n auto --dist loadscope

lint: $(DEV_STAMP)
	$(BIN)/ruff check .
	$(BIN)/lint-imports --no-cache

bench: $(DEV_STAMP)
	$(BIN)/python benchmarks/collect.py
	$(BIN)/python benchmarks/mppi.py

clean:
	rm -rf $(VENV) build *.egg-info src/*.egg-info
