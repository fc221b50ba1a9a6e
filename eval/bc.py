"""The ``bc`` scoring mode: BC-Bench's released evaluation scripts, reproduced on our targets.

BC-Bench's published tables were made with its released scripts (Lumos-Jiateng/Brick-Composer,
``reasoning/MLLM_Brick_Selection/evaluate.py`` and ``eval_test_split.py``;
``reasoning/MLLM_Brick_Pose_Estimation/pose_metrics.py``, ``evaluate_assembly.py``,
``compute_success_rate.py``, ``reeval_with_symmetry.py``, ``aggregate_by_object.py``), whose
definitions differ from the paper's text. This module scores our predictions by those
definitions, so that our numbers can be set beside the published ones. It was written from
reading the scripts; none of their code is copied. Answers are read with our parsers
(`eval.parse`: reasoning removed, tolerant wording), not the scripts' regular expressions
(bugs 3 and 5 below).

Definitions (script in brackets):

- Step kind [evaluate.py]: a step with more than one target brick is a *module* step, else a
  *single* step. (The scripts look for a ground-truth label starting ``module "``; our targets
  carry no label, and a module is the only kind of step that places several bricks.) A step
  with no target brick is blank and skipped by every metric, as the scripts skip blank steps.
- Names [evaluate.py]: the predicted names are the part labels of the parsed picks, in answer
  order; a pick without a label adds no name. Names are compared as the scripts compare them:
  case-insensitively, whole name for whole name, both sides in `eval.parse.normalise_part`'s
  form (``3023.DAT`` and ``3023`` are ``3023.dat``); target names are `BrickTarget.part`. Colour
  is not part of a name.
- Single step selection [evaluate.py]: right when the *first* name equals the target's name OR
  the *first* picked cell is one of the target's equivalent cells (`BrickTarget.cells`). The
  first name and the first cell are taken independently, as the script reads them.
- Module step selection [evaluate.py]: right when the multiset of names equals the multiset of
  target names (order free, counts matter) OR *any* picked cell is an equivalent cell of *any*
  target brick. Multiset recall, precision and F1 of names are reported too (precision 0 when
  no name was given).
- Selection aggregation [evaluate.py, eval_test_split.py]: micro over steps, single and module
  steps apart (``selection``); ``overall.selection_accuracy`` is the micro rate over both
  (the scripts print no combined rate; this is their two rates weighted by their step counts).
- Brick pose [compute_success_rate.py, aggregate_by_object.py]: the per-axis offsets
  ``pred - gt`` are rounded to 4 decimals (Python's ``round``), then each must be within 10 LDU,
  inclusive: 10.00004 rounds to 10.0 and passes, 10.0001 fails. The rotation error is the
  geodesic angle minimised over the part's symmetries (`eval.metrics.rotation_error_deg`, on
  ``R_gt @ S`` as the scripts do), right when under 45 degrees (exclusive; 1e-9 of numeric
  slack below, as in `eval.metrics`). The translation error is the Euclidean distance, unrounded.
- Step success [compute_success_rate.py, aggregate_by_object.py]: every target brick's pose is
  right. The pose only: the selection answer plays no part.
- Pose answers to bricks [pose_metrics.py]: ``Brick N`` answers target brick N (`eval.parse`).
  For a single-brick step, an answer without block 1 that has another block uses its first
  block: the script reads a single-brick answer whole, headers or not.
- Unparseable and missing answers: a selection answer with no pick fails its step [evaluate.py];
  a pose answer for which no target brick got a pose is dropped from the per-object macro
  [aggregate_by_object.py] but fails in the micro success rate [compute_success_rate.py]; a
  pose answer that gives some bricks and not others is kept and fails in both. A step with no
  answer (key absent or None) leaves every denominator of its task, as the scripts drop steps
  with no result file [eval_test_split.py] or no model answer [evaluate_assembly.py]. Counted in
  ``counts``: ``missing_predictions``, ``dropped_pose_steps``, ``skipped_blank``.
- Pose aggregation, ``overall`` and ``best_object`` [aggregate_by_object.py]: a step's errors are
  the means over its bricks with a pose; an object's errors and success are the means over its
  kept steps; ``overall`` is the mean over objects (macro; objects with no kept step leave it).
  ``best_object`` is the object with the highest step success, ties to the lower translation
  error, then the lower rotation error, then the object id (the script: folder order), with its
  own metrics and its own selection rate. ``best_per_metric`` is the script's printed "Best
  Value" column: each metric's best over objects taken separately, each naming its object.
- Micro pose aggregates: ``success_rate`` [compute_success_rate.py]: steps answered, correct
  steps, their rate; bricks of answered steps, bricks with a pose ("evaluable"), correct bricks,
  ``brick_success_rate = correct / evaluable``, and the failure breakdown of evaluable bricks.
  ``brick_errors`` [evaluate_assembly.py, reeval_with_symmetry.py]: mean and median translation
  and rotation errors over all bricks with a pose.

Bugs and quirks found in the released scripts, and the choice for each (R: reproduced, F: fixed):

1. R. Name OR cell decides a selection: a right name in a wrong cell, or a wrong name in a right
   cell, counts as a right selection. It is the published definition.
2. R. A module selection is right when any one cell is right, so an answer listing every
   catalog cell always passes. The published definition; `strict` matches cells to bricks.
3. F. The script reads names from every ``<word>.dat`` anywhere in the answer, prose included,
   and positions only as ``row R, col C`` (not ``column``, ``row=``, nor ``col C, row R``); a
   bare ``3023`` is no name. We read the picks `eval.parse.parse_selection` finds (a name only
   where it labels a cell), names normalised as above.
4. F. The rates of a step kind with no steps print as 0.0 (``_rate``, ``_avg``); here None.
5. F. A multi-brick pose answer is cut at ``Brick N:`` headers and the pieces are given to the
   bricks in the order written, the numbers ignored (a decorated header does not cut at all,
   and the whole step fails); each axis is the first ``x=`` anywhere in a piece and the
   rotation the first three bracketed triples, so ``t = [x, y, z]`` becomes a rotation row. We
   match blocks by number with `eval.parse.parse_pose`.
6. F. The rotation error is computed on the matrix as written, with the cosine clamped to
   [-1, 1], never checked to be a rotation: ``2 R_gt`` scores 0 degrees, and so can a
   reflection (``diag(1.5, 1.5, -0.5)`` against the identity scores 41.4 degrees and passes).
   Deliberate fix, the rule of `strict` and `paper` (`eval.metrics.judge_rotation`): a matrix
   with det < 0 is a mirrored answer, and one whose columns are not orthonormal within
   `eval.metrics.DEGENERATE_TOL` (singular, scaled, sheared, non-finite) a degenerate one; both
   are wrong whatever their angle, with rotation error 180 degrees (counted in
   ``mirrored_rotations``/``degenerate_rotations`` and ``failures``). Slightly-off rotations
   (printed with few decimals) are replaced by the nearest rotation and counted in
   ``projected_rotations``. Translation errors are capped at `eval.metrics.TRANSLATION_CAP_LDU`
   (``capped_translations``), as in `strict` and `paper`.
7. F. Symmetry groups are rebuilt from text metadata: a continuous symmetry becomes 360 turns of
   1 degree (the error overstated by up to 0.5 degrees), and then drops the part's other
   symmetries (e.g. a round part's flip); two or more "about" clauses add all three 180-degree
   flips whatever the axes. We use the part's own symmetry (`BrickTarget.symmetry`, continuous
   axes in closed form).
8. R, both ways. Steps where nothing parsed drop out of aggregate_by_object.py's denominator
   and fail in compute_success_rate.py's. ``overall`` and ``best_object`` follow
   aggregate_by_object.py (the one script that averages over objects and names a best object,
   as the published average and best-object columns do); ``success_rate`` follows
   compute_success_rate.py, so both figures are at hand.
9. R. compute_success_rate.py's brick rate divides by bricks whose translation parsed, not by
   all bricks (an unparsed brick fails its step but leaves the brick rate's denominator).
   ``success_rate`` keeps its definition
   and reports both counts, so the rate over all bricks can be read off.
10. F. compute_success_rate.py and reeval_with_symmetry.py key their per-object tables by
    ``result["object"]``, which pose results do not carry, so "per object" is per step; and
    compute_success_rate.py's per-object brick rate divides by all bricks where its overall
    rate divides by evaluable ones. Per-object figures here follow aggregate_by_object.py.
11. F. Aggregates are rounded to 4 decimals (per object before the macro mean); we keep full
    precision (a difference below 1e-4).
12. R. Steps with no answer are dropped (definitions above); `strict` and `paper` count them
    as wrong.
"""

