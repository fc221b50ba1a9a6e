"""`python -m train.recipe`: the paper's staged recipe (Brick-Composer) as one command.

    python -m train.recipe --designs DESIGNS --synthetic SYNTH --outdir RUN [--model PATH]
        [--stage-steps 200,100,200] [--feedback-weights 1,1] [--synthetic-weights 1,1,1]
        [--feedback-limit N] [--eval-limit N] [any `python -m train` setting: --lr, --batch-size, ...]

1. **Designer supervision**: train on the train split of the human designs (DESIGNS, `python -m
   pipelines.designs` output) from MODEL (or, without it, a tiny model built from a config as
   `python -m train` builds it).
2. **+ World feedback**: stage 1's model answers the pose task on the designs' *train* split
   (`eval.predict`); each answer that parses and fails its step in paper mode becomes a
   correction row (the wrong answer drawn in red, the revision prompt, the right answer:
   `pipelines.feedback`, written by the dataset builder into RUN/feedback/data). Stage 2 trains
   on the designs and those rows, mixed by `feedback_weights`, from stage 1's final weights. When
   the stage-1 model gives no such answer (all right, or none that parses) there are no rows:
   stage 2 is skipped, said so in the output and the report, and stage 3 starts from stage 1.
3. **+ Synthetic experience**: the designs, the feedback rows and the synthetic data (SYNTH,
   `make synth` output), mixed by `synthetic_weights`, from stage 2's final weights.

Each stage is a `python -m train` run (`train.loop.train`, its own warmup and decay, LoRA or full
fine-tuning as `--lora` says for every stage) in RUN/stage1, RUN/stage2, RUN/stage3. The model
before and after each stage (the base model, then each stage's `final/`) answers the test split
of the designs and of the synthetic data (those that have one; `--eval-limit` steps of each) and
is scored by `eval.score` in strict and paper mode (RUN/eval/). RUN/report.json and RUN/report.md
hold, per stage, its data, weights, steps, starting model, training summary and the metrics
before and after on each test split.

Re-running the same command resumes: finished stages (their `final/` at their step count, made
under the same settings), predictions, feedback shards and evaluations are kept and skipped, and an
interrupted stage continues from its last checkpoint (`train.loop`). Other settings in an existing
RUN are refused, listing the differences (output-only settings may change).
"""

from __future__ import annotations

import argparse
import gc
import json
import sys
from dataclasses import dataclass, replace
from pathlib import Path

from eval.data import DatasetError, library, shard_files
from eval.predict import write_predictions
from eval.score import PredictionsError, score_file
from factory.atomic import write_atomic
from factory.cli import ArgumentParser, add_config_args, add_progress_flag, run_guarded
from factory.config import config_from_dict, config_to_dict, field_docs
from pipelines.feedback import build_feedback
from train.config import ConfigError, TrainConfig, lora_value, resume_conflicts
from train.distributed import launched_processes
from train.evaluate import trained_predictor
from train.loop import FINAL, base_model_path, final_step, resolve_device, train as run_training
from train.model import ModelError
from train.report import SUMMARY_FILE

CONFIG_FILE = "recipe_config.json"
REPORT_JSON = "report.json"
REPORT_MD = "report.md"
STAGES = ("designer supervision", "+ world feedback", "+ synthetic experience")
"""The stages' names, in order."""
PER_STAGE = ("train.data", "train.outdir", "train.weights", "train.steps", "train.eval", "train.eval_split",
             "train.lora")
"""`TrainConfig` fields the recipe sets per stage (not flags; `--lora` takes auto too)."""


