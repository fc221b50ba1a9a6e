"""The training run's settings: one frozen `TrainConfig`, saved into every checkpoint.

A checkpoint records the config it was trained under, so a re-run of the same command resumes it
and a run with different settings is refused (`resume_conflicts`) instead of silently mixing two
trainings in one folder. Settings that do not change what is trained (how often to save or log,
what to evaluate afterwards) may change between runs; the rest may not.
"""

from __future__ import annotations

import argparse
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from factory.config import ConfigError as _ConfigError, config_from_dict, config_to_dict
from factory.dataset.tasks import TASKS

DTYPES = ("auto", "bf16", "fp32")
WEIGHT_DTYPES = ("auto", "bf16", "fp32")
DEVICES = ("auto", "cpu", "cuda")
SPLITS = ("train", "test")
SHARD_MODES = ("ddp", "fsdp")
"""How several processes under torchrun share the model (`TrainConfig.shard`)."""
LORA_TARGETS = ("q_proj", "k_proj", "v_proj", "o_proj", "gate_proj", "up_proj", "down_proj")
"""The language model's attention and MLP projections (Qwen2 / Llama names)."""

RESUME_FREE = ("outdir", "workers", "save_every", "log_every", "keep_checkpoints", "eval", "eval_limit", "eval_split",
               "max_new_tokens", "device", "fsdp_keep_gathered")
"""Fields that may differ between a checkpoint's config and the run resuming it."""

CONFIG_FILE = "train_config.json"

FAMILY_NAMES = ("qwen2-vl", "qwen2.5-vl", "qwen3-vl", "gemma3", "internvl3")
"""The model families `train.tiny` builds (`train.tiny.FAMILIES` is keyed by these names; kept here
so a config is checked without importing transformers)."""


class ConfigError(_ConfigError):
    """A setting out of range, or a config that cannot resume a checkpoint."""


def lora_value(text: str):
    """The command lines' `--lora`: 1 (True), 0 (False) or auto (LoRA for a given checkpoint, full
    fine-tuning for a model built from a config; resolved where the model is known)."""
    v = text.lower()
    if v == "auto":
        return "auto"
    if v in ("1", "true", "yes", "on"):
        return True
    if v in ("0", "false", "no", "off"):
        return False
    raise argparse.ArgumentTypeError(f"expected 1, 0 or auto, got {text!r}")


