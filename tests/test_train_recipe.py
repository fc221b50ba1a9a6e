"""The staged recipe (`python -m train.recipe`) end to end on the tiny Qwen2-VL and the session's
tiny dataset: designer supervision, world-feedback rows made from the stage-1 model's own wrong
answers, synthetic experience; before/after metrics per stage; finished stages skipped, an
interrupted stage resumed, other settings refused; and the path where the stage-1 model gives no
wrong answer that parses."""

from __future__ import annotations

import json
import shutil

import pytest
from training_support import assert_resumed_run_is_the_same, train_log

torch = pytest.importorskip("torch")
pytest.importorskip("transformers")
pytest.importorskip("peft")

# Pose only, 4 image tokens per image: 100 full fine-tuning steps at lr 3e-3 teach the tiny model
# the pose answer's format (measured: all 6 train answers of the tiny dataset parse, 4 wrong, 2 right).
SETTINGS = ["--tasks", "pose", "--lr", "3e-3", "--warmup", "2", "--max-pixels", "3136", "--workers", "0",
            "--save-every", "2", "--eval-limit", "1", "--lora", "0", "--no-progress"]


@pytest.fixture(scope="module")
def synthetic(tiny_dataset, tmp_path_factory):
    """A second dataset folder for stage 3 (a copy of the tiny dataset)."""
    out = tmp_path_factory.mktemp("recipe") / "synth"
    shutil.copytree(tiny_dataset, out)
    return out


def _argv(designs, synth, run, steps="100,2,4", *more):
    return ["--designs", str(designs), "--synthetic", str(synth), "--outdir", str(run), "--stage-steps", steps,
            "--max-new-tokens", "90", *SETTINGS, *more]


def _wrong(designs, preds) -> dict[str, str]:
    """{step id: answer} of the pose answers in `preds` that parse and fail in paper mode."""
    from eval.data import iter_rows
    from eval.feedback import pose_errors

    answers = {r["id"]: r["text"] for r in map(json.loads, preds.read_text().splitlines())}
    return {row["step_id"]: answers[row["step_id"]]
            for row in iter_rows(designs, "train", ["step_id", "object_id", "bricks"])
            if pose_errors(row, answers.get(row["step_id"])) is not None}


