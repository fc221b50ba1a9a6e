"""Benchmark metrics: symmetric rotation error, correctness modes, selection matching, aggregation."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from eval.baselines import EMPTY_LABEL, format_pose, format_selection, heuristic, oracle, random_baseline
from eval.metrics import (
    BrickTarget,
    StepTarget,
    evaluate_brick,
    match_cells,
    project_to_rotation,
    rotation_error_deg,
    score,
    score_step,
    selection_score,
    translation_error,
)
from eval.parse import PoseAnswer, Selection, parse_selection
from factory import get_reader, load_part
from factory.symmetry import Symmetry, axis_rotations, rotation_about

Y_UP = (0.0, -1.0, 0.0)
ROUND = Symmetry((np.eye(3),), continuous_axis=Y_UP)


@pytest.fixture(scope="module")
def sym_3001():
    return load_part(get_reader(), "3001").symmetry


def rot(axis, deg):
    return rotation_about(axis, deg)


def random_rotations(rng, n):
    out = []
    for _ in range(n):
        q, r = np.linalg.qr(rng.normal(size=(3, 3)))
        q = q @ np.diag(np.sign(np.diag(r)))
        out.append(q if np.linalg.det(q) > 0 else -q)
    return out


# -- geometry ---------------------------------------------------------------------------------


def test_project_to_rotation():
    r = rot((1, 2, 3), 40)
    out, flagged = project_to_rotation(r)
    assert np.allclose(out, r) and not flagged
    out, flagged = project_to_rotation(np.round(rot((0, 1, 0), 45), 4))  # printed 0.7071: not flagged
    assert not flagged
    out, flagged = project_to_rotation(2.5 * r)
    assert flagged and np.allclose(out, r)
    out, flagged = project_to_rotation(np.diag([1.0, 1.0, -1.0]))  # a reflection
    assert flagged and np.linalg.det(out) > 0 and np.allclose(out @ out.T, np.eye(3))
    for m in (np.zeros((3, 3)), np.full((3, 3), np.nan), np.ones((3, 3))):
        out, flagged = project_to_rotation(m)
        assert flagged and np.allclose(out @ out.T, np.eye(3), atol=1e-9) and np.linalg.det(out) > 0


def test_translation_error():
    assert translation_error([0, 0, 0], [3, 4, 0]) == 5.0
    assert translation_error([1, 2, 3], [1, 2, 3]) == 0.0


def test_rotation_error_plain():
    rng = np.random.default_rng(1)
    for r in random_rotations(rng, 20):
        assert rotation_error_deg(r, r) == pytest.approx(0.0, abs=1e-6)
        for deg in (0.001, 1.0, 30.0, 90.0, 179.0, 180.0):
            axis = rng.normal(size=3)
            assert rotation_error_deg(r, r @ rot(axis, deg)) == pytest.approx(deg, abs=1e-6)


def test_2x4_brick_symmetry(sym_3001):
    assert sym_3001.order == 2
    r_gt = rot((1, 0, 0), 90) @ rot((0, 1, 0), 30)  # any placement
    assert rotation_error_deg(r_gt, r_gt @ rot((0, 1, 0), 180), sym_3001) == pytest.approx(0.0, abs=1e-9)
    assert rotation_error_deg(r_gt, r_gt @ rot((0, 1, 0), 90), sym_3001) == pytest.approx(90.0, abs=1e-9)
    assert rotation_error_deg(r_gt, r_gt @ rot((0, 1, 0), 170), sym_3001) == pytest.approx(10.0, abs=1e-9)
    # Symmetry acts in the part frame: turning about the *world* y of a tilted brick is not free.
    assert rotation_error_deg(r_gt, rot((0, 1, 0), 180) @ r_gt, sym_3001) > 1.0
    sym_3003 = load_part(get_reader(), "3003").symmetry
    assert rotation_error_deg(r_gt, r_gt @ rot((0, 1, 0), 90), sym_3003) == pytest.approx(0.0, abs=1e-9)


def brute_force(r_gt, r_pred, sym):
    """Dense 1-D search over the twist, refined: an independent check of the closed form."""
    axis = np.asarray(sym.continuous_axis)
    best = 180.0
    for s in sym.rotations:
        grid = np.arange(0, 360, 0.5)
        vals = [err_s(r_gt @ s, r_pred, axis, g) for g in grid]
        g0 = grid[int(np.argmin(vals))]
        res = minimize_scalar(lambda g: err_s(r_gt @ s, r_pred, axis, g), bounds=(g0 - 1, g0 + 1), method="bounded",
                              options={"xatol": 1e-10})
        best = min(best, res.fun)
    return best


def err_s(a0, r_pred, axis, deg):
    a = a0 @ rot(axis, deg)
    return np.degrees(np.arccos(np.clip((np.trace(a.T @ r_pred) - 1) / 2, -1, 1)))


@pytest.mark.parametrize("axis", [Y_UP, (1.0, 0.0, 0.0), tuple(np.array([1.0, 2.0, -3.0]) / np.sqrt(14))])
def test_continuous_axis_exact(axis):
    sym = Symmetry((np.eye(3),), continuous_axis=axis)
    a = np.asarray(axis)
    perp = np.cross(a, [0.3, 0.5, 0.7])
    rng = np.random.default_rng(7)
    for r_gt in random_rotations(rng, 6):
        for twist in (0.0, 13.0, 90.0, 180.0, 271.3):
            r_twisted = r_gt @ rot(a, twist)
            assert rotation_error_deg(r_gt, r_twisted, sym) == pytest.approx(0.0, abs=1e-6)
            for tilt in (0.5, 10.0, 30.0, 89.0, 150.0):
                assert rotation_error_deg(r_gt, r_twisted @ rot(perp, tilt), sym) == pytest.approx(tilt, abs=1e-6)
        for r_pred in random_rotations(rng, 3):
            assert rotation_error_deg(r_gt, r_pred, sym) == pytest.approx(brute_force(r_gt, r_pred, sym), abs=1e-6)


def test_round_part_with_discrete_symmetry():
    """A round part that may also flip over (a cylinder): both kinds combine."""
    sym = Symmetry((np.eye(3), rot((1, 0, 0), 180)), continuous_axis=Y_UP)
    r_gt = rot((0, 0, 1), 20)
    assert rotation_error_deg(r_gt, r_gt @ rot((1, 0, 0), 180) @ rot(Y_UP, 33), sym) == pytest.approx(0.0, abs=1e-6)
    assert rotation_error_deg(r_gt, r_gt @ rot((1, 0, 0), 160), sym) == pytest.approx(20.0, abs=1e-6)


def test_real_round_plate(real_reader):
    part = load_part(real_reader, "4073")
    sym = part.symmetry
    assert sym.continuous_axis == Y_UP
    r_gt = rot((0, 0, 1), 90) @ rot((0, 1, 0), 10)
    for twist in (1.0, 22.5, 45.0, 77.7, 200.0):
        assert rotation_error_deg(r_gt, r_gt @ rot(Y_UP, twist), sym) == pytest.approx(0.0, abs=1e-6)
    assert rotation_error_deg(r_gt, r_gt @ rot(Y_UP, 77.7) @ rot((1, 0, 0), 30), sym) == pytest.approx(30.0, abs=1e-6)
    assert rotation_error_deg(r_gt, r_gt @ rot((0, 0, 1), 90), sym) == pytest.approx(90.0, abs=1e-6)


# -- brick correctness ------------------------------------------------------------------------


def brick(part="3001.dat", cells=((1, 1),), r=None, t=(0.0, 0.0, 0.0), sym=None, colour=4):
    return BrickTarget(part, colour, frozenset(cells), np.eye(3) if r is None else r, np.asarray(t, float), sym)


def answer(t, r=None):
    return PoseAnswer(np.asarray(t, float), np.eye(3) if r is None else np.asarray(r, float))


def test_one_plate_high_passes_paper_fails_strict():
    b = brick(t=(20.0, -24.0, 10.0))
    off = answer((20.0, -32.0, 10.0))
    assert evaluate_brick(b, off, "paper").ok
    res = evaluate_brick(b, off, "strict")
    assert not res.ok and not res.translation_ok and res.rotation_ok and res.translation_error == 8.0


def test_thresholds():
    b = brick(t=(20.0, 0.0, 0.0))
    assert evaluate_brick(b, answer((30.0, -10.0, 10.0)), "paper").translation_ok  # 10 is inclusive, per axis
    assert not evaluate_brick(b, answer((30.001, 0.0, 0.0)), "paper").translation_ok
    assert evaluate_brick(b, answer((20.5, 0.0, 0.0)), "strict").translation_ok
    assert not evaluate_brick(b, answer((20.3, 0.3, 0.3)), "strict").translation_ok  # Euclidean 0.52
    assert evaluate_brick(b, answer((20.0, 0.0, 0.0), rot((0, 0, 1), 44.9)), "paper").rotation_ok
    assert not evaluate_brick(b, answer((20.0, 0.0, 0.0), rot((0, 0, 1), 45.0)), "paper").rotation_ok
    assert evaluate_brick(b, answer((20.0, 0.0, 0.0), rot((0, 0, 1), 1.0)), "strict").rotation_ok
    assert not evaluate_brick(b, answer((20.0, 0.0, 0.0), rot((0, 0, 1), 1.01)), "strict").rotation_ok
    with pytest.raises(ValueError):
        evaluate_brick(b, answer((0, 0, 0)), "lenient")


# -- selection --------------------------------------------------------------------------------


def test_selection_is_set_based():
    a, b = frozenset({(1, 1), (1, 2)}), frozenset({(1, 1)})
    assert match_cells([a, b], [(1, 1), (1, 2)]) == [1, 0]  # needs an augmenting path
    same = brick(cells=[(1, 1), (1, 2)])
    two = StepTarget("s", "o", (same, same))
    assert selection_score(two, [Selection("", 1, 2), Selection("", 1, 1)]) == 1.0
    assert selection_score(two, [Selection("", 1, 1), Selection("", 1, 1)]) == 0.5  # one cell, one brick
    assert selection_score(two, [(1, 1), (1, 2), (3, 3)]) == pytest.approx(2 / 3)  # extra picks cost
    one = StepTarget("s", "o", (same,))
    assert selection_score(one, [(1, 2)]) == 1.0 and selection_score(one, [(2, 1)]) == 0.0
    assert selection_score(one, []) == 0.0
    mixed = StepTarget("s", "o", (brick(cells=[(1, 1)]), brick(cells=[(2, 2)])))
    assert selection_score(mixed, [(2, 2), (1, 1)]) == 1.0  # order does not matter


# -- scoring ----------------------------------------------------------------------------------


def synthetic_steps(n_objects=4, steps_per_object=5, seed=0, n_rows=5, n_cols=6):
    rng = np.random.default_rng(seed)
    rotations = axis_rotations()
    steps = []
    for o in range(n_objects):
        for s in range(steps_per_object):
            k = int(rng.integers(1, 3))
            bricks = []
            for _ in range(k):
                n_cells = int(rng.integers(1, 4))
                cells = {(int(rng.integers(1, n_rows + 1)), int(rng.integers(1, n_cols + 1))) for _ in range(n_cells)}
                t = rng.integers(-10, 11, size=3) * 20.0
                bricks.append(brick(cells=cells, r=rotations[int(rng.integers(24))], t=t))
            steps.append(StepTarget(f"o{o}s{s}", f"o{o}", tuple(bricks)))
    return steps


def predictions_from(steps, make):
    preds = {}
    for step in steps:
        out = make(step)
        preds[(step.id, "selection")] = out["selection"]
        preds[(step.id, "pose")] = out["pose"]
    return preds


KEYS = {"selection_accuracy", "translation_error_ldu", "rotation_error_deg", "step_success"}


@pytest.mark.parametrize("mode", ["strict", "paper"])
def test_oracle_is_perfect(mode, sym_3001):
    steps = synthetic_steps()
    steps.append(StepTarget("rot", "o9", (brick(r=rot((1, 1, 1), 37), t=(1.25, -3.5, 0.1), sym=sym_3001),)))
    out = score(steps, predictions_from(steps, oracle), mode)
    assert set(out) == {"overall", "best_object", "counts", "mode"} and out["mode"] == mode
    assert set(out["overall"]) == KEYS and set(out["best_object"]) == KEYS | {"object"}
    assert out["overall"]["selection_accuracy"] == 1.0 and out["overall"]["step_success"] == 1.0
    assert out["overall"]["translation_error_ldu"] < 1e-6 and out["overall"]["rotation_error_deg"] < 1e-4
    c = out["counts"]
    assert c["steps"] == len(steps) and c["objects"] == 5
    assert c["unparseable"] == c["missing_predictions"] == c["projected_rotations"] == c["mirrored_rotations"] == 0
    assert c["failures"] == {"mirrored": 0, "degenerate": 0, "translation_only": 0, "rotation_only": 0, "both": 0, "unparseable": 0}


def test_random_baseline_is_near_chance():
    n_rows, n_cols = 5, 6
    steps = synthetic_steps(n_objects=20, steps_per_object=100, seed=3, n_rows=n_rows, n_cols=n_cols)
    single = [StepTarget(s.id, s.object_id, s.bricks[:1]) for s in steps]
    rng = np.random.default_rng(11)
    out = score(single, predictions_from(single, lambda s: random_baseline(s, rng, n_rows, n_cols)), "paper")
    chance = np.mean([len(s.bricks[0].cells) / (n_rows * n_cols) for s in single])
    assert out["overall"]["selection_accuracy"] == pytest.approx(chance, abs=0.02)
    assert out["overall"]["step_success"] < 0.01
    assert out["overall"]["rotation_error_deg"] > 60.0  # mean angle between random axis-aligned rotations: 105
    assert out["counts"]["unparseable"] == 0 and out["counts"]["projected_rotations"] == 0


def test_unparseable_and_missing_are_counted_and_fail():
    steps = [StepTarget("a", "o", (brick(t=(0, -24, 0)),))]
    steps += [StepTarget("b", "o", (brick(),)), StepTarget("c", "o", (brick(),))]
    good = oracle(steps[1])
    preds = {
        ("a", "selection"): "I am not sure.",
        ("a", "pose"): "<think>Brick 1:\nTranslation:\nx=0, y=-24, z=0\nRotation:\n[1,0,0]\n[0,1,0]\n[0,0,1]",
        ("b", "selection"): good["selection"],
        ("b", "pose"): good["pose"],
        ("c", "pose"): 12345,  # not a string: unparseable
    }
    out = score(steps, preds, "paper")
    c = out["counts"]
    assert c["unparseable_selection"] == 1 and c["unparseable_pose"] == 2 and c["unparseable"] == 3
    assert c["missing_predictions"] == 1  # c's selection
    assert c["failures"]["unparseable"] == 2
    assert out["overall"]["step_success"] == pytest.approx(1 / 3)
    assert out["overall"]["selection_accuracy"] == pytest.approx(1 / 3)
    assert out["overall"]["translation_error_ldu"] == 0.0  # only b's parsed pose enters the error means
    alone = score(steps[:1], preds, "paper")
    assert alone["overall"]["translation_error_ldu"] is None and alone["overall"]["step_success"] == 0.0


def test_step_success_rule():
    b = brick(cells=[(2, 3)], t=(10, -24, 0))
    step = StepTarget("s", "o", (b,))
    right = oracle(step)
    assert score_step(step, right["selection"], right["pose"]).success
    assert not score_step(step, "3001.dat, row 1, col 1", right["pose"]).success  # wrong selection fails
    assert not score_step(step, "", right["pose"]).success  # unparseable selection fails
    res = score_step(step, None, right["pose"])  # missing selection: pose decides
    assert res.success and res.selection == 0.0
    assert not score_step(step, right["selection"], None).success
    two = StepTarget("t", "o", (b, brick(t=(50, 0, 0))))
    half = format_pose([(b.t, b.R)])  # only brick 1
    res = score_step(two, None, half)
    assert not res.success and res.pose_status == "unparseable" and res.translation_error == 0.0


def test_failure_kinds_and_projection():
    steps = [StepTarget(f"s{i}", "o", (brick(t=(0, 0, 0)),)) for i in range(6)]
    tilt = rot((1, 0, 0), 90)
    preds = {
        ("s0", "pose"): format_pose([((50, 0, 0), np.eye(3))]),
        ("s1", "pose"): format_pose([((0, 0, 0), tilt)]),
        ("s2", "pose"): format_pose([((50, 0, 0), tilt)]),
        ("s3", "pose"): "garbage",
        ("s4", "pose"): format_pose([((0, 0, 0), 0.99 * np.eye(3))]),  # a little off: projected, then right
        ("s5", "pose"): format_pose([((0, 0, 0), 3.0 * np.eye(3))]),  # scaled: degenerate, wrong
    }
    out = score(steps, preds, "strict")
    assert out["counts"]["failures"] == {"mirrored": 0, "degenerate": 1, "translation_only": 1, "rotation_only": 1,
                                         "both": 1, "unparseable": 1}
    assert out["counts"]["projected_rotations"] == 1 and out["counts"]["degenerate_rotations"] == 1
    assert out["counts"]["missing_predictions"] == 6  # no selection predictions at all
    assert out["overall"]["step_success"] == pytest.approx(1 / 6)


def test_overall_is_mean_of_object_means_and_best_object():
    def steps_for(obj, n):
        return [StepTarget(f"{obj}{i}", obj, (brick(),)) for i in range(n)]

    steps = steps_for("A", 1) + steps_for("B", 3) + steps_for("C", 2) + steps_for("D", 2)
    preds = {}
    right, off3, off5, wrong = (format_pose([(t, np.eye(3))]) for t in ((0, 0, 0), (3, 0, 0), (5, 0, 0), (90, 0, 0)))
    preds[("A0", "pose")] = off5  # A: 1/1 success, error 5
    for i in range(3):
        preds[(f"B{i}", "pose")] = wrong  # B: 0/3
    preds[("C0", "pose")], preds[("C1", "pose")] = off3, off3  # C: 2/2, error 3
    preds[("D0", "pose")], preds[("D1", "pose")] = right, wrong  # D: 1/2
    out = score(steps, preds, "paper")
    assert out["overall"]["step_success"] == pytest.approx((1 + 0 + 1 + 0.5) / 4)  # not 5/8 over steps
    assert out["overall"]["translation_error_ldu"] == pytest.approx((5 + 90 + 3 + 45) / 4)
    best = out["best_object"]
    assert best["object"] == "C"  # ties with A on success; lower translation error wins
    assert best["step_success"] == 1.0 and best["translation_error_ldu"] == pytest.approx(3.0)
    assert best["selection_accuracy"] == 0.0
    # full tie: the object id decides
    preds[("A0", "pose")] = off3
    assert score(steps, preds, "paper")["best_object"]["object"] == "A"


def test_score_edges():
    empty = score([], {}, "strict")
    assert empty["overall"]["step_success"] is None and empty["best_object"]["object"] is None
    assert empty["counts"]["steps"] == 0
    step = StepTarget("s", "o", (brick(),))
    with pytest.raises(ValueError):
        score([step, step], {}, "paper")
    with pytest.raises(ValueError):
        score([step], {}, "loose")
    out = score([step], {("other", "pose"): "x", ("s", "pose"): None}, "paper")  # unknown ids ignored
    assert out["counts"]["missing_predictions"] == 2


def test_heuristic_stacks_on_the_previous_brick():
    prev = StepTarget("p", "o", (brick(t=(20, -24, 0)),))
    target = brick(cells=[(2, 1)], t=(20, -48, 0))
    step = StepTarget("s", "o", (target,))
    catalog = {(1, 1): ("3003.dat", 4), (2, 1): ("3001.dat", 4), (2, 2): ("3001.dat", 4)}
    out = heuristic(step, prev, catalog)
    assert out["selection"] == format_selection([("3001.dat", 2, 1)])
    res = score_step(step, out["selection"], out["pose"], "strict")
    assert res.success and res.translation_error == 0.0
    first = heuristic(step)  # no previous step, no catalog: origin, top-left cell, no part named
    assert score_step(step, first["selection"], first["pose"]).translation_error == pytest.approx(np.hypot(20, 24))
    assert first["selection"] == format_selection([(EMPTY_LABEL, 1, 1)])


def test_random_baseline_names_the_part_in_its_cell():
    """A baseline that wrote the target's own name beside a random cell scored 100 % with any
    scorer that reads names: each line must name what lies in the cell it picked."""
    catalog = {(r, c): (f"30{r}{c}.dat", 4) for r in (1, 2) for c in range(1, 7)}
    del catalog[(2, 6)]  # the last row is not full
    steps = [StepTarget(f"s{i}", "o", (brick(part="9999.dat", cells=[(1, 1)]), brick(part="9998.dat", cells=[(2, 2)])))
             for i in range(40)]
    rng = np.random.default_rng(0)
    names = []
    for step in steps:
        picks = parse_selection(random_baseline(step, rng, 2, 6, catalog=catalog)["selection"])
        assert len(picks) == 2
        for pick in picks:
            assert pick.part == catalog[(pick.row, pick.col)][0]  # only cells that hold a brick
            names.append(pick.part)
    assert not {"9999.dat", "9998.dat"} & set(names) and len(set(names)) > 5
    bare = random_baseline(steps[0], rng, 2, 6)["selection"]  # no catalog: no part named
    assert bare.splitlines()[0].startswith(EMPTY_LABEL) and {p.part for p in parse_selection(bare)} == {""}


MIRROR_Z = np.diag([1.0, 1.0, -1.0])


@pytest.mark.parametrize("mode", ["strict", "paper"])
@pytest.mark.parametrize("part", ["3001", "3039", "round"])
def test_mirrored_rotation_is_wrong_in_every_mode(mode, part, sym_3001):
    """The oracle's pose with its z column negated (det -1) scored 0 degrees and passed: the
    nearest rotation to a reflection is a tie that the SVD broke arbitrarily. Symmetric (2x4 brick,
    round), and asymmetric (slope) parts alike: wrong, 180 degrees, counted as mirrored."""
    sym = {"3001": sym_3001, "3039": load_part(get_reader(), "3039").symmetry, "round": ROUND}[part]
    r = rot((0, 1, 0), 90) if part != "round" else np.eye(3)
    steps = [StepTarget("s", "o", (brick(r=r, t=(20, -24, 0), sym=sym),))]
    good = oracle(steps[0])
    for column in range(3):
        flip = np.eye(3)
        flip[column, column] = -1.0
        mirrored = format_pose([((20, -24, 0), r @ flip)])
        out = score(steps, {("s", "selection"): good["selection"], ("s", "pose"): mirrored}, mode)
        assert out["overall"]["step_success"] == 0.0
        assert out["overall"]["rotation_error_deg"] == 180.0 and out["overall"]["translation_error_ldu"] == 0.0
        c = out["counts"]
        assert c["mirrored_rotations"] == 1 and c["projected_rotations"] == 0
        assert c["failures"] == {"mirrored": 1, "degenerate": 0, "translation_only": 0, "rotation_only": 0, "both": 0, "unparseable": 0}
    assert rotation_error_deg(r, -r, sym) == 180.0  # every column negated: det -1 as well
    assert score(steps, {("s", "pose"): good["pose"]}, mode)["overall"]["step_success"] == 1.0