from __future__ import annotations

import math
import statistics
from collections import Counter
from dataclasses import dataclass

import numpy as np

from eval.metrics import (
    BrickTarget,
    StepTarget,
    answer_text,
    count_bricks,
    judge_rotation,
    new_counts,
    translation_capped,
    translation_error,
)
from eval.parse import PoseAnswer, normalise_part, parse_pose, parse_selection

MODE = "bc"
T_LDU = 10.0
"""Per-axis translation threshold (inclusive) of compute_success_rate.py."""
R_DEG = 45.0
"""Rotation threshold (exclusive) of compute_success_rate.py."""
OFFSET_DECIMALS = 4
"""The released scripts round each per-axis offset to 4 decimals before the threshold test."""
_EPS = 1e-9


# -- selection --------------------------------------------------------------------------------


@dataclass(frozen=True)
class SelectionResult:
    """One step's selection answer by evaluate.py's rules."""

    module: bool
    name_ok: bool
    """single: the first name is the target's; module: the multisets of names are equal."""
    cell_ok: bool
    """single: the first cell is the target's; module: some cell is some target's."""
    parsed: bool
    """At least one pick was read."""
    recall: float | None = None
    precision: float | None = None
    f1: float | None = None

    @property
    def ok(self) -> bool:
        return self.name_ok or self.cell_ok


