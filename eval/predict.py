"""Answer every step of a dataset split with a model or a baseline; write the answers as JSONL.

`python -m eval.predict --data OUT --model SPEC --out preds.jsonl [--split test]
    [--tasks selection,pose] [--seed 0] [--limit N] [--feedback] [--max-new-tokens 256] [--device D]`

SPEC is one of:

- ``baseline:oracle``: the ground truth (a pipeline check: scores 1.0);
- ``baseline:random``: chance (`eval.baselines.random_baseline`). Each step draws from its own
  generator seeded by (seed, step id), so a step's answer does not depend on which other steps,
  tasks or `--limit` were asked: the same seed writes the same file, byte for byte;
- ``baseline:heuristic``: `eval.baselines.heuristic` with the step's catalog and the previous step
  of the same object and assembly;
- ``hf:PATH``: a local checkpoint folder, full model or LoRA adapter (`eval.hf.HFPredictor`).

One line per answer, in dataset order: ``{"id": step id, "task": "selection" | "pose", "text": ...}``.
`--limit N` answers N steps spread evenly over the split (every (steps / N)-th step, so every
object is reached); score them with `eval.score --only-predicted`. The file is written to a temporary file
beside it and renamed into place, so an interrupted run never leaves a half file under the name.

`--feedback` (the paper's world feedback, `eval.feedback`): a pose answer that parses and fails the
step in paper mode is executed in the simulator (each brick released where it was put and settled on
the before-assembly), drawn as a red outline with where it ended up in solid red, and the model is
asked again with that image, what happened to each brick and its errors (`--static-feedback`: drawn
in red where it was put, errors only); the second answer is written as an extra line with
``"revised": true``. One revision per step. The baselines under feedback: the oracle is never
wrong; random answers afresh (a new draw, seeded by (seed, step id, 1)); the heuristic sees nothing
it uses in the feedback, so it gives the same answer again.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import zlib
from collections.abc import Iterator
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from eval import baselines
from eval.chat import columns_for, task_chat
from eval.data import (
    SPLITS,
    TARGET_COLUMNS,
    DatasetError,
    catalog_of,
    library,
    catalog_rows,
    count_rows,
    info,
    iter_objects,
    iter_rows,
    step_target,
)
from eval.feedback import Feedback, assembly_rows, before_rows, feedback_columns, feedback_example
from eval.hf import CheckpointError, HFPredictor
from eval.metrics import StepTarget
from factory.atomic import umask
from factory.cli import ArgumentParser, add_progress_flag, run_guarded
from factory.dataset.tasks import TASKS
from factory.ldraw import get_reader

BASELINES = ("baseline:random", "baseline:oracle", "baseline:heuristic")
MODEL_CHOICES = (*BASELINES, "hf:PATH")


class ModelSpecError(ValueError):
    """A --model value that names no predictor."""


@dataclass
class StepContext:
    """What a predictor may use to answer one step: the row and its object's history."""

    row: dict
    target: StepTarget
    previous: StepTarget | None
    """The previous step of the same object and assembly (None at its first step)."""
    object_rows: list[dict] = field(default_factory=list)
    """Every row of the step's object (the feedback render's before-assembly and framing)."""


class Predictor:
    """Answers the tasks of a step, and revises a pose answer given world feedback."""

    needs_chat = False
    """Whether `answer` reads the prompt messages and images (the row's task columns)."""

    def answer(self, ctx: StepContext, task: str) -> str:
        raise NotImplementedError

    def revise(self, ctx: StepContext, feedback: Feedback, first: str) -> str:
        raise NotImplementedError


class OraclePredictor(Predictor):
    def answer(self, ctx, task):
        return baselines.oracle(ctx.target)[task]

    def revise(self, ctx, feedback, first):
        return baselines.oracle(ctx.target)["pose"]


class RandomPredictor(Predictor):
    def __init__(self, seed: int = 0):
        self.seed = int(seed)

    def _draw(self, ctx, attempt: int) -> dict:
        key = zlib.crc32(ctx.row["step_id"].encode())
        rng = np.random.default_rng([self.seed, key, attempt])
        return baselines.random_baseline(ctx.target, rng, catalog_rows(ctx.row), catalog=catalog_of(ctx.row))

    def answer(self, ctx, task):
        return self._draw(ctx, 0)[task]

    def revise(self, ctx, feedback, first):
        return self._draw(ctx, 1)["pose"]


