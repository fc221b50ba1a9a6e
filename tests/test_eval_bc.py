"""The `bc` mode: worked examples of BC-Bench's released scorer, one or more per definition.

Each expected number is what the released scripts compute for the answer, worked by hand in the
comment beside it (evaluate.py for selection; compute_success_rate.py, aggregate_by_object.py and
evaluate_assembly.py for poses), except where `eval.bc`'s docstring says the mode fixes a bug.
"""

from __future__ import annotations

import numpy as np
import pytest

from eval.baselines import oracle
from eval.bc import evaluate_brick_bc, rounded_offsets, score_bc, score_pose, score_selection
from eval.metrics import BrickTarget, StepTarget, evaluate_brick, score
from eval.parse import PoseAnswer
from factory import get_reader, load_part
from factory.symmetry import Symmetry, rotation_about

T0 = (20.0, -24.0, 0.0)


def brick(part="3001.dat", cells=((1, 1),), r=None, t=T0, sym=None):
    return BrickTarget(part, 4, frozenset(cells), np.eye(3) if r is None else r, np.asarray(t, float), sym)


def step(sid="s", obj="o", *bricks):
    return StepTarget(sid, obj, bricks or (brick(),))


def pose_text(*poses):
    """``Brick N`` blocks of (t, R), numbers written with repr so that 30.00004 stays 30.00004."""
    out = []
    for n, (t, r) in enumerate(poses, 1):
        rows = "\n".join("[" + ", ".join(repr(float(v)) for v in row) + "]" for row in np.asarray(r, float))
        out.append(f"Brick {n}:\nTranslation:\nx={t[0]!r}, y={t[1]!r}, z={t[2]!r}\nRotation:\n{rows}")
    return "\n".join(out)


RIGHT = pose_text((T0, np.eye(3)))
WRONG = pose_text(((60.0, -24.0, 0.0), np.eye(3)))  # 40 LDU off in x


# -- selection: single steps ------------------------------------------------------------------


def test_single_name_right_cell_wrong_counts():
    # first name 3001.dat == target: brick_correct; (2, 2) not in {(1, 1)}; either = True -> 1.0
    r = score_selection(step(), "3001.dat, row 2, col 2")
    assert (r.name_ok, r.cell_ok, r.ok) == (True, False, True)
    out = score_bc([step()], {("s", "selection"): "3001.dat, row 2, col 2"})
    assert out["overall"]["selection_accuracy"] == 1.0
    assert out["selection"]["single_brick_acc"] == 1.0 and out["selection"]["single_position_acc"] == 0.0


def test_single_cell_right_name_wrong_counts():
    # 3023.dat != 3001.dat, but (1, 1) is an equivalent cell of the target: either = True -> 1.0
    r = score_selection(step(), "3023.dat, row 1, col 1")
    assert (r.name_ok, r.cell_ok, r.ok) == (False, True, True)


def test_single_reads_the_first_name_and_the_first_cell():
    # first name 3023.dat (wrong), first cell (5, 5) (wrong); the right second line is not read -> 0
    r = score_selection(step(), "3023.dat, row 5, col 5\n3001.dat, row 1, col 1")
    assert not r.ok
    # both wrong on a single line: 0
    assert not score_selection(step(), "3023.dat, row 5, col 5").ok


def test_names_compare_case_insensitively_as_dat_names():
    # "3001.DAT" lower-cases to the target's "3001.dat"; a target stored as "3001" is "3001.dat"
    assert score_selection(step(), "3001.DAT, row 9, col 9").name_ok
    assert score_selection(step("s", "o", brick(part="3001")), "3001.dat, row 9, col 9").name_ok
    assert not score_selection(step(), "3001a.dat, row 9, col 9").name_ok  # whole names only


# -- selection: module steps ------------------------------------------------------------------


def module_step():
    return step("m", "o", brick("3001.dat", [(1, 1)]), brick("3001.dat", [(1, 2)]), brick("3020.dat", [(2, 1)]))


def test_module_multiset_of_names_matches():
    # names {3020: 1, 3001: 2} == targets' {3001: 2, 3020: 1} in another order; no cell right
    text = "3020.dat, row 7, col 7\n3001.dat, row 8, col 8\n3001.dat, row 9, col 9"
    r = score_selection(module_step(), text)
    assert (r.module, r.name_ok, r.cell_ok, r.ok) == (True, True, False, True)
    assert (r.recall, r.precision, r.f1) == (1.0, 1.0, 1.0)


