# Quick start:  `make main` trains UA2C on the SUMO env;  `make test` runs the test suite.
# Both create .venv if it is missing and install everything they need (CPU torch first).
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.sb3-ua2c-installed

.PHONY: main test test-slow install

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

# The tests over about 10 s (whole experiments in quick mode, Ray, PostgreSQL, torch.compile); CI runs them.
test-slow: $(STAMP)
	$(PY) -m pytest -q -m slow