@dataclass(frozen=True)
class RecipeConfig:
    """Everything that decides a staged run (see the module docstring)."""

    designs: str
    """Dataset folder of human designs (`python -m pipelines.designs` output): stage 1 trains on its
    train split, stage 1's model answers that split for the feedback rows, every stage trains on it,
    and its test split (if any) scores every stage."""
    synthetic: str
    """Synthetic dataset folder (`make synth` output): added in stage 3; its test split (if any)
    scores every stage."""
    outdir: str
    """The recipe's folder: stage1/, stage2/, stage3/ (training runs), feedback/ (stage 1's answers
    and the correction rows), eval/ (predictions and scores), report.json, report.md."""
    train: TrainConfig
    """The training settings of every stage (`python -m train`'s flags), as stage 1 runs them (its
    data, weights, folder and steps are set from the fields here: the designs, none, RUN/stage1,
    the first of `stage_steps`; no evaluation of its own). Stages 2 and 3 run the same settings with
    their own data, weights, steps, starting model and folder. `eval_limit` and `max_new_tokens`
    apply to the recipe's evaluations and to stage 1's answers for the feedback rows."""
    stage_steps: tuple[int, ...] = (200, 100, 200)
    """Optimizer steps of stages 1, 2 and 3."""
    feedback_weights: tuple[float, ...] = (1.0, 1.0)
    """Stage 2's sampling weights of the designs and the feedback rows (`TrainConfig.weights`)."""
    synthetic_weights: tuple[float, ...] = (1.0, 1.0, 1.0)
    """Stage 3's sampling weights of the designs, the feedback rows and the synthetic data (without
    feedback rows: the first and last)."""
    feedback_limit: int | None = None
    """Steps of the designs' train split that stage 1's model answers for the feedback rows, spread
    evenly over the split (None: every step)."""
    ldraw: str | None = None
    """The LDraw library the feedback rows' renders draw the designs' parts from (None: the folder
    the designs were built with; give the same library's folder when the designs were built on
    another machine)."""

    def __post_init__(self):
        object.__setattr__(self, "stage_steps", tuple(int(s) for s in self.stage_steps))
        if len(self.stage_steps) != 3 or min(self.stage_steps) < 1:
            raise ConfigError(f"stage_steps: three step counts >= 1 (stages 1, 2, 3), got {self.stage_steps!r}")
        if "pose" not in self.train.tasks:
            raise ConfigError("tasks: the recipe needs the pose task (world feedback corrects pose answers)")
        # `train` is stage 1's run, whatever data, folder and steps it was given
        object.__setattr__(self, "train", replace(self.train, data=(self.designs,), weights=(), eval=False,
                                                  outdir=str(Path(self.outdir) / "stage1"), steps=self.stage_steps[0]))
        for name, n in (("feedback_weights", 2), ("synthetic_weights", 3)):
            w = getattr(self, name)
            if len(w) != n or not all(0 < float(x) < float("inf") for x in w):
                raise ConfigError(f"{name}: {n} weights > 0, got {w!r}")
        if self.feedback_limit is not None and self.feedback_limit < 1:
            raise ConfigError(f"feedback_limit must be >= 1 (or None for all), got {self.feedback_limit!r}")

    def to_dict(self) -> dict:
        return config_to_dict(self)

    @classmethod
    def from_dict(cls, d: dict) -> RecipeConfig:
        return config_from_dict(cls, d, ConfigError)

    # -- the stages ----------------------------------------------------------------------------------
    @property
    def run(self) -> Path:
        return Path(self.outdir)

    @property
    def feedback_data(self) -> Path:
        """The folder of the correction rows (a dataset folder)."""
        return self.run / "feedback" / "data"

    def stage(self, k: int, start: str | None, feedback: bool = True) -> TrainConfig:
        """Stage `k`'s (1-3) training config, from model `start` (None: stage 1's base); `feedback`:
        whether the correction rows exist (stage 3 leaves them out otherwise)."""
        data, weights = (self.designs,), ()
        if k == 2:
            data, weights = (self.designs, str(self.feedback_data)), self.feedback_weights
        elif k == 3:
            d, f, s = self.synthetic_weights
            data, weights = (((self.designs, str(self.feedback_data), self.synthetic), (d, f, s)) if feedback
                             else ((self.designs, self.synthetic), (d, s)))
        return replace(self.train, data=data, weights=tuple(float(w) for w in weights), steps=self.stage_steps[k - 1],
                       model=start if k > 1 else self.train.model, outdir=str(self.run / f"stage{k}"), eval=False)


