# Brick Factory: the front door. `make synth N=8` sets up and runs the main job; `make test` runs the tests.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
N ?= 8
SEED ?= 0
OUT ?= out
EXAMPLE := factory/data/examples/tower.mpd

.PHONY: setup synth test clean

setup: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[mjx,dev]'
	touch $(STAMP)

# Until the dataset pipeline exists, the main job prints the build steps of the bundled example
# model, read through the embedded default part library.
synth: setup
	$(PY) -m factory.ldraw steps $(EXAMPLE) --json

test: setup
	$(PY) -m pytest -q

clean:
	rm -rf $(VENV) .pytest_cache
