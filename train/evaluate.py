"""The comparison after training: the untrained base model and the trained model answer the same
test steps with `eval.predict`'s machinery, and `eval.score` scores both in strict and paper mode.

Writes `RUN/preds_before.jsonl`, `RUN/preds_after.jsonl` and `RUN/metrics.json`
(``{"before": score, "after": score, "split", "limit", "data", ...}``). A finished evaluation with
the same split and limit is not redone when the command is re-run.
"""

from __future__ import annotations

import gc
import json
from pathlib import Path

import torch

from eval.data import DatasetError, shard_files
from eval.hf import HFPredictor
from eval.predict import ModelPredictor, write_predictions
from eval.processor import load_processor
from eval.score import score_file
from train.checkpoint import write_atomic_text
from train.config import TrainConfig
from train.model import load_base

METRICS_FILE = "metrics.json"


def eval_folder(config: TrainConfig) -> str:
    """The first dataset folder that has the eval split (feedback folders have only train)."""
    for folder in config.data:
        try:
            shard_files(folder, config.eval_split)
            return folder
        except DatasetError:
            continue
    raise DatasetError(f"no {config.eval_split} split in {', '.join(config.data)}")


def trained_predictor(path, config: TrainConfig, device):
    """An `eval.predict.ModelPredictor` of the model folder `path` (processor via
    `eval.processor.load_processor`, which also works without torchvision)."""
    dtype = torch.bfloat16 if device.type == "cuda" and config.dtype != "fp32" else torch.float32
    model = load_base(path, dtype).to(device).eval()
    processor = load_processor(path, config.max_pixels)
    return ModelPredictor(HFPredictor(model, processor), config.max_new_tokens)


def evaluate(config: TrainConfig, base: Path, final: Path, device, progress: bool = True) -> dict:
    """Predict and score the eval split with `base` and `final` (see the module docstring)."""
    run = Path(config.outdir)
    out = run / METRICS_FILE
    data = eval_folder(config)
    key = {"split": config.eval_split, "limit": config.eval_limit, "data": str(data), "tasks": list(config.tasks),
           "steps": config.steps, "max_new_tokens": config.max_new_tokens}
    if out.is_file():
        old = json.loads(out.read_text())
        if all(old.get(k) == v for k, v in key.items()):
            return old
    result = dict(key)
    for name, path in (("before", base), ("after", final)):
        if progress:
            print(f"evaluating the {name} model ({path}) on {config.eval_split} of {data}", flush=True)
        predictor = trained_predictor(path, config, device)
        preds = run / f"preds_{name}.jsonl"
        write_predictions(data, predictor, preds, split=config.eval_split, tasks=config.tasks,
                          limit=config.eval_limit, progress=progress)
        result[name] = score_file(data, preds, config.eval_split, "both",
                                  only_predicted=config.eval_limit is not None)
        result[f"{name}_model"] = str(path)
        result[f"{name}_predictions"] = str(preds)
        del predictor
        gc.collect()
        if device.type == "cuda":
            torch.cuda.empty_cache()
    write_atomic_text(out, json.dumps(result, indent=1, sort_keys=True) + "\n")
    return result


def headline(result: dict) -> str:
    """One line per model: selection accuracy and step success in both modes."""
    lines = []
    for name in ("before", "after"):
        r = result.get(name) or {}
        parts = []
        for mode in ("strict", "paper"):
            o = (r.get(mode) or {}).get("overall") or {}
            sel, ok = o.get("selection_accuracy"), o.get("step_success")
            parts.append(f"{mode}: selection {'-' if sel is None else f'{sel:.3f}'}, "
                         f"step success {'-' if ok is None else f'{ok:.3f}'}")
        lines.append(f"{name:>6}: " + "; ".join(parts))
    return "\n".join(lines)