def test_module_multiset_must_match_counts():
    # {3001: 1, 3020: 1} != {3001: 2, 3020: 1}: not exact; tp = 2, recall 2/3, precision 2/2,
    # F1 = 2 * 1 * 2/3 / (1 + 2/3) = 0.8; no cell right -> wrong
    r = score_selection(module_step(), "3001.dat, row 7, col 7\n3020.dat, row 8, col 8")
    assert not r.ok
    assert r.recall == pytest.approx(2 / 3) and r.precision == 1.0 and r.f1 == pytest.approx(0.8)


def test_module_one_cell_right_counts():
    # every name wrong, two cells wrong, (2, 1) is the 3020's cell: position_any_match -> right
    text = "3023.dat, row 7, col 7\n3023.dat, row 2, col 1\n3023.dat, row 9, col 9"
    r = score_selection(module_step(), text)
    assert (r.name_ok, r.cell_ok, r.ok) == (False, True, True)
    assert r.precision == 0.0 and r.recall == 0.0 and r.f1 == 0.0


def test_module_any_cell_is_why_listing_every_cell_passes():
    # the released rule's flaw (reproduced): a list of all 12 cells of a 3 x 4 catalog passes
    text = "\n".join(f"3023.dat, row {r}, col {c}" for r in range(1, 4) for c in range(1, 5))
    assert score_selection(module_step(), text).ok


def test_selection_aggregation_is_micro_by_step_kind():
    # single steps: right, wrong -> single_either_acc 1/2; module: right -> 1/1; combined 2/3
    steps = [step("a"), step("b"), module_step()]
    preds = {("a", "selection"): "3001.dat, row 1, col 1", ("b", "selection"): "3023.dat, row 5, col 5",
             ("m", "selection"): "3023.dat, row 1, col 2"}
    out = score_bc(steps, preds)
    assert out["selection"]["single_either_acc"] == 0.5 and out["selection"]["module_either_acc"] == 1.0
    assert out["overall"]["selection_accuracy"] == pytest.approx(2 / 3)
    assert out["selection"]["single_count"] == 2 and out["selection"]["module_count"] == 1


def test_unparseable_selection_fails_and_missing_selection_is_dropped():
    # "a": no pick -> either False, counted (evaluate.py); "b": no answer -> no result, dropped
    # (eval_test_split.py); "c": right. Accuracy = 1 / 2 (a and c), not 1 / 3.
    steps = [step("a"), step("b"), step("c")]
    out = score_bc(steps, {("a", "selection"): "I cannot tell.", ("c", "selection"): "3001.dat, row 1, col 1"})
    assert out["overall"]["selection_accuracy"] == 0.5
    assert out["selection"]["evaluated"] == 2
    c = out["counts"]
    assert c["unparseable_selection"] == 1 and c["missing_predictions"] == 1 + 3  # b's selection, 3 poses


def test_no_steps_of_a_kind_is_none_not_zero():
    # evaluate.py prints module_either_acc 0.0 with no module step (bug 4): here None
    out = score_bc([step()], {("s", "selection"): "3001.dat, row 1, col 1"})
    assert out["selection"]["module_either_acc"] is None and out["selection"]["module_mean_f1"] is None


def test_blank_steps_are_skipped():
    out = score_bc([StepTarget("blank", "o", ()), step()], {("blank", "selection"): "x", ("s", "pose"): RIGHT})
    assert out["counts"]["skipped_blank"] == 1 and out["selection"]["evaluated"] == 0
    assert out["overall"]["step_success"] == 1.0


# -- brick pose -------------------------------------------------------------------------------