def _name(part: str) -> str:
    # normalise_part lower-cases and adds ".dat": the scripts' case-insensitive whole-name match.
    return normalise_part(str(part))


def score_selection(step: StepTarget, text: str) -> SelectionResult:
    """Score one selection answer of a non-blank step (see the module docstring)."""
    picks = parse_selection(text)
    names = [_name(p.part) for p in picks if p.part]
    cells = [(p.row, p.col) for p in picks]
    if len(step.bricks) > 1:
        return _module_selection(step, names, cells, bool(picks))
    return _single_selection(step.bricks[0], names, cells, bool(picks))


def _single_selection(target: BrickTarget, names: list, cells: list, parsed: bool) -> SelectionResult:
    name_ok = bool(names) and names[0] == _name(target.part)
    cell_ok = bool(cells) and cells[0] in target.cells
    return SelectionResult(False, name_ok, cell_ok, parsed)


def _module_selection(step: StepTarget, names: list, cells: list, parsed: bool) -> SelectionResult:
    want = Counter(_name(b.part) for b in step.bricks)
    got = Counter(names)
    hits = sum((want & got).values())
    recall = hits / sum(want.values())
    precision = hits / sum(got.values()) if got else 0.0
    f1 = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    any_cell = frozenset().union(*(b.cells for b in step.bricks))
    cell_ok = any(c in any_cell for c in cells)
    return SelectionResult(True, want == got, cell_ok, parsed, recall, precision, f1)


# -- pose -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class BcBrick:
    """One predicted brick pose against its target, by compute_success_rate.py's rules."""

    offsets: tuple
    """Per-axis ``pred - gt`` in LDU, rounded to `OFFSET_DECIMALS`."""
    translation_error: float
    rotation_error: float
    translation_ok: bool
    rotation_ok: bool
    projected: bool
    mirrored: bool
    degenerate: bool = False
    capped: bool = False

    @property
    def ok(self) -> bool:
        return self.translation_ok and self.rotation_ok


def rounded_offsets(t_gt, t_pred) -> tuple:
    """``round(pred - gt, 4)`` per axis, in Python floats as the script computes it."""
    return tuple(round(float(p) - float(g), OFFSET_DECIMALS) for p, g in zip(t_pred, t_gt))


def evaluate_brick_bc(target: BrickTarget, answer: PoseAnswer) -> BcBrick:
    """Errors and correctness of one predicted pose in the ``bc`` mode."""
    t_pred = np.asarray(answer.t, dtype=np.float64).reshape(3)
    offsets = rounded_offsets(target.t, t_pred)
    capped = translation_capped(target.t, t_pred)
    t_ok = not capped and all(abs(o) <= T_LDU for o in offsets)  # rounding already absorbs float noise
    # The released script would score the raw matrix and may pass a mirrored or degenerate one
    # (bug 6): never right.
    r_err, kind = judge_rotation(target.R, answer.R, target.symmetry)
    r_ok = kind not in ("mirrored", "degenerate") and r_err < R_DEG - _EPS
    return BcBrick(offsets, translation_error(target.t, t_pred), r_err, bool(t_ok), bool(r_ok), kind == "projected",
                   kind == "mirrored", kind == "degenerate", capped)


@dataclass(frozen=True)
class PoseResult:
    """One step's pose answer: a `BcBrick` or None (no pose) per target brick."""

    object_id: str
    bricks: tuple

    @property
    def parsed_any(self) -> bool:
        return any(b is not None for b in self.bricks)

    @property
    def ok(self) -> bool:
        return all(b is not None and b.ok for b in self.bricks)

    @property
    def translation_error(self) -> float | None:
        return _mean(b.translation_error for b in self.bricks if b is not None)

    @property
    def rotation_error(self) -> float | None:
        return _mean(b.rotation_error for b in self.bricks if b is not None)


