"""Score a predictions file against a dataset split: BC-Bench metrics in strict, paper and bc modes.

`python -m eval.score --data OUT --pred preds.jsonl [--split test] [--mode strict|paper|bc|both|all] [--json]`

`strict` and `paper` are ours (`eval.metrics`); `bc` reproduces BC-Bench's released scorer
(`eval.bc`: its definitions, and the released scripts' bugs with the choice made for each);
`both` is strict and paper, `all` the three.

The predictions file is what `eval.predict` writes: one JSON object per line,
``{"id": step id, "task": "selection" | "pose", "text": answer}``, and optionally
``"revised": true`` on a pose answer given after world feedback. Blank lines are skipped. A line
that is not such an object, names an unknown task or a step id not in the split, or repeats an
(id, task) (or a revised pose) is an error naming the file and line (exit 2): a file that silently
scores fewer answers than it holds would misreport a model. Steps without an answer count as wrong
(`eval.metrics.score` counts them in ``missing_predictions``).

Output (the same shape for every `--mode`, so callers need no special case): a dict keyed by mode
(``strict``, ``paper``, ``bc``), each the `eval.metrics.score` result (`eval.bc.score_bc` for bc) (``overall``,
``best_object``, ``counts``, ``mode``; rates are fractions in [0, 1], errors in LDU and degrees),
plus ``split``, and ``notes`` when the dataset itself limits what the scores mean (an imported
BC-Bench set scored without part symmetry: `dataset_notes`). When the file holds revised answers, ``feedback`` holds the same metrics by mode
over the answers after revision: a revised step is scored with its revised pose (and its original
selection); a step that was not revised keeps its original answers (a right answer, or one that
does not parse, gets no feedback: `eval.feedback`). ``feedback.revised_steps`` counts revised
steps, ``feedback.fixed[mode]`` those of them that fail with the original pose and succeed with
the revised one.
Without `--json`, a short table is printed instead.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from eval.bc import MODE as BC_MODE
from eval.bc import score_bc, score_pose
from eval.data import SPLITS, DatasetError, info, load_targets
from eval.metrics import MODES, score, score_step
from factory.cli import ArgumentParser, run_guarded
from factory.dataset.tasks import TASKS
from factory.jsonl import json_objects

SCORE_MODES = (*MODES, BC_MODE)
"""Every scoring mode: ours (`eval.metrics`: strict, paper) and BC-Bench's released scorer (`eval.bc`)."""
MODE_CHOICES = (*SCORE_MODES, "both", "all")
"""`both`: strict and paper; `all`: strict, paper and bc."""


class PredictionsError(ValueError):
    """A predictions file that cannot be scored as written."""


def read_predictions(path, step_ids) -> tuple[dict, dict]:
    """(answers {(id, task): text}, revised pose answers {id: text}) of a predictions file.

    Every line is checked against the rules of the module docstring; the first bad one raises
    `PredictionsError` naming ``path:line``.
    """
    path = Path(path)
    if not path.is_file():
        raise PredictionsError(f"{path}: no such predictions file")
    known = set(step_ids)
    answers: dict[tuple[str, str], str] = {}
    revised: dict[str, str] = {}
    revised_line: dict[str, str] = {}
    for where, rec in json_objects(path, PredictionsError, ("id", "task", "text"),
                                   "a JSON object with id, task and text"):
        sid, task, text = rec["id"], rec["task"], rec["text"]
        if not isinstance(sid, str):
            raise PredictionsError(f"{where}: id must be a string, got {sid!r}")
        if task not in TASKS:
            raise PredictionsError(f"{where}: unknown task {task!r}; valid: {', '.join(TASKS)}")
        if not isinstance(text, str):
            raise PredictionsError(f"{where}: text must be a string, got {type(text).__name__}")
        if sid not in known:
            raise PredictionsError(f"{where}: step id {sid!r} is not in the split")
        is_revised = rec.get("revised", False)
        if is_revised not in (True, False):
            raise PredictionsError(f"{where}: revised must be true or false, got {is_revised!r}")
        if is_revised:
            if task != "pose":
                raise PredictionsError(f"{where}: only pose answers are revised, got task {task!r}")
            if sid in revised:
                raise PredictionsError(f"{where}: second revised pose for {sid!r}")
            revised[sid], revised_line[sid] = text, where
        else:
            if (sid, task) in answers:
                raise PredictionsError(f"{where}: second {task} answer for {sid!r}")
            answers[(sid, task)] = text
    for sid, where in revised_line.items():
        if (sid, "pose") not in answers:
            raise PredictionsError(f"{where}: revised pose for {sid!r} without an original pose answer")
    return answers, revised


def _modes(mode: str) -> tuple[str, ...]:
    if mode not in MODE_CHOICES:
        raise PredictionsError(f"unknown mode {mode!r}; valid: {', '.join(MODE_CHOICES)}")
    return {"both": MODES, "all": SCORE_MODES}.get(mode, (mode,))


def _score(steps, answers: dict, mode: str) -> dict:
    return score_bc(steps, answers) if mode == BC_MODE else score(steps, answers, mode)


def _succeeds(step, selection, pose, mode: str) -> bool:
    if mode == BC_MODE:  # BC-Bench's step success reads the pose only
        return pose is not None and score_pose(step, pose).ok
    return score_step(step, selection, pose, mode).success