def test_offsets_are_rounded_to_4_decimals_before_the_inclusive_10_ldu_test():
    # 30.00004 - 20 = 10.000039999999998 -> round(., 4) = 10.0 <= 10: passes
    b = brick()
    near = PoseAnswer(np.array([30.00004, -24.0, 0.0]), np.eye(3))
    assert rounded_offsets(b.t, near.t) == (10.0, 0.0, 0.0)
    assert evaluate_brick_bc(b, near).translation_ok
    assert not evaluate_brick(b, near, "paper").translation_ok  # paper mode: 10.00004 > 10
    # 30.0001 - 20 -> 10.0001 > 10: fails
    far = PoseAnswer(np.array([30.0001, -24.0, 0.0]), np.eye(3))
    assert rounded_offsets(b.t, far.t)[0] == 10.0001 and not evaluate_brick_bc(b, far).translation_ok
    # negative side: 9.99996 - 20 = -10.00004 -> -10.0: passes; exactly 10 in z: passes
    assert evaluate_brick_bc(b, PoseAnswer(np.array([9.99996, -24.0, 10.0]), np.eye(3))).translation_ok


def test_translation_error_is_euclidean_and_unrounded():
    # offsets (3, 4, 0): error 5, each axis within 10
    res = evaluate_brick_bc(brick(), PoseAnswer(np.array([23.0, -20.0, 0.0]), np.eye(3)))
    assert res.translation_error == 5.0 and res.translation_ok


@pytest.mark.parametrize("deg, ok", [(44.0, True), (45.0, False), (46.0, False)])
def test_rotation_under_45_degrees(deg, ok):
    # geodesic angle of a turn of deg about x: deg; right when < 45 (exclusive)
    res = evaluate_brick_bc(brick(), PoseAnswer(np.array(T0), rotation_about((1, 0, 0), deg)))
    assert res.rotation_error == pytest.approx(deg, abs=1e-9) and res.rotation_ok is ok


def test_rotation_error_is_minimised_over_symmetries():
    # a part symmetric under a half turn about y: R_gt @ S = Ry(180) is the answer -> 0 degrees;
    # the answer Ry(180) @ Rx(30) is 30 degrees from R_gt @ S -> right
    sym = Symmetry((np.eye(3), rotation_about((0, 1, 0), 180)))
    b = brick(sym=sym)
    assert evaluate_brick_bc(b, PoseAnswer(np.array(T0), rotation_about((0, 1, 0), 180))).rotation_error == \
        pytest.approx(0.0, abs=1e-9)
    tilted = rotation_about((0, 1, 0), 180) @ rotation_about((1, 0, 0), 30)
    assert evaluate_brick_bc(b, PoseAnswer(np.array(T0), tilted)).rotation_error == pytest.approx(30.0, abs=1e-9)
    assert evaluate_brick_bc(brick(), PoseAnswer(np.array(T0), rotation_about((0, 1, 0), 180))).rotation_error == \
        pytest.approx(180.0, abs=1e-9)  # no symmetry: a half turn is 180 degrees


def test_mirrored_rotation_fails():
    # diag(1.5, 1.5, -0.5), det -1.125: the released script takes acos((tr - 1) / 2) of the raw
    # matrix, (2.5 - 1) / 2 = 0.75 -> 41.4 degrees < 45, and passes it. Fixed here: wrong, 180
    # degrees (degenerate: its columns are not unit). A pure reflection diag(1, 1, -1) is mirrored
    # and wrong too (the script: 90 degrees).
    for m, kind in ((np.diag([1.5, 1.5, -0.5]), "degenerate"), (np.diag([1.0, 1.0, -1.0]), "mirrored")):
        res = evaluate_brick_bc(brick(), PoseAnswer(np.array(T0), m))
        assert getattr(res, kind) and not res.rotation_ok and res.rotation_error == 180.0 and res.translation_ok
    out = score_bc([step()], {("s", "pose"): pose_text((T0, np.diag([1.0, 1.0, -1.0])))})
    assert out["overall"]["step_success"] == 0.0 and out["overall"]["rotation_error_deg"] == 180.0
    c = out["counts"]
    assert c["mirrored_rotations"] == 1 and c["projected_rotations"] == 0
    assert c["failures"] == {"mirrored": 1, "degenerate": 0, "translation_only": 0, "rotation_only": 0, "both": 0,
                             "unparseable": 0}
    assert out["success_rate"]["failure_rot_only"] == 1  # the script's breakdown: rotation only


def test_a_scaled_rotation_is_degenerate_and_a_rounded_one_projected():
    # 2 * I is no rotation (the released script scores it 0 degrees): wrong, counted degenerate
    out = score_bc([step()], {("s", "pose"): pose_text((T0, 2.0 * np.eye(3)))})
    assert out["overall"]["step_success"] == 0.0 and out["counts"]["degenerate_rotations"] == 1
    # 0.99 * I, a rotation printed a little off: projected to I (0 degrees), right
    out = score_bc([step()], {("s", "pose"): pose_text((T0, 0.99 * np.eye(3)))})
    assert out["overall"]["step_success"] == 1.0 and out["counts"]["projected_rotations"] == 1