def recipe_config(designs, synthetic, outdir, settings: dict | None = None, **fields) -> RecipeConfig:
    """A `RecipeConfig` of plain values: folders made absolute, `settings` the `TrainConfig` fields
    the stages share (`lora` defaults as the command line's auto: LoRA for a given model, else full
    fine-tuning), `fields` further `RecipeConfig` fields."""
    designs, synthetic, outdir = (str(Path(p).resolve()) for p in (designs, synthetic, outdir))
    settings = dict(settings or {})
    if settings.get("model"):
        settings["model"] = str(Path(settings["model"]).resolve())
    settings.setdefault("lora", bool(settings.get("model")))
    first = TrainConfig(data=(designs,), outdir=str(Path(outdir) / "stage1"), **settings)
    return RecipeConfig(designs, synthetic, outdir, first, **fields)


def recipe_conflicts(saved: RecipeConfig, new: RecipeConfig) -> list[str]:
    """'field: saved -> new' for each difference that forbids resuming `saved`'s folder."""
    a, b = saved.to_dict(), new.to_dict()
    out = [f"{k}: {a[k]!r} -> {b[k]!r}" for k in sorted(a) if k != "train" and a[k] != b[k]]
    return out + [f"train.{c}" for c in resume_conflicts(saved.train, new.train)]


# -- the run -----------------------------------------------------------------------------------------
def check_inputs(recipe: RecipeConfig) -> dict[str, str]:
    """Both folders are datasets with a train split; returns {name: folder} of the test splits
    that score the stages (at least one)."""
    for name in ("designs", "synthetic"):
        folder = getattr(recipe, name)
        if not Path(folder).is_dir():
            raise DatasetError(f"--{name} {folder}: no such folder")
        try:
            shard_files(folder, "train")
        except DatasetError as exc:
            raise DatasetError(f"--{name}: {exc} (every stage trains on the train split)") from None
    tests = {}
    for name in ("designs", "synthetic"):
        try:
            shard_files(getattr(recipe, name), "test")
            tests[name] = getattr(recipe, name)
        except DatasetError:
            continue
    if not tests:
        raise DatasetError(f"neither {recipe.designs} nor {recipe.synthetic} has a test split: nothing to "
                           "evaluate the stages on")
    library(recipe.designs, recipe.ldraw)  # the feedback renders need it: say so now, not after stage 1
    return tests


def check_folder(recipe: RecipeConfig) -> None:
    """Refuse a recipe folder made under other settings; record the settings in a new one."""
    path = recipe.run / CONFIG_FILE
    if path.is_file():
        saved = RecipeConfig.from_dict(json.loads(path.read_text()))
        conflicts = recipe_conflicts(saved, recipe)
        if conflicts:
            raise ConfigError(f"{recipe.run} holds a recipe run made with other settings, which cannot be resumed "
                              "with these: " + "; ".join(conflicts) + ". Use the same settings, or another --outdir.")
    _write_json(path, recipe.to_dict())


def stage_done(config: TrainConfig) -> bool:
    """Whether the run folder of `config` holds its final model, trained to its step count under
    the same settings."""
    final = Path(config.outdir) / FINAL
    if final_step(final) != config.steps:
        return False
    try:
        saved = TrainConfig.load(final)
    except (OSError, ValueError, KeyError, ConfigError):
        return False
    return not resume_conflicts(saved, config)


def _same(path: Path, key: dict) -> bool:
    try:
        return json.loads(path.read_text()).get("key") == key
    except (OSError, ValueError):
        return False