@pytest.mark.slow
def test_staged_recipe_end_to_end_resumes_and_refuses_other_settings(tiny_dataset, synthetic, tmp_path, capsys):
    from safetensors.torch import load_file

    from eval.data import iter_rows
    from eval.predict import write_predictions
    from train.config import TrainConfig
    from train.evaluate import trained_predictor
    from train.recipe import RecipeConfig, main

    run = tmp_path / "run"
    argv = _argv(tiny_dataset, synthetic, run)
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "stage 1/3 (designer supervision): 100 steps" in out and "report: " in out
    s1, s2, s3 = (run / f"stage{k}" for k in (1, 2, 3))

    # the feedback rows are the stage-1 model's wrong answers on the designs' train split, one row each
    preds = run / "feedback" / "preds_train.jsonl"
    wrong = _wrong(tiny_dataset, preds)
    rows = list(iter_rows(run / "feedback" / "data", "train"))
    assert wrong and len(wrong) < 6  # some wrong, some right
    assert {r["step_id"]: r["pose_messages"][2]["content"][0]["text"] for r in rows} == wrong
    report = json.loads((run / "report.json").read_text())
    assert report["feedback"]["reasons"]["built"] == len(wrong) == report["feedback"]["total"]["steps"]
    assert sum(report["feedback"]["reasons"].values()) == 6
    # ... and those answers are stage 1's final model's: asked again, it answers the same
    config = RecipeConfig.from_dict(json.loads((run / "recipe_config.json").read_text()))
    again = tmp_path / "again.jsonl"
    write_predictions(tiny_dataset, trained_predictor(s1 / "final", config.train, torch.device("cpu")), again,
                      split="train", tasks=("pose",), limit=1)
    first = {r["id"]: r["text"] for r in map(json.loads, preds.read_text().splitlines())}
    assert all(first[r["id"]] == r["text"] for r in map(json.loads, again.read_text().splitlines()))

    # each stage starts from the previous stage's final weights, on its own mix of folders
    c1, c2, c3 = (TrainConfig.load(s) for s in (s1, s2, s3))
    assert c1.data == (str(tiny_dataset),) and c1.model is None and c1.steps == 100
    fb = str(run / "feedback" / "data")
    assert (c2.data, c2.weights, c2.model) == ((str(tiny_dataset), fb), (1.0, 1.0), str(s1 / "final"))
    assert (c3.data, c3.weights, c3.model) == ((str(tiny_dataset), fb, str(synthetic)), (1.0, 1.0, 1.0),
                                               str(s2 / "final"))
    assert train_log(s2)[0]["loss"] < train_log(s1)[0]["loss"] / 4  # stage 2 starts trained, not from scratch

    # metrics before and after every stage on both test splits; a stage's "before" is the last one's "after"
    stages = report["stages"]
    assert [(s["stage"], s["status"]) for s in stages] == [(1, "trained"), (2, "trained"), (3, "trained")]
    for s in stages:
        assert set(s["metrics"]) == {"designs", "synthetic"}
        for m in s["metrics"].values():
            assert m["before"]["paper"]["counts"]["steps"] == 1 and "strict" in m["after"]
    for a, b in zip(stages, stages[1:]):
        assert b["metrics"]["designs"]["before"] == a["metrics"]["designs"]["after"]
        assert b["model_before"] == a["model_after"]
    md = (run / "report.md").read_text()
    assert md.count("| 3 + synthetic experience | trained | synthetic |") == 2 and not any(
        "selection" in line for line in md.splitlines() if line.startswith("|"))  # pose only: no selection column

    # re-run: every stage is done, nothing is trained or predicted again
    kept = {p: p.stat().st_mtime_ns for d in (s1, s2, s3, run / "eval", run / "feedback") for p in d.rglob("*")
            if p.is_file() and p.suffix in (".safetensors", ".jsonl", ".parquet") and p.parent.name != "meta"}
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert all(f"stage {k}/3 ({n}): done" in out for k, n in ((1, "designer supervision"), (2, "+ world feedback"),
                                                               (3, "+ synthetic experience")))
    assert "evaluating" not in out, out
    assert {p: p.stat().st_mtime_ns for p in kept} == kept

    # stage 3 killed after its step 4 was logged, before its checkpoint: the re-run resumes it from step 2
    uninterrupted, log_before = load_file(str(s3 / "final" / "model.safetensors")), train_log(s3)
    shutil.rmtree(s3 / "checkpoint-000004")
    shutil.rmtree(s3 / "final")
    (s3 / "last").write_text("checkpoint-000004\n")
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "stage 2/3 (+ world feedback): done" in out and "stage 3/3 (+ synthetic experience): 4 steps" in out
    assert_resumed_run_is_the_same(s3, log_before, uninterrupted)

    # other settings are refused, naming them
    assert main(_argv(tiny_dataset, synthetic, run, "100,2,6")) == 2
    assert "stage_steps: [100, 2, 4] -> [100, 2, 6]" in capsys.readouterr().err


@pytest.mark.slow
def test_no_wrong_answer_skips_stage_2_and_bad_inputs_are_named(tiny_dataset, synthetic, tmp_path, capsys):
    """A stage-1 model of one step answers nothing that parses: no feedback rows, stage 2 is
    skipped (said so), stage 3 trains on the designs and the synthetic data from stage 1."""
    from train.config import TrainConfig
    from train.recipe import main

    run = tmp_path / "run"
    argv = [*_argv(tiny_dataset, synthetic, run, "1,1,1"), "--max-new-tokens", "8", "--feedback-limit", "2"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "0 world-feedback rows" in out and "stage 2/3 (+ world feedback) skipped: stage 1's model gave no wrong" in out
    report = json.loads((run / "report.json").read_text())
    assert report["feedback"]["reasons"] == {"missing": 4, "unparseable": 2}
    assert [s["status"] for s in report["stages"]] == ["trained", "skipped", "trained"]
    c3 = TrainConfig.load(run / "stage3")
    assert c3.data == (str(tiny_dataset), str(synthetic)) and c3.model == str(run / "stage1" / "final")
    assert not (run / "stage2").exists()

    assert main(_argv(tmp_path / "none", synthetic, tmp_path / "r2")) == 2
    assert "--designs" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert main(_argv(tiny_dataset, tmp_path / "empty", tmp_path / "r3")) == 2
    assert "--synthetic" in capsys.readouterr().err and not (tmp_path / "r3").exists()


@pytest.mark.parametrize("text, step", [('{"step": 12}', 12), ('{"step": null}', None), ("[12]", None),
                                        ('{"steps": 12}', None), ("{", None), (None, None)])
def test_final_step_reads_a_final_folder_and_takes_a_damaged_one_as_unfinished(tmp_path, text, step):
    """`train.loop.final_step`: the step a stage's `final/` was trained to; a missing or damaged
    final.json (a null step, not an object, cut short) reads as no step, so the stage trains
    again instead of the recipe stopping with a TypeError."""
    from train.loop import final_step

    if text is not None:
        (tmp_path / "final.json").write_text(text)
    assert final_step(tmp_path) == step
