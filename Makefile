# Quick start:  `make main` trains UA2C on the SUMO env;  `make test` runs the test suite.
# Both create .venv if it is missing and install everything they need (CPU torch first).
# `make docs` builds the documentation site into docs/_build/html (the `docs` extra).
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.sb3-ua2c-installed
DOCS_STAMP := $(VENV)/.sb3-ua2c-docs-installed

.PHONY: main test test-slow install docs

$(STAMP): setup.cfg pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet torch==2.13.0
	$(PY) -m pip install --quiet -e ".[test,zoo]"
	touch $(STAMP)

install: $(STAMP)

main: $(STAMP)
	$(PY) -m envs main

test: $(STAMP)
	$(PY) -m pytest -q -m "not slow"

# The tests over about 10 s (whole experiments in quick mode, Ray, two-worker Optuna sweeps, torch.compile); CI runs them.
test-slow: $(STAMP)
	$(PY) -m pytest -q -m slow

$(DOCS_STAMP): $(STAMP)
	$(PY) -m pip install --quiet -e ".[docs]"
	touch $(DOCS_STAMP)

# The user pages, the API reference from the docstrings and the reports as one site; nitpicky, and
# any warning (a broken link or anchor, a stale reference in a docstring) fails the build.
docs: $(DOCS_STAMP)
	$(PY) -m sphinx -W --keep-going -n -b html docs docs/_build/html