def _write_json(path: Path, obj) -> None:
    write_atomic(path, (json.dumps(obj, indent=1, sort_keys=True) + "\n").encode())


def _weights_id(model: Path) -> list:
    """The model folder's weight files as (name, bytes, mtime in ns): a folder trained again (a
    new `final/` renamed into place) gives another id, so its answers are made again."""
    files = sorted(f for f in Path(model).iterdir() if f.suffix in (".safetensors", ".bin")) if Path(model).is_dir() else []
    return [[f.name, f.stat().st_size, f.stat().st_mtime_ns] for f in files]


def _answers_key(recipe: RecipeConfig, model: Path, data: str, tasks, limit) -> dict:
    """What decides `model`'s answers on `data`: kept files made under another key are made again."""
    return {"model": str(model), "weights": _weights_id(model), "data": str(data), "tasks": list(tasks),
            "limit": limit, "max_new_tokens": recipe.train.max_new_tokens, "max_pixels": recipe.train.max_pixels}


def answers(recipe: RecipeConfig, model: Path, data: str, split: str, out: Path, tasks, limit, device,
            progress: bool) -> Path:
    """Predictions of `model` on `split` of `data` into `out` (kept when made by the same model
    on the same steps: `out`.key.json)."""
    key = {**_answers_key(recipe, model, data, tasks, limit), "split": split}
    marker = out.with_name(out.name + ".key.json")
    if out.is_file() and _same(marker, key):
        return out
    predictor = trained_predictor(model, recipe.train, device)
    write_predictions(data, predictor, out, split=split, tasks=tasks, limit=limit, progress=progress)
    del predictor
    gc.collect()
    _write_json(marker, {"key": key})
    return out


def evaluation(recipe: RecipeConfig, name: str, model: Path, tests: dict[str, str], device, progress: bool,
               log) -> dict:
    """{test split name: eval.score result (strict and paper)} of `model`, kept in RUN/eval/."""
    out = {}
    limit = recipe.train.eval_limit
    for test, data in tests.items():
        preds = recipe.run / "eval" / f"{name}-{test}.jsonl"
        scored = preds.with_suffix(".score.json")
        key = _answers_key(recipe, model, data, recipe.train.tasks, limit)
        if not _same(scored, key):
            log(f"evaluating {name} ({model}) on the test split of {test}")
            answers(recipe, model, data, "test", preds, recipe.train.tasks, limit, device, progress)
            _write_json(scored, {"key": key, "score": score_file(data, preds, "test", "both",
                                                                  only_predicted=limit is not None)})
        out[test] = json.loads(scored.read_text())["score"]
    return out


def feedback_rows(recipe: RecipeConfig, model: Path, device, progress: bool, log) -> dict:
    """Stage 1's model answers the pose task on the designs' train split; its wrong answers become
    the correction dataset RUN/feedback/data. Returns that dataset's info.json (with `reasons`)."""
    preds = recipe.run / "feedback" / "preds_train.jsonl"
    log(f"stage 1's model answers the pose task on the train split of {recipe.designs}")
    answers(recipe, model, recipe.designs, "train", preds, ("pose",), recipe.feedback_limit, device, progress)
    log(f"building the world-feedback rows from its wrong answers into {recipe.feedback_data}")
    meta = build_feedback(recipe.designs, preds, recipe.feedback_data, "train", progress=progress, ldraw=recipe.ldraw)
    meta["predictions_file"] = str(preds)
    return meta


def _train_summary(run: Path) -> dict:
    try:
        s = json.loads((run / SUMMARY_FILE).read_text())
    except (OSError, ValueError):
        return {}
    return {k: s.get(k) for k in ("steps", "examples", "epochs", "first_loss", "final_loss", "train_seconds",
                                  "samples_per_s", "skipped_too_long")}


