# Brick Factory: the front door. `make synth N=8` sets up and runs the main job; `make test` runs the tests.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
N ?= 8
SEED ?= 0
OUT ?= out/synth
BACKEND ?= local
WORKERS ?= 2

.PHONY: setup synth designs test clean

setup: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[mjx,ray,dev]'
	touch $(STAMP)

# The main job: sample N physics-verified objects, render every step, write sharded Parquet to OUT
# (embedded part library unless LDRAWDIR is set). Re-running resumes; a changed config is refused.
synth: setup
	$(PY) -m pipelines.synth --n $(N) --out $(OUT) --seed $(SEED) --backend $(BACKEND) --workers $(WORKERS)

# Human-designed models into the same rows (source "design").
designs: setup
	$(PY) -m pipelines.designs ../shared/ldraw_models/*.ldr ../shared/ldraw_models/*.mpd --out out/designs --ldraw ../shared/ldraw

test: setup
	$(PY) -m pytest -q

clean:
	rm -rf $(VENV) .pytest_cache
