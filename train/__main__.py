"""`python -m train`: fine-tune a vision-language model on the dataset's two tasks, then compare it
with the untrained model on the test split.

    python -m train --data OUT [--data OUT_FB ...] --outdir RUN [--model PATH] [--tasks selection,pose]
        [--steps N] [--batch-size B] [--grad-accum G] [--lr LR] [--warmup W] [--lora 1|0|auto]
        [--save-every K] [--seed S] [--eval-limit N] [--no-eval] [--device auto|cpu|cuda] [--no-progress] ...
    torchrun --standalone --nproc_per_node N -m train ...   # N GPUs of this machine, one process each
    torchrun --standalone --nproc_per_node N -m train --shard fsdp --lora 0 ...   # the model sharded over them

A flag per `TrainConfig` field, with its default and meaning (`--help`).

Without --model a tiny model of --base-family (default qwen2-vl) is built into RUN/base first. Re-running the same command
resumes from the last checkpoint; other settings in an existing RUN are refused. See
`train.loop` for the folder's contents and `train.config.TrainConfig` for every setting.

Under torchrun every process trains (DistributedDataParallel, or with --shard fsdp the model
sharded by FSDP2 for full fine-tuning; `batch_size * grad_accum * N` examples per step); rank 0
alone writes the run folder, prints, and evaluates after training, while the others end
(`train.loop`, docs/guides/train.md).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from eval.data import DatasetError
from factory.cli import ArgumentParser, add_config_args, add_progress_flag, config_from_args as config_of, run_guarded
from factory.config import field_docs
from train.config import ConfigError, TrainConfig, lora_value
from train.distributed import launched_rank
from train.evaluate import evaluate, headline
from train.loop import FINAL, resolve_device, train
from train.model import ModelError


def parser() -> argparse.ArgumentParser:
    """A flag per `TrainConfig` field (`factory.cli.add_config_args`); `--lora` also takes auto."""
    ap = ArgumentParser(prog="python -m train", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    add_config_args(ap, TrainConfig, skip=("lora",))
    ap.add_argument("--lora", type=lora_value, default="auto", metavar="1|0|auto",
                    help=field_docs(TrainConfig)["lora"] + " (default: auto)")
    add_progress_flag(ap)
    return ap


def config_from_args(args) -> TrainConfig:
    """The `TrainConfig` of parsed arguments; paths made absolute, so a resume from another
    working directory compares equal."""
    return config_of(TrainConfig, args, data=tuple(str(Path(p).resolve()) for p in args.data),
                     outdir=str(Path(args.outdir).resolve()), model=str(Path(args.model).resolve()) if args.model else None,
                     lora=(args.model is not None) if args.lora == "auto" else args.lora)


def run(args) -> int:
    config = config_from_args(args)
    if args.no_progress:
        from transformers.utils import logging as hf_logging

        hf_logging.disable_progress_bar()
    summary = train(config, progress=not args.no_progress)
    if launched_rank() != 0:
        return 0  # under torchrun: rank 0 reports and evaluates
    print(json.dumps({k: summary[k] for k in ("steps", "train_seconds", "samples_per_s", "tokens_per_s",
                                              "final_loss", "peak_gpu_mem_gb")}), flush=True)
    if config.eval:
        base = Path(config.model) if config.model else Path(config.outdir) / "base"
        result = evaluate(config, base, Path(config.outdir) / FINAL, resolve_device(config), progress=not args.no_progress)
        print(headline(result), flush=True)
    how = "full weights, LoRA merged in" if config.lora else "full weights"
    print(f"final model: {Path(config.outdir) / FINAL} ({how}; evaluate with --model hf:PATH)", flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    return run_guarded(lambda: run(args), {ConfigError: 2, DatasetError: 2, ModelError: 2})


if __name__ == "__main__":
    sys.exit(main())