@dataclass(frozen=True)
class TrainConfig:
    """Everything that decides a training run (see the module docstring)."""

    data: tuple[str, ...]
    """Dataset folders (`make synth` output, `python -m pipelines.designs` output, `python -m
    train.feedback` output) whose train splits are mixed into one stream."""
    outdir: str
    """The run folder: base model, checkpoints, logs, final model, metrics."""
    weights: tuple[float, ...] = ()
    """Sampling weight of each `data` folder, in order (`--weights 2,1,1`): each example's folder
    is drawn with probability weight / sum of weights, whatever the folders' sizes (each folder's
    own examples in its own shuffled order, epoch after epoch). Empty: every example of every
    folder once per epoch, folders in proportion to their sizes."""
    model: str | None = None
    """A local model folder to fine-tune (any supported family, see docs/guides/train.md); None builds a
    tiny model of `base_family` into OUTDIR/base first."""
    tasks: tuple[str, ...] = field(default=TASKS, metadata={"choices": TASKS})
    """Tasks to train on; each (row, task) is one example. Feedback folders give pose only."""
    steps: int = 200
    """Optimizer steps (each `batch_size * grad_accum` examples, times N with N processes under
    torchrun)."""
    batch_size: int = 2
    """Examples per forward pass (of each process under torchrun)."""
    grad_accum: int = 1
    """Forward passes whose gradients are summed before one optimizer step."""
    lr: float = 2e-4
    """Peak learning rate of AdamW."""
    warmup: int = 10
    """Steps of linear warmup from 0 to `lr`; then linear decay to 0 at `steps`."""
    weight_decay: float = 0.0
    """AdamW weight decay (not applied to biases and norms)."""
    max_grad_norm: float = 1.0
    """Gradient clipping by global norm; 0 turns clipping off."""
    lora: bool = True
    """Train LoRA adapters on the language model's projections (True) or every weight (False). The
    command line's default `auto` is LoRA for a given checkpoint and full fine-tuning for a model
    built from a config (adapters on random weights learn little)."""
    base_size: str = "tiny"
    """Size of the model built from a config when `model` is None: tiny or small (`train.tiny.SIZES`)."""
    base_family: str = field(default="qwen2-vl", metadata={"choices": FAMILY_NAMES})
    """Model family built from a config when `model` is None (`train.tiny.FAMILIES`): qwen2-vl,
    qwen2.5-vl, qwen3-vl, gemma3 or internvl3."""
    lora_r: int = 16
    """LoRA rank."""
    lora_alpha: int = 32
    """LoRA scale numerator (the update is scaled by alpha / r)."""
    lora_dropout: float = 0.05
    """Dropout on the LoRA branch's input."""
    lora_targets: tuple[str, ...] = LORA_TARGETS
    """Names of the Linear layers of the language model that get adapters (the vision tower never)."""
    max_pixels: int = 28 * 28 * 64
    """Most pixels per image after resizing (28 x 28 pixels make one merged image token in
    Qwen2-VL, so 28*28*64 is at most 64 tokens per image)."""
    shard: str = field(default="ddp", metadata={"choices": SHARD_MODES})
    """How the processes under torchrun hold the model: ddp (DistributedDataParallel: every GPU
    holds the whole model, its gradients and AdamW states; for LoRA, and for anything one GPU
    holds) or fsdp (PyTorch's FSDP2, `fully_shard` on each transformer block and the root: weights,
    gradients and AdamW states split over the GPUs, each block gathered for its forward and
    backward; for full fine-tuning of a model whose weights and AdamW states do not fit one GPU;
    full fine-tuning only). The same examples and updates either way; one process trains the plain
    model under both."""
    fsdp_keep_gathered: bool = False
    """With shard=fsdp: keep each block's gathered weights from its forward until its backward
    (FSDP2's `reshard_after_forward=False`, as ZeRO-2 does) instead of freeing them after the
    forward and gathering them again. One all-gather per block and step less, for the memory of
    the whole model's weights held gathered at the end of the forward. The same updates either way."""
    gradient_checkpointing: bool = False
    """Recompute activations in the backward pass (less GPU memory, about a third slower)."""
    max_length: int = 2048
    """Longest sequence in tokens (image tokens included); longer examples are skipped and counted,
    never truncated (a cut answer would teach a wrong one)."""
    shuffle_window: int = 16
    """Row groups (objects) whose examples are shuffled together; the order of row groups is
    shuffled too. Bounds the rows held in memory."""
    workers: int | None = None
    """Processes that decode and encode examples (PNGs, image resizing, tokenizing) ahead of the
    model; 0 does it in a thread of the trainer; None picks min(8, CPUs - 2), or 0 below 4 CPUs (CPUs:
    each process's share under torchrun; every process encodes every example).
    Changes speed only, never which examples come in which order."""
    save_every: int = 100
    """Write a checkpoint every this many steps (and always at the last step); 0: only at the end."""
    keep_checkpoints: int = 2
    """Checkpoints kept (oldest removed first); 0 keeps all."""
    log_every: int = 1
    """Write a line to log.jsonl every this many steps."""
    seed: int = 0
    """Seed of the model build, LoRA init, data order and dropout."""
    dtype: str = field(default="auto", metadata={"choices": DTYPES})
    """Compute precision: auto (bf16 autocast on CUDA, fp32 on CPU), bf16, or fp32."""
    weight_dtype: str = field(default="auto", metadata={"choices": WEIGHT_DTYPES})
    """Precision the weights are held in: auto (a LoRA run's frozen base in bf16 on CUDA with bf16
    compute, every trained weight in fp32), bf16 (every weight, so in full fine-tuning also its
    gradients and AdamW states: 8 bytes a parameter instead of 16, which lets full fine-tuning of
    an 8B-12B model fit one 141 GB GPU; an update smaller than a weight's bf16 step is lost), or
    fp32 (every weight, a LoRA base too)."""
    device: str = field(default="auto", metadata={"choices": DEVICES})
    """auto (cuda when available), cpu or cuda."""
    eval: bool = True
    """Predict and score the test split with the base and the trained model after training."""
    eval_limit: int | None = None
    """Steps of the eval split to predict (None: all)."""
    eval_split: str = field(default="test", metadata={"choices": SPLITS})
    """Split predicted after training."""
    max_new_tokens: int = 256
    """Generation budget per answer in the evaluation."""

    def __post_init__(self):
        def choice(name, value, valid):
            if value not in valid:
                raise ConfigError(f"{name}={value!r} is not valid; valid: {', '.join(map(str, valid))}")

        choice("base_size", self.base_size, ("tiny", "small"))
        choice("base_family", self.base_family, FAMILY_NAMES)

        if not self.data:
            raise ConfigError("data: give at least one dataset folder (--data OUT)")
        if self.weights:
            if len(self.weights) != len(self.data):
                raise ConfigError(f"weights: give one per data folder ({len(self.data)}), got {len(self.weights)}")
            bad = [w for w in self.weights if not (isinstance(w, (int, float)) and 0 < w < float("inf"))]
            if bad:
                raise ConfigError(f"weights must be > 0 (leave a folder out instead of weighting it 0), got {bad[0]!r}")
        if not self.tasks:
            raise ConfigError(f"tasks: give at least one; valid: {', '.join(TASKS)}")
        for t in self.tasks:
            choice("task", t, TASKS)
        choice("dtype", self.dtype, DTYPES)
        choice("weight_dtype", self.weight_dtype, WEIGHT_DTYPES)
        choice("device", self.device, DEVICES)
        choice("eval_split", self.eval_split, SPLITS)
        choice("shard", self.shard, SHARD_MODES)
        if self.shard == "fsdp" and self.lora:
            raise ConfigError("shard=fsdp trains every weight (full fine-tuning) and cannot train LoRA adapters: "
                              "give --lora 0 for full fine-tuning sharded over the GPUs, or --shard ddp for LoRA "
                              "(its frozen bf16 base fits one GPU)")
        if self.fsdp_keep_gathered and self.shard != "fsdp":
            raise ConfigError("fsdp_keep_gathered keeps FSDP's gathered weights and applies with shard=fsdp only; "
                              "give --shard fsdp, or leave out --fsdp-keep-gathered")
        positive = ("steps", "batch_size", "grad_accum", "lora_r", "lora_alpha", "max_pixels", "max_length",
                    "shuffle_window", "log_every", "max_new_tokens")
        for name in positive:
            if int(getattr(self, name)) < 1:
                raise ConfigError(f"{name} must be >= 1, got {getattr(self, name)!r}")
        for name in ("warmup", "save_every", "keep_checkpoints"):
            if int(getattr(self, name)) < 0:
                raise ConfigError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        if not self.lr > 0:
            raise ConfigError(f"lr must be > 0, got {self.lr!r}")
        if self.weight_decay < 0 or self.max_grad_norm < 0:
            raise ConfigError("weight_decay and max_grad_norm must be >= 0")
        if not 0 <= self.lora_dropout < 1:
            raise ConfigError(f"lora_dropout must be in [0, 1), got {self.lora_dropout!r}")
        if self.lora and not self.lora_targets:
            raise ConfigError(f"lora_targets: give at least one module name, e.g. {','.join(LORA_TARGETS)}")
        if self.workers is not None and self.workers < 0:
            raise ConfigError(f"workers must be >= 0 (or None for automatic), got {self.workers!r}")
        if self.eval_limit is not None and self.eval_limit < 1:
            raise ConfigError(f"eval_limit must be >= 1 (or None for all), got {self.eval_limit!r}")

    # -- (de)serialisation --------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """Every field as JSON values (`factory.config`)."""
        return config_to_dict(self)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1, sort_keys=True)

    @classmethod
    def from_dict(cls, d: dict) -> "TrainConfig":
        """The inverse of `to_dict`; unknown keys are refused, naming the valid ones."""
        return config_from_dict(cls, d, ConfigError)

    @classmethod
    def from_json(cls, text: str) -> "TrainConfig":
        return cls.from_dict(json.loads(text))

    def save(self, folder) -> Path:
        path = Path(folder) / CONFIG_FILE
        path.write_text(self.to_json() + "\n")
        return path

    @classmethod
    def load(cls, folder) -> "TrainConfig":
        return cls.from_json((Path(folder) / CONFIG_FILE).read_text())

    # -- derived -------------------------------------------------------------------------------------
    @property
    def examples_per_step(self) -> int:
        return self.batch_size * self.grad_accum

    def resolved_workers(self, processes: int = 1) -> int:
        """`workers`, or (None) min(8, C - 2) for each of `processes` processes sharing the CPUs,
        C being their share of the CPUs (0 below 4)."""
        if self.workers is not None:
            return int(self.workers)
        cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
        cpus //= max(1, int(processes))
        return min(8, cpus - 2) if cpus >= 4 else 0


def resume_conflicts(saved: TrainConfig, new: TrainConfig) -> list[str]:
    """'field: saved -> new' for each difference that forbids resuming `saved`'s checkpoint."""
    a, b = saved.to_dict(), new.to_dict()
    return [f"{k}: {a[k]!r} -> {b[k]!r}" for k in sorted(a) if k not in RESUME_FREE and a[k] != b[k]]