def pose_answers(step: StepTarget, text: str) -> list:
    """The `PoseAnswer` (or None) of each target brick: block N for brick N; a single-brick step
    without block 1 takes the first block, as the script reads such an answer whole."""
    blocks = parse_pose(text)
    if len(step.bricks) == 1 and 1 not in blocks and blocks:
        return [next(iter(blocks.values()))]
    return [blocks.get(i + 1) for i in range(len(step.bricks))]


def score_pose(step: StepTarget, text: str) -> PoseResult:
    """Score one pose answer of a non-blank step."""
    answers = pose_answers(step, text)
    bricks = tuple(None if a is None else evaluate_brick_bc(b, a) for b, a in zip(step.bricks, answers))
    return PoseResult(step.object_id, bricks)


# -- aggregation ------------------------------------------------------------------------------


def _mean(vals) -> float | None:
    vals = [v for v in vals if v is not None]
    return float(sum(vals) / len(vals)) if vals else None


def _median(vals) -> float | None:
    vals = [v for v in vals if v is not None]
    return float(statistics.median(vals)) if vals else None


def _rate(flags) -> float | None:
    """Fraction true; None for no items (the script prints 0.0: bug 4)."""
    flags = [bool(f) for f in flags]
    return sum(flags) / len(flags) if flags else None


def selection_summary(results: list) -> dict:
    """evaluate.py's ``aggregate_metrics``: micro rates over single and module steps apart."""
    single = [r for r in results if not r.module]
    module = [r for r in results if r.module]
    return {
        "evaluated": len(results),
        "either_acc": _rate(r.ok for r in results),
        "single_count": len(single),
        "single_either_acc": _rate(r.ok for r in single),
        "single_brick_acc": _rate(r.name_ok for r in single),
        "single_position_acc": _rate(r.cell_ok for r in single),
        "module_count": len(module),
        "module_either_acc": _rate(r.ok for r in module),
        "module_brick_exact": _rate(r.name_ok for r in module),
        "module_position_acc": _rate(r.cell_ok for r in module),
        "module_mean_f1": _mean(r.f1 for r in module),
        "module_mean_recall": _mean(r.recall for r in module),
        "module_mean_precision": _mean(r.precision for r in module),
    }


def success_summary(poses: list) -> dict:
    """compute_success_rate.py's summary over answered steps (unparsed steps fail here)."""
    bricks = [b for p in poses for b in p.bricks]
    evaluable = [b for b in bricks if b is not None]
    failed = [b for b in evaluable if not b.ok]
    correct_steps = sum(p.ok for p in poses)
    return {
        "evaluated_steps": len(poses),
        "correct_steps": correct_steps,
        "step_success_rate": correct_steps / len(poses) if poses else None,
        "total_bricks": len(bricks),
        "evaluable_bricks": len(evaluable),
        "correct_bricks": len(evaluable) - len(failed),
        "brick_success_rate": (len(evaluable) - len(failed)) / len(evaluable) if evaluable else None,
        "failure_trans_only": sum(not b.translation_ok and b.rotation_ok for b in failed),
        "failure_rot_only": sum(b.translation_ok and not b.rotation_ok for b in failed),
        "failure_both": sum(not b.translation_ok and not b.rotation_ok for b in failed),
    }


def brick_error_summary(poses: list) -> dict:
    """evaluate_assembly.py's / reeval_with_symmetry.py's micro errors over bricks with a pose."""
    bricks = [b for p in poses for b in p.bricks if b is not None]
    t = [b.translation_error for b in bricks]
    r = [b.rotation_error for b in bricks]
    return {
        "total_bricks": sum(len(p.bricks) for p in poses),
        "translation_evaluated": len(t),
        "translation_mean_ldu": _mean(t),
        "translation_median_ldu": _median(t),
        "rotation_evaluated": len(r),
        "rotation_mean_deg": _mean(r),
        "rotation_median_deg": _median(r),
    }


POSE_KEYS = ("translation_error_ldu", "rotation_error_deg", "step_success")


def object_pose_metrics(poses: list) -> dict | None:
    """aggregate_by_object.py's row of one object; None when none of its steps is kept (a step
    is kept when some brick got a pose)."""
    kept = [p for p in poses if p.parsed_any]
    if not kept:
        return None
    return {
        "translation_error_ldu": _mean(p.translation_error for p in kept),
        "rotation_error_deg": _mean(p.rotation_error for p in kept),
        "step_success": _rate(p.ok for p in kept),
        "pose_steps": len(kept),
    }