# -- steps ------------------------------------------------------------------------------------


def test_step_success_reads_the_pose_only():
    # pose right, selection wrong (name and cell): step success 1.0, selection 0.0
    preds = {("s", "selection"): "3023.dat, row 5, col 5", ("s", "pose"): RIGHT}
    out = score_bc([step()], preds)
    assert out["overall"]["step_success"] == 1.0 and out["overall"]["selection_accuracy"] == 0.0
    assert score([step()], preds, "paper")["overall"]["step_success"] == 0.0  # paper mode: selection counts
    # pose wrong, selection right: 0.0
    out = score_bc([step()], {("s", "selection"): "3001.dat, row 1, col 1", ("s", "pose"): WRONG})
    assert out["overall"]["step_success"] == 0.0


def test_multi_brick_step_needs_every_brick_and_matches_blocks_by_number():
    two = step("t", "o", brick(t=T0), brick(t=(0.0, -48.0, 0.0)))
    both = pose_text((T0, np.eye(3)), ((0.0, -48.0, 0.0), np.eye(3)))
    assert score_pose(two, both).ok
    swapped = "Brick 2:" + both.split("Brick 2:")[1] + "\n" + both.split("Brick 2:")[0]
    assert score_pose(two, swapped).ok  # written 2 then 1: by number, right (bug 5 fixed)
    assert not score_pose(two, pose_text((T0, np.eye(3)), ((0.0, -24.0, 0.0), np.eye(3)))).ok  # 24 LDU off


def test_single_brick_answer_under_another_number_is_read():
    # the script reads a single-brick answer whole, so "Brick 2:" still answers the only brick
    text = RIGHT.replace("Brick 1:", "Brick 2:")
    assert score_pose(step(), text).ok


def test_unparseable_pose_drops_from_the_macro_and_fails_in_the_micro_rate():
    # object o: a right, b unparseable, c missing.
    # aggregate_by_object.py: b has no parsed brick -> dropped; c has no result -> dropped;
    #   success = 1 / 1 = 1.0 (followed by overall).
    # compute_success_rate.py: a, b evaluated (c skipped); correct 1 / 2 = 0.5.
    steps = [step("a"), step("b"), step("c")]
    out = score_bc(steps, {("a", "pose"): RIGHT, ("b", "pose"): "no idea"})
    assert out["overall"]["step_success"] == 1.0
    assert out["success_rate"]["evaluated_steps"] == 2 and out["success_rate"]["step_success_rate"] == 0.5
    # bricks: 2 in answered steps, 1 evaluable and right -> brick rate 1 / 1 (bug 9, reproduced)
    assert out["success_rate"]["total_bricks"] == 2 and out["success_rate"]["brick_success_rate"] == 1.0
    c = out["counts"]
    assert c["dropped_pose_steps"] == 1 and c["unparseable_pose"] == 1 and c["failures"]["unparseable"] == 1


def test_partly_parsed_step_is_kept_and_fails():
    # two bricks, only brick 1 answered: some translation parsed -> kept by aggregate_by_object.py,
    # and brick 2 has no offsets -> the step fails (both scripts): success 0 / 1
    two = step("t", "o", brick(), brick(t=(0.0, -48.0, 0.0)))
    out = score_bc([two], {("t", "pose"): RIGHT})
    assert out["overall"]["step_success"] == 0.0 and out["success_rate"]["step_success_rate"] == 0.0
    assert out["overall"]["translation_error_ldu"] == 0.0  # the mean over its parsed brick
    assert out["counts"]["dropped_pose_steps"] == 0


# -- aggregation ------------------------------------------------------------------------------