def run_recipe(recipe: RecipeConfig, progress: bool = True, log=None) -> dict:
    """Run or resume every stage of `recipe` (see the module docstring); returns the report."""
    log = log or (lambda text: print(f"[recipe] {text}", flush=True))
    tests = check_inputs(recipe)
    recipe.run.mkdir(parents=True, exist_ok=True)
    check_folder(recipe)
    device = resolve_device(recipe.train)
    start = base_model_path(recipe.train, progress)  # stage 1's starting model (a tiny one is built first)
    report = {"recipe": recipe.to_dict(), "test_splits": tests, "stages": [], "feedback": None}
    current = "base"  # the name of the evaluation of `start`
    evals = {current: evaluation(recipe, current, start, tests, device, progress, log)}
    has_feedback = True
    for k in (1, 2, 3):
        name = f"stage{k}"
        entry = {"stage": k, "name": STAGES[k - 1], "model_before": str(start)}
        if k == 2:
            meta = feedback_rows(recipe, start, device, progress, log)
            report["feedback"] = {key: meta.get(key) for key in ("predictions_file", "reasons", "total")}
            rows = meta["total"]["steps"]
            log(f"{rows} world-feedback rows ({', '.join(f'{r} {n}' for r, n in meta['reasons'].items())})")
            if not rows:
                has_feedback = False
                why = ("stage 1's model gave no wrong pose answer that parses (pose answers: "
                       + (", ".join(f"{r} {n}" for r, n in meta["reasons"].items()) or "none") + ")")
                log(f"stage 2/3 ({STAGES[1]}) skipped: {why}; stage 3 starts from stage 1's model, without "
                    "feedback rows")
                report["stages"].append({**entry, "status": "skipped", "reason": why, "model_after": str(start),
                                         "metrics": {t: {"before": evals[current][t], "after": evals[current][t]}
                                                     for t in tests}})
                continue
        config = recipe.stage(k, str(start), has_feedback)
        entry.update(data=list(config.data), weights=list(config.weights), steps=config.steps,
                     outdir=config.outdir)
        if stage_done(config):
            log(f"stage {k}/3 ({STAGES[k - 1]}): done ({Path(config.outdir) / FINAL})")
            entry["status"] = "done"
        else:
            log(f"stage {k}/3 ({STAGES[k - 1]}): {config.steps} steps on {', '.join(config.data)}"
                + (f" (weights {', '.join(f'{w:g}' for w in config.weights)})" if config.weights else "")
                + f" from {start}")
            run_training(config, progress=progress)
            entry["status"] = "trained"
        start = Path(config.outdir) / FINAL
        evals[name] = evaluation(recipe, name, start, tests, device, progress, log)
        entry.update(model_after=str(start), train=_train_summary(Path(config.outdir)),
                     metrics={t: {"before": evals[current][t], "after": evals[name][t]} for t in tests})
        current = name
        report["stages"].append(entry)
        log(f"stage {k}/3 after: " + "; ".join(f"{t} {_headline(evals[name][t])}" for t in tests))
    _write_json(recipe.run / REPORT_JSON, report)
    write_atomic(recipe.run / REPORT_MD, markdown(report).encode())
    log(f"report: {recipe.run / REPORT_MD}")
    return report


METRICS = (("selection", "selection_accuracy", "selection", ".3f"), (None, "step_success", "step success", ".3f"),
           ("pose", "translation_error_ldu", "translation LDU", ".2f"),
           ("pose", "rotation_error_deg", "rotation deg", ".2f"))
"""The overall metrics of `eval.score` in the report's table: the task they need (None: any), key,
heading, format."""


def _overall(score: dict, mode: str) -> dict:
    return ((score or {}).get(mode) or {}).get("overall") or {}


def _headline(score: dict) -> str:
    o = _overall(score, "paper")
    sel, ok = o.get("selection_accuracy"), o.get("step_success")
    return (f"selection {'-' if sel is None else f'{sel:.3f}'}, step success "
            f"{'-' if ok is None else f'{ok:.3f}'} (paper)")


