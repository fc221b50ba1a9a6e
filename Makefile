# Brick Factory: the front door. `make synth N=8` sets up and runs the main job; `make test` runs the tests.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
N ?= 8
SEED ?= 0
OUT ?= out/synth
RUNNER ?= local
CHECK_BACKEND ?= auto
WORKERS ?= $(shell nproc 2>/dev/null || echo 2)
DATA ?= $(OUT)
OUTDIR ?= checkpoints/run
TASKS ?= selection,pose
STEPS ?= 200
LORA ?= auto
MODEL ?=
WEIGHTS ?=
SHARD ?=
WEIGHT_DTYPE ?=
RECIPE ?=
DESIGNS ?= out/designs
STAGE_STEPS ?= 200,100,200
GPUS ?= 1

.PHONY: setup synth designs train bench test test-fast clean

setup: $(STAMP)

# pyproject.toml declares ranges; constraints.txt pins the exact versions the project is tested with.
$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet -c constraints.txt --upgrade pip
	$(PY) -m pip install --quiet -c constraints.txt -e '.[jax,warp,ray,train,bench,dev]'
	touch $(STAMP)

# The main job: sample N physics-verified objects, render every step, write sharded Parquet to OUT
# (embedded part library unless LDRAWDIR is set). RUNNER=local|ray says where shards run,
# CHECK_BACKEND=auto|cpu|jax how the physics checks run (cpu: MuJoCo's C collision and NumPy/SciPy,
# one candidate at a time; jax: this project's batched JAX kernels; auto: jax where a CUDA GPU and
# the gpu extra are, else cpu; both write the same files). Re-running resumes; a changed config is refused.
synth: setup
	$(PY) -m pipelines.synth --n $(N) --out $(OUT) --seed $(SEED) --runner $(RUNNER) --check-backend $(CHECK_BACKEND) --workers $(WORKERS)

# Human-designed models into the same rows (source "design").
designs: setup
	$(PY) -m pipelines.designs ../shared/ldraw_models/*.ldr ../shared/ldraw_models/*.mpd --out out/designs --ldraw ../shared/ldraw

# Fine-tune a vision-language model on DATA (default: the synth output; several folders: DATA=a,b
# with WEIGHTS=2,1 to sample them by weight); with no MODEL, a small Qwen2-VL-architecture model
# built from a config. RECIPE=staged runs the paper's staged recipe instead (python -m train.recipe):
# DESIGNS, then + world feedback from the stage-1 model's wrong answers, then + DATA as synthetic
# data, STAGE_STEPS steps each. Re-running resumes (finished stages are skipped). GPUS=N trains on N
# GPUs of this machine (torchrun, one process per GPU, each step N times the examples; not with RECIPE);
# SHARD=fsdp with LORA=0 shards the model over them (FSDP) for models whose full fine-tuning one GPU cannot hold;
# WEIGHT_DTYPE=bf16 holds every weight and AdamW state in bf16 (full fine-tuning of an 8B-12B model on one 141 GB GPU).
TRAIN_LAUNCH = $(if $(filter-out 1,$(GPUS)),$(PY) -m torch.distributed.run --standalone --nproc_per_node $(GPUS),$(PY))
train: setup
ifeq ($(RECIPE),staged)
	$(if $(filter-out 1,$(GPUS)),$(error RECIPE=staged runs in one process; leave out GPUS))
	$(PY) -m train.recipe --designs $(DESIGNS) --synthetic $(DATA) --outdir $(OUTDIR) --tasks $(TASKS) --stage-steps $(STAGE_STEPS) --lora $(LORA) $(if $(MODEL),--model $(MODEL))
else ifeq ($(RECIPE),)
	$(TRAIN_LAUNCH) -m train --data $(DATA) --outdir $(OUTDIR) --tasks $(TASKS) --steps $(STEPS) --lora $(LORA) $(if $(WEIGHTS),--weights $(WEIGHTS)) $(if $(SHARD),--shard $(SHARD)) $(if $(WEIGHT_DTYPE),--weight-dtype $(WEIGHT_DTYPE)) $(if $(MODEL),--model $(MODEL))
else
	$(error RECIPE=$(RECIPE) is not a recipe; valid: staged (or leave it out for one training run))
endif

# Throughput of the factory and the baselines' scores: bench/report.md, report.json, PNG plots.
bench: setup
	$(PY) -m pipelines.bench --out bench

# Test files run two at a time on a 2-core machine (-n auto: one per core), each file in one
# process (--dist loadfile) so that a file's shared fixtures are made once.
test: setup
	$(PY) -m pytest -q -n auto --dist loadfile

# The development lane: the suite without the tests marked slow (whole builds, training runs,
# wheels in fresh environments, large batches; pyproject.toml lists the markers).
test-fast: setup
	$(PY) -m pytest -q -n auto --dist loadfile -m "not slow"

clean:
	rm -rf $(VENV) .pytest_cache