def pick_best_object(per_object: dict) -> str | None:
    """Highest step success, then lower translation error, lower rotation error, object id."""
    def rank(obj):
        m = per_object[obj]
        t, r = m["translation_error_ldu"], m["rotation_error_deg"]
        return (-(m["step_success"] or 0.0), math.inf if t is None else t, math.inf if r is None else r, obj)

    return min(per_object, key=rank) if per_object else None


def best_per_metric(per_object: dict) -> dict:
    """aggregate_by_object.py's printed "Best Value" column: each metric's best object apart."""
    out = {}
    for key, better in (("translation_error_ldu", min), ("rotation_error_deg", min), ("step_success", max)):
        cands = sorted((obj, m[key]) for obj, m in per_object.items() if m[key] is not None)
        obj, value = better(cands, key=lambda kv: kv[1]) if cands else (None, None)
        out[key] = {"object": obj, "value": value}
    return out


# -- scoring ----------------------------------------------------------------------------------


def _new_counts(steps: list) -> dict:
    """`eval.metrics`' counts, and the steps the released scripts skip or drop."""
    return {**new_counts(steps), "objects": len({s.object_id for s in steps}), "skipped_blank": 0,
            "dropped_pose_steps": 0}


def _count_pose(counts: dict, pose: PoseResult) -> None:
    counts["unparseable_pose"] += not all(b is not None for b in pose.bricks)
    counts["dropped_pose_steps"] += not pose.parsed_any
    count_bricks(counts, pose.bricks)


def _per_object(selections: dict, poses: dict) -> dict:
    """Every object's selection rate (micro over its steps) and aggregate_by_object.py row."""
    out = {}
    for obj in sorted(set(selections) | set(poses)):
        sel = selections.get(obj, [])
        pose = object_pose_metrics(poses.get(obj, [])) or {**{k: None for k in POSE_KEYS}, "pose_steps": 0}
        out[obj] = {"selection_accuracy": _rate(r.ok for r in sel), "selection_steps": len(sel), **pose}
    return out


def score_bc(steps: list, predictions: dict) -> dict:
    """Score predictions ``{(step id, "selection" | "pose"): text}`` by BC-Bench's released scripts.

    Returns ``{"overall", "best_object", "counts", "mode": "bc"}`` as `eval.metrics.score` does,
    plus ``selection``, ``success_rate``, ``brick_errors`` (the scripts' micro aggregates),
    ``best_per_metric`` and ``per_object``; see the module docstring.
    """
    ids = [s.id for s in steps]
    if len(set(ids)) != len(ids):
        raise ValueError("step ids must be unique")
    counts = _new_counts(steps)
    selections: dict[str, list] = {}
    poses: dict[str, list] = {}
    for step in steps:
        if not step.bricks:
            counts["skipped_blank"] += 1
            continue
        sel, pose = answer_text(predictions, (step.id, "selection")), answer_text(predictions, (step.id, "pose"))
        counts["missing_predictions"] += (sel is None) + (pose is None)
        if sel is not None:
            result = score_selection(step, sel)
            counts["unparseable_selection"] += not result.parsed
            selections.setdefault(step.object_id, []).append(result)
        if pose is not None:
            result = score_pose(step, pose)
            _count_pose(counts, result)
            poses.setdefault(step.object_id, []).append(result)
    counts["unparseable"] = counts["unparseable_selection"] + counts["unparseable_pose"]

    all_selections = [r for rs in selections.values() for r in rs]
    all_poses = [p for ps in poses.values() for p in ps]
    per_object = _per_object(selections, poses)
    ranked = {obj: m for obj, m in per_object.items() if m["pose_steps"]}
    overall = {
        "selection_accuracy": _rate(r.ok for r in all_selections),
        **{k: _mean(m[k] for m in ranked.values()) for k in POSE_KEYS},
    }
    best = pick_best_object(ranked)
    keys = ("selection_accuracy", *POSE_KEYS)
    best_object = {**{k: per_object[best][k] if best else None for k in keys}, "object": best}
    return {
        "overall": overall,
        "best_object": best_object,
        "counts": counts,
        "mode": MODE,
        "selection": selection_summary(all_selections),
        "success_rate": success_summary(all_poses),
        "brick_errors": brick_error_summary(all_poses),
        "best_per_metric": best_per_metric(ranked),
        "per_object": per_object,
    }