def markdown(report: dict) -> str:
    """The report as a markdown table: per stage and test split, each metric before -> after."""
    lines = ["# Staged recipe", ""]
    fb = report.get("feedback")
    if fb:
        reasons = ", ".join(f"{k} {v}" for k, v in (fb.get("reasons") or {}).items()) or "none"
        lines += [f"World feedback: {fb['total']['steps']} correction rows from stage 1's answers on the designs' "
                  f"train split (pose answers: {reasons}).", ""]
    tasks = report["recipe"]["train"]["tasks"]
    shown = [(key, head, spec) for task, key, head, spec in METRICS if task is None or task in tasks]
    lines += ["| stage | status | test split | mode | " + " | ".join(h for _, h, _ in shown) + " |",
              "|" + "---|" * (4 + len(shown))]
    for s in report["stages"]:
        for test, m in (s.get("metrics") or {}).items():
            for mode in ("strict", "paper"):
                cells = []
                for key, _, spec in shown:
                    a, b = _overall(m["before"], mode).get(key), _overall(m["after"], mode).get(key)
                    cells.append(f"{'-' if a is None else format(a, spec)} → {'-' if b is None else format(b, spec)}")
                lines.append(f"| {s['stage']} {s['name']} | {s['status']} | {test} | {mode} | " + " | ".join(cells) + " |")
    lines += ["", "Each cell: the model before the stage → after it (`eval.score` overall: the mean over objects).", ""]
    for s in report["stages"]:
        if s["status"] == "skipped":
            lines.append(f"- stage {s['stage']} skipped: {s['reason']}")
            continue
        t = s.get("train") or {}
        lines.append(f"- stage {s['stage']} ({s['name']}): {s['steps']} steps on "
                     + ", ".join(f"`{d}`" + (f" (weight {w:g})" if s["weights"] else "")
                                 for d, w in zip(s["data"], s["weights"] or [None] * len(s["data"])))
                     + f" from `{s['model_before']}`; loss {t.get('first_loss')} → {t.get('final_loss')}")
    return "\n".join(lines) + "\n"


# -- the command line ------------------------------------------------------------------------------
def parser() -> argparse.ArgumentParser:
    """A flag per `RecipeConfig` field and per `TrainConfig` field the stages share
    (`factory.cli.add_config_args`), `--lora 1|0|auto`."""
    ap = ArgumentParser(prog="python -m train.recipe", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    add_config_args(ap, RecipeConfig, skip=PER_STAGE)
    ap.add_argument("--lora", dest="train.lora", type=lora_value, default="auto", metavar="1|0|auto",
                    help=field_docs(TrainConfig)["lora"] + " The same for every stage. (default: auto)")
    add_progress_flag(ap)
    return ap


def config_from_args(args) -> RecipeConfig:
    """The `RecipeConfig` of parsed arguments (folders made absolute)."""
    settings = {k[len("train."):]: v for k, v in vars(args).items() if k.startswith("train.")}
    if settings["lora"] == "auto":
        del settings["lora"]
    return recipe_config(args.designs, args.synthetic, args.outdir, settings, stage_steps=args.stage_steps,
                         feedback_weights=args.feedback_weights, synthetic_weights=args.synthetic_weights,
                         feedback_limit=args.feedback_limit,
                         ldraw=str(Path(args.ldraw).resolve()) if args.ldraw else None)


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)

    def run() -> int:
        if launched_processes() > 1:
            raise ConfigError(f"python -m train.recipe runs in one process (this is one of {launched_processes()} "
                              "under torchrun): its stages predict and evaluate between trainings; run it with "
                              "python -m train.recipe, or each stage's training with torchrun -m train")
        run_recipe(config_from_args(args), progress=not args.no_progress)
        return 0

    return run_guarded(run, {ConfigError: 2, DatasetError: 2, ModelError: 2, PredictionsError: 2})


if __name__ == "__main__":
    sys.exit(main())