class HeuristicPredictor(Predictor):
    def answer(self, ctx, task):
        return baselines.heuristic(ctx.target, ctx.previous, catalog_of(ctx.row))[task]

    def revise(self, ctx, feedback, first):
        return first  # nothing in the feedback is an input of the heuristic


class ModelPredictor(Predictor):
    """An `eval.hf.HFPredictor` (or anything with its `predict(messages, images, max_new_tokens)`)."""

    needs_chat = True

    def __init__(self, model, max_new_tokens: int = 256):
        self.model, self.max_new_tokens = model, int(max_new_tokens)

    def answer(self, ctx, task):
        messages, images, _ = task_chat(ctx.row, task)
        return self.model.predict(messages, images, self.max_new_tokens)

    def revise(self, ctx, feedback, first):
        return self.model.predict(feedback.messages, feedback.images, self.max_new_tokens)


def make_predictor(spec: str, seed: int = 0, max_new_tokens: int = 256, device: str | None = None) -> Predictor:
    """The predictor named by a --model value (see the module docstring)."""
    if spec == "baseline:oracle":
        return OraclePredictor()
    if spec == "baseline:random":
        return RandomPredictor(seed)
    if spec == "baseline:heuristic":
        return HeuristicPredictor()
    if spec.startswith("hf:") and len(spec) > 3:
        return ModelPredictor(HFPredictor.from_path(spec[3:], device=device), max_new_tokens)
    raise ModelSpecError(f"unknown model {spec!r}; valid: {', '.join(MODEL_CHOICES)}")


def parse_tasks(value: str) -> tuple[str, ...]:
    tasks = tuple(dict.fromkeys(t.strip() for t in value.split(",") if t.strip()))
    bad = [t for t in tasks if t not in TASKS]
    if bad or not tasks:
        raise ModelSpecError(f"unknown task(s) {', '.join(bad) or repr(value)}; valid: {', '.join(TASKS)}")
    return tasks


def iter_predictions(data, predictor: Predictor, split: str | None = "test", tasks=TASKS,
                     limit: int | None = None, feedback: bool = False, progress: bool = False,
                     ldraw=None, physics: bool = True) -> Iterator[dict]:
    """The answer records of the split's steps (`split` None: every split), in dataset order;
    feedback renders draw parts from `ldraw` (default: the dataset's library, `eval.data.library`);
    `physics` False: the static feedback (`eval.feedback.feedback_example`)."""
    tasks = tuple(tasks)
    columns = list(TARGET_COLUMNS)
    if predictor.needs_chat:
        columns += [c for t in tasks for c in columns_for(t)]
    reader = size = None
    if feedback and "pose" in tasks:
        columns += feedback_columns()
        from factory.render import Renderer  # lazy: GL at import; only feedback images need it

        src = info(data)
        reader, size = get_reader(library(data, ldraw, src)), int(src.config["size"])
    columns = list(dict.fromkeys(columns))
    n_rows = count_rows(data, split)
    total = min(n_rows, limit) if limit is not None else n_rows
    # A limit picks steps spread evenly over the split (every n_rows/limit-th), so a small
    # evaluation still covers every object and every stage of assembly.
    chosen = None if total == n_rows else {int(i * n_rows / total) for i in range(total)}
    bar = tqdm(total=total, unit="step", desc="predict", disable=not progress, file=sys.stderr)
    done = 0
    index = -1
    try:
        for rows in iter_objects(iter_rows(data, split, columns)):
            previous: dict[str, StepTarget] = {}
            # One renderer per object (its feedback renders share scenes), freed before the next object.
            with Renderer(reader) if reader is not None else nullcontext() as renderer:
                for row in rows:
                    if done >= total:
                        return
                    index += 1
                    target = step_target(row)
                    ctx = StepContext(row, target, previous.get(row["assembly"]), rows)
                    previous[row["assembly"]] = target
                    if chosen is not None and index not in chosen:
                        continue
                    for task in tasks:
                        text = predictor.answer(ctx, task)
                        yield {"id": row["step_id"], "task": task, "text": text}
                        if task == "pose" and reader is not None:
                            fb = feedback_example(row, text, before_rows(rows, row), renderer, size,
                                                  scene=assembly_rows(rows, row), physics=physics)
                            if fb is not None:
                                yield {"id": row["step_id"], "task": "pose", "text": predictor.revise(ctx, fb, text),
                                       "revised": True}
                    done += 1
                    bar.update(1)
    finally:
        bar.close()


