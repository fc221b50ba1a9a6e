"""`python -m train`: fine-tune a vision-language model on the dataset's two tasks, then compare it
with the untrained model on the test split.

    python -m train --data OUT [--data OUT_FB ...] --outdir RUN [--model PATH] [--tasks selection,pose]
        [--steps N] [--batch-size B] [--grad-accum G] [--lr LR] [--warmup W] [--lora 1|0]
        [--save-every K] [--seed S] [--eval-limit N] [--no-eval] [--device auto|cpu|cuda] ...

Without --model a tiny model of --base-family (default qwen2-vl) is built into RUN/base first. Re-running the same command
resumes from the last checkpoint; other settings in an existing RUN are refused. See
`train.loop` for the folder's contents and `train.config.TrainConfig` for every setting.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from train.config import DEVICES, DTYPES, FAMILY_NAMES, LORA_TARGETS, SPLITS, ConfigError, TrainConfig


def _bool(v: str) -> bool:
    if v.lower() in ("1", "true", "yes", "on"):
        return True
    if v.lower() in ("0", "false", "no", "off"):
        return False
    raise argparse.ArgumentTypeError(f"expected 1 or 0, got {v!r}")


def _list(v: str) -> tuple[str, ...]:
    return tuple(dict.fromkeys(x.strip() for x in v.split(",") if x.strip()))


def parser() -> argparse.ArgumentParser:
    d = TrainConfig(data=("x",), outdir="x")
    ap = argparse.ArgumentParser(prog="python -m train", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", action="append", required=True, help="dataset folder (repeat to mix several)")
    ap.add_argument("--outdir", required=True, help="run folder (checkpoints, logs, final model, metrics)")
    ap.add_argument("--model", default=None, help="local model folder to fine-tune (default: build the tiny Qwen2-VL)")
    ap.add_argument("--tasks", type=_list, default=d.tasks, help="comma-separated: selection,pose (default both)")
    ap.add_argument("--steps", type=int, default=d.steps)
    ap.add_argument("--batch-size", type=int, default=d.batch_size)
    ap.add_argument("--grad-accum", type=int, default=d.grad_accum)
    ap.add_argument("--lr", type=float, default=d.lr)
    ap.add_argument("--warmup", type=int, default=d.warmup, help="warmup steps")
    ap.add_argument("--weight-decay", type=float, default=d.weight_decay)
    ap.add_argument("--max-grad-norm", type=float, default=d.max_grad_norm, help="0: no clipping")
    ap.add_argument("--lora", default="auto", help="1: LoRA adapters, 0: full fine-tuning, auto (default): LoRA "
                    "for a --model checkpoint, full fine-tuning for a model built from a config")
    ap.add_argument("--base-size", default=d.base_size, help="model built when no --model is given: tiny or small")
    ap.add_argument("--base-family", default=d.base_family,
                    help=f"family of the model built when no --model is given: {', '.join(FAMILY_NAMES)}")
    ap.add_argument("--lora-r", type=int, default=d.lora_r)
    ap.add_argument("--lora-alpha", type=int, default=d.lora_alpha)
    ap.add_argument("--lora-dropout", type=float, default=d.lora_dropout)
    ap.add_argument("--lora-targets", type=_list, default=d.lora_targets,
                    help=f"language-model Linear names (default {','.join(LORA_TARGETS)})")
    ap.add_argument("--gradient-checkpointing", type=_bool, default=d.gradient_checkpointing)
    ap.add_argument("--max-pixels", type=int, default=d.max_pixels, help="most pixels per image (28*28 per token)")
    ap.add_argument("--max-length", type=int, default=d.max_length,
                    help="longest example in tokens; longer ones are skipped")
    ap.add_argument("--shuffle-window", type=int, default=d.shuffle_window, help="row groups shuffled together")
    ap.add_argument("--workers", type=int, default=None,
                    help="processes encoding examples (default: min(8, CPUs - 2); 0: a thread of the trainer)")
    ap.add_argument("--save-every", type=int, default=d.save_every, help="0: only at the end")
    ap.add_argument("--keep-checkpoints", type=int, default=d.keep_checkpoints, help="0: keep all")
    ap.add_argument("--log-every", type=int, default=d.log_every)
    ap.add_argument("--seed", type=int, default=d.seed)
    ap.add_argument("--dtype", default=d.dtype, choices=DTYPES)
    ap.add_argument("--device", default=d.device, choices=DEVICES)
    ap.add_argument("--eval-limit", type=int, default=None, help="test steps to predict (default all)")
    ap.add_argument("--eval-split", default=d.eval_split, choices=SPLITS)
    ap.add_argument("--max-new-tokens", type=int, default=d.max_new_tokens)
    ap.add_argument("--no-eval", action="store_true", help="skip the before/after evaluation")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    return ap


def config_from_args(args) -> TrainConfig:
    """The `TrainConfig` of parsed arguments; paths made absolute, so a resume from another
    working directory compares equal."""
    return TrainConfig(
        data=tuple(str(Path(p).resolve()) for p in args.data), outdir=str(Path(args.outdir).resolve()),
        model=str(Path(args.model).resolve()) if args.model else None, tasks=args.tasks, steps=args.steps,
        batch_size=args.batch_size, grad_accum=args.grad_accum, lr=args.lr, warmup=args.warmup,
        weight_decay=args.weight_decay, max_grad_norm=args.max_grad_norm, lora=(args.model is not None) if str(args.lora).lower() == "auto" else _bool(str(args.lora)),
        base_size=args.base_size, base_family=args.base_family, lora_r=args.lora_r,
        lora_alpha=args.lora_alpha, lora_dropout=args.lora_dropout, lora_targets=args.lora_targets,
        gradient_checkpointing=args.gradient_checkpointing, max_pixels=args.max_pixels,
        max_length=args.max_length, shuffle_window=args.shuffle_window, workers=args.workers,
        save_every=args.save_every,
        keep_checkpoints=args.keep_checkpoints, log_every=args.log_every, seed=args.seed, dtype=args.dtype,
        device=args.device, eval=not args.no_eval, eval_limit=args.eval_limit, eval_split=args.eval_split,
        max_new_tokens=args.max_new_tokens)


def run(args) -> int:
    import json

    from train.evaluate import evaluate, headline
    from train.loop import FINAL, resolve_device, train

    config = config_from_args(args)
    if args.quiet:
        from transformers.utils import logging as hf_logging

        hf_logging.disable_progress_bar()
    summary = train(config, progress=not args.quiet)
    print(json.dumps({k: summary[k] for k in ("steps", "train_seconds", "samples_per_s", "tokens_per_s",
                                              "final_loss", "peak_gpu_mem_gb")}), flush=True)
    if config.eval:
        base = Path(config.model) if config.model else Path(config.outdir) / "base"
        result = evaluate(config, base, Path(config.outdir) / FINAL, resolve_device(config), progress=not args.quiet)
        print(headline(result), flush=True)
    how = "full weights, LoRA merged in" if config.lora else "full weights"
    print(f"final model: {Path(config.outdir) / FINAL} ({how}; evaluate with --model hf:PATH)", flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    from eval.data import DatasetError
    from factory.cli import run_guarded
    from train.model import ModelError

    args = parser().parse_args(argv)
    return run_guarded(lambda: run(args), {ConfigError: 2, DatasetError: 2, ModelError: 2})


if __name__ == "__main__":
    sys.exit(main())