def test_macro_over_objects_and_micro_over_steps_and_bricks():
    # object A: 1 step, right (error 0). Object B: 3 steps, each 40 LDU off in x (error 40), wrong.
    # aggregate_by_object.py (overall): success (1 + 0) / 2 = 0.5; translation (0 + 40) / 2 = 20.
    # compute_success_rate.py: 1 / 4 = 0.25. evaluate_assembly.py: bricks (0 + 3 * 40) / 4 = 30.
    steps = [step("a1", "A")] + [step(f"b{i}", "B") for i in range(3)]
    preds = {("a1", "pose"): RIGHT, **{(f"b{i}", "pose"): WRONG for i in range(3)}}
    out = score_bc(steps, preds)
    assert out["overall"]["step_success"] == 0.5 and out["overall"]["translation_error_ldu"] == 20.0
    assert out["success_rate"]["step_success_rate"] == 0.25
    assert out["brick_errors"]["translation_mean_ldu"] == 30.0 and out["brick_errors"]["translation_median_ldu"] == 40.0
    assert out["best_object"] == {"selection_accuracy": None, "translation_error_ldu": 0.0,
                                  "rotation_error_deg": 0.0, "step_success": 1.0, "object": "A"}
    assert out["per_object"]["B"]["pose_steps"] == 3 and out["per_object"]["B"]["step_success"] == 0.0
    assert out["counts"]["failures"]["translation_only"] == 3


def test_best_object_ties_and_best_per_metric():
    # A and B both succeed 1/2; A's mean translation error (0 + 40) / 2 = 20, B's (0 + 12) / 2 = 6:
    # the tie goes to the lower error, B. Rotation: A's 0, B's (30 + 30) / 2 = 30, so the best
    # rotation by itself is A's: best_per_metric names A there, B for translation, A for success
    # (ties to the object id), a row no one object achieved.
    rot30 = pose_text((T0, rotation_about((1, 0, 0), 30)))
    off12 = pose_text(((32.0, -24.0, 0.0), rotation_about((1, 0, 0), 30)))
    steps = [step("a1", "A"), step("a2", "A"), step("b1", "B"), step("b2", "B")]
    preds = {("a1", "pose"): RIGHT, ("a2", "pose"): WRONG, ("b1", "pose"): rot30, ("b2", "pose"): off12}
    out = score_bc(steps, preds)
    assert out["best_object"]["object"] == "B" and out["best_object"]["translation_error_ldu"] == 6.0
    best = out["best_per_metric"]
    assert best["translation_error_ldu"] == {"object": "B", "value": 6.0}
    assert best["rotation_error_deg"]["object"] == "A" and best["step_success"] == {"object": "A", "value": 0.5}


def test_result_has_the_shape_of_metrics_score():
    steps = [step()]
    preds = {("s", "selection"): "3001.dat, row 1, col 1", ("s", "pose"): RIGHT}
    ours, theirs = score_bc(steps, preds), score(steps, preds, "strict")
    assert ours["mode"] == "bc"
    assert set(ours["overall"]) == set(theirs["overall"]) and set(ours["best_object"]) == set(theirs["best_object"])
    assert set(theirs["counts"]) <= set(ours["counts"])
    assert ours["overall"] == {"selection_accuracy": 1.0, "translation_error_ldu": 0.0, "rotation_error_deg": 0.0,
                               "step_success": 1.0}
    empty = score_bc(steps, {})
    assert empty["overall"] == {k: None for k in ours["overall"]} and empty["best_object"]["object"] is None
    with pytest.raises(ValueError):
        score_bc([step(), step()], {})


def test_oracle_is_perfect_with_a_real_symmetric_part():
    # the ground truth as answers, on single and module steps and a 2x4 brick turned about
    # (1, 1, 1): every rate 1.0, every error 0, nothing dropped or counted.
    sym = load_part(get_reader(), "3001").symmetry
    steps = [step("a", "A"), module_step(),
             step("r", "B", brick(r=rotation_about((1, 1, 1), 37), t=(1.25, -3.5, 0.1), sym=sym))]
    preds = {(s.id, task): text for s in steps for task, text in oracle(s).items()}
    out = score_bc(steps, preds)
    assert out["overall"]["selection_accuracy"] == 1.0 and out["overall"]["step_success"] == 1.0
    assert out["overall"]["translation_error_ldu"] < 1e-6 and out["overall"]["rotation_error_deg"] < 1e-4
    assert out["selection"]["module_brick_exact"] == 1.0 and out["success_rate"]["brick_success_rate"] == 1.0
    c = out["counts"]
    assert c["unparseable"] == c["missing_predictions"] == c["dropped_pose_steps"] == c["mirrored_rotations"] == 0