def write_predictions(data, predictor: Predictor, out, split: str | None = "test", tasks=TASKS,
                      limit: int | None = None, feedback: bool = False, progress: bool = False,
                      ldraw=None, physics: bool = True) -> dict:
    """Write `iter_predictions` to `out` atomically; returns {"lines", "steps", "revised", "path"}."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent)
    summary = {"lines": 0, "steps": 0, "revised": 0, "path": str(out)}
    steps = set()
    try:
        os.fchmod(fd, 0o666 & ~umask())  # readable as a plain open would leave it, not mkstemp's 0600
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            for rec in iter_predictions(data, predictor, split, tasks, limit, feedback, progress, ldraw, physics):
                f.write(json.dumps(rec, ensure_ascii=False) + "\n")
                summary["lines"] += 1
                summary["revised"] += bool(rec.get("revised"))
                steps.add(rec["id"])
        os.replace(tmp, out)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    summary["steps"] = len(steps)
    return summary


def predict_file(data, model, out, split: str | None = "test", tasks=TASKS, seed: int = 0,
                 limit: int | None = None, feedback: bool = False, max_new_tokens: int = 256, device: str | None = None,
                 progress: bool = False) -> dict:
    """The command line as a function: `model` is a --model value or a `Predictor`; `split` None
    answers every split. Returns `write_predictions`'s summary."""
    predictor = model if isinstance(model, Predictor) else make_predictor(model, seed, max_new_tokens, device)
    return write_predictions(data, predictor, out, split, tasks, limit, feedback, progress)


def run(args) -> int:
    if args.limit is not None and args.limit < 0:
        raise ModelSpecError("--limit must be >= 0")
    if Path(args.out).is_dir():
        raise ModelSpecError(f"--out {args.out} is a folder; give a file name (preds.jsonl)")
    tasks = parse_tasks(args.tasks)
    src = info(args.data)  # a clear error before a model is loaded
    if args.feedback:
        library(args.data, args.ldraw, src)
    predictor = make_predictor(args.model, args.seed, args.max_new_tokens, args.device)
    summary = write_predictions(args.data, predictor, args.out, args.split, tasks, args.limit, args.feedback,
                                progress=not args.no_progress, ldraw=args.ldraw,
                                physics=not args.static_feedback)
    print(f"wrote {summary['lines']} answers for {summary['steps']} steps"
          + (f" ({summary['revised']} revised after feedback)" if args.feedback else "")
          + f" to {summary['path']}", file=sys.stderr)
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = ArgumentParser(prog="python -m eval.predict", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True, help="dataset folder (make synth / pipelines.designs output)")
    ap.add_argument("--model", required=True, help=f"one of: {', '.join(MODEL_CHOICES)}")
    ap.add_argument("--out", required=True, help="predictions file to write (JSONL)")
    ap.add_argument("--split", default="test", choices=SPLITS, help="default: test")
    ap.add_argument("--tasks", default=",".join(TASKS), help="comma-separated tasks (default: selection,pose)")
    ap.add_argument("--seed", type=int, default=0, help="seed of baseline:random (default 0)")
    ap.add_argument("--limit", type=int, help="answer only N steps, spread evenly over the split")
    ap.add_argument("--feedback", action="store_true", help="revise failed pose answers with world feedback")
    ap.add_argument("--ldraw", help="with --feedback: the LDraw library the feedback renders draw parts from "
                    "(default: the one the dataset was built with)")
    ap.add_argument("--static-feedback", action="store_true",
                    help="with --feedback: draw the prediction where it was put, without executing it in the simulator")
    ap.add_argument("--max-new-tokens", type=int, default=256, help="hf: longest answer in tokens (default 256)")
    ap.add_argument("--device", help="hf: torch device (default: cuda when available, else cpu)")
    add_progress_flag(ap)
    args = ap.parse_args(argv)
    return run_guarded(lambda: run(args), {DatasetError: 2, ModelSpecError: 2, CheckpointError: 2})


if __name__ == "__main__":
    sys.exit(main())