def score_predictions(steps, answers: dict, revised: dict | None = None, mode: str = "both") -> dict:
    """Metrics by mode of `answers` {(id, task): text} over `steps` (`StepTarget`s), and with
    `revised` {id: revised pose text} a ``feedback`` section (see the module docstring); revised
    answers of ids not in `steps` are ignored, as `eval.metrics.score` ignores such answers."""
    modes = _modes(mode)
    result: dict = {m: _score(steps, answers, m) for m in modes}
    by_id = {s.id: s for s in steps}
    revised = {sid: text for sid, text in (revised or {}).items() if sid in by_id}
    if revised:
        after = {**answers, **{(sid, "pose"): text for sid, text in revised.items()}}
        fixed = {}
        for m in modes:
            fixed[m] = sum(
                not _succeeds(by_id[sid], answers.get((sid, "selection")), answers.get((sid, "pose")), m)
                and _succeeds(by_id[sid], answers.get((sid, "selection")), text, m)
                for sid, text in revised.items())
        result["feedback"] = {"revised_steps": len(revised), "fixed": fixed,
                              **{m: _score(steps, after, m) for m in modes}}
    return result


def dataset_notes(data) -> list[str]:
    """What a reader of the scores must know about the dataset itself: an imported BC-Bench set
    without an LDraw library has no part symmetry, so a turned answer that is right for a
    symmetric part scores as wrong (`pipelines.bcbench`)."""
    imported = info(data).details.get("bcbench_import") or {}
    symmetry = str(imported.get("symmetry", ""))
    if symmetry.startswith("none"):
        return [f"parts scored without symmetry: {symmetry} (import again with --ldraw DIR to score with it)"]
    return []


def score_file(data, pred_path, split: str | None = "test", mode: str = "both",
               only_predicted: bool = False) -> dict:
    """Score a predictions file against `split` (None: every split) of the dataset folder `data`.

    Steps with no answer count as wrong; with `only_predicted` the steps scored are those the file
    answers (for a `--limit`ed prediction run), and the result says how many of the split's that is.
    """
    _modes(mode)  # a bad mode fails before the dataset is read
    steps = load_targets(data, split)
    answers, revised = read_predictions(pred_path, [s.id for s in steps])
    n_split = len(steps)
    if only_predicted:
        answered = {sid for sid, _task in answers}
        steps = [s for s in steps if s.id in answered]
    notes = dataset_notes(data)
    return {"split": split, "split_steps": n_split, "scored_steps": len(steps),
            **score_predictions(steps, answers, revised, mode), **({"notes": notes} if notes else {})}


def _fmt(v, spec: str) -> str:
    return "-" if v is None else format(v, spec)


def format_table(result: dict) -> str:
    """A short human-readable summary of a `score_file` result."""
    modes = [m for m in SCORE_MODES if m in result]
    first = result[modes[0]]["counts"]
    lines = [(f"split {result.get('split') or 'all'}: {first['steps']} steps of {first['objects']} objects; "
              f"missing answers {first['missing_predictions']}, unparseable {first['unparseable']}")]
    head = f"{'':<24}{'selection':>10}{'step ok':>10}{'transl LDU':>12}{'rot deg':>10}"

    def block(res: dict, title: str) -> list[str]:
        out = [title, head]
        for m in modes:
            for label, row in (("overall", res[m]["overall"]), ("best object", res[m]["best_object"])):
                out.append(f"{m + ' ' + label:<24}{_fmt(row['selection_accuracy'], '.3f'):>10}"
                           f"{_fmt(row['step_success'], '.3f'):>10}{_fmt(row['translation_error_ldu'], '.2f'):>12}"
                           f"{_fmt(row['rotation_error_deg'], '.2f'):>10}")
        return out

    lines += [f"note: {n}" for n in result.get("notes", ())]
    lines += block(result, "")
    fb = result.get("feedback")
    if fb:
        fixed = ", ".join(f"{m} {fb['fixed'][m]}" for m in modes)
        lines += block(fb, f"\nafter world feedback ({fb['revised_steps']} steps revised; fixed: {fixed})")
    return "\n".join(line for line in lines if line != "")


def _finite(value):
    """`value` with every non-finite float as None: JSON has no Infinity or NaN (an error too large
    for a float, say from a translation of 1e300 LDU, is written null)."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def run(args) -> int:
    result = score_file(args.data, args.pred, args.split, args.mode, only_predicted=args.only_predicted)
    if args.json:
        print(json.dumps(_finite(result), indent=1, sort_keys=True, allow_nan=False))
    else:
        print(format_table(result))
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = ArgumentParser(prog="python -m eval.score", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True, help="dataset folder")
    ap.add_argument("--pred", required=True, help="predictions file (JSONL, eval.predict's output)")
    ap.add_argument("--split", default="test", choices=SPLITS, help="default: test")
    ap.add_argument("--mode", default="both", choices=MODE_CHOICES, help="strict, paper (ours), bc (BC-Bench's released scorer), both (strict and paper) or all "
                         "(default: both)")
    ap.add_argument("--json", action="store_true", help="print the metrics as JSON")
    ap.add_argument("--only-predicted", action="store_true",
                    help="score only the steps the file answers (after `eval.predict --limit`); default: "
                         "every step of the split, missing answers counted wrong")
    args = ap.parse_args(argv)
    return run_guarded(lambda: run(args), {DatasetError: 2, PredictionsError: 2})


if __name__ == "__main__":
    sys.exit(main())
